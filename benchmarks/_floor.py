"""A plain numpy/scipy "floor" for the package's meshing steps, and a timing harness.

The floor does the essential work of a moving-domain update of a body given as a rigidly
moved parametric curve, with none of the package's generality or checks:

* signs near the body: the exact polar test ``|x - c| < r(angle)`` (the solid, outside the
  domain) for the vertices in the annulus that the curve sweeps (padded by ``R_r``), the
  solid inside it and the fluid (``-1``) outside it;
* the band: vertices whose nearest dense sample of the curve (a k-d tree query) is within
  their own ``R_r`` plus the sample spacing;
* closest points by Newton's method on the curve parameter (``c'(t).(c(t) - x) = 0``, from
  the nearest sample, a fixed number of steps: quadratic convergence to rounding);
* ``M_h`` (positive-edge vertices snapped, inside band vertices relaxed) and the degree-2
  nodes of the cells at the band written in place: affine, except the midpoint of each
  positive edge, projected onto the curve (the value of the blend ``G_h`` there).

:func:`timed_pairs` times the package and the floor interleaved (median over repeats,
maximum over ranks). Used by ``update_floor.py``, ``conform_floor.py`` and
``curved_floor.py`` in this folder.
"""

from __future__ import annotations

import importlib.util
import time
from collections.abc import Callable
from pathlib import Path

from mpi4py import MPI

import basix
import numpy as np
from dolfinx import fem
from dolfinx import mesh as dmesh
from moving_update import propeller
from scipy.spatial import cKDTree

import dolfinx_universal as du

ROOT = Path(__file__).resolve().parents[1]
NEWTON_STEPS = 5
"""Newton steps from the nearest of 4096 samples: the error squares at each (to rounding)."""


def three_blades() -> du.PolarCurve:
    """The smooth three-blade body of ``moving_update.py``."""
    return propeller()


