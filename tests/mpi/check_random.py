"""Check meshes of random domains under MPI; write the checker's numbers as JSON."""

import json
import sys
from pathlib import Path

from mpi4py import MPI

import dolfinx_universal as du

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from mesh_checks import check_mesh  # noqa: E402
from random_domains import random_domain  # noqa: E402

comm = MPI.COMM_WORLD
out = {}
for seed, degree in ((3, 2), (0, 3), (1, 1)):
    d = random_domain(seed)
    hb = d.uniform_size()
    bg = du.equilateral_mesh(comm, d.box(5 * hb), hb)
    cv = du.curved_mesh(du.conform(bg, d.boundary), degree)
    r = check_mesh(cv.mesh, cv.facet_tags, d.boundary, d.exact_area, n_curves=d.n_curves)
    out[f"{d.label} degree={degree}"] = {k: v for k, v in r.items() if not k.endswith("_at")}
if comm.rank == 0:
    with open(sys.argv[1], "w") as f:
        json.dump(out, f)
