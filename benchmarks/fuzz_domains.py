"""Fuzz ``mesh_domain`` with seeded random smooth domains and check every mesh independently.

Each seed gives a random domain (``tests/random_domains.py``: splines, polar curves,
ellipses, containers with bodies, thin necks) and a coarse largest size ``h``; the domain
is meshed with ``dolfinx_universal.mesh_domain(comm, boundary, h, degree=q)`` and the mesh
is checked by ``tests/mesh_checks.py`` (det J on a fine lattice, nodes on Gamma, area,
loops and pieces). Outcomes: ``ok``, ``meshing_error`` (``MeshingError``), ``wrong_mesh``
(a check failed), ``exception`` (anything else).

Without ``mesh_domain`` (older package), each domain is conformed instead on a uniform
equilateral background fine enough for its smallest feature (outcome ``skipped`` above
``--max-cells`` background cells): a baseline of the checks, not of the mesher.

    python benchmarks/fuzz_domains.py --quick --out out/fuzz
    python benchmarks/fuzz_domains.py --n 2000 --degrees 1,2,3,4 --out out/fuzz

``--dim 3``: random closed surfaces instead (``tests/random_surfaces.py``: ellipsoids up to
aspect 6, tori with random axes, superellipsoids and Gaussian blobs under random rigid
motions, containers with 1-3 bodies), meshed with ``mesh_domain(comm, surface, h)`` (degree
1) and checked by ``tests/mesh_checks_3d.py`` (signed volumes, the immersed faces as a
closed oriented 2-manifold with the right Euler characteristics, vertices on Gamma, volume
against the exact one, one piece); the same outcomes, plus the smallest and largest
dihedral angles (target: at least 20 degrees on every domain), refinement rounds and times.

    python benchmarks/fuzz_domains.py --dim 3 --n 20 --out out/fuzz3d
    python benchmarks/fuzz_domains.py --dim 3 --n 500 --out out/fuzz3d

``--dim 3 --degrees 2,3,4``: curved tetrahedra (``mesh_domain(..., degree=q)``, q cycled over
the seeds); the straight mesh is checked as above and the curved one by
``tests/mesh_checks_3d.check_curved_surface_mesh``: ``det J`` sampled on a lattice of every
curved cell (positive, and not below the certificate's proven bound), every node of the
immersed faces on Gamma, the volume within the straight mesh's a priori bound (and its
gain over the straight mesh reported).

``--dim 3 --moving K``: each surface moved through ``K`` positions of a random rigid motion
on one background (``MovingDomain.from_motion``), visited in order and one step back; after
every update the active cells and nodes must equal a fresh ``conform`` + ``curved_mesh`` of
the same position, which is checked as above.

    python benchmarks/fuzz_domains.py --dim 3 --n 300 --degrees 2,3,4 --out out/fuzz3d_curved
    python benchmarks/fuzz_domains.py --dim 3 --n 100 --degrees 1,2,3 --moving 4 --out out/moving

``--against-serial`` (under mpirun, static meshes, both dimensions): rank 0 also meshes each
domain on one rank and every node of the parallel mesh must have a node of the serial one
within :data:`SERIAL_ATOL` times the extent, and the other way round (a ``wrong_mesh``
otherwise: the same mesh on any number of ranks, to rounding).

    mpirun -n 3 python benchmarks/fuzz_domains.py --dim 3 --n 20 --degrees 2,3,4 --against-serial
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from mpi4py import MPI

import numpy as np

import dolfinx_universal as du

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import _results  # noqa: E402  (the results' common header)
from mesh_checks import check_domain_mesh  # noqa: E402
from random_domains import KINDS, random_domain  # noqa: E402

OUTCOMES = ("ok", "meshing_error", "wrong_mesh", "exception", "skipped")
OUTCOMES_3D = ("ok", "meshing_error", "wrong_mesh", "exception", "timeout")
TARGET_DIHEDRAL = 20.0
"""The issue's target: smallest dihedral angle of every 3D mesh (degrees)."""


def _cert(result: Any, name: str) -> Any:
    """A certificate field, or None."""
    value = getattr(getattr(result, "certificate", None), name, None)
    return value if isinstance(value, (int, float, str, type(None))) else str(value)


def _baseline(comm: MPI.Comm, d: Any, degree: int, max_cells: float) -> Any:
    """Conform on a uniform background fine enough for the domain (no ``mesh_domain``)."""
    hb = d.uniform_size()
    box = d.box(4 * hb + 0.05 * d.extent)
    cells = 2.4 * np.prod(box[1] - box[0]) / hb**2
    if cells > max_cells:
        return None
    cm = du.conform(du.equilateral_mesh(comm, box, hb), d.boundary)
    return du.curved_mesh(cm, degree)


