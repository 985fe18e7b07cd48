"""mesh_domain on a spline domain with a body; write a rank-independent fingerprint as JSON."""

import json
import sys

from mpi4py import MPI

import numpy as np
import ufl
from dolfinx import fem

import dolfinx_universal as du

comm = MPI.COMM_WORLD
t = np.linspace(0, 2 * np.pi, 11, endpoint=False)
r = 1 + 0.25 * np.cos(3 * t) + 0.1 * np.sin(5 * t)
spline = du.PeriodicSpline(np.column_stack([r * np.cos(t), r * np.sin(t)]))
domain = du.Domain(spline, [du.Ellipse((0.1, 0.05), 0.25, 0.06, angle=0.4)])
md = du.mesh_domain(comm, domain, 0.3, degree=3)
msh = md.mesh
area = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(msh))))
nodes = msh.geometry.x[msh.geometry.dofmaps[0]][:, :, :2]
owned = msh.topology.index_map(2).size_local
cents = comm.gather(nodes[:owned].mean(axis=1), root=0)
if comm.rank == 0:
    c = np.concatenate(cents)
    c = c[np.lexsort((c[:, 1], c[:, 0]))]
    with open(sys.argv[1], "w") as fh:
        json.dump(
            {
                "n_cells": msh.topology.index_map(2).size_global,
                "area": area,
                "rounds": md.certificate.refinement_rounds,
                "centroids": c.tolist(),
            },
            fh,
        )
