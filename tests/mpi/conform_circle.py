"""Conform (and curve) a disc and a spline domain; write rank-independent fingerprints as JSON."""

import json
import sys

from mpi4py import MPI

import numpy as np
import ufl
from dolfinx import fem

import dolfinx_universal as du


def sorted_points(msh) -> list:
    """Owned geometry nodes of ``msh``, gathered and sorted (rank-independent)."""
    n = msh.geometry.index_map().size_local
    pts = msh.comm.gather(msh.geometry.x[:n, :2], root=0)
    if msh.comm.rank != 0:
        return []
    p = np.concatenate(pts)
    return p[np.lexsort((p[:, 1], p[:, 0]))].tolist()


def fingerprint(cm, degree: int) -> dict:
    comm = cm.mesh.comm
    cv = du.curved_mesh(cm, degree, "I")
    area = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(cv.mesh))))
    ds = ufl.ds(cv.mesh, subdomain_data=cv.facet_tags)
    length = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ds(du.IMMERSED))))
    return {
        "quality": du.quality_report(cm),
        "vertices": sorted_points(cm.mesh),
        "nodes": sorted_points(cv.mesh),
        "area": area,
        "length": length,
        "num_immersed_facets": comm.allreduce(len(cm.facet_tags.find(du.IMMERSED))),
        "num_outer_facets": comm.allreduce(len(cm.facet_tags.find(du.OUTER))),
    }


comm = MPI.COMM_WORLD
bg = du.equilateral_mesh(comm, [[-1.6, -1.6], [1.6, 1.6]], 0.1)
circle = du.conform(bg, du.Circle((0.013, -0.021), 1.0), eta=0.2)
t = np.linspace(0, 2 * np.pi, 14, endpoint=False)
r = 1 + 0.25 * np.sin(2 * t) + 0.1 * np.cos(5 * t)
spline = du.conform(bg, du.PeriodicSpline(np.column_stack([r * np.cos(t), r * np.sin(t)])))
# A container with a hole: the outer facets are the background's own boundary.
holed = du.conform(bg, du.Domain(None, [du.Circle((0.2, 0.1), 0.5)]))
out = {
    "circle": fingerprint(circle, 3),
    "spline": fingerprint(spline, 2),
    "holed": fingerprint(holed, 2),
}
if comm.rank == 0:
    with open(sys.argv[1], "w") as f:
        json.dump(out, f)
