"""Command line: mesh a curved domain on an equilateral background and write mesh files."""

from __future__ import annotations

import argparse
import ast
import json
import math
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from .boundaries import Boundary

__all__ = ["ArgumentError", "build_parser", "main", "make_boundary", "polar_functions", "run"]

PROG = "dolfinx-universal"
MAPS = ("I", "I~", "G", "G~")

Float = npt.NDArray[np.float64]


class ArgumentError(ValueError):
    """A bad command-line argument (exit status 2)."""


class _Parser(argparse.ArgumentParser):
    """Argument parser that raises :class:`ArgumentError` and prints help on rank 0 only."""

    def error(self, message: str) -> NoReturn:
        raise ArgumentError(message)

    def _print_message(self, message: str, file: Any = None) -> None:
        if MPI.COMM_WORLD.rank == 0:
            super()._print_message(message, file)


class _Formatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows ``(default: ...)`` only for options with a meaningful default."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None or action.default is False or "[default" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


# --------------------------------------------------------------------------------------------
# Polar curves from expressions
# --------------------------------------------------------------------------------------------

_NAMESPACE: dict[str, Any] = {
    "np": np,
    "pi": np.pi,
    "sin": np.sin,
    "cos": np.cos,
    "tan": np.tan,
    "exp": np.exp,
    "log": np.log,
    "sqrt": np.sqrt,
    "sinh": np.sinh,
    "cosh": np.cosh,
    "tanh": np.tanh,
    "arctan": np.arctan,
}
_NODES = (
    ast.Expression,
    ast.BinOp,
    ast.UnaryOp,
    ast.Call,
    ast.Name,
    ast.Attribute,
    ast.Constant,
    ast.Load,
    ast.operator,
    ast.unaryop,
)
_COMPLEX_STEP = 1e-20
_FD_STEP = 1e-3


def _compile_expression(expr: str) -> Callable[[npt.ArrayLike], npt.NDArray]:
    """Compile a restricted numpy expression in ``theta`` into a vectorised function."""
    try:
        tree = ast.parse(expr.strip(), mode="eval")
    except SyntaxError as e:
        raise ArgumentError(f"invalid polar expression {expr!r}: {e.msg}") from None
    for node in ast.walk(tree):
        if not isinstance(node, _NODES):
            raise ArgumentError(
                f"invalid polar expression {expr!r}: {type(node).__name__} is not allowed"
            )
        if isinstance(node, ast.Name) and node.id != "theta" and node.id not in _NAMESPACE:
            raise ArgumentError(
                f"invalid polar expression {expr!r}: unknown name {node.id!r} (use theta, "
                f"{', '.join(sorted(_NAMESPACE))})"
            )
        if isinstance(node, ast.Attribute) and (
            node.attr.startswith("_")
            or not isinstance(node.value, ast.Name)
            or node.value.id != "np"
        ):
            raise ArgumentError(
                f"invalid polar expression {expr!r}: only np.<function> attributes are allowed"
            )
        if isinstance(node, ast.Constant) and not isinstance(node.value, int | float | complex):
            raise ArgumentError(f"invalid polar expression {expr!r}: non-numeric constant")
    code = compile(tree, "<polar>", "eval")

    def f(theta: npt.ArrayLike) -> npt.NDArray:
        theta = np.asarray(theta)
        with np.errstate(all="ignore"):
            value = eval(code, {"__builtins__": {}}, {**_NAMESPACE, "theta": theta})
        return np.broadcast_to(np.asarray(value), theta.shape)

    return f


def polar_functions(
    expr: str,
) -> tuple[Callable[[Float], Float], Callable[[Float], Float], Callable[[Float], Float], str]:
    """``r(theta)``, ``r'(theta)``, ``r''(theta)`` of a polar curve given as an expression.

    The expression may use ``theta``, ``np`` and ``pi, sin, cos, tan, exp, log, sqrt, sinh,
    cosh, tanh, arctan`` (numpy functions); no other names, attributes of ``np`` only.

    Derivatives are computed by the complex step, ``r' = Im r(theta + i t) / t`` with
    ``t = 1e-20`` (exact to rounding for expressions analytic in ``theta``), and ``r''`` by
    the fourth-order central difference of that ``r'`` with step ``1e-3`` (error ~1e-12).
    Expressions that do not accept complex input (or are not analytic) fall back to
    fourth-order central differences for both (step ``1e-3``: errors ~1e-12 for ``r'`` and
    ~1e-10 for ``r''``).

    Returns
    -------
    r, dr, d2r
        Vectorised functions of ``theta``.
    method
        ``"complex-step"`` or ``"finite-difference"``.

    Raises
    ------
    ArgumentError
        If the expression is invalid, not finite, not positive or not ``2 pi``-periodic.
    """
    f = _compile_expression(expr)
    theta = np.linspace(0.0, 2.0 * np.pi, 1025)

    def r(t: Float) -> Float:
        return np.real(f(np.asarray(t, dtype=np.float64))).astype(np.float64)

    try:
        values = r(theta)
    except Exception as e:  # any error of the user's expression is an argument error
        raise ArgumentError(f"cannot evaluate polar expression {expr!r}: {e}") from None
    if not np.all(np.isfinite(values)):
        raise ArgumentError(f"polar expression {expr!r} is not finite for all theta")
    if values.min() <= 0:
        raise ArgumentError(
            f"polar expression {expr!r} must be positive: r = {values.min():.4g} at theta = "
            f"{theta[np.argmin(values)]:.4g}"
        )

    def fd(g: Callable[[Float], Float], t: Float) -> Float:
        d = _FD_STEP
        return (-g(t + 2 * d) + 8 * g(t + d) - 8 * g(t - d) + g(t - 2 * d)) / (12 * d)

    def dr_fd(t: Float) -> Float:
        return fd(r, np.asarray(t, dtype=np.float64))

    def d2r_fd(t: Float) -> Float:
        t = np.asarray(t, dtype=np.float64)
        d = _FD_STEP
        return (-r(t + 2 * d) + 16 * r(t + d) - 30 * r(t) + 16 * r(t - d) - r(t - 2 * d)) / (
            12 * d * d
        )

    def dr_cs(t: Float) -> Float:
        t = np.asarray(t, dtype=np.float64)
        return np.asarray(np.imag(f(t + 1j * _COMPLEX_STEP)), dtype=np.float64) / _COMPLEX_STEP

    def d2r_cs(t: Float) -> Float:
        return fd(dr_cs, np.asarray(t, dtype=np.float64))

    dr, d2r, method = dr_fd, d2r_fd, "finite-difference"
    try:
        with np.errstate(all="ignore"):
            z = f(theta + 1j * _COMPLEX_STEP)
            ok = np.iscomplexobj(z) and bool(np.all(np.isfinite(z)))
            if ok:
                ok = np.allclose(np.real(z), values, rtol=1e-12, atol=1e-14)
            if ok:
                scale = max(float(np.abs(dr_fd(theta)).max()), float(values.max()))
                ok = float(np.abs(dr_cs(theta) - dr_fd(theta)).max()) <= 1e-6 * scale
    except Exception:  # not complex-safe: keep finite differences
        ok = False
    if ok:
        dr, d2r, method = dr_cs, d2r_cs, "complex-step"

    scale = float(values.max())
    if (
        abs(values[0] - values[-1]) > 1e-9 * scale
        or abs(float(dr(theta[:1])[0]) - float(dr(theta[-1:])[0])) > 1e-6 * scale
    ):
        raise ArgumentError(f"polar expression {expr!r} is not 2*pi-periodic in theta")
    return r, dr, d2r, method


# --------------------------------------------------------------------------------------------
# Arguments
# --------------------------------------------------------------------------------------------


def _version() -> str:
    import dolfinx

    from . import __version__

    return f"{__version__} (DOLFINx {dolfinx.__version__})"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``dolfinx-universal`` / ``python -m dolfinx_universal``."""
    p = _Parser(
        prog=PROG,
        description=(
            "Mesh the domain bounded by a closed curve with a universal mesh (Rangarajan & "
            "Lew 2014): a background triangulation of the curve's bounding box, graded "
            "automatically from the curve's curvature and feature sizes (or equilateral with "
            "--uniform), is conformed to the curve by snapping the vertices of the positive "
            "edges onto it and relaxing nearby interior vertices (no vertex added); where a "
            "validity check fails the background is refined there and the curve meshed "
            "again. Optionally the cells along the curve are curved (degree-K Lagrange "
            "geometry). Writes mesh.vtkhdf + mesh.tags.npz (a checkpoint for any degree: "
            "dolfinx_universal.io.read_mesh reads it back with its facet tags; ParaView "
            "reads the .vtkhdf), mesh.bp (VTX), mesh.xdmf (grids 'mesh' and 'facet_tags': 1 = "
            "immersed boundary, 2 = outer; K <= 2 only), mesh.png and summary.json (with the "
            "validity certificate). Lengths are in the units of the curve's coordinates. "
            "Runs under mpirun (only rank 0 prints and plots)."
        ),
        formatter_class=_Formatter,
    )
    shape = p.add_argument_group("shape (exactly one)")
    g = shape.add_mutually_exclusive_group(required=True)
    g.add_argument("--circle", type=float, metavar="R", help="circle of radius R")
    g.add_argument(
        "--ellipse", type=float, nargs=2, metavar=("A", "B"), help="ellipse of semi-axes A, B"
    )
    g.add_argument(
        "--polar",
        metavar="EXPR",
        help=(
            "star-shaped curve r(theta) around the center, a numpy expression in theta "
            "using np, pi, sin, cos, tan, exp, log, sqrt, sinh, cosh, tanh, arctan, e.g. "
            "'1 + 0.2*cos(3*theta)'; r' by complex step, r'' by 4th-order differences of r' "
            "(finite differences when the expression is not complex-safe)"
        ),
    )
    g.add_argument(
        "--spline",
        metavar="FILE",
        type=Path,
        help="closed periodic cubic spline through the points of a CSV (x,y per line) or JSON file",
    )
    shape.add_argument(
        "--center",
        type=float,
        nargs=2,
        default=(0.0, 0.0),
        metavar=("X", "Y"),
        help="center of the circle, ellipse or polar curve",
    )
    shape.add_argument(
        "--angle",
        type=float,
        default=0.0,
        metavar="DEG",
        help="rotation of the ellipse's A axis from the x axis, in degrees",
    )
    m = p.add_argument_group("meshing")
    m.add_argument(
        "--h",
        type=float,
        default=None,
        metavar="H",
        help="largest mesh size (length units): the background is graded from the curve's "
        "curvature and feature sizes up to H and refined where a check fails; with "
        "--uniform, the edge length of the equilateral background [default: 1/10 (graded) "
        "or 1/20 (--uniform) of the larger side of the shape's bounding box, to 3 digits]",
    )
    m.add_argument(
        "--uniform",
        action="store_true",
        help="use one equilateral background of edge H instead of the automatically sized "
        "graded one (fails with an error where H is too coarse for the curve)",
    )
    m.add_argument(
        "--min-angle",
        type=float,
        default=10.0,
        metavar="DEG",
        help="quality floor: smallest angle of the conforming triangles (graded mode refines "
        "below it; --uniform warns)",
    )
    m.add_argument(
        "--margin",
        type=float,
        default=None,
        metavar="M",
        help="the background covers the shape's bounding box enlarged by M on each side "
        "(length units); must leave a layer of cells between the shape and the background's "
        "boundary [default: (RR + 1) * h, so that the relaxation zone R_r fits]",
    )
    m.add_argument(
        "--rr",
        type=float,
        default=3.0,
        metavar="RR",
        help="relaxation radius R_r in units of h (R_r = RR * h, RR > 1)",
    )
    m.add_argument(
        "--alpha",
        type=float,
        default=None,
        help="relaxation factor in [(1 + 1/RR)^-1, 1] [default: (1 + h/R_r)^-1]",
    )
    m.add_argument(
        "--eta",
        type=float,
        default=0.2,
        help="quality perturbation threshold in [0, 1) (0 disables relocation of inside "
        "vertices too close to the curve)",
    )
    m.add_argument(
        "--degree",
        type=int,
        default=1,
        metavar="K",
        help="geometry degree; K > 1 curves the cells along the curve",
    )
    m.add_argument(
        "--map",
        choices=MAPS,
        default="I",
        help="curved map for K > 1: I / G interpolate the blend G_h from the background "
        "edges, I~ / G~ the blend G~_h through the straight conforming mesh",
    )
    o = p.add_argument_group("output")
    o.add_argument(
        "--out",
        type=Path,
        default=Path("universal_mesh_out"),
        metavar="DIR",
        help="output directory (created if needed)",
    )
    o.add_argument("--no-plot", action="store_true", help="do not write mesh.png")
    o.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    return p


def _positive(name: str, value: float | None) -> None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise ArgumentError(f"{name} must be a positive number, got {value}")


def make_boundary(args: argparse.Namespace) -> tuple[Boundary, dict[str, Any]]:
    """The boundary curve chosen by the shape arguments, and a JSON description of it.

    Raises
    ------
    ArgumentError
        For invalid shape parameters or an unreadable spline file.
    """
    from .boundaries import Circle, Ellipse, PeriodicSpline, PolarCurve

    center = np.asarray(args.center, dtype=np.float64)
    if not np.all(np.isfinite(center)):
        raise ArgumentError(f"--center must be finite, got {list(args.center)}")
    if args.circle is not None:
        _positive("--circle R", args.circle)
        desc = {"type": "circle", "radius": args.circle, "center": center.tolist()}
        return Circle(center, args.circle), desc
    if args.ellipse is not None:
        a, b = args.ellipse
        _positive("--ellipse A", a)
        _positive("--ellipse B", b)
        if not math.isfinite(args.angle):
            raise ArgumentError(f"--angle must be finite, got {args.angle}")
        desc = {
            "type": "ellipse",
            "semi_axes": [a, b],
            "center": center.tolist(),
            "angle_deg": args.angle,
        }
        return Ellipse(center, a, b, angle=math.radians(args.angle)), desc
    if args.polar is not None:
        r, dr, d2r, method = polar_functions(args.polar)
        desc = {
            "type": "polar",
            "expression": args.polar,
            "center": center.tolist(),
            "derivatives": method,
        }
        return PolarCurve(r, dr, d2r, center), desc
    path = Path(args.spline)
    if not path.is_file():
        why = "not a regular file" if path.exists() else "no such file"
        raise ArgumentError(f"--spline: cannot read {str(path)!r}: {why}")
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            boundary = PeriodicSpline.from_file(path)
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, IndexError) as e:
        raise ArgumentError(f"--spline {str(path)!r}: {_one_line(str(e))}") from None
    if MPI.COMM_WORLD.rank == 0:
        for w in caught:
            print(f"{PROG}: warning: {_one_line(str(w.message))}", file=sys.stderr)
    desc = {"type": "spline", "file": str(path.resolve()), "n_points": len(boundary.points)}
    return boundary, desc


def _check_numbers(args: argparse.Namespace) -> None:
    """Range checks of the meshing arguments that do not depend on the shape."""
    _positive("--h", args.h)
    _positive("--margin", args.margin)
    if not (math.isfinite(args.rr) and args.rr > 1):
        raise ArgumentError(f"--rr must exceed 1 (R_r > h), got {args.rr}")
    if not (math.isfinite(args.eta) and 0 <= args.eta < 1):
        raise ArgumentError(f"--eta must lie in [0, 1), got {args.eta}")
    if args.alpha is not None:
        lo = 1.0 / (1.0 + 1.0 / args.rr)
        if not (math.isfinite(args.alpha) and lo - 1e-12 <= args.alpha <= 1.0):
            raise ArgumentError(
                f"--alpha must lie in [(1 + 1/rr)^-1, 1] = [{lo:.4g}, 1], got {args.alpha}"
            )
    if args.degree < 1:
        raise ArgumentError(f"--degree must be >= 1, got {args.degree}")
    if not (math.isfinite(args.min_angle) and 0 <= args.min_angle < 60):
        raise ArgumentError(f"--min-angle must lie in [0, 60) degrees, got {args.min_angle}")
    if args.alpha is not None and not args.uniform:
        raise ArgumentError(
            "--alpha applies to --uniform only (graded backgrounds use the "
            "local default (1 + h/R_r)^-1)"
        )


# --------------------------------------------------------------------------------------------
# Meshing and output
# --------------------------------------------------------------------------------------------


def _json_safe(value: Any) -> Any:
    """Plain-Python, strict-JSON version of a value (non-finite floats become ``None``)."""
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return _json_safe(value.tolist())
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    return value


def run(args: argparse.Namespace, comm: MPI.Comm = MPI.COMM_WORLD) -> dict[str, Any]:
    """Mesh the domain described by parsed arguments and write the outputs (collective).

    Returns
    -------
    The summary written to ``summary.json`` (on every rank).

    Raises
    ------
    ArgumentError
        Bad arguments.
    MeshingError
        When the domain cannot be meshed with these parameters.
    """
    import dolfinx
    from dolfinx import io

    from .background import equilateral_mesh
    from .conform import IMMERSED, OUTER, conform
    from .curved import curved_mesh
    from .demo_support import versions
    from .domain import default_box, mesh_domain
    from .io import tags_path, write_mesh
    from .quality import quality_report
    from .validation import MeshingError

    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    _check_numbers(args)
    boundary, shape = make_boundary(args)
    bbox = np.asarray(boundary.bounding_box(), dtype=np.float64).reshape(2, 2)
    extent = float((bbox[1] - bbox[0]).max())
    if not (np.all(np.isfinite(bbox)) and extent > 0):
        raise ArgumentError(f"the shape has an empty or invalid bounding box {bbox.tolist()}")
    far = float(np.abs(bbox).max())
    if far > 1e8 * extent:  # float64 keeps 16 digits: fewer than 8 would be left for h
        raise ArgumentError(
            f"the shape (extent {extent:.3g}) lies {far:.3g} from the origin: float64 "
            "coordinates would keep too few digits to mesh it; move it near the origin "
            "(e.g. --center 0 0) and shift the mesh afterwards"
        )
    out = Path(args.out)
    _prepare_out(comm, out)
    plot = not args.no_plot and _have_matplotlib(comm)
    divisor = 20.0 if args.uniform else 10.0
    h = float(f"{extent / divisor:.3g}") if args.h is None else float(args.h)
    margin = (args.rr + 1.0) * h if args.margin is None else float(args.margin)
    if args.uniform or args.margin is not None:
        box = np.array([bbox[0] - margin, bbox[1] + margin])
    else:
        box = default_box(boundary, h, args.rr)
        margin = float(bbox[0, 0] - box[0, 0])
    size = box[1] - box[0]
    n_estimate = 2.0 * (size[0] / h + 2) * (size[1] / (h * math.sqrt(3) / 2) + 2)
    if n_estimate > 5e7:
        raise ArgumentError(
            f"--h {h:.4g} would give ~{n_estimate:.3g} background cells; use a larger h"
        )

    certificate = None
    curved_info: dict[str, Any] = {}
    t = time.perf_counter()
    try:
        if args.uniform:
            background = equilateral_mesh(comm, box.tolist(), h)
            timings["background"] = time.perf_counter() - t
            t = time.perf_counter()
            cm = conform(
                background,
                boundary,
                alpha=args.alpha,
                eta=args.eta,
                relaxation_factor=args.rr,
                min_angle=args.min_angle,
            )
            timings["conform"] = time.perf_counter() - t
            msh, tags = cm.mesh, cm.facet_tags
            if args.degree > 1:
                t = time.perf_counter()
                curved = curved_mesh(cm, args.degree, args.map)
                msh, tags = curved.mesh, curved.facet_tags
                curved_info["min_jacobian_ratio"] = float(curved.min_jacobian_ratio)
                timings["curved"] = time.perf_counter() - t
        else:
            md = mesh_domain(
                comm,
                boundary,
                h,
                degree=args.degree,
                map=args.map,
                box=box if args.margin is not None else None,
                eta=args.eta,
                relaxation_factor=args.rr,
                min_angle=args.min_angle,
            )
            cm, msh, tags, background = md.conforming, md.mesh, md.facet_tags, md.background
            certificate = md.certificate
            for stage, seconds in md.timings.items():
                if stage != "total":
                    timings[stage] = seconds
            if md.curved is not None:
                curved_info["min_jacobian_ratio"] = float(md.curved.min_jacobian_ratio)
    except ValueError as e:  # parameter checks (collective)
        if isinstance(e, MeshingError):
            raise
        raise ArgumentError(str(e)) from None
    if cm.mesh.topology.index_map(2).size_global == 0:  # same verdict on every rank
        raise MeshingError(
            f"no background vertex lies inside the domain: h = {h:.4g} is too coarse for a "
            f"shape of extent {extent:.4g}; use a smaller --h"
        )
    for stage, seconds in cm.timings.items():
        timings[f"conform.{stage}"] = seconds

    t = time.perf_counter()
    quality = quality_report(cm)
    timings["quality"] = time.perf_counter() - t

    # Output files.
    t = time.perf_counter()
    write_mesh(out / "mesh.vtkhdf", msh, tags)  # a checkpoint for any degree, with its tags
    files = ["mesh.vtkhdf", tags_path(out / "mesh.vtkhdf").name]
    with io.VTXWriter(comm, out / "mesh.bp", msh, engine="BPFile") as vtx:
        vtx.write(0.0)
    files.append("mesh.bp")
    if args.degree <= 2:
        with io.XDMFFile(comm, out / "mesh.xdmf", "w") as xdmf:
            xdmf.write_mesh(msh)
            tags.name = "facet_tags"
            xdmf.write_meshtags(tags, msh.geometry)
        files += ["mesh.xdmf", "mesh.h5"]
    elif comm.rank == 0:  # XDMF cannot hold degree >= 3: drop stale files of earlier runs
        for name in ("mesh.xdmf", "mesh.h5"):
            (out / name).unlink(missing_ok=True)
    timings["write"] = time.perf_counter() - t

    if plot:
        t = time.perf_counter()
        from .plotting import plot_conforming, save

        fig, _ = plot_conforming(None, cm, mesh=msh, title=_title(shape, h, args))
        save(fig, out / "mesh.png")
        files.append("mesh.png")
        timings["plot"] = time.perf_counter() - t

    # Global counts.
    nfo = msh.topology.index_map(1).size_local
    owned = tags.indices < nfo
    facets = {
        "immersed": comm.allreduce(int((tags.values[owned] == IMMERSED).sum())),
        "outer": comm.allreduce(int((tags.values[owned] == OUTER).sum())),
    }
    n_vertices = msh.topology.index_map(0).size_global
    timings = {k: comm.allreduce(v, op=MPI.MAX) for k, v in timings.items()}
    timings["total"] = comm.allreduce(time.perf_counter() - t_start, op=MPI.MAX)
    files.append("summary.json")
    summary = {
        "shape": shape,
        "bounding_box": bbox.tolist(),
        "background_box": box.tolist(),
        "h": h,
        "margin": margin,
        "rr": args.rr,
        "R_r": args.rr * h,
        "alpha": cm.alpha,
        "eta": cm.eta,
        "degree": args.degree,
        "map": args.map if args.degree > 1 else None,
        "n_background_cells": background.topology.index_map(2).size_global,
        "n_cells": int(quality["n_cells"]),
        "n_vertices": n_vertices,
        "n_geometry_nodes": msh.geometry.index_map().size_global,
        "n_relocated": cm.num_relocated,
        "facets": {"tags": {"immersed": IMMERSED, "outer": OUTER}, "counts": facets},
        "quality": quality,
        **({"curved": curved_info} if curved_info else {}),
        "background": "equilateral" if args.uniform else "graded (mesh_domain)",
        "certificate": certificate.as_dict() if certificate is not None else None,
        "mpi_size": comm.size,
        "dolfinx_version": dolfinx.__version__,
        "versions": versions(),
        "files": files,
        "timings_s": timings,
    }
    summary = _json_safe(summary)
    summary["certificate_text"] = str(certificate) if certificate is not None else None
    if comm.rank == 0:
        with open(out / "summary.json", "w") as fh:
            json.dump(summary, fh, indent=2, allow_nan=False)
            fh.write("\n")
    comm.barrier()
    return summary


def _prepare_out(comm: MPI.Comm, out: Path) -> None:
    """Create the output folder on rank 0; a failure is an ArgumentError on every rank."""
    error = None
    if comm.rank == 0:
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            error = f"--out {str(out)!r}: cannot create the output folder: {e.strerror or e}"
    error = comm.bcast(error, root=0)
    if error is not None:
        raise ArgumentError(error)


def _have_matplotlib(comm: MPI.Comm) -> bool:
    """Whether matplotlib is importable (rank 0 decides; rank 0 warns when it is not)."""
    import importlib.util

    ok = comm.bcast(importlib.util.find_spec("matplotlib") is not None, root=0)
    if not ok and comm.rank == 0:
        print(
            f"{PROG}: warning: matplotlib is not installed, mesh.png is not written "
            "(pip install dolfinx_universal[plot])",
            file=sys.stderr,
            flush=True,
        )
    return ok


def _title(shape: dict[str, Any], h: float, args: argparse.Namespace) -> str:
    kind = shape["type"]
    deg = f", degree {args.degree} ({args.map})" if args.degree > 1 else ""
    return f"universal mesh: {kind}, h = {h:.3g}{deg}"


def _one_line(message: str) -> str:
    return "; ".join(line.strip() for line in str(message).splitlines() if line.strip())


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line (``python -m dolfinx_universal`` / ``dolfinx-universal``).

    Parameters
    ----------
    argv
        Arguments without the program name (default ``sys.argv[1:]``).

    Returns
    -------
    Exit status: 0 on success (and for ``--help``), 2 for bad arguments, 1 when the domain
    cannot be meshed. Errors are reported as one line ``dolfinx-universal: error: ...`` on
    standard error (rank 0 only), without a traceback.
    """
    from .validation import MeshingError

    comm = MPI.COMM_WORLD
    parser = build_parser()

    def fail(message: str, status: int) -> int:
        if comm.rank == 0:
            print(f"{PROG}: error: {_one_line(message)}", file=sys.stderr, flush=True)
        return status

    try:
        args = parser.parse_args(None if argv is None else list(argv))
    except ArgumentError as e:
        return fail(str(e), 2)
    except SystemExit as e:  # --help
        return int(e.code or 0) if not isinstance(e.code, str) else 2
    try:
        summary = run(args, comm)
    except ArgumentError as e:
        return fail(str(e), 2)
    except MeshingError as e:
        return fail(str(e), 1)
    if comm.rank == 0 and not args.quiet:
        q = summary["quality"]
        print(
            f"{summary['n_cells']} cells ({q['n_positively_cut']} positively cut, "
            f"{q['percent_unaltered']:.1f}% unaltered), angles in "
            f"[{q['theta_min_deg']:.1f}, {q['theta_max_deg']:.1f}] degrees, h = "
            f"{summary['h']:.4g}; wrote {', '.join(summary['files'])} to {args.out}",
            flush=True,
        )
        if summary["certificate"] is not None:
            print(summary["certificate_text"], flush=True)
    return 0
