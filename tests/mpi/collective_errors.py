"""A user callback failing on one rank only, and per-rank reports merged: write each rank's
error message as JSON (the test runs this under mpirun with a timeout: a hang fails it)."""

import json
import sys

from mpi4py import MPI

import numpy as np

import dolfinx_universal as du
from dolfinx_universal.validation import Problem, raise_collective

comm = MPI.COMM_WORLD


class FailsOnRank1(du.Circle):
    def sign(self, x):
        if comm.rank == 1:
            raise KeyError("lookup table")
        return super().sign(x)


bg = du.equilateral_mesh(comm, [[-1, -1], [1, 1]], 0.1)
messages, counts = [], []
try:
    du.conform(bg, FailsOnRank1((0.0, 0.0), 0.6))
except du.MeshingError as e:
    messages.append(str(e))
try:
    raise_collective(
        comm,
        [
            Problem(
                "{count} cells are bad near {where}",
                np.array([[float(comm.rank), 0.0]]),
                comm.rank + 1,
            )
        ],
    )
except du.MeshingError as e:
    counts.append(str(e))
messages = comm.gather(messages[0] if messages else None, root=0)
counts = comm.gather(counts[0] if counts else None, root=0)
if comm.rank == 0:
    with open(sys.argv[1], "w") as fh:
        json.dump({"messages": messages, "count_messages": counts}, fh)