def _reference_time(comm: MPI.Comm, result: Any, boundary: du.Boundary, degree: int) -> Any:
    """Seconds of one ``conform`` + ``curved_mesh`` on the final background, if exposed."""
    bg = getattr(result, "background", None)
    if bg is None:
        bg = getattr(getattr(result, "certificate", None), "background", None)
    if bg is None:
        return None
    try:
        comm.Barrier()
        t0 = time.perf_counter()
        cm = du.conform(bg, boundary, local_size=True)
        du.curved_mesh(cm, degree)
        return time.perf_counter() - t0
    except Exception:  # noqa: BLE001 - the reference is optional
        return None


SERIAL_ATOL = 1e-12
"""Largest difference (relative to the extent of the mesh) between the nodes of a mesh made
on several ranks and those of the same mesh made on one (``--against-serial``): the same
computation on another partition, so rounding of O(extent) coordinates (measured at most
1.7e-14 on random surfaces, 9e-16 on planar domains); a changed node moves far more."""


def serial_gap(comm: MPI.Comm, msh: Any, serial: Callable[[], Any]) -> float:
    """The largest distance between a node of ``msh`` (made on ``comm``) and the nearest node
    of ``serial()``, the same mesh made on one rank (rank 0, ``COMM_SELF``), both ways and
    relative to the extent; ``inf`` where the node counts differ or the serial mesh fails.
    The same value on every rank (collective)."""
    from scipy.spatial import cKDTree

    n = msh.geometry.index_map().size_local
    parts = comm.gather(msh.geometry.x[:n], root=0)
    gap = 0.0
    if comm.rank == 0:
        x = np.concatenate(parts)
        try:
            one = serial()
            y = one.geometry.x[: one.geometry.index_map().size_local]
        except Exception:  # noqa: BLE001 - a serial failure is a difference
            y = None
        if y is None or len(y) != len(x):
            gap = np.inf
        elif len(x):
            extent = float(np.linalg.norm(x.max(axis=0) - x.min(axis=0))) or 1.0
            d = max(cKDTree(y).query(x)[0].max(), cKDTree(x).query(y)[0].max())
            gap = float(d) / extent
    return float(comm.bcast(gap, root=0))


def _against_serial(
    comm: MPI.Comm, rec: dict, msh: Any, serial: Callable[[], Any], label: str
) -> list[str]:
    """:func:`serial_gap` recorded in ``rec``; the failure it makes, if any (collective)."""
    gap = rec["serial_gap"] = serial_gap(comm, msh, serial)
    return (
        [f"{label}: the mesh differs from the serial one by {gap:.3g}"] if gap > SERIAL_ATOL else []
    )


def run_one(
    comm: MPI.Comm,
    seed: int,
    degree: int,
    max_cells: float,
    ref: bool,
    against_serial: bool = False,
) -> dict:
    """Mesh and check one random domain; a JSON-serialisable record."""
    d = random_domain(seed)
    rec: dict[str, Any] = {
        "seed": seed,
        "kind": d.kind,
        "degree": degree,
        "h": d.h,
        "h_over_feature": d.h / d.min_feature,
        "description": d.description,
    }
    have = hasattr(du, "mesh_domain")
    comm.Barrier()
    t0 = time.perf_counter()
    try:
        if have:
            result = du.mesh_domain(comm, d.boundary, d.h, degree=degree)
        else:
            result = _baseline(comm, d, degree, max_cells)
    except du.MeshingError as e:
        rec.update(outcome="meshing_error", message=str(e).splitlines()[0][:300])
        rec["time"] = time.perf_counter() - t0
        return rec
    except Exception as e:  # noqa: BLE001 - every failure is recorded
        rec.update(
            outcome="exception",
            message=f"{type(e).__name__}: {e}"[:300],
            traceback=traceback.format_exc()[-2000:],
        )
        rec["time"] = time.perf_counter() - t0
        return rec
    rec["time"] = time.perf_counter() - t0
    if result is None:
        rec.update(outcome="skipped", message="background too large for the baseline")
        return rec
    label = f"seed={seed} kind={d.kind} degree={degree}"
    t1 = time.perf_counter()
    try:
        r = check_domain_mesh(result.mesh, result.facet_tags, d, label)
    except Exception as e:  # noqa: BLE001
        rec.update(
            outcome="exception",
            message=f"check_mesh: {type(e).__name__}: {e}"[:300],
            traceback=traceback.format_exc()[-2000:],
        )
        return rec
    rec["check_time"] = time.perf_counter() - t1
    failures = list(r["failures"])
    if against_serial and have and comm.size > 1:
        failures += _against_serial(
            comm,
            rec,
            result.mesh,
            lambda: du.mesh_domain(MPI.COMM_SELF, d.boundary, d.h, degree=degree).mesh,
            label,
        )
    rec["outcome"] = "wrong_mesh" if failures else "ok"
    if failures:
        rec["message"] = " | ".join(failures)[:600]
    for k in (
        "num_cells",
        "min_detJ_ratio",
        "min_angle_deg",
        "max_angle_deg",
        "area_rel_error",
        "area_constant",
        "boundary_deviation",
        "h_near",
    ):
        rec[k] = r[k]
    for k in (
        "min_angle_deg",
        "max_angle_deg",
        "min_jacobian_ratio",
        "refinement_rounds",
        "h_min",
        "num_background_cells",
    ):
        rec[f"cert_{k}"] = _cert(result, k)
    if ref and have:
        tr = _reference_time(comm, result, d.boundary, degree)
        rec["reference_time"] = tr
        rec["time_ratio"] = rec["time"] / tr if tr else None
    return rec


