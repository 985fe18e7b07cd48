"""Property tests of ``mesh_domain``: seeded random smooth domains, meshes checked independently.

Every case ``(seed, degree)`` meshes ``random_domain(seed)`` at its coarse largest size with
``mesh_domain`` and checks the mesh with ``mesh_checks.check_mesh`` (det J on a fine
lattice, nodes on Gamma, area, loops, pieces) and the certificate against those
measurements. Reproduce a failure with::

    python -c "import sys; sys.path.insert(0, 'tests'); import test_property_domains as t; \\
        print(t.run_case(SEED, DEGREE))"
"""

from __future__ import annotations

import time
from typing import Any

from mpi4py import MPI

import pytest
from conftest import needs_ranks
from mesh_checks import check_domain_mesh
from random_domains import KINDS, random_domain

import dolfinx_universal as du

N_SEEDS = 120
"""Seeds ``0 .. N_SEEDS - 1``; seed ``s`` has kind ``KINDS[s % 5]`` and degree ``1 + s % 4``,
so each (kind, degree) pair comes ``N_SEEDS / 20`` times."""
CASES = [(seed, 1 + seed % 4) for seed in range(N_SEEDS)]
JACOBIAN_SLACK = 1e-9
"""The certificate's det J ratio is a proven lower bound: at most the sampled minimum."""
ANGLE_SLACK = 1e-6
"""Degrees by which the certificate's angles may differ from the measured ones."""


def certificate_failures(cert: Any, r: dict, n_curves: int, n_pieces: int) -> list[str]:
    """Claims of the certificate that the independent measurements ``r`` contradict."""
    out = []
    get = getattr
    if cert.min_angle_deg > r["min_angle_deg"] + ANGLE_SLACK:
        out.append(
            f"certificate min angle {cert.min_angle_deg:.6g} > measured {r['min_angle_deg']:.6g}"
        )
    if cert.max_angle_deg < r["max_angle_deg"] - ANGLE_SLACK:
        out.append(
            f"certificate max angle {cert.max_angle_deg:.6g} < measured {r['max_angle_deg']:.6g}"
        )
    if cert.min_jacobian_ratio > r["min_detJ_ratio"] + JACOBIAN_SLACK:
        out.append(
            f"certificate det J ratio {cert.min_jacobian_ratio:.6g} > sampled minimum "
            f"{r['min_detJ_ratio']:.6g}"
        )
    if not cert.min_jacobian_ratio > 0:
        out.append(f"certificate det J ratio {cert.min_jacobian_ratio:.3g} is not positive")
    floor = get(cert, "min_angle_floor_deg", None)
    if floor is not None and r["min_angle_deg"] < floor - ANGLE_SLACK:
        out.append(f"measured min angle {r['min_angle_deg']:.6g} below the floor {floor}")
    for name, want in (("num_loops", n_curves), ("num_pieces", n_pieces)):
        got = get(cert, name, want)
        if got != want:
            out.append(f"certificate {name} = {got}, expected {want}")
    cells = get(cert, "num_cells", r["num_cells"])
    if cells != r["num_cells"]:
        out.append(f"certificate num_cells = {cells}, mesh has {r['num_cells']}")
    if not isinstance(cert.refinement_rounds, int) or cert.refinement_rounds < 0:
        out.append(f"refinement_rounds = {cert.refinement_rounds!r}")
    return out


def run_case(seed: int, degree: int, comm: MPI.Comm = MPI.COMM_WORLD) -> dict:
    """Mesh and check one case; the checker's numbers, ``failures`` and ``label``."""
    d = random_domain(seed)
    label = f"seed={seed} kind={d.kind} degree={degree}"
    t0 = time.perf_counter()
    try:
        res = du.mesh_domain(comm, d.boundary, d.h, degree=degree)
    except du.MeshingError as e:
        return {"label": label, "failures": [f"{label}: MeshingError: {e}"], "domain": d}
    t1 = time.perf_counter()
    r = check_domain_mesh(res.mesh, res.facet_tags, d, label)
    r["failures"] += [
        f"{label}: {m}" for m in certificate_failures(res.certificate, r, d.n_curves, d.n_pieces)
    ]
    r.update(
        label=label,
        domain=d,
        mesh_time=t1 - t0,
        check_time=time.perf_counter() - t1,
        certificate=res.certificate,
    )
    return r


@pytest.mark.parametrize(("seed", "degree"), CASES, ids=[f"seed{s}-q{q}" for s, q in CASES])
def test_random_domain(seed, degree):
    r = run_case(seed, degree)
    d = r["domain"]
    assert not r["failures"], (
        "\n".join(r["failures"])
        + f"\n  domain: {d.description}"
        + f"\n  reproduce: random_domain({seed}) -> mesh_domain(comm, d.boundary, {d.h!r}, "
        f"degree={degree})"
    )


def test_cases_cover_every_kind_and_degree():
    assert all(random_domain(s).kind == KINDS[s % len(KINDS)] for s in range(10))
    pairs = {(KINDS[s % len(KINDS)], q) for s, q in CASES}
    assert pairs == {(k, q) for k in KINDS for q in (1, 2, 3, 4)}
    assert len(CASES) >= 100


def _record(seed: int, degree: int, c: MPI.Comm) -> dict[str, Any]:
    r = run_case(seed, degree, c)
    cert = r.pop("certificate", None)
    r.pop("domain")
    rec = {k: v for k, v in r.items() if not k.endswith("_at") and not k.endswith("_time")}
    rec["refinement_rounds"] = getattr(cert, "refinement_rounds", None)
    return rec


@pytest.mark.mpi
@needs_ranks(2)
def test_random_domains_in_parallel():
    """The same meshes, certificates and measurements on all ranks as on one."""
    for seed, degree in ((0, 2), (6, 3), (12, 4), (13, 2), (19, 1)):
        g, r = _record(seed, degree, MPI.COMM_WORLD), _record(seed, degree, MPI.COMM_SELF)
        case = r["label"]
        assert r["failures"] == [] and g["failures"] == [], (case, r["failures"], g["failures"])
        for k in ("num_cells", "n_loops", "n_pieces", "n_immersed_facets", "refinement_rounds"):
            assert g[k] == r[k], (case, k)
        # the same mesh: sums in another order, nodes computed by another rank (rounding,
        # ~1e-15 relative); abs: a floor for values near 0
        for k in ("area", "boundary_defect", "min_detJ_ratio", "min_angle_deg"):
            assert g[k] == pytest.approx(r[k], rel=1e-9, abs=1e-13), (case, k)
