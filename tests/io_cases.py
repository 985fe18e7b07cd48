"""Meshes to checkpoint and rank-independent fingerprints of them (for tests/test_io.py)."""

from __future__ import annotations

from mpi4py import MPI

import basix
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


def tetrahedron_cases(comm: MPI.Comm) -> dict:
    """Tetrahedron meshes: a conformed ball (IMMERSED tags), a box with a spherical hole
    (OUTER tags too), and a curved degree-3 box (GLL-warped nodes, interior face nodes)."""
    h = 0.25
    ball = du.conform(du.a15_mesh(comm, [[-1.6] * 3, [1.6] * 3], h), du.Sphere(C3, 1.0))
    hole = du.conform(
        du.a15_mesh(comm, [[-1.5] * 3, [1.5] * 3], h), du.Domain(None, [du.Sphere(C3, 0.6)])
    )
    box = dmesh.create_unit_cube(comm, 2, 2, 2, dmesh.CellType.tetrahedron)
    ce = fem.coordinate_element(dmesh.CellType.tetrahedron, 3, basix.LagrangeVariant.gll_warped)
    curved = fem.interpolate_geometry(box, ce)
    x = curved.geometry.x
    x[:, 0] += 0.1 * np.sin(np.pi * x[:, 1]) * x[:, 2]
    curved.topology.create_entities(2)
    return {
        "ball": (ball.mesh, ball.facet_tags),
        "hole": (hole.mesh, hole.facet_tags),
        "box3": (curved, dmesh.meshtags(curved, 2, *_boundary_faces(curved))),
    }


C3 = np.array([0.0123, 0.0071, 0.0049])  # off the lattice's symmetry planes


def _boundary_faces(msh: dmesh.Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Exterior faces, tagged 1 on ``x = 0`` and 2 elsewhere."""
    msh.topology.create_connectivity(2, 3)
    faces = dmesh.exterior_facet_indices(msh.topology)
    on_x0 = dmesh.locate_entities_boundary(msh, 2, lambda x: np.isclose(x[0], 0.0))
    values = np.where(np.isin(faces, on_x0), du.IMMERSED, du.OUTER).astype(np.int32)
    return faces.astype(np.int32), values


def _gather(comm: MPI.Comm, a: np.ndarray, gdim: int = 2) -> list:
    parts = comm.gather(np.asarray(a, dtype=np.float64).reshape(-1, gdim), root=0)
    return np.concatenate(parts).tolist() if comm.rank == 0 else []


def fingerprint(msh: dmesh.Mesh, tags: dmesh.MeshTags) -> dict:
    """Rank-independent data of a mesh and its facet tags (complete on rank 0). Collective.

    ``area`` is the measure of the domain (the volume for tetrahedra); points have the
    mesh's topological dimension as their number of coordinates."""
    comm = msh.comm
    tdim = msh.topology.dim
    n_nodes = msh.geometry.index_map().size_local
    msh.topology.create_connectivity(tdim - 1, tdim)
    n_facets = msh.topology.index_map(tdim - 1).size_local
    out = {
        "degree": msh.geometry.cmaps[0].degree,
        "variant": int(msh.geometry.cmaps[0].variant),
        "num_cells": msh.topology.index_map(tdim).size_global,
        "area": comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(msh)))),
        "nodes": _gather(comm, msh.geometry.x[:n_nodes, :tdim], tdim),
        "tags": {},
    }
    for value in TAGS:
        facets = tags.find(value)
        facets = facets[facets < n_facets]  # owned: each facet once
        nodes = dmesh.entities_to_geometry(msh, tdim - 1, facets)
        mid = msh.geometry.x[nodes, :tdim].mean(axis=1) if len(facets) else np.zeros((0, tdim))
        out["tags"][str(value)] = {
            "count": comm.allreduce(len(facets)),
            "midpoints": _gather(comm, mid, tdim),
        }
    return out