def _pct(values: list[float], q: list[float]) -> list[float] | None:
    v = [x for x in values if x is not None and np.isfinite(x)]
    return np.percentile(v, q).round(6).tolist() if v else None


def summarise(records: list[dict], wall: float) -> dict:
    """Counts, rates, times and quality percentiles of the records."""
    n = len(records)
    counts = Counter(r["outcome"] for r in records)
    by = {
        f"{k}/q{q}": Counter(r["outcome"] for r in records if r["kind"] == k and r["degree"] == q)
        for k in KINDS
        for q in sorted({r["degree"] for r in records})
    }
    times = [r["time"] for r in records if r["outcome"] in ("ok", "wrong_mesh")]
    rounds = Counter(r.get("cert_refinement_rounds") for r in records if r["outcome"] == "ok")
    return {
        "n": n,
        "mesher": "mesh_domain" if hasattr(du, "mesh_domain") else "uniform baseline",
        "wall_s": wall,
        "counts": {k: counts.get(k, 0) for k in OUTCOMES},
        "success_rate": counts.get("ok", 0) / n if n else 0.0,
        "by_kind_degree": {k: dict(v) for k, v in by.items() if v},
        "time_s": {
            "median": float(np.median(times)) if times else None,
            "max": float(np.max(times)) if times else None,
        },
        "check_time_s_median": float(
            np.median([r["check_time"] for r in records if "check_time" in r] or [np.nan])
        ),
        "min_angle_percentiles_0_1_5_50": _pct(
            [r.get("cert_min_angle_deg") for r in records if r["outcome"] == "ok"], [0, 1, 5, 50]
        ),
        "measured_min_angle_percentiles_0_1_5_50": _pct(
            [r.get("min_angle_deg") for r in records if r["outcome"] == "ok"], [0, 1, 5, 50]
        ),
        "min_detJ_ratio_percentiles_0_1_5_50": _pct(
            [r.get("min_detJ_ratio") for r in records if r["outcome"] == "ok"], [0, 1, 5, 50]
        ),
        "refinement_rounds": {str(k): v for k, v in sorted(rounds.items(), key=str)},
        "time_ratio_to_conform": _pct([r.get("time_ratio") for r in records], [50, 100]),
        "failures": [
            {k: r.get(k) for k in ("seed", "kind", "degree", "outcome", "message", "description")}
            for r in records
            if r["outcome"] not in ("ok", "skipped")
        ],
    }


def print_table(s: dict) -> None:
    """The summary as text."""
    print(f"\n{s['n']} random domains through {s['mesher']} in {s['wall_s']:.1f} s")
    print("| outcome | count |\n|---|---|")
    for k, v in s["counts"].items():
        print(f"| {k} | {v} |")
    print(f"success rate: {100 * s['success_rate']:.2f} %")
    t = s["time_s"]
    if t["median"] is not None:
        print(
            f"time per domain: median {t['median']:.3f} s, max {t['max']:.3f} s "
            f"(checks: median {s['check_time_s_median']:.3f} s)"
        )
    print(f"certificate min angle p0/p1/p5/p50: {s['min_angle_percentiles_0_1_5_50']}")
    print(f"measured min angle p0/p1/p5/p50: {s['measured_min_angle_percentiles_0_1_5_50']}")
    print(f"min det J ratio p0/p1/p5/p50: {s['min_detJ_ratio_percentiles_0_1_5_50']}")
    print(f"refinement rounds: {s['refinement_rounds']}")
    print(
        f"mesh_domain / (conform + curved_mesh on final background) p50/max: "
        f"{s['time_ratio_to_conform']}"
    )
    print("\n| kind/degree | outcomes |\n|---|---|")
    for k, v in s["by_kind_degree"].items():
        print(f"| {k} | {', '.join(f'{o}: {c}' for o, c in sorted(v.items()))} |")
    for f in s["failures"][:20]:
        print(
            f"- seed={f['seed']} kind={f['kind']} degree={f['degree']}: {f['outcome']}: "
            f"{f['message']}"
        )


