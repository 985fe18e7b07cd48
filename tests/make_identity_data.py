"""Freeze the package's meshing outputs, so that speed work can prove it changed nothing.

``python tests/make_identity_data.py`` (serial) writes ``tests/data/identity_<case>.npz``
with the outputs of :meth:`UniversalMesh.straight_map` / :meth:`UniversalMesh.conform`, the
geometry nodes of :func:`curved_mesh` (q = 2 and 3) and three steps of
:meth:`MovingDomain.update` for the cases of :func:`cases`. ``tests/test_identity.py``
rebuilds the same cases with the current code and compares. The data were written with the
code of commit c6e9e3a (before the optimisations of issue 9); regenerate them only for a
change that alters meshes by design, and say so in the commit.

Every case passes ``relax=False``: vertex relaxation changes meshes on purpose.

Storage (the files stay well below 2 MB): per-vertex arrays in full; curved and moving
geometry nodes only where they differ from the straight (affine) nodes that
``dolfinx.fem.interpolate_geometry`` gives, which the test recomputes.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from pathlib import Path

from mpi4py import MPI

import basix
import numpy as np
from dolfinx import fem
from dolfinx import mesh as dmesh

import dolfinx_universal as du
from dolfinx_universal.moving.domain import MovingDomain

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from _floor import propeller_demo, three_blades  # noqa: E402  (the benchmarks' cases)

DATA = ROOT / "tests" / "data"
AFFINE_TOL = 1e-12
"""Nodes farther than this from their affine position are stored (curved or moved)."""


def equilateral(comm: MPI.Comm, cells: float = 5e3) -> dmesh.Mesh:
    """Equilateral background of about ``cells`` triangles on ``[-1, 1]^2``."""
    h = float(np.sqrt(4.0 / (cells * np.sqrt(3) / 4)))
    return du.equilateral_mesh(comm, [[-1, -1], [1, 1]], h)


def cases(comm: MPI.Comm) -> Iterator[tuple[str, str, dict, Callable[[], object]]]:
    """``(name, kind, options, build)`` of every frozen case.

    ``kind`` is ``"conform"`` (``build()`` returns ``(background, boundary)``) or ``"moving"``
    (``build()`` returns ``(background, [boundary of each step])``).
    """
    blades = three_blades()
    demo = propeller_demo()

    def circle():
        return equilateral(comm), du.Circle([0.03, -0.02], 0.55)

    def blades_case():
        return equilateral(comm), du.Domain(None, [du.RigidMotion(blades, angle=0.3)])

    def container_body():
        container = du.Circle([0.0, 0.0], 0.85)
        body = du.Ellipse([0.1, 0.05], 0.3, 0.15, angle=0.4)
        return equilateral(comm), du.Domain(container, [body])

    def graded():
        h_fine, h_coarse, _ = demo.sizes(True)
        background = demo.background_mesh(comm, h_fine, h_coarse)
        return background, du.Domain(None, [du.RigidMotion(demo.propeller, angle=-0.2)])

    def moving_blades():
        steps = [
            du.Domain(None, [du.RigidMotion(blades, angle=np.radians(3.0 * k))]) for k in range(3)
        ]
        return equilateral(comm), steps

    def moving_graded():
        h_fine, h_coarse, step = demo.sizes(True)
        background = demo.background_mesh(comm, h_fine, h_coarse)
        bodies = [du.RigidMotion(demo.propeller, angle=np.radians(-step * k)) for k in range(3)]
        return background, [du.Domain(None, [b]) for b in bodies]

    yield "circle", "conform", {}, circle
    yield "blades", "conform", {}, blades_case
    yield "container_body", "conform", {}, container_body
    yield "graded_propeller", "conform", {"local_size": True}, graded
    yield "moving_blades", "moving", {}, moving_blades
    yield "moving_graded", "moving", {"local_size": True}, moving_graded


def affine_mesh(msh: dmesh.Mesh, degree: int) -> dmesh.Mesh:
    """The degree-q straight (affine) geometry of a degree-1 triangle mesh, as DOLFINx
    numbers it."""
    ce = fem.coordinate_element(dmesh.CellType.triangle, degree, basix.LagrangeVariant.gll_warped)
    return fem.interpolate_geometry(msh, ce)


def affine_geometry(msh: dmesh.Mesh, degree: int) -> np.ndarray:
    """Nodes ``(n, 2)`` of the degree-q straight (affine) geometry of a degree-1 mesh."""
    return affine_mesh(msh, degree).geometry.x[:, :2].copy()


def in_affine_numbering(curved: dmesh.Mesh, affine: dmesh.Mesh) -> np.ndarray:
    """The nodes ``(n, 2)`` of a degree-q mesh numbered as the :func:`affine_mesh` of the
    same topology and degree numbers them: cell by cell, the same reference node.

    A geometry is defined by each cell's nodes, not by the numbering of the nodes, which
    ``curved_mesh`` chooses itself (``_lagrange``) and ``interpolate_geometry`` by a graph
    reordering."""
    x = np.empty((len(affine.geometry.x), 2))
    x[affine.geometry.dofmaps[0]] = curved.geometry.x[curved.geometry.dofmaps[0], :2]
    return x


def curved_nodes(x: np.ndarray, affine: np.ndarray) -> dict[str, np.ndarray]:
    """Nodes of ``x`` away from their affine position: indices and coordinates."""
    idx = np.flatnonzero(np.abs(x - affine).max(axis=1) > AFFINE_TOL).astype(np.int32)
    return {"idx": idx, "x": x[idx]}


def conform_outputs(background: dmesh.Mesh, boundary: du.Boundary, options: dict) -> dict:
    """Everything frozen for one conform case, as named arrays."""
    um = du.UniversalMesh(background, relax=False, **options)
    sm = um.straight_map(boundary)
    cm = um.conform(boundary)
    finite = np.isfinite(sm.phi)
    out: dict[str, np.ndarray] = {
        "sm_sign": sm.sign,
        "sm_phi_finite": finite,
        "sm_phi": sm.phi[finite],
        "sm_closest": sm.closest[finite],
        "sm_x": sm.x,
        "sm_y": sm.y,
        "sm_kept": sm.kept,
        "sm_moved": sm.moved,
        "sm_on_positive_edge": sm.on_gamma,
        "sm_near_cells": np.sort(sm.near_cells),
        "sm_num_relocated": np.array(sm.num_relocated),
        "cm_x": cm.mesh.geometry.x[:, :2].copy(),
        "cm_cell_map": cm.cell_map,
        "cm_vertex_map": cm.vertex_map,
        "cm_sign": cm.sign,
        "cm_moved": cm.moved,
        "cm_on_positive_edge": cm.on_gamma,
        "cm_tag_indices": cm.facet_tags.indices,
        "cm_tag_values": cm.facet_tags.values,
    }
    affine = {q: affine_mesh(cm.mesh, q) for q in (2, 3)}  # each built once
    for q in (2, 3):
        cv = du.curved_mesh(cm, q)
        x = in_affine_numbering(cv.mesh, affine[q])
        for key, value in curved_nodes(x, affine[q].geometry.x[:, :2]).items():
            out[f"curved{q}_{key}"] = value
        out[f"curved{q}_ratio"] = np.array(cv.min_jacobian_ratio)
    cv = du.curved_mesh(cm, 2, "I~")
    x = in_affine_numbering(cv.mesh, affine[2])
    for key, value in curved_nodes(x, affine[2].geometry.x[:, :2]).items():
        out[f"curved2t_{key}"] = value
    return out


def moving_outputs(background: dmesh.Mesh, steps: list, options: dict) -> dict:
    """Geometry nodes (where moved) and the indicator after each of the steps."""
    md = MovingDomain(background, 2, relax=False, **options)
    x0 = md.mesh.geometry.x[:, :2].copy()
    out: dict[str, np.ndarray] = {}
    for k, boundary in enumerate(steps):
        report = md.update(boundary)
        for key, value in curved_nodes(md.mesh.geometry.x[:, :2], x0).items():
            out[f"step{k}_{key}"] = value
        out[f"step{k}_active"] = md.active.x.array.copy()
        out[f"step{k}_immersed"] = np.sort(md.immersed_facets)
        out[f"step{k}_ratio"] = np.array(report.min_jacobian_ratio)
    return out


def outputs(name: str, kind: str, options: dict, build: Callable[[], object]) -> dict:
    background, arg = build()  # type: ignore[misc]
    if kind == "conform":
        return conform_outputs(background, arg, options)
    return moving_outputs(background, arg, options)


def main() -> None:
    comm = MPI.COMM_WORLD
    if comm.size != 1:
        raise SystemExit("run serially: the frozen arrays are process-local")
    DATA.mkdir(parents=True, exist_ok=True)
    total = 0
    for name, kind, options, build in cases(comm):
        path = DATA / f"identity_{name}.npz"
        np.savez_compressed(path, **outputs(name, kind, options, build))
        total += path.stat().st_size
        print(f"{path.relative_to(ROOT)}: {path.stat().st_size / 1e3:.0f} kB")
    print(f"total {total / 1e6:.2f} MB")


if __name__ == "__main__":
    main()
