"""Command line: mesh a curved 2D domain or a solid bounded by a surface and write mesh files."""

from __future__ import annotations

import argparse
import ast
import importlib.util
import json
import math
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple, NoReturn

from mpi4py import MPI

import dolfinx
import numpy as np
import numpy.typing as npt
from dolfinx import mesh as dmesh
from dolfinx.io import VTXWriter, XDMFFile

from dolfinx_universal import __version__
from dolfinx_universal.backgrounds.lattice_tet import a15_mesh
from dolfinx_universal.backgrounds.lattice_tri import equilateral_mesh
from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.boundaries.curves import Circle, Ellipse, PeriodicSpline, PolarCurve
from dolfinx_universal.boundaries.surfaces import Ellipsoid, ImplicitSurface, Sphere, Torus
from dolfinx_universal.boundaries.topology import grid_topology
from dolfinx_universal.conforming.quality import quality_report
from dolfinx_universal.conforming.universal import IMMERSED, OUTER, ConformingMesh, conform
from dolfinx_universal.core.arrays import Float
from dolfinx_universal.core.collective import MeshingError
from dolfinx_universal.curved.maps import MAPS, curved_mesh
from dolfinx_universal.demo_support import versions
from dolfinx_universal.io import tags_path, write_mesh
from dolfinx_universal.meshing.domain import DEFAULT_MAP, default_box, mesh_domain

__all__ = [
    "ArgumentError",
    "ImplicitFunctions",
    "build_parser",
    "grid_topology",
    "implicit_functions",
    "main",
    "make_boundary",
    "polar_functions",
    "run",
]

PROG = "dolfinx-universal"


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
    g = _compile_in(expr, ("theta",), "polar")

    def f(theta: npt.ArrayLike) -> npt.NDArray:
        return g(np.asarray(theta))

    return f


def _compile_in(expr: str, variables: tuple[str, ...], what: str) -> Callable[..., npt.NDArray]:
    """Compile a restricted numpy expression in ``variables`` into a vectorised function of
    as many arrays (of one shape, the shape of the result)."""
    try:
        tree = ast.parse(expr.strip(), mode="eval")
    except SyntaxError as e:
        raise ArgumentError(f"invalid {what} expression {expr!r}: {e.msg}") from None
    for node in ast.walk(tree):
        if not isinstance(node, _NODES):
            raise ArgumentError(
                f"invalid {what} expression {expr!r}: {type(node).__name__} is not allowed"
            )
        if isinstance(node, ast.Name) and node.id not in variables and node.id not in _NAMESPACE:
            raise ArgumentError(
                f"invalid {what} expression {expr!r}: unknown name {node.id!r} (use "
                f"{', '.join(variables)}, {', '.join(sorted(_NAMESPACE))})"
            )
        if isinstance(node, ast.Attribute) and (
            node.attr.startswith("_")
            or not isinstance(node.value, ast.Name)
            or node.value.id != "np"
        ):
            raise ArgumentError(
                f"invalid {what} expression {expr!r}: only np.<function> attributes are allowed"
            )
        if isinstance(node, ast.Constant) and not isinstance(node.value, int | float | complex):
            raise ArgumentError(f"invalid {what} expression {expr!r}: non-numeric constant")
    code = compile(tree, f"<{what}>", "eval")

    def f(*args: npt.NDArray) -> npt.NDArray:
        with np.errstate(all="ignore"):
            value = eval(code, {"__builtins__": {}}, {**_NAMESPACE, **dict(zip(variables, args))})
        return np.broadcast_to(np.asarray(value), np.shape(args[0]))

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
# Implicit surfaces from expressions
# --------------------------------------------------------------------------------------------

_GRID = 64
"""Samples per side of the grids on which an implicit surface's bounding box is found."""
_HALF_WIDTHS = tuple(2.0**k for k in range(11)) + tuple(2.0**-k for k in range(1, 11))
"""Half-widths of the cubes around the centre searched for the inside of an implicit
surface, in this order."""
_IMPLICIT_FD_STEP = 1e-3
"""Step of the central differences of ``phi``, relative to the longest side of its box."""