# ----------------------------------------------------------------------------- 3D mode
class _Timeout(BaseException):
    """``mesh_domain`` ran past ``--timeout`` (serial runs only). A BaseException: the
    package turns the Exceptions of user callbacks into MeshingErrors."""


def _alarm(signum: int, frame: Any) -> None:
    raise _Timeout


def _stopped(rec: dict, t0: float, e: BaseException, timeout_message: str) -> dict:
    """The record of a 3D run stopped by ``e`` (in an ``except`` block): ``timeout``,
    ``meshing_error`` (the message) or ``exception`` (with the traceback); its time."""
    if isinstance(e, _Timeout):
        rec.update(outcome="timeout", message=timeout_message)
    elif isinstance(e, du.MeshingError):
        rec.update(outcome="meshing_error", message=str(e)[:1500])
    else:
        rec.update(
            outcome="exception",
            message=f"{type(e).__name__}: {e}"[:400],
            traceback=traceback.format_exc()[-2000:],
        )
    rec["time"] = time.perf_counter() - t0
    return rec


def run_one_3d(
    comm: MPI.Comm,
    seed: int,
    mild: bool,
    max_cells: float,
    timeout: float | None = None,
    degree: int = 1,
    against_serial: bool = False,
) -> dict:
    """Mesh and check one random surface at geometry degree ``degree``; a JSON record.

    The straight mesh is checked by ``check_surface_mesh``; for ``degree >= 2`` the curved
    mesh also by ``check_curved_surface_mesh`` (sampled ``det J``, nodes on Gamma, volume).

    With ``timeout`` (seconds, serial only) a ``mesh_domain`` call still running then is
    stopped (at the next Python bytecode) and recorded as ``timeout``.
    """
    import signal

    from mesh_checks_3d import check_curved_surface_mesh, check_surface_mesh
    from random_surfaces import random_surface

    t0 = time.perf_counter()
    d = random_surface(seed, mild=mild)
    rec: dict[str, Any] = {
        "seed": seed,
        "kind": d.kind,
        "degree": degree,
        "h": d.h,
        "h_over_feature": d.h / d.min_feature,
        "extent_over_feature": d.extent / d.min_feature,
        "estimated_cells": d.estimated_cells,
        "n_surfaces": d.n_components,
        "description": d.description,
        "generate_time": time.perf_counter() - t0,
    }
    comm.Barrier()
    alarm = timeout is not None and comm.size == 1
    if alarm:
        signal.signal(signal.SIGALRM, _alarm)
        signal.setitimer(signal.ITIMER_REAL, float(timeout))  # type: ignore[arg-type]
    t0 = time.perf_counter()
    try:
        result = du.mesh_domain(comm, d.boundary, d.h, degree=degree, max_cells=max_cells)
    except (_Timeout, Exception) as e:  # noqa: BLE001 - every failure is recorded
        return _stopped(rec, t0, e, f"mesh_domain still running after {timeout} s")
    finally:
        if alarm:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
    rec["time"] = time.perf_counter() - t0
    rec["timings"] = dict(result.timings)
    t1 = time.perf_counter()
    try:
        cm = result.conforming
        r = check_surface_mesh(cm.mesh, cm.facet_tags, d, d.label)
        rc = None
        if degree > 1:
            rc = check_curved_surface_mesh(
                result.mesh,
                result.facet_tags,
                d,
                r,
                result.certificate.min_jacobian_ratio,
                f"{d.label} q={degree}",
            )
    except Exception as e:  # noqa: BLE001
        rec.update(
            outcome="exception",
            message=f"check_surface_mesh: {type(e).__name__}: {e}"[:400],
            traceback=traceback.format_exc()[-2000:],
        )
        return rec
    rec["check_time"] = time.perf_counter() - t1
    failures = r["failures"] + (rc["failures"] if rc is not None else [])
    if against_serial and comm.size > 1:

        def serial() -> Any:
            return du.mesh_domain(
                MPI.COMM_SELF, d.boundary, d.h, degree=degree, max_cells=max_cells
            ).mesh

        failures += _against_serial(comm, rec, result.mesh, serial, d.label)
    rec["outcome"] = "wrong_mesh" if failures else "ok"
    if failures:
        rec["message"] = " | ".join(failures)[:800]
    if rc is not None:
        for k in ("curved_cells", "min_sampled_jacobian_ratio", "volume_gain"):
            rec[k] = rc[k]
        rec["curved_volume_rel_error"] = rc["volume_rel_error"]
        rec["curved_max_node_distance"] = rc["max_node_distance"]
    for k in (
        "num_cells",
        "min_dihedral_deg",
        "max_dihedral_deg",
        "min_normalised_volume",
        "volume_rel_error",
        "volume_constant",
        "max_node_distance",
        "surface_faces",
        "surface_euler",
        "h_face",
    ):
        rec[k] = r[k]
    rec["below_target"] = bool(r["min_dihedral_deg"] < TARGET_DIHEDRAL)
    for k in (
        "min_jacobian_ratio",
        "min_angle_deg",
        "max_angle_deg",
        "refinement_rounds",
        "refinements",
        "h_min",
        "num_background_cells",
    ):
        rec[f"cert_{k}"] = _cert(result, k)
    return rec


