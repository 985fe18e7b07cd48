"""Curved meshes to checkpoint and rank-independent fingerprints of them (for tests/test_io.py)."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh

import dolfinx_universal as du

TAGS = (du.IMMERSED, du.OUTER)


def cases(comm: MPI.Comm) -> dict:
    """Curved meshes to checkpoint: a disc of degrees 1-4 and a holed box (OUTER tags too)."""
    bg = du.equilateral_mesh(comm, [[-1.3, -1.3], [1.3, 1.3]], 0.2)
    disc = du.conform(bg, du.Circle((0.01, 0.02), 1.0))
    holed = du.conform(bg, du.Domain(None, [du.Circle((0.2, 0.1), 0.5)]))
    out = {f"disc{q}": du.curved_mesh(disc, q) for q in (1, 2, 3, 4)}
    out["holed3"] = du.curved_mesh(holed, 3)
    return out


def _gather(comm: MPI.Comm, a: np.ndarray) -> list:
    parts = comm.gather(np.asarray(a, dtype=np.float64).reshape(-1, 2), root=0)
    return np.concatenate(parts).tolist() if comm.rank == 0 else []


def fingerprint(msh: dmesh.Mesh, tags: dmesh.MeshTags) -> dict:
    """Rank-independent data of a mesh and its facet tags (complete on rank 0). Collective."""
    comm = msh.comm
    n_nodes = msh.geometry.index_map().size_local
    msh.topology.create_connectivity(1, 2)
    n_facets = msh.topology.index_map(1).size_local
    out = {
        "degree": msh.geometry.cmaps[0].degree,
        "variant": int(msh.geometry.cmaps[0].variant),
        "num_cells": msh.topology.index_map(2).size_global,
        "area": comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(msh)))),
        "nodes": _gather(comm, msh.geometry.x[:n_nodes, :2]),
        "tags": {},
    }
    for value in TAGS:
        facets = tags.find(value)
        facets = facets[facets < n_facets]  # owned: each facet once
        nodes = dmesh.entities_to_geometry(msh, 1, facets)
        mid = msh.geometry.x[nodes, :2].mean(axis=1) if len(facets) else np.zeros((0, 2))
        out["tags"][str(value)] = {
            "count": comm.allreduce(len(facets)),
            "midpoints": _gather(comm, mid),
        }
    return out