def _grid(box: Float, n: int = _GRID) -> tuple[Float, float]:
    """Points ``(n^3, 3)`` of a regular grid over ``box`` (its faces included) and its spacing."""
    axes = [np.linspace(box[0, i], box[1, i], n) for i in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return pts, float(np.max((box[1] - box[0]) / (n - 1)))


def _on_grid_boundary(n: int = _GRID) -> npt.NDArray[np.bool_]:
    """Mask of the grid points of :func:`_grid` on the faces of its box, ``(n^3,)``."""
    i = np.indices((n, n, n)).reshape(3, -1)
    return ((i == 0) | (i == n - 1)).any(axis=0)


class ImplicitFunctions(NamedTuple):
    """What :func:`implicit_functions` derives from an expression."""

    phi: Callable[[Float], Float]
    """Level-set function of points ``(n, 3)``, ``(n,)``."""
    grad: Callable[[Float], Float]
    """Its gradient, ``(n, 3)``."""
    box: Float
    """``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` containing the surface."""
    gradient: str
    """``"complex-step"`` or ``"finite-difference"``."""


def implicit_functions(
    expr: str, center: npt.ArrayLike, box: npt.ArrayLike | None = None
) -> ImplicitFunctions:
    """``phi``, ``grad phi`` and a bounding box of the surface ``phi = 0`` of an expression.

    The expression may use ``x, y, z`` (coordinates relative to ``center``), ``np`` and
    ``pi, sin, cos, tan, exp, log, sqrt, sinh, cosh, tanh, arctan``; ``phi < 0`` inside
    the solid, ``phi > 0`` outside.

    The gradient is computed by the complex step, ``d phi / dx_i = Im phi(p + i t e_i) / t``
    with ``t = 1e-20`` (exact to rounding for expressions analytic in ``x, y, z``), after a
    check against fourth-order central differences near the surface; expressions that do
    not accept complex input (or are not analytic) use those differences, with a step of
    ``1e-3`` times the longest side of the box.

    The bounding box is ``box`` when given (absolute coordinates: ``phi`` must be negative
    somewhere on a grid of ``64^3`` points over it and positive on its faces). Otherwise
    ``phi`` is sampled on grids of ``64^3`` points over cubes of half-width ``2^k`` around
    the centre (``k = 0, 1, ..., 10``, then ``-1, ..., -10``) until the negative samples of
    one lie strictly inside it, then on a grid over the box of those samples padded by two
    spacings; the box is that of the negative samples of this second grid, padded by two of
    its spacings. Parts of the solid thinner than a spacing of the first grid (1/31 of the
    cube's half-width) may be missed: give ``box`` for such shapes. The number of
    components and the genus of the surface are the
    :class:`~dolfinx_universal.boundaries.surfaces.ImplicitSurface`'s (counted on its grid
    unless given).

    Returns
    -------
    The functions, the box and how the gradient is computed (:class:`ImplicitFunctions`).

    Raises
    ------
    ArgumentError
        If the expression is invalid or not finite, or no box with the surface inside is
        found (or ``box`` does not contain it).
    """
    f = _compile_in(expr, ("x", "y", "z"), "implicit")
    c = np.asarray(center, dtype=np.float64).reshape(3)

    def phi(p: Float) -> Float:
        p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        return np.real(f(p[:, 0] - c[0], p[:, 1] - c[1], p[:, 2] - c[2])).astype(np.float64)

    if box is not None:
        b, pts, values = _given_box(expr, phi, box)
    else:
        b, pts, values = _found_box(expr, phi, c)
    grad, gradient = _implicit_gradient(f, phi, c, b, pts, values)
    return ImplicitFunctions(phi, grad, b, gradient)


def _sample(expr: str, phi: Callable[[Float], Float], box: Float) -> tuple[Float, Float, float]:
    """The points of the grid of :func:`_grid` over ``box``, ``phi`` there and the spacing;
    an :class:`ArgumentError` where the expression fails or is not finite."""
    pts, spacing = _grid(box)
    try:
        values = phi(pts)
    except Exception as e:  # any error of the user's expression is an argument error
        raise ArgumentError(f"cannot evaluate implicit expression {expr!r}: {e}") from None
    bad = ~np.isfinite(values)
    if bad.any():
        q = pts[np.argmax(bad)]
        raise ArgumentError(
            f"implicit expression {expr!r} is not finite at ({q[0]:.4g}, {q[1]:.4g}, {q[2]:.4g})"
        )
    return pts, values, spacing


def _given_box(
    expr: str, phi: Callable[[Float], Float], box: npt.ArrayLike
) -> tuple[Float, Float, Float]:
    """``--box`` checked to hold the solid (``phi < 0`` at a grid point, ``phi > 0`` on its
    faces), with the grid's points and values of ``phi``."""
    b = np.asarray(box, dtype=np.float64).reshape(2, 3)
    if not (np.isfinite(b).all() and (b[1] > b[0]).all()):
        raise ArgumentError(
            f"--box must be X0 Y0 Z0 X1 Y1 Z1 with X0 < X1, Y0 < Y1, Z0 < Z1, got "
            f"{b.ravel().tolist()}"
        )
    pts, values, _ = _sample(expr, phi, b)
    if not (values < 0).any():
        raise ArgumentError(
            f"implicit expression {expr!r} has no negative value on a {_GRID}^3 grid in "
            "--box: the solid is phi < 0 (empty, or thinner than the grid: enlarge it)"
        )
    edge = _on_grid_boundary()
    if (values[edge] <= 0).any():
        q = pts[edge][np.argmin(values[edge])]
        raise ArgumentError(
            f"the implicit surface leaves --box near ({q[0]:.4g}, {q[1]:.4g}, "
            f"{q[2]:.4g}) (phi <= 0 on the box's faces): enlarge the box"
        )
    return b, pts, values


def _found_box(expr: str, phi: Callable[[Float], Float], c: Float) -> tuple[Float, Float, Float]:
    """The box of the solid found on the growing (then shrinking) cubes around the centre
    ``c`` (see :func:`implicit_functions`), with the last grid's points and values."""
    edge = _on_grid_boundary()
    found: Float | None = None
    for half in _HALF_WIDTHS:
        pts, values, spacing = _sample(expr, phi, np.array([c - half, c + half]))
        inside = values < 0
        if inside.any() and not inside[edge].any():
            found = np.array([pts[inside].min(axis=0), pts[inside].max(axis=0)])
            found += np.array([-2.0, 2.0])[:, None] * spacing
            break
    if found is None:
        raise ArgumentError(
            f"implicit expression {expr!r}: found no solid (phi < 0) strictly inside a cube "
            f"of half-width 2^-10 to 2^10 around the center {c.tolist()}: check the sign "
            "(negative inside) or give --box"
        )
    pts, values, spacing = _sample(expr, phi, found)
    inside = values < 0
    b = np.array([pts[inside].min(axis=0), pts[inside].max(axis=0)])
    b += np.array([-2.0, 2.0])[:, None] * spacing
    return b, pts, values


def _implicit_gradient(
    f: Callable[..., npt.NDArray],
    phi: Callable[[Float], Float],
    c: Float,
    b: Float,
    pts: Float,
    values: Float,
) -> tuple[Callable[[Float], Float], str]:
    """``grad phi`` by the complex step where the expression ``f`` (of coordinates relative
    to ``c``) takes it and it agrees with central differences at the grid points ``pts``
    nearest the surface (``values`` of ``phi`` there), else by those differences; and which
    (``"complex-step"`` or ``"finite-difference"``)."""
    step = _IMPLICIT_FD_STEP * float(np.max(b[1] - b[0]))
    unit = np.eye(3)

    def grad_fd(p: Float) -> Float:
        p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        cols = []
        for j in range(3):  # three directions, not a loop over points
            e = step * unit[j]
            cols.append(
                (-phi(p + 2 * e) + 8 * phi(p + e) - 8 * phi(p - e) + phi(p - 2 * e)) / (12 * step)
            )
        return np.column_stack(cols)

    def grad_cs(p: Float) -> Float:
        p = np.asarray(p, dtype=np.float64).reshape(-1, 3) - c
        cols = []
        for j in range(3):
            q = p.astype(np.complex128)
            q[:, j] += 1j * _COMPLEX_STEP
            cols.append(np.imag(f(q[:, 0], q[:, 1], q[:, 2])) / _COMPLEX_STEP)
        return np.column_stack(cols).astype(np.float64)

    # Check the complex step near the surface: the samples with a neighbour of the other sign.
    near = pts[np.abs(values) <= np.quantile(np.abs(values), 0.02)][:2000]
    ok = False
    try:
        with np.errstate(all="ignore"):
            z = f(*(near - c + 1j * _COMPLEX_STEP * unit[0]).T)
            ok = np.iscomplexobj(z) and bool(np.all(np.isfinite(z)))
            if ok:
                ok = np.allclose(np.real(z), phi(near), rtol=1e-12, atol=1e-14)
            if ok:
                g_fd = grad_fd(near)
                g_cs = grad_cs(near)
                scale = max(float(np.abs(g_fd).max()), 1e-300)
                ok = (
                    bool(np.all(np.isfinite(g_cs)))
                    and float(np.abs(g_cs - g_fd).max()) <= 1e-6 * scale
                )
    except Exception:  # not complex-safe: keep finite differences
        ok = False
    return (grad_cs, "complex-step") if ok else (grad_fd, "finite-difference")


# --------------------------------------------------------------------------------------------
# Arguments
# --------------------------------------------------------------------------------------------


def _version() -> str:
    return f"{__version__} (DOLFINx {dolfinx.__version__})"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``dolfinx-universal`` / ``python -m dolfinx_universal``."""
    p = _Parser(
        prog=PROG,
        description=(
            "Mesh the domain bounded by a closed curve (2D) or a closed surface (3D) with a "
            "universal mesh (Rangarajan & Lew 2014; Rangarajan, Kabaria & Lew 2019): a "
            "background mesh of the shape's bounding box is conformed to the boundary by "
            "snapping the vertices of the positive edges (faces) onto it and relaxing nearby "
            "interior vertices (no vertex added). Curves: a triangulation graded automatically "
            "from the curve's curvature and feature sizes (or equilateral with --uniform), "
            "refined where a validity check fails; optionally the cells along the curve are "
            "curved (degree-K Lagrange geometry). Surfaces: a tetrahedral background sized "
            "by the surface's local feature size (at most H; dolfinx_universal.mesh_domain), "
            "refined while a check fails (with --uniform: one A15 lattice of size H); "
            "optionally the tetrahedra along the surface are curved (degree-K geometry). "
            "Writes mesh.vtkhdf + mesh.tags.npz (a checkpoint for any degree: "
            "dolfinx_universal.io.read_mesh reads it back with its "
            "facet tags; ParaView reads the .vtkhdf), mesh.bp (VTX), mesh.xdmf (grids 'mesh' "
            "and 'facet_tags': 1 = immersed boundary, 2 = outer; K <= 2 only), mesh.png and "
            "summary.json (with the validity certificate). Lengths are in the units of the "
            "shape's coordinates. Runs under mpirun (only rank 0 prints and plots)."
        ),
        formatter_class=_Formatter,
    )
    _shape_options(p)
    _meshing_options(p)
    _output_options(p)
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    return p


def _shape_options(p: argparse.ArgumentParser) -> None:
    """The shape options of :func:`build_parser`: one curve or surface, and its placement."""
    shape = p.add_argument_group("shape (exactly one): curves in 2D, surfaces in 3D")
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
    g.add_argument("--sphere", type=float, metavar="R", help="sphere of radius R (3D)")
    g.add_argument(
        "--ellipsoid",
        type=float,
        nargs=3,
        metavar=("A", "B", "C"),
        help="ellipsoid of semi-axes A, B, C along x, y, z (3D)",
    )
    g.add_argument(
        "--torus",
        type=float,
        nargs=2,
        metavar=("R", "r"),
        help="ring torus of major radius R and minor radius r < R, around --axis (3D)",
    )
    g.add_argument(
        "--implicit",
        metavar="EXPR",
        help=(
            "the solid phi(x, y, z) < 0 of a numpy expression in x, y, z (relative to the "
            "center), using the names of --polar, e.g. 'x**2 + 2*y**2 + 3*z**2 - 1' (3D); "
            "grad phi by complex step (4th-order central differences when the expression is "
            "not complex-safe); the surface's bounding box from --box, else found by "
            "sampling phi on 64^3 grids over cubes of half-width 1, 2, 4, ..., 1024, 1/2, "
            "..., 1/1024 around the center until phi < 0 lies strictly inside one (give "
            "--box for thin solids); its genus and number of components are counted on a "
            "grid of 64 cells along the box unless --genus and --components give them "
            "(then checked against those counted)"
        ),
    )
    shape.add_argument(
        "--center",
        type=float,
        nargs="+",
        default=None,
        metavar="C",
        help="center of the shape: X Y for curves, X Y Z for surfaces [default: the origin]",
    )
    shape.add_argument(
        "--angle",
        type=float,
        default=0.0,
        metavar="DEG",
        help="rotation of the ellipse's A axis from the x axis, in degrees",
    )
    shape.add_argument(
        "--axis",
        type=float,
        nargs=3,
        default=None,
        metavar=("X", "Y", "Z"),
        help="axis of the torus [default: 0 0 1]",
    )
    shape.add_argument(
        "--box",
        type=float,
        nargs=6,
        default=None,
        metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
        help="box containing the implicit surface (absolute coordinates) [default: found by "
        "sampling, see --implicit]",
    )
    shape.add_argument(
        "--genus",
        type=int,
        default=None,
        metavar="G",
        help="total genus of the implicit surface (0 for a sphere, 1 for a torus), checked "
        "against the genus counted on a grid [default: counted on a grid over the box]",
    )
    shape.add_argument(
        "--components",
        type=int,
        default=None,
        metavar="N",
        help="number of connected components of the implicit surface, checked against the "
        "number counted on a grid [default: counted on a grid over the box]",
    )


def _meshing_options(p: argparse.ArgumentParser) -> None:
    """The meshing options of :func:`build_parser`: sizes, background and method parameters."""
    m = p.add_argument_group("meshing")
    m.add_argument(
        "--h",
        type=float,
        default=None,
        metavar="H",
        help="largest mesh size (length units): the background is graded from the curve's "
        "curvature and feature sizes up to H (surfaces: sized by the surface's feature "
        "size, at most H) and refined where a check fails; with --uniform, the "
        "edge length of the equilateral background (surfaces: the size of the A15 "
        "background) [default: 1/10 (graded, surfaces) or 1/20 (--uniform curves) of the "
        "larger side of the shape's bounding box, to 3 digits]",
    )
    m.add_argument(
        "--uniform",
        action="store_true",
        help="use one equilateral (surfaces: A15) background of size H instead of the "
        "automatically sized one (fails with an error where H is too coarse for the shape)",
    )
    m.add_argument(
        "--min-angle",
        type=float,
        default=10.0,
        metavar="DEG",
        help="quality floor: smallest angle of the conforming triangles (dihedral angle of "
        "the tetrahedra; graded mode refines below it; --uniform warns)",
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
        help="geometry degree; K > 1 curves the cells along the curve or surface (nodes "
        "on it, every curved cell proven valid by Bernstein bounds of det J)",
    )
    m.add_argument(
        "--map",
        choices=MAPS,
        default=None,
        help="curved map for K > 1: I / G interpolate the blend G_h from the background "
        "edges (faces), I~ / G~ the blend G~_h through the straight conforming mesh "
        "[default: I for curves, I~ for surfaces]",
    )


def _output_options(p: argparse.ArgumentParser) -> None:
    """The output options of :func:`build_parser`."""
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


def _positive(name: str, value: float | None) -> None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise ArgumentError(f"{name} must be a positive number, got {value}")


_CURVES = ("circle", "ellipse", "polar", "spline")
_SURFACES = ("sphere", "ellipsoid", "torus", "implicit")


def _shape_name(args: argparse.Namespace) -> str:
    """The chosen shape option, e.g. ``"circle"`` or ``"torus"``."""
    for name in (*_CURVES, *_SURFACES):
        if getattr(args, name, None) is not None:
            return name
    raise ArgumentError("one of the shape arguments is required")


def _check_shape_options(args: argparse.Namespace) -> None:
    """The options that belong to one shape are not given with another."""
    name = _shape_name(args)
    own = {"axis": "torus", "box": "implicit", "genus": "implicit", "components": "implicit"}
    for option, shape in own.items():
        if getattr(args, option, None) is not None and name != shape:
            raise ArgumentError(f"--{option} applies to --{shape} only")
    if args.angle != 0.0 and name in _SURFACES:
        raise ArgumentError("--angle applies to --ellipse only")


def make_boundary(args: argparse.Namespace) -> tuple[Boundary, dict[str, Any]]:
    """The boundary (curve or surface) chosen by the shape arguments, and a JSON description.

    Raises
    ------
    ArgumentError
        For invalid shape parameters or an unreadable spline file.
    """
    _check_shape_options(args)
    kind = _kind(args)
    raw = [0.0] * kind.gdim if args.center is None else list(args.center)
    if len(raw) != kind.gdim:
        raise ArgumentError(f"--center needs {kind.center_words}, got {len(raw)} number(s)")
    center = np.asarray(raw, dtype=np.float64)
    if not np.all(np.isfinite(center)):
        raise ArgumentError(f"--center must be finite, got {raw}")
    return kind.make(args, center)


def _make_curve(args: argparse.Namespace, center: Float) -> tuple[Boundary, dict[str, Any]]:
    """The curve of ``--circle``, ``--ellipse``, ``--polar`` or ``--spline``."""
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
    return _read_spline(Path(args.spline))


def _read_spline(path: Path) -> tuple[Boundary, dict[str, Any]]:
    """The spline of ``--spline``; its warnings printed on rank 0."""
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


def _make_surface(args: argparse.Namespace, center: Float) -> tuple[Boundary, dict[str, Any]]:
    """The surface of ``--sphere``, ``--ellipsoid``, ``--torus`` or ``--implicit``."""
    c = center.tolist()
    if args.sphere is not None:
        _positive("--sphere R", args.sphere)
        return Sphere(center, args.sphere), {"type": "sphere", "radius": args.sphere, "center": c}
    if args.ellipsoid is not None:
        for name, value in zip("ABC", args.ellipsoid):
            _positive(f"--ellipsoid {name}", value)
        desc = {"type": "ellipsoid", "semi_axes": list(args.ellipsoid), "center": c}
        return Ellipsoid(center, args.ellipsoid), desc
    if args.torus is not None:
        major, minor = args.torus
        _positive("--torus R", major)
        _positive("--torus r", minor)
        if not minor < major:
            raise ArgumentError(
                f"--torus R r needs r < R (a ring torus), got R = {major}, r = {minor}"
            )
        axis = np.array([0.0, 0.0, 1.0] if args.axis is None else args.axis)
        if not (np.isfinite(axis).all() and (axis @ axis) > 0):
            raise ArgumentError(f"--axis must be a finite non-zero vector, got {axis.tolist()}")
        axis = axis / np.sqrt(axis @ axis)
        desc = {"type": "torus", "major": major, "minor": minor, "axis": axis.tolist(), "center": c}
        return Torus(center, major, minor, axis=axis), desc
    return _make_implicit(args, center)


def _make_implicit(args: argparse.Namespace, center: Float) -> tuple[Boundary, dict[str, Any]]:
    """The surface of ``--implicit``: its topology given (``--genus``, ``--components``) and
    checked, or counted (:class:`~dolfinx_universal.boundaries.surfaces.ImplicitSurface`)."""
    for option, low in (("genus", 0), ("components", 1)):
        value = getattr(args, option)
        if value is not None and value < low:
            raise ArgumentError(f"--{option} must be >= {low}, got {value}")
    imp = implicit_functions(args.implicit, center, args.box)
    try:
        surface = ImplicitSurface(
            imp.phi, imp.grad, imp.box, genus=args.genus, num_components=args.components
        )
        genus, components = surface.genus, surface.num_components  # counted, or checked
    except ValueError as e:
        raise ArgumentError(f"--implicit: {e}") from None
    desc = {
        "type": "implicit",
        "expression": args.implicit,
        "center": center.tolist(),
        "bounding_box": imp.box.tolist(),
        "box_given": args.box is not None,
        "genus": genus,
        "num_components": components,
        "topology": "grid" if surface.topology_counted else "given",
        "gradient": imp.gradient,
    }
    return surface, desc


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
# Curves and surfaces: what differs
# --------------------------------------------------------------------------------------------


class _Sizes(NamedTuple):
    """The sizes of a run: the shape's bounding box, the background's box, the size asked
    (``--h`` or its default), the margin around the shape and the size used."""

    bbox: Float
    box: Float
    h: float
    margin: float
    h_used: float


class _Curves:
    """What the command line does for a curve: triangles on an equilateral background
    (``--uniform``) or the graded one of ``mesh_domain``."""

    gdim = 2
    center_words = "X Y for a curve"
    cells_note, angles_word = "", ""
    make = staticmethod(_make_curve)
    uniform_background = staticmethod(equilateral_mesh)

    @staticmethod
    def sizes(boundary: Boundary, bbox: Float, args: argparse.Namespace) -> _Sizes:
        """``--h`` (default: the larger side of the box over 10, over 20 with
        ``--uniform``), the background's box and margin; an :class:`ArgumentError` where
        an equilateral background would have too many cells."""
        extent = float((bbox[1] - bbox[0]).max())
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
        return _Sizes(bbox, box, h, margin, h)

    @staticmethod
    def record(stage: str, args: argparse.Namespace) -> bool:
        """Whether the time of a stage of ``mesh_domain`` goes into the summary."""
        return True

    @staticmethod
    def used(comm: MPI.Comm, meshed: _Meshed, sizes: _Sizes) -> _Sizes:
        """The sizes of the summary: those asked."""
        return sizes

    @staticmethod
    def summary_sizes(sizes: _Sizes) -> dict[str, float]:
        return {"h": sizes.h, "margin": sizes.margin}

    @staticmethod
    def background_name(args: argparse.Namespace, meshed: _Meshed) -> str:
        return "equilateral" if args.uniform else "graded (mesh_domain)"

    @staticmethod
    def plot(
        comm: MPI.Comm,
        meshed: _Meshed,
        path: Path,
        shape: dict[str, Any],
        sizes: _Sizes,
        args: argparse.Namespace,
        quality: dict[str, Any],
    ) -> None:
        """The conforming mesh drawn with the curve (matplotlib is optional: imported
        here, where a plot is asked for)."""
        from dolfinx_universal.plotting import plot_conforming, save

        deg = f", degree {args.degree} ({args.map})" if args.degree > 1 else ""
        title = f"universal mesh: {shape['type']}, h = {sizes.h:.3g}{deg}"
        fig, _ = plot_conforming(None, meshed.conforming, mesh=meshed.mesh, title=title)
        save(fig, path)


class _Surfaces:
    """What the command line does for a surface: tetrahedra on an A15 background
    (``--uniform``) or the one ``mesh_domain`` chooses."""

    gdim = 3
    center_words = "X Y Z for a surface"
    cells_note, angles_word = "tetrahedra; ", "dihedral "
    make = staticmethod(_make_surface)
    uniform_background = staticmethod(a15_mesh)

    @staticmethod
    def sizes(boundary: Boundary, bbox: Float, args: argparse.Namespace) -> _Sizes:
        """``--h`` (default: the larger side of the box over 10), the background's box and
        margin; an :class:`ArgumentError` where an A15 background would have too many
        cells."""
        extent = float((bbox[1] - bbox[0]).max())
        h = float(f"{extent / 10.0:.3g}") if args.h is None else float(args.h)
        margin = (args.rr + 1.0) * h if args.margin is None else float(args.margin)
        box = np.array([bbox[0] - margin, bbox[1] + margin])
        if args.uniform:
            n_estimate = 11.5 * float(np.prod(box[1] - box[0])) / h**3  # A15: 11.5 per h^3
            if n_estimate > 2e7:
                raise ArgumentError(
                    f"--h {h:.4g} would give ~{n_estimate:.3g} background cells; use a larger h"
                )
        return _Sizes(bbox, box, h, margin, h)

    @staticmethod
    def record(stage: str, args: argparse.Namespace) -> bool:
        """Whether the time of a stage of ``mesh_domain`` goes into the summary."""
        return stage != "curved" or args.degree > 1

    @staticmethod
    def used(comm: MPI.Comm, meshed: _Meshed, sizes: _Sizes) -> _Sizes:
        """The sizes of the summary: the background's own box (collective) and the
        certificate's smallest size."""
        x = meshed.background.geometry.x
        lo = np.min(x, axis=0, initial=np.inf)
        hi = np.max(x, axis=0, initial=-np.inf)
        comm.Allreduce(MPI.IN_PLACE, lo, op=MPI.MIN)
        comm.Allreduce(MPI.IN_PLACE, hi, op=MPI.MAX)
        cert = meshed.certificate
        h_used = float(sizes.h if cert is None else cert.h_min)
        margin = float(sizes.bbox[0, 0] - lo[0])
        return sizes._replace(box=np.array([lo, hi]), margin=margin, h_used=h_used)

    @staticmethod
    def summary_sizes(sizes: _Sizes) -> dict[str, float]:
        return {"h": sizes.h, "h_used": sizes.h_used, "margin": sizes.margin}

    @staticmethod
    def background_name(args: argparse.Namespace, meshed: _Meshed) -> str:
        cert = meshed.certificate  # the background mesh_domain chose
        return "A15 uniform (--uniform)" if cert is None else f"{cert.background} (mesh_domain)"

    @staticmethod
    def plot(
        comm: MPI.Comm,
        meshed: _Meshed,
        path: Path,
        shape: dict[str, Any],
        sizes: _Sizes,
        args: argparse.Namespace,
        quality: dict[str, Any],
    ) -> None:
        """A clipped view and the surface of the tetrahedra (:func:`_plot_surface_mesh`)."""
        deg = (
            f", degree {args.degree} ({args.map}; straight cells shown)" if args.degree > 1 else ""
        )
        title = f"universal mesh: {shape['type']}, h = {sizes.h_used:.3g}{deg}"
        _plot_surface_mesh(comm, meshed.conforming, path, title, float(quality["theta_min_deg"]))


_Kind = type[_Curves] | type[_Surfaces]
"""The curves' or the surfaces' way (:class:`_Curves`, :class:`_Surfaces`)."""
_KINDS: dict[int, _Kind] = {2: _Curves, 3: _Surfaces}
"""What differs between curves and surfaces, by the dimension of the space."""
_DIMENSION = {**{name: 2 for name in _CURVES}, **{name: 3 for name in _SURFACES}}
"""The dimension of the space of each shape option."""


def _kind(args: argparse.Namespace) -> _Kind:
    """The curves' or the surfaces' way, by the shape option given."""
    return _KINDS[_DIMENSION[_shape_name(args)]]


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


class _Meshed(NamedTuple):
    """What :func:`_mesh` returns."""

    conforming: ConformingMesh
    mesh: dmesh.Mesh
    facet_tags: dmesh.MeshTags
    background: dmesh.Mesh
    certificate: Any
    """``mesh_domain``'s certificate (None with ``--uniform``)."""
    curved: dict[str, Any]
    """The curved map's smallest Jacobian ratio, if curved."""


def _mesh(
    comm: MPI.Comm,
    boundary: Boundary,
    h: float,
    box: npt.NDArray[np.float64],
    args: argparse.Namespace,
    uniform_background: Callable[[MPI.Comm, list[list[float]], float], dmesh.Mesh],
    timings: dict[str, float],
    record: Callable[[str], bool],
) -> _Meshed:
    """The conforming mesh of the CLI, curves and surfaces alike (collective): ``--uniform``
    conforms ``uniform_background(comm, box, h)`` (and curves it for ``--degree`` > 1), else
    :func:`mesh_domain` (its stages' times recorded where ``record(stage)``). Returns the
    conforming mesh, the final mesh and its facet tags, the background, the certificate
    (``None`` with ``--uniform``) and the curved map's smallest Jacobian ratio (if curved)."""
    certificate = None
    curved_info: dict[str, Any] = {}
    t = time.perf_counter()
    if args.uniform:
        background = uniform_background(comm, box.tolist(), h)
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
            if stage != "total" and record(stage):
                timings[stage] = seconds
        if md.curved is not None:
            curved_info["min_jacobian_ratio"] = float(md.curved.min_jacobian_ratio)
    return _Meshed(cm, msh, tags, background, certificate, curved_info)


def _write_mesh_files(
    comm: MPI.Comm, out: Path, msh: dmesh.Mesh, tags: dmesh.MeshTags, degree: int
) -> list[str]:
    """Write the mesh with its facet tags to ``out``: a VTKHDF checkpoint (any degree), VTX
    and, up to degree 2, XDMF (collective). Returns the names of the files written."""
    write_mesh(out / "mesh.vtkhdf", msh, tags)  # a checkpoint for any degree, with its tags
    files = ["mesh.vtkhdf", tags_path(out / "mesh.vtkhdf").name]
    with VTXWriter(comm, out / "mesh.bp", msh, engine="BPFile") as vtx:
        vtx.write(0.0)
    files.append("mesh.bp")
    if degree <= 2:
        with XDMFFile(comm, out / "mesh.xdmf", "w") as xdmf:
            xdmf.write_mesh(msh)
            tags.name = "facet_tags"
            xdmf.write_meshtags(tags, msh.geometry)
        files += ["mesh.xdmf", "mesh.h5"]
    elif comm.rank == 0:  # XDMF cannot hold degree >= 3: drop stale files of earlier runs
        for name in ("mesh.xdmf", "mesh.h5"):
            (out / name).unlink(missing_ok=True)
    return files


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
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    _check_numbers(args)
    boundary, shape = make_boundary(args)
    kind = _kind(args)
    if getattr(args, "map", None) is None:
        args.map = DEFAULT_MAP[kind.gdim]
    bbox = _shape_box(boundary, kind.gdim)
    out = Path(args.out)
    _prepare_out(comm, out)
    plot = not args.no_plot and _have_matplotlib(comm)
    sizes = kind.sizes(boundary, bbox, args)
    meshed = _conform_shape(comm, boundary, shape, sizes, args, kind, timings)
    sizes = kind.used(comm, meshed, sizes)
    quality, files = _outputs(comm, out, meshed, shape, sizes, args, kind, plot, timings)
    summary = _summary(comm, meshed, shape, sizes, args, kind, quality, files, timings, t_start)
    if comm.rank == 0:
        with open(out / "summary.json", "w") as fh:
            json.dump(summary, fh, indent=2, allow_nan=False)
            fh.write("\n")
    comm.barrier()
    return summary


def _shape_box(boundary: Boundary, gdim: int) -> Float:
    """The shape's bounding box ``(2, gdim)``; an :class:`ArgumentError` where it is empty or
    so far from the origin that float64 coordinates keep too few digits to mesh it."""
    bbox = np.asarray(boundary.bounding_box(), dtype=np.float64).reshape(2, gdim)
    extent = float((bbox[1] - bbox[0]).max())
    if not (np.all(np.isfinite(bbox)) and extent > 0):
        raise ArgumentError(f"the shape has an empty or invalid bounding box {bbox.tolist()}")
    far = float(np.abs(bbox).max())
    if far > 1e8 * extent:  # float64 keeps 16 digits: fewer than 8 would be left for h
        raise ArgumentError(
            f"the shape (extent {extent:.3g}) lies {far:.3g} from the origin: float64 "
            "coordinates would keep too few digits to mesh it; move it near the origin "
            f"(e.g. --center {' '.join(['0'] * gdim)}) and shift the mesh afterwards"
        )
    return bbox


def _conform_shape(
    comm: MPI.Comm,
    boundary: Boundary,
    shape: dict[str, Any],
    sizes: _Sizes,
    args: argparse.Namespace,
    kind: _Kind,
    timings: dict[str, float],
) -> _Meshed:
    """:func:`_mesh` with its errors for the command line (collective): a parameter check
    is an :class:`ArgumentError`; a wrong topology of an implicit surface says which
    options give it; an empty domain asks for a smaller ``--h``."""
    try:
        meshed = _mesh(
            comm, boundary, sizes.h, sizes.box, args, kind.uniform_background, timings,
            lambda stage: kind.record(stage, args),
        )  # fmt: skip
    except MeshingError as e:
        if shape["type"] == "implicit" and "Euler characteristic" in str(e):
            how = "given" if shape["topology"] == "given" else "counted on a grid"
            raise MeshingError(
                f"{e}; for --implicit check the surface's topology ({shape['num_components']} "
                f"component(s), genus {shape['genus']}, {how}): give --genus and --components",
                e.points,
                refinable=False,
            ) from None
        raise
    except ValueError as e:  # parameter checks (collective)
        raise ArgumentError(str(e)) from None
    cm = meshed.conforming
    if cm.mesh.topology.index_map(cm.mesh.topology.dim).size_global == 0:  # on every rank
        extent = float((sizes.bbox[1] - sizes.bbox[0]).max())
        raise MeshingError(
            f"no background vertex lies inside the domain: h = {sizes.h:.4g} is too coarse "
            f"for a shape of extent {extent:.4g}; use a smaller --h"
        )
    for stage, seconds in cm.timings.items():
        timings[f"conform.{stage}"] = seconds
    return meshed


def _outputs(
    comm: MPI.Comm,
    out: Path,
    meshed: _Meshed,
    shape: dict[str, Any],
    sizes: _Sizes,
    args: argparse.Namespace,
    kind: _Kind,
    plot: bool,
    timings: dict[str, float],
) -> tuple[dict[str, Any], list[str]]:
    """The quality report, the mesh files and the plot (collective); the report and the
    names of the files written."""
    t = time.perf_counter()
    quality = quality_report(meshed.conforming)
    timings["quality"] = time.perf_counter() - t
    t = time.perf_counter()
    files = _write_mesh_files(comm, out, meshed.mesh, meshed.facet_tags, args.degree)
    timings["write"] = time.perf_counter() - t
    if plot:
        t = time.perf_counter()
        kind.plot(comm, meshed, out / "mesh.png", shape, sizes, args, quality)
        files.append("mesh.png")
        timings["plot"] = time.perf_counter() - t
    return quality, files


def _summary(
    comm: MPI.Comm,
    meshed: _Meshed,
    shape: dict[str, Any],
    sizes: _Sizes,
    args: argparse.Namespace,
    kind: _Kind,
    quality: dict[str, Any],
    files: list[str],
    timings: dict[str, float],
    t_start: float,
) -> dict[str, Any]:
    """The summary of a run, the same on every rank (collective)."""
    msh, tags, background = meshed.mesh, meshed.facet_tags, meshed.background
    owned = tags.indices < msh.topology.index_map(msh.topology.dim - 1).size_local
    facets = {
        name: comm.allreduce(int((tags.values[owned] == tag).sum()))
        for name, tag in (("immersed", IMMERSED), ("outer", OUTER))
    }
    timings = {k: comm.allreduce(v, op=MPI.MAX) for k, v in timings.items()}
    timings["total"] = comm.allreduce(time.perf_counter() - t_start, op=MPI.MAX)
    files.append("summary.json")
    certificate = meshed.certificate
    cm = meshed.conforming
    summary = {
        "dimension": kind.gdim,
        "shape": shape,
        "bounding_box": sizes.bbox.tolist(),
        "background_box": sizes.box.tolist(),
        **kind.summary_sizes(sizes),
        "rr": args.rr,
        "R_r": args.rr * sizes.h_used,
        "alpha": cm.alpha,
        "eta": cm.eta,
        "degree": args.degree,
        "map": args.map if args.degree > 1 else None,
        "n_background_cells": background.topology.index_map(background.topology.dim).size_global,
        "n_cells": int(quality["n_cells"]),
        "n_vertices": msh.topology.index_map(0).size_global,
        "n_geometry_nodes": msh.geometry.index_map().size_global,
        "n_relocated": cm.num_relocated,
        "facets": {"tags": {"immersed": IMMERSED, "outer": OUTER}, "counts": facets},
        "quality": quality,
        **({"curved": meshed.curved} if meshed.curved else {}),
        "background": kind.background_name(args, meshed),
        "certificate": certificate.as_dict() if certificate is not None else None,
        "mpi_size": comm.size,
        "dolfinx_version": dolfinx.__version__,
        "versions": versions(),
        "files": files,
        "timings_s": timings,
    }
    summary = _json_safe(summary)
    summary["certificate_text"] = str(certificate) if certificate is not None else None
    return summary


def _plot_surface_mesh(comm: MPI.Comm, cm: Any, path: Path, title: str, low: float) -> None:
    """Clipped view and surface of a tetrahedral conforming mesh, coloured by quality (the
    smallest dihedral angle of each cell, from ``low`` to the regular tetrahedron's).
    matplotlib is optional: imported here, where a plot is asked for."""
    from dolfinx_universal.plotting import plot_tetrahedra, save

    fig, axes = None, [None, None]
    if comm.rank == 0:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(13.0, 6.0), layout="constrained")
        axes = [fig.add_subplot(1, 2, i + 1, projection="3d") for i in range(2)]
        fig.suptitle(title)
    hi = float(np.degrees(np.arccos(1.0 / 3.0)))  # 70.53: the regular tetrahedron's
    lo = min(low, hi - 1.0)
    plot_tetrahedra(
        cm, axes[0], view="clipped", vmin=lo, vmax=hi, colorbar=False,
        title="the cells behind the plane y = y_c",
    )  # fmt: skip
    plot_tetrahedra(
        cm, axes[1], view="surface", vmin=lo, vmax=hi, title="Gamma_h (the immersed faces)"
    )
    save(fig, path)


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
    ok = comm.bcast(importlib.util.find_spec("matplotlib") is not None, root=0)
    if not ok and comm.rank == 0:
        print(
            f"{PROG}: warning: matplotlib is not installed, mesh.png is not written "
            "(pip install dolfinx_universal[plot])",
            file=sys.stderr,
            flush=True,
        )
    return ok


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
        _print_summary(summary, args)
    return 0


def _print_summary(summary: dict[str, Any], args: argparse.Namespace) -> None:
    """The one-line report of a run (and the certificate, if any)."""
    q = summary["quality"]
    kind = _KINDS[summary["dimension"]]
    print(
        f"{summary['n_cells']} cells ({kind.cells_note}"
        f"{q['n_positively_cut']} positively cut, "
        f"{q['percent_unaltered']:.1f}% unaltered), {kind.angles_word}angles in "
        f"[{q['theta_min_deg']:.1f}, {q['theta_max_deg']:.1f}] degrees, h = "
        f"{summary.get('h_used', summary['h']):.4g}; wrote {', '.join(summary['files'])} "
        f"to {args.out}",
        flush=True,
    )
    if summary["certificate"] is not None:
        print(summary["certificate_text"], flush=True)