MOVING_ATOL = 1e-12
"""Largest difference (relative to the extent of Gamma) between a moving update's nodes and
those of a fresh ``conform`` + ``curved_mesh`` of the same position: the same computation in
another order of the cells (a node shared by two cells is written by each), so rounding of
the O(extent) coordinates, about 1e-16 relative; 1e-12 is far below any changed node."""


def run_one_moving_3d(
    comm: MPI.Comm,
    seed: int,
    mild: bool,
    degree: int,
    steps: int,
    timeout: float | None = None,
) -> dict:
    """One random surface moved by a random rigid motion through ``MovingDomain``.

    The positions ``k = 0 .. steps - 1`` turn the surface about a random axis through its
    centre by ``k theta / (steps - 1)`` (``theta`` uniform in [0.2, 1.2] rad) and translate
    it by ``k d / (steps - 1)`` (``|d|`` uniform in [0.5, 3] h, a random direction).
    ``MovingDomain.from_motion`` sizes one background for all of them; the positions are
    then visited in order and position 1 once more (a step back). After every step the
    active cells and their nodes must equal those of a fresh ``conform`` + ``curved_mesh``
    of that position on the same background (:data:`MOVING_ATOL`, the indicator exactly),
    and that fresh mesh must pass ``check_surface_mesh`` and, for ``degree >= 2``,
    ``check_curved_surface_mesh`` against the moved surface's exact data (the update's
    proven Jacobian ratio as the certificate).
    """
    import signal

    from mesh_checks_3d import active_node_gap, check_curved_surface_mesh, check_surface_mesh
    from random_surfaces import moved_surface, random_surface
    from scipy.spatial.transform import Rotation

    d = random_surface(seed, mild=mild)
    rng = np.random.default_rng([seed, 31])
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    theta = rng.uniform(0.2, 1.2)
    shift = rng.normal(size=3)
    shift *= rng.uniform(0.5, 3.0) * d.h / np.linalg.norm(shift)
    centre = d.shapes[0].samples(2000).mean(axis=0)
    fractions = np.linspace(0.0, 1.0, steps)
    positions = [
        moved_surface(d, Rotation.from_rotvec(f * theta * axis).as_matrix(), centre, f * shift)
        for f in fractions
    ]
    rec: dict[str, Any] = {
        "seed": seed,
        "kind": d.kind,
        "degree": degree,
        "h": d.h,
        "steps": steps,
        "theta": theta,
        "shift_over_h": float(np.linalg.norm(shift) / d.h),
        "estimated_cells": d.estimated_cells,
        "description": d.description,
    }
    alarm = timeout is not None and comm.size == 1
    if alarm:
        signal.signal(signal.SIGALRM, _alarm)
        signal.setitimer(signal.ITIMER_REAL, float(timeout))  # type: ignore[arg-type]
    t0 = time.perf_counter()
    failures: list[str] = []
    try:
        md = du.MovingDomain.from_motion(comm, [p.boundary for p in positions], d.h, degree=degree)
        rec["num_background_cells"] = md.mesh.topology.index_map(3).size_global
        rec["refinement_rounds"] = md.refinement_rounds
        dmin, gap, ratio = np.inf, 0.0, np.inf
        update_time = 0.0
        for k in [*range(steps), 1]:
            p = positions[k]
            label = f"{d.label} q={degree} position {k}"
            t1 = time.perf_counter()
            report = md.update(p.boundary)
            update_time += time.perf_counter() - t1
            cm = md.universal.conform(p.boundary)
            fresh = du.curved_mesh(cm, degree, md.map) if degree > 1 else None
            same, g = active_node_gap(md, cm, fresh.mesh if fresh is not None else cm.mesh)
            if not comm.allreduce(same, op=MPI.LAND):
                failures.append(f"{label}: the active cells are not the cells conform keeps")
            else:
                gap = max(gap, comm.allreduce(g, op=MPI.MAX))
            r = check_surface_mesh(cm.mesh, cm.facet_tags, p, label)
            failures += r["failures"]
            dmin = min(dmin, r["min_dihedral_deg"])
            if fresh is not None:
                rc = check_curved_surface_mesh(
                    fresh.mesh, fresh.facet_tags, p, r, report.min_jacobian_ratio, label
                )
                failures += rc["failures"]
                ratio = min(ratio, rc["min_sampled_jacobian_ratio"])
        if gap > MOVING_ATOL * d.extent:
            failures.append(
                f"{d.label} q={degree}: a moving update's nodes differ from a fresh "
                f"conform + curved_mesh by {gap:.3g}"
            )
    except (_Timeout, Exception) as e:  # noqa: BLE001 - every failure is recorded
        return _stopped(rec, t0, e, f"still running after {timeout} s")
    finally:
        if alarm:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
    rec["time"] = time.perf_counter() - t0
    rec["update_time_s"] = update_time / (steps + 1)
    rec["outcome"] = "wrong_mesh" if failures else "ok"
    if failures:
        rec["message"] = " | ".join(failures)[:800]
    rec["max_gap_to_fresh"] = gap
    rec["min_dihedral_deg"] = dmin
    rec["min_sampled_jacobian_ratio"] = ratio if degree > 1 else None
    return rec


