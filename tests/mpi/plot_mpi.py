"""Draw a conforming curved disc and a field on 1 or 2 ranks; write what rank 0 drew as JSON.

Usage: plot_mpi.py OUT.json PNG_DIR
"""

import json
import sys
from pathlib import Path

from mpi4py import MPI

import numpy as np
from dolfinx import fem

import dolfinx_universal as du
from dolfinx_universal.plotting import (
    GAMMA_H_COLOR,
    field_triangulation,
    plot_conforming,
    plot_function,
    save,
)

comm = MPI.COMM_WORLD
out, png = Path(sys.argv[1]), Path(sys.argv[2])
bg = du.equilateral_mesh(comm, [[-1.5, -1.5], [1.5, 1.5]], 0.25)
cm = du.conform(bg, du.Circle([0.0, 0.0], 1.0))
cv = du.curved_mesh(cm, 3)
fig, ax = plot_conforming(None, cm, mesh=cv, title="2 ranks")
save(fig, png / "mesh.png")
V = fem.functionspace(cv.mesh, ("Lagrange", 2))
u = fem.Function(V, name="u")
u.interpolate(lambda x: x[0] ** 2 - x[1])
pts, tris, vals = field_triangulation(u)
fig2, ax2 = plot_function(None, u, show_mesh=True)
save(fig2, png / "field.png")
if comm.rank == 0:
    from matplotlib.collections import LineCollection
    from matplotlib.colors import to_rgba

    gamma = [
        c
        for c in ax.collections
        if isinstance(c, LineCollection) and np.allclose(c.get_colors()[0], to_rgba(GAMMA_H_COLOR))
    ]
    a = pts[tris]
    d1, d2 = a[:, 1] - a[:, 0], a[:, 2] - a[:, 0]
    result = {
        "size": comm.size,
        "num_cells": len(ax.collections[1].get_paths()),
        "num_gamma_segments": len(gamma[0].get_segments()),
        "legend": len(ax.get_legend().get_texts()),
        "field_area": float((0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])).sum()),
        "field_points": len(pts),
    }
    out.write_text(json.dumps(result))
else:
    assert fig is None and ax is None and pts is None and fig2 is None
