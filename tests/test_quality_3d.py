"""quality_report of tetrahedral conforming meshes, against a direct computation.

The reference recomputes every figure per cell with other formulas (dihedral angles from
arccos of the facet normals, circumcentres from a linear solve, volumes from determinants)
on the owned cells' geometry nodes and the background cells (through ``cell_map``), and
reduces over the ranks itself. Run serially and under ``mpirun -n 2 python -m pytest -m mpi``.
"""

from __future__ import annotations

from itertools import combinations

from mpi4py import MPI

import numpy as np
import pytest

import dolfinx_universal as du
from dolfinx_universal.backgrounds.lattice_tet import a15_mesh
from dolfinx_universal.boundaries.surfaces import Sphere
from dolfinx_universal.conforming.quality import background_positions, cell_quality

comm = MPI.COMM_WORLD


def _conforming(c: MPI.Comm) -> du.ConformingMesh:
    bg = a15_mesh(c, [[-1.2] * 3, [1.2] * 3], 0.2)
    return du.conform(bg, Sphere([0.05, 0.02, -0.03], 0.9), relax=False, min_angle=0.0)


@pytest.fixture(scope="module")
def cm() -> du.ConformingMesh:
    return _conforming(comm)


def _reference(p: np.ndarray, p0: np.ndarray) -> dict:
    """Per-cell figures of tetrahedra with corners ``p (m, 4, 3)``, background ``p0``."""
    vol = np.linalg.det(p[:, 1:] - p[:, :1]) / 6.0
    vol0 = np.linalg.det(p0[:, 1:] - p0[:, :1]) / 6.0
    angles, lsum = [], np.zeros(len(p))
    for i, j in combinations(range(4), 2):
        k, m = (v for v in range(4) if v not in (i, j))
        e = p[:, j] - p[:, i]
        lsum += (e * e).sum(axis=1)
        # normals of the faces (i, j, k) and (i, j, m), made orthogonal to the edge
        u, w = p[:, k] - p[:, i], p[:, m] - p[:, i]
        e1 = e / np.linalg.norm(e, axis=1)[:, None]
        u -= (u * e1).sum(axis=1)[:, None] * e1
        w -= (w * e1).sum(axis=1)[:, None] * e1
        cos = (u * w).sum(axis=1) / (np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1))
        angles.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    ang = np.array(angles).T
    # circumcentre c: 2 (x_i - x_0) . c = |x_i|^2 - |x_0|^2
    a = 2.0 * (p[:, 1:] - p[:, :1])
    b = (p[:, 1:] ** 2).sum(axis=2) - (p[:, :1] ** 2).sum(axis=2)
    centre = np.linalg.solve(a, b[..., None])[..., 0]
    circ = np.linalg.norm(centre - p[:, 0], axis=1)
    faces = [(1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)]
    area = sum(
        0.5 * np.linalg.norm(np.cross(p[:, j] - p[:, i], p[:, k] - p[:, i]), axis=1)
        for i, j, k in faces
    )
    inr = 3.0 * np.abs(vol) / area
    orient = np.sign(vol0)
    return {
        "angles": ang,
        "radius_ratio": 3.0 * inr / circ,
        "mean_ratio": orient * np.sign(vol) * 12.0 * (3.0 * np.abs(vol)) ** (2 / 3) / lsum,
        "volume_ratio": vol / vol0,
    }


@pytest.mark.mpi
def test_report_matches_direct_computation(cm):
    topo = cm.mesh.topology
    assert topo.dim == 3
    nco = topo.index_map(3).size_local
    dofs = cm.mesh.geometry.dofmaps[0][:nco]
    p = cm.mesh.geometry.x[dofs]
    bg = cm.background
    p0 = bg.geometry.x[bg.geometry.dofmaps[0][cm.cell_map[:nco]]]
    # background_positions agrees with the background cells' own nodes
    np.testing.assert_array_equal(background_positions(cm)[cm.cells[:nco]], p0)
    ref = _reference(p, p0)
    cells = cm.cells[:nco]
    sign, moved = cm.sign[cells], cm.moved[cells]

    def total(v):
        return comm.allreduce(int(v), op=MPI.SUM)

    def low(v):
        return comm.allreduce(float(v.min()) if len(v) else np.inf, op=MPI.MIN)

    def high(v):
        return comm.allreduce(float(v.max()) if len(v) else -np.inf, op=MPI.MAX)

    hist = comm.allreduce(np.histogram(ref["angles"], bins=18, range=(0, 180))[0], op=MPI.SUM)
    rep = du.quality_report(cm)
    assert set(rep) == {
        "n_cells",
        "n_positively_cut",
        "n_unaltered",
        "percent_unaltered",
        "theta_min_deg",
        "theta_max_deg",
        "dihedral_histogram",
        "radius_ratio_min",
        "mean_ratio_min",
        "n_inverted",
        "min_volume_ratio",
    }
    assert rep["n_cells"] == total(nco) == cm.mesh.topology.index_map(3).size_global
    assert rep["n_positively_cut"] == total(((sign > 0).sum(axis=1) == 3).sum())
    assert rep["n_unaltered"] == total((~moved.any(axis=1)).sum())
    assert rep["percent_unaltered"] == pytest.approx(100 * rep["n_unaltered"] / rep["n_cells"])
    assert rep["theta_min_deg"] == pytest.approx(low(ref["angles"]), abs=1e-9)
    assert rep["theta_max_deg"] == pytest.approx(high(ref["angles"]), abs=1e-9)
    assert isinstance(rep["dihedral_histogram"], list)
    assert all(type(c) is int for c in rep["dihedral_histogram"])
    assert rep["dihedral_histogram"] == hist.tolist()
    assert sum(hist) == 6 * rep["n_cells"]
    assert rep["radius_ratio_min"] == pytest.approx(low(ref["radius_ratio"]), rel=1e-9)
    assert rep["mean_ratio_min"] == pytest.approx(low(ref["mean_ratio"]), rel=1e-9)
    assert rep["n_inverted"] == total((ref["volume_ratio"] <= 0).sum()) == 0
    assert rep["min_volume_ratio"] == pytest.approx(low(ref["volume_ratio"]), rel=1e-9)
    # a conforming mesh of a sphere: moved, cut, and still fair tetrahedra
    assert 0 < rep["n_unaltered"] < rep["n_cells"] and rep["n_positively_cut"] > 0
    assert 0 < rep["theta_min_deg"] < 70.53 < rep["theta_max_deg"] < 180
    assert 0 < rep["radius_ratio_min"] < 1 and 0 < rep["mean_ratio_min"] < 1
    assert 0 < rep["min_volume_ratio"] < 1