def summarise_3d(records: list[dict], wall: float) -> dict:
    """Counts, times and dihedral-angle percentiles of the 3D records."""
    from random_surfaces import KINDS as KINDS_3D

    n = len(records)
    counts = Counter(r["outcome"] for r in records)
    meshed = [r for r in records if r["outcome"] in ("ok", "wrong_mesh")]
    times = [r["time"] for r in meshed]
    rounds = Counter(r.get("cert_refinement_rounds") for r in meshed)
    q = [0, 1, 5, 50]
    return {
        "n": n,
        "dim": 3,
        "mesher": ("MovingDomain" if any("steps" in r for r in records) else "mesh_domain")
        + " (degree "
        + ",".join(str(q) for q in sorted({r.get("degree", 1) for r in records}))
        + ")",
        "by_degree": {
            str(q): dict(Counter(r["outcome"] for r in records if r.get("degree", 1) == q))
            for q in sorted({r.get("degree", 1) for r in records})
        },
        "curved_sampled_jacobian_ratio_percentiles_0_1_50": _pct(
            [r.get("min_sampled_jacobian_ratio") for r in meshed if r.get("degree", 1) > 1],
            [0, 1, 50],
        ),
        "curved_certificate_ratio_percentiles_0_1_50": _pct(
            [r.get("cert_min_jacobian_ratio") for r in meshed if r.get("degree", 1) > 1],
            [0, 1, 50],
        ),
        "curved_volume_gain_percentiles_0_50": _pct(
            [r.get("volume_gain") for r in meshed if r.get("degree", 1) > 1], [0, 50]
        ),
        "wall_s": wall,
        "counts": {k: counts.get(k, 0) for k in OUTCOMES_3D},
        "success_rate": counts.get("ok", 0) / n if n else 0.0,
        "by_kind": {
            k: dict(Counter(r["outcome"] for r in records if r["kind"] == k)) for k in KINDS_3D
        },
        "time_s": {
            "median": float(np.median(times)) if times else None,
            "mean": float(np.mean(times)) if times else None,
            "max": float(np.max(times)) if times else None,
            "per_kind_median": {
                k: float(np.median([r["time"] for r in meshed if r["kind"] == k]))
                for k in KINDS_3D
                if any(r["kind"] == k for r in meshed)
            },
        },
        "check_time_s_median": float(
            np.median([r["check_time"] for r in records if "check_time" in r] or [np.nan])
        ),
        "num_cells_percentiles_50_100": _pct([r.get("num_cells") for r in meshed], [50, 100]),
        "min_dihedral_percentiles_0_1_5_50": _pct([r.get("min_dihedral_deg") for r in meshed], q),
        "max_dihedral_percentiles_50_95_99_100": _pct(
            [r.get("max_dihedral_deg") for r in meshed], [50, 95, 99, 100]
        ),
        "below_target": [r["seed"] for r in meshed if r.get("below_target")],
        "volume_constant_percentiles_50_100": _pct(
            [r.get("volume_constant") for r in meshed], [50, 100]
        ),
        "refinement_rounds": {str(k): v for k, v in sorted(rounds.items(), key=str)},
        "failures": [
            {k: r.get(k) for k in ("seed", "kind", "outcome", "message", "description")}
            for r in records
            if r["outcome"] != "ok"
        ],
    }