def load_demo(filename: str, name: str):
    """The module ``demos/<filename>`` (its functions and constants), named ``name``."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "demos" / filename)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def propeller_demo():
    """The module ``demos/stokes_propeller.py`` (its propeller and graded background)."""
    return load_demo("stokes_propeller.py", "_stokes_propeller_demo")


def equilateral(comm: MPI.Comm, cells: float) -> dmesh.Mesh:
    """Equilateral background of about ``cells`` triangles on ``[-1, 1]^2``."""
    h = float(np.sqrt(4.0 / (cells * np.sqrt(3) / 4)))
    return du.equilateral_mesh(comm, [[-1, -1], [1, 1]], h)


def timed_pairs(
    comm: MPI.Comm, fns: dict[str, Callable[[int], object]], repeats: int, apart: bool = False
) -> dict[str, float]:
    """Median seconds (maximum over ranks) of each ``fn(step)``, the functions interleaved.

    Step 0 is a warm-up (not timed); steps ``1..repeats`` are timed. ``apart``: all steps of
    one function, then all of the next. The two orders can differ by more than the machine's
    drift where the functions allocate differently: interleaved, one side's page faults
    land on memory the other freed (glibc trims and re-grows its heap), apart each side
    pays its own.
    """
    times: dict[str, list[float]] = {k: [] for k in fns}
    order = (
        [(step, key) for key in fns for step in range(repeats + 1)]
        if apart
        else [(step, key) for step in range(repeats + 1) for key in fns]
    )
    for step, key in order:
        comm.Barrier()
        t = time.perf_counter()
        fns[key](step)
        dt = comm.allreduce(time.perf_counter() - t, op=MPI.MAX)
        if step:
            times[key].append(dt)
    return {k: float(np.median(v)) for k, v in times.items()}


class CurveFloor:
    """Samples, k-d tree and Newton projection of one parametric curve (its own frame)."""

    def __init__(self, curve: du.ParametricCurve, n: int = 4096) -> None:
        self.curve, self.period = curve, curve.period
        self.t = np.arange(n) * (curve.period / n)
        self.p = curve.point(self.t)
        self.tree = cKDTree(self.p)
        self.spacing = float(np.linalg.norm(np.roll(self.p, -1, axis=0) - self.p, axis=1).max())
        lo, hi = self.p.min(axis=0), self.p.max(axis=0)
        self.box = np.array([lo - self.spacing, hi + self.spacing])

    def project(self, x: np.ndarray, t: np.ndarray | None = None):
        """Parameters, closest points and outward normals of points ``x (n, 2)``."""
        c = self.curve
        if t is None:
            t = self.t[self.tree.query(x)[1]]
        for _ in range(NEWTON_STEPS):
            r = c.point(t) - x
            d1, d2 = c.derivative(t), c.second_derivative(t)
            t = t - (d1 * r).sum(axis=1) / ((d2 * r).sum(axis=1) + (d1 * d1).sum(axis=1))
        y, d1 = c.point(t), c.derivative(t)
        n = np.column_stack([d1[:, 1], -d1[:, 0]]) / np.hypot(d1[:, 0], d1[:, 1])[:, None]
        return t, y, n


class MotionFloor:
    """The floor of the straight map for a rigidly rotated body on one background.

    Parameters
    ----------
    um
        The package's prepared background (its vertex arrays, sizes ``h`` and ``R_r`` and
        ``alpha`` are reused: preparation is not timed).
    curve
        The body's curve in its reference position, a polar curve with its pole at the
        origin, the centre of the rotation (the fluid is outside it).
    """

    def __init__(self, um: du.UniversalMesh, curve: du.PolarCurve) -> None:
        self.x, self.c2v = um._x, um._c2v
        self.h, self.R_r, self.alpha = um.h, um.R_r, um.alpha
        if np.any(curve.center != 0):
            raise ValueError("the floor rotates a polar curve about its pole at the origin")
        self.curve = CurveFloor(curve)
        self.centre = curve.center
        self.r = curve.r
        radii = np.hypot(*(self.curve.p - self.centre).T)
        self.rho = (radii.min() - self.curve.spacing, radii.max() + self.curve.spacing)
        self.rmax = float(self.R_r.max()) if len(self.R_r) else 0.0

    def straight(self, angle: float):
        """Signs, band, closest points, ``M_h`` images, the cells at the band and the
        positively cut ones (with the inside vertex's local index)."""
        x, c2v = self.x, self.c2v
        c, s_ = np.cos(angle), np.sin(angle)
        rot = np.array([[c, s_], [-s_, c]])  # to the body's frame: R(-angle), row vectors
        # only the annulus swept by the curve can be near it: r_min - R_r <= |x| <= r_max + R_r
        rho = np.hypot(x[:, 0] - self.centre[0], x[:, 1] - self.centre[1])
        box = np.flatnonzero((rho >= self.rho[0] - self.rmax) & (rho <= self.rho[1] + self.rmax))
        xb = (x[box] - self.centre) @ rot.T + self.centre
        d = xb - self.centre
        s = -np.ones(len(x))  # the fluid: outside the body
        s[rho < self.rho[0] - self.rmax] = 1.0  # inside the hub
        solid = np.hypot(d[:, 0], d[:, 1]) < self.r(np.arctan2(d[:, 1], d[:, 0]))
        s[box[solid]] = 1.0
        dist, j = self.curve.tree.query(xb, distance_upper_bound=self.rmax + self.curve.spacing)
        near = dist <= self.R_r[box] + self.curve.spacing
        band = box[near]
        _, yb, nb = self.curve.project(xb[near], self.curve.t[j[near]])
        back = rot  # R(angle) for column vectors = rot.T; rows: v @ rot
        y_band = (yb - self.centre) @ back + self.centre
        n_band = -(nb @ back)  # out of the fluid: into the body
        phi = np.where(s[band] < 0, -1.0, 1.0) * np.hypot(*(x[band] - y_band).T)
        mark = np.zeros(len(x), dtype=bool)
        mark[band] = True
        cells = np.flatnonzero(mark[c2v].any(axis=1))
        sc = s[c2v[cells]]
        cut = cells[(sc < 0).sum(axis=1) == 1]
        k = np.argmin(s[c2v[cut]], axis=1)
        on_edge = np.zeros(len(x), dtype=bool)
        cv = c2v[cut]
        rows = np.arange(len(cut))
        on_edge[cv[rows, (k + 1) % 3]] = True
        on_edge[cv[rows, (k + 2) % 3]] = True
        y = x.copy()
        ob = on_edge[band]
        y[band[ob]] = y_band[ob]
        hb, rb = self.h[band], self.R_r[band]
        relax = ~ob & (phi < 0) & (phi > -rb)
        f = self.alpha * hb[relax] * (1.0 + phi[relax] / rb[relax])
        y[band[relax]] -= f[:, None] * n_band[relax]
        return s, y, cells, cut, k, rot


class UpdateFloor(MotionFloor):
    """The floor of one moving-domain update: the straight map, then degree-2 nodes of the
    cells at the band (now or at the previous step) written in place."""

    def __init__(self, um: du.UniversalMesh, curve: du.PolarCurve) -> None:
        super().__init__(um, curve)
        ce = fem.coordinate_element(dmesh.CellType.triangle, 2, basix.LagrangeVariant.gll_warped)
        self.mesh = fem.interpolate_geometry(um.background, ce)
        self.dofmap = self.mesh.geometry.dofmaps[0]
        self.dirty = np.zeros(len(self.c2v), dtype=bool)
        p = basix.create_element(
            basix.ElementFamily.P, basix.CellType.triangle, 2, basix.LagrangeVariant.gll_warped
        ).points
        self.lam = np.column_stack([1.0 - p.sum(axis=1), p])

    def update(self, angle: float) -> None:
        s, y, cells, cut, k, rot = self.straight(angle)
        near = np.zeros(len(self.c2v), dtype=bool)
        near[cells] = True
        redo = np.flatnonzero(near | self.dirty)
        nodes = np.einsum("pi,cid->cpd", self.lam, y[self.c2v[redo]])  # affine nodes
        # positive-edge midpoints: node 3 + k (edge k is opposite local vertex k)
        cv = self.c2v[cut]
        rows = np.arange(len(cut))
        a, b = self.x[cv[rows, (k + 1) % 3]], self.x[cv[rows, (k + 2) % 3]]
        mid = (0.5 * (a + b) - self.centre) @ rot.T + self.centre
        _, pm, _ = self.curve.project(mid)
        x = self.mesh.geometry.x
        x[self.dofmap[redo].ravel(), :2] = nodes.reshape(-1, 2)
        x[self.dofmap[cut, 3 + k], :2] = (pm - self.centre) @ rot + self.centre  # wins on Gamma_h
        self.dirty = near


class ConformFloor(MotionFloor):
    """The floor of conforming: the straight map, the kept cells and their DOLFINx submesh."""

    def __init__(self, um: du.UniversalMesh, curve: du.PolarCurve) -> None:
        super().__init__(um, curve)
        self.background, self.n2v, self.nco = um.background, um._n2v, um._nco

    def conform(self, angle: float) -> dmesh.Mesh:
        s, y, *_ = self.straight(angle)
        owned = self.c2v[: self.nco]
        kept = np.flatnonzero((s[owned] < 0).any(axis=1)).astype(np.int32)
        sub, _, _, node_map = dmesh.create_submesh(self.background, 2, kept)
        sub.geometry.x[:, :2] = y[self.n2v[node_map]]
        return sub


TABLES: list[dict] = []
"""The tables :func:`print_table` printed, for the scripts' ``--json`` results."""


def print_table(comm: MPI.Comm, title: str, rows: list[tuple[str, float, float]]) -> None:
    """``| case | package | floor | ratio |`` on rank 0, times in milliseconds; the table is
    also kept in :data:`TABLES` (times in seconds)."""
    if comm.rank:
        return
    TABLES.append(
        {
            "title": title,
            "ranks": comm.size,
            "rows": [
                {"case": name.strip(), "package_s": p, "floor_s": f, "ratio": p / f}
                for name, p, f in rows
            ],
        }
    )
    print(f"\n{title} (ranks: {comm.size}; median, max over ranks)")
    print(f"| {'case':<52} | {'package':>9} | {'floor':>9} | {'ratio':>6} |")
    print(f"|{'-' * 54}|{'-' * 11}|{'-' * 11}|{'-' * 8}|")
    for name, package, floor in rows:
        print(
            f"| {name:<52} | {1e3 * package:7.2f}ms | {1e3 * floor:7.2f}ms | "
            f"{package / floor:5.2f}x |"
        )
    print("ratios: " + ", ".join(f"{n}: {p / f:.2f}" for n, p, f in rows))