@pytest.mark.mpi
def test_same_report_on_any_number_of_ranks(cm):
    """The report is global: the mesh conformed on all ranks and on each rank alone agree."""
    got, ref = du.quality_report(cm), du.quality_report(_conforming(MPI.COMM_SELF))
    assert got.keys() == ref.keys()
    for key, value in ref.items():
        assert got[key] == pytest.approx(value, rel=1e-12, abs=1e-14), key
    everywhere = comm.allgather(got)
    assert all(r == everywhere[0] for r in everywhere)


def test_inverted_flat_and_oppositely_oriented_tetrahedra():
    """cell_quality on hand-made tetrahedra: orientation and volumes against the
    background's, whatever its sign; the regular tetrahedron has every ratio 1."""
    reg = np.array([[1, 1, 1], [-1, 1, -1], [1, -1, -1], [-1, -1, 1]], dtype=float)
    assert np.linalg.det(reg[1:] - reg[0]) > 0
    x0 = np.concatenate([reg, reg + 5.0])  # background: two regular tetrahedra
    cells = np.array([[0, 1, 2, 3], [4, 6, 5, 7]])  # the second negatively oriented
    x = x0.copy()
    x[7] = x0[7] - 0.5 * (x0[7] - x0[4:7].mean(axis=0))  # second one: half as high
    sign = np.array([-1.0, 1, 1, 1, 1, 1, 1, 1])
    moved = np.zeros(8, dtype=bool)
    moved[7] = True
    rep = cell_quality(MPI.COMM_SELF, x, x0, cells, sign, moved)
    assert rep["n_cells"] == 2 and rep["n_positively_cut"] == 1 and rep["n_unaltered"] == 1
    assert rep["percent_unaltered"] == 50.0
    assert rep["n_inverted"] == 0
    assert rep["min_volume_ratio"] == pytest.approx(0.5)
    assert 0 < rep["mean_ratio_min"] < 1 and 0 < rep["radius_ratio_min"] < 1
    assert rep["theta_max_deg"] > np.degrees(np.arccos(1 / 3)) > rep["theta_min_deg"]
    assert sum(rep["dihedral_histogram"]) == 12
    # the regular one alone
    one = cell_quality(MPI.COMM_SELF, x, x0, cells[:1], sign, moved)
    assert one["radius_ratio_min"] == pytest.approx(1.0)
    assert one["mean_ratio_min"] == pytest.approx(1.0)
    assert one["theta_min_deg"] == pytest.approx(one["theta_max_deg"])
    assert one["theta_min_deg"] == pytest.approx(np.degrees(np.arccos(1 / 3)))
    assert one["dihedral_histogram"][7] == 6 and one["min_volume_ratio"] == pytest.approx(1)
    # inverted (the top vertex pushed through its base) and flat (exactly in its plane)
    base = x0[4:7].mean(axis=0)
    for top, ratio in ((base - 0.5 * (x0[7] - base), -0.5), (x0[5] + x0[6] - x0[4], 0.0)):
        x[7] = top
        rep = cell_quality(MPI.COMM_SELF, x, x0, cells, sign, moved)
        assert rep["n_inverted"] == 1
        assert rep["min_volume_ratio"] == pytest.approx(ratio)
        if ratio:
            assert rep["mean_ratio_min"] == pytest.approx(-0.84, abs=0.01)
            assert rep["theta_max_deg"] < 180.0
        else:
            assert rep["mean_ratio_min"] == 0.0 and rep["theta_max_deg"] == 180.0
    # no cells on this rank: neutral values
    none = cell_quality(MPI.COMM_SELF, x, x0, cells[:0], sign, moved)
    assert none["n_cells"] == 0 and none["dihedral_histogram"] == [0] * 18
    assert none["theta_min_deg"] == 180.0 and none["theta_max_deg"] == 0.0
    assert none["min_volume_ratio"] == np.inf and none["percent_unaltered"] == 0.0