def print_table_3d(s: dict) -> None:
    """The 3D summary as text."""
    print(f"\n{s['n']} random surfaces through {s['mesher']} in {s['wall_s']:.1f} s")
    print("| outcome | count |\n|---|---|")
    for k, v in s["counts"].items():
        print(f"| {k} | {v} |")
    print(f"success rate: {100 * s['success_rate']:.2f} %")
    t = s["time_s"]
    if t["median"] is not None:
        print(
            f"time per domain: median {t['median']:.2f} s, mean {t['mean']:.2f} s, max "
            f"{t['max']:.2f} s (checks: median {s['check_time_s_median']:.2f} s); per kind "
            + ", ".join(f"{k} {v:.2f}" for k, v in t["per_kind_median"].items())
        )
    print(f"min dihedral p0/p1/p5/p50: {s['min_dihedral_percentiles_0_1_5_50']}")
    print(f"max dihedral p50/p95/p99/p100: {s['max_dihedral_percentiles_50_95_99_100']}")
    print(f"below {TARGET_DIHEDRAL:g} degrees: {s['below_target']}")
    print(f"cells p50/p100: {s['num_cells_percentiles_50_100']}")
    print(f"volume constant p50/p100: {s['volume_constant_percentiles_50_100']}")
    print(f"refinement rounds: {s['refinement_rounds']}")
    print(f"outcomes by degree: {s['by_degree']}")
    if any(q != "1" for q in s["by_degree"]):
        print(
            "curved: sampled det J ratio p0/p1/p50 "
            f"{s['curved_sampled_jacobian_ratio_percentiles_0_1_50']}, proven (certificate) "
            f"{s['curved_certificate_ratio_percentiles_0_1_50']}, volume error straight / "
            f"curved p0/p50 {s['curved_volume_gain_percentiles_0_50']}"
        )
    print("\n| kind | outcomes |\n|---|---|")
    for k, v in s["by_kind"].items():
        print(f"| {k} | {', '.join(f'{o}: {c}' for o, c in sorted(v.items()))} |")
    for f in s["failures"][:40]:
        print(f"- seed={f['seed']} kind={f['kind']}: {f['outcome']}: {f['message']}")


def _progress_3d(rec: dict) -> str:
    """One line on a 3D record (static or moving)."""
    seed, degree, outcome = rec["seed"], rec["degree"], rec["outcome"]
    meshed = outcome in ("ok", "wrong_mesh")
    if "steps" in rec:  # a moving record
        extra = (
            f"bg {rec['num_background_cells']} tets, update {rec['update_time_s']:.2f} s, gap "
            f"to fresh {rec['max_gap_to_fresh']:.1e}, min dihedral {rec['min_dihedral_deg']:.1f}"
            if meshed
            else ""
        )
        head = f"seed={seed} kind={rec['kind']} q={degree} moving: {outcome} in {rec['time']:.1f} s"
    else:
        extra = (
            f"dihedral [{rec['min_dihedral_deg']:.1f}, {rec['max_dihedral_deg']:.1f}]"
            if "min_dihedral_deg" in rec
            else ""
        )
        if "min_sampled_jacobian_ratio" in rec:
            extra += (
                f" q={degree}: det J ratio >= {rec['cert_min_jacobian_ratio']:.3f} "
                f"(sampled {rec['min_sampled_jacobian_ratio']:.3f}), volume "
                f"{rec['volume_gain']:.0f}x better than straight"
            )
        if "serial_gap" in rec:
            extra += f", serial gap {rec['serial_gap']:.1e}"
        head = (
            f"seed={seed} kind={rec['kind']}: {outcome} in {rec['time']:.1f} s "
            f"(~{rec['estimated_cells']:.2g} bg tets)"
        )
    if outcome != "ok":
        extra += " " + rec.get("message", "")[:300]
    return f"{head} {extra}".rstrip()


def main_3d(args: argparse.Namespace) -> dict:
    """The 3D mode of :func:`main`."""
    import signal

    from random_surfaces import KINDS as KINDS_3D

    comm = MPI.COMM_WORLD
    n = 20 if args.quick else (args.n if args.n is not None else 500)
    kinds = args.kinds.split(",") if args.kinds else list(KINDS_3D)
    degrees = [int(q) for q in (args.degrees or "1").split(",")]
    records: list[dict] = []
    wall0 = 0.0
    if args.resume and args.out is not None and (args.out / "summary.json").exists():
        old = json.loads((args.out / "summary.json").read_text())
        if old.get("dim") == 3:
            records, wall0 = old.get("records", []), float(old.get("wall_s", 0.0))
    done = {r["seed"] for r in records}

    def _terminate(signum: int, frame: Any) -> None:
        raise SystemExit(f"signal {signum}")  # write the summary on the way out

    if comm.size == 1:
        signal.signal(signal.SIGTERM, _terminate)
    t0 = time.perf_counter()
    try:
        for i in range(n):
            seed = args.seed0 + i
            if KINDS_3D[seed % len(KINDS_3D)] not in kinds or seed in done:
                continue
            degree = degrees[i % len(degrees)]
            if args.moving:
                rec = run_one_moving_3d(comm, seed, args.mild, degree, args.moving, args.timeout)
            else:
                rec = run_one_3d(
                    comm, seed, args.mild, args.mesh_max_cells, args.timeout, degree,
                    args.against_serial,
                )  # fmt: skip
            records.append(rec)
            if comm.rank == 0:
                print(_progress_3d(rec), flush=True)
            if args.out is not None and comm.rank == 0:
                wall = wall0 + time.perf_counter() - t0
                _write(args.out, summarise_3d(records, wall), records)
    finally:
        records.sort(key=lambda r: r["seed"])
        summary = summarise_3d(records, wall0 + time.perf_counter() - t0)
        if comm.rank == 0:
            print_table_3d(summary)
            if args.out is not None:
                _write(args.out, summary, records)
            if args.json is not None:
                _results.write(args.json, summary, _argv(args))
    return summary


