"""Mesh random domains with ``mesh_domain`` under MPI and check them; write JSON.

Usage: ``random_domains_mpi.py OUT.json SEED:DEGREE,SEED:DEGREE,...``
"""

import json
import sys
from pathlib import Path

from mpi4py import MPI

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from test_property_domains import run_case  # noqa: E402

comm = MPI.COMM_WORLD
out = {}
for item in sys.argv[2].split(","):
    seed, degree = (int(v) for v in item.split(":"))
    r = run_case(seed, degree, comm)
    cert = r.pop("certificate", None)
    r.pop("domain")
    rec = {k: v for k, v in r.items() if not k.endswith("_at") and not k.endswith("_time")}
    rec["refinement_rounds"] = getattr(cert, "refinement_rounds", None)
    out[r["label"]] = rec
if comm.rank == 0:
    with open(sys.argv[1], "w") as f:
        json.dump(out, f)