def _write(out: Path, summary: dict, records: list[dict]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").write_text(json.dumps({**summary, "records": records}, indent=1))


def _argv(args: argparse.Namespace) -> list[str] | None:
    """The command line of :func:`main`'s call (``sys.argv`` when run as a script)."""
    return None if args.argv is None else [__file__, *args.argv]


def main(argv: list[str] | None = None) -> dict:
    """Command line entry point; returns the summary."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dim", type=int, choices=(2, 3), default=2, help="2: curves, 3: surfaces")
    p.add_argument("--n", type=int, default=None, help="number of random domains (2000; 3D: 500)")
    p.add_argument("--seed0", type=int, default=0, help="first seed")
    p.add_argument(
        "--degrees",
        default=None,
        help="geometry degrees, cycled over the seeds (comma-separated; 1,2,3,4, 3D: 1)",
    )
    p.add_argument("--quick", action="store_true", help="50 domains (3D: 20)")
    p.add_argument("--kinds", default=None, help="kinds to run (comma-separated; others skipped)")
    p.add_argument("--out", type=Path, default=None, help="directory for summary.json")
    p.add_argument(
        "--json", type=Path, default=None, help="write the summary (no records) to this file"
    )
    p.add_argument(
        "--max-cells",
        type=float,
        default=2e5,
        help="largest background of the uniform baseline (without mesh_domain)",
    )
    p.add_argument(
        "--no-reference",
        action="store_true",
        help="skip timing conform + curved_mesh on the final background",
    )
    p.add_argument(
        "--mild",
        action="store_true",
        help="3D: the generator's mild ranges (the test suite's cheap cases)",
    )
    p.add_argument(
        "--mesh-max-cells",
        type=float,
        default=5e6,
        help="3D: max_cells of mesh_domain (its default: 5e6)",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="3D: keep the records of OUT/summary.json and run only the missing seeds",
    )
    p.add_argument(
        "--moving",
        type=int,
        default=0,
        help="3D: move each surface through this many positions with MovingDomain instead",
    )
    p.add_argument(
        "--timeout",
        type=float,
        default=None,
        help="3D, serial: stop a mesh_domain call after this many seconds (outcome timeout)",
    )
    p.add_argument(
        "--against-serial",
        action="store_true",
        help="on several ranks, also mesh each domain on one rank and compare the nodes",
    )
    args = p.parse_args(argv)
    args.argv = argv
    if args.against_serial and args.moving:
        p.error(
            "--against-serial compares static meshes (the moving mode compares each "
            "update with a fresh conform + curved_mesh)"
        )
    if args.moving and (args.dim != 3 or args.moving < 2):
        p.error("--moving K needs --dim 3 and K >= 2 positions (the last step goes back to 1)")
    if args.dim == 3:
        return main_3d(args)
    comm = MPI.COMM_WORLD
    n = 50 if args.quick else (args.n if args.n is not None else 2000)
    degrees = [int(q) for q in (args.degrees or "1,2,3,4").split(",")]
    kinds = args.kinds.split(",") if args.kinds else list(KINDS)
    records = []
    t0 = time.perf_counter()
    try:
        for i in range(n):
            seed = args.seed0 + i
            if KINDS[seed % len(KINDS)] not in kinds:
                continue
            rec = run_one(
                comm, seed, degrees[i % len(degrees)], args.max_cells, not args.no_reference,
                args.against_serial,
            )  # fmt: skip
            records.append(rec)
            if comm.rank == 0 and rec["outcome"] not in ("ok", "skipped"):
                print(
                    f"seed={seed} kind={rec['kind']} degree={rec['degree']}: "
                    f"{rec['outcome']}: {rec.get('message', '')[:200]}",
                    flush=True,
                )
            if comm.rank == 0 and (i + 1) % 100 == 0:
                print(f"{i + 1}/{n} done, {time.perf_counter() - t0:.0f} s", flush=True)
    finally:
        summary = summarise(records, time.perf_counter() - t0)
        if comm.rank == 0:
            print_table(summary)
            if args.json is not None:
                _results.write(args.json, summary, _argv(args))
            if args.out is not None:
                args.out.mkdir(parents=True, exist_ok=True)
                summary["records"] = records
                (args.out / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


if __name__ == "__main__":
    main()
