"""The common header of the benchmarks' JSON results, and the writer that adds it.

Every benchmark writes its results with ``write(path, results)``: a JSON object whose
``"run"`` entry says how the numbers were made (``header``):

* ``command``: the command line that reproduces the run, relative to the repository root
  (``mpirun -n N`` in front when it ran on several ranks);
* ``machine``: the CPU model (``/proc/cpuinfo``), the number of cores the process may use,
  the memory (``/proc/meminfo``), the load average when the results were written;
* ``date``: when the results were written (UTC, ISO 8601), and ``wall_s``, the seconds since
  this module was imported (the benchmarks import it first: about the run's wall time);
* ``versions``: Python, dolfinx_universal, DOLFINx, numpy, scipy, and gmsh where the
  benchmark imported it.

``docs/measurements.md`` is generated from these files (``benchmarks/measurements_page.py``).
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import shlex
import sys
import time
from importlib import metadata
from pathlib import Path

_T0 = time.perf_counter()
ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
"""Where the committed results live (one JSON file per benchmark run)."""


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _memory_gib() -> float | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return round(int(line.split()[1]) / 2**20, 1)
    except OSError:
        pass
    return None


def machine() -> dict:
    """The CPU model, usable cores, memory (GiB) and the 1-minute load average."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count() or 1
    return {
        "cpu": _cpu_model(),
        "cores": cores,
        "memory_gib": _memory_gib(),
        "load_average": round(os.getloadavg()[0], 2),
        "system": f"{platform.system()} {platform.machine()}",
    }


def _version(module: str, distribution: str | None = None) -> str | None:
    mod = sys.modules.get(module)
    if mod is not None and getattr(mod, "__version__", None):
        return str(mod.__version__)
    for name in (distribution, module):
        if name is None:
            continue
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return None


def versions() -> dict:
    """The versions of Python and of the packages the numbers depend on."""
    out = {
        "python": platform.python_version(),
        "dolfinx_universal": _version("dolfinx_universal"),
        "dolfinx": _version("dolfinx", "fenics-dolfinx"),
        "numpy": _version("numpy"),
        "scipy": _version("scipy"),
    }
    if "gmsh" in sys.modules:
        out["gmsh"] = _version("gmsh")
    return out


def command(argv: list[str] | None = None, ranks: int = 1) -> str:
    """The command line of this process, the script's path relative to the repository root."""
    argv = list(sys.argv if argv is None else argv)
    script = Path(argv[0])
    try:
        script = script.resolve().relative_to(ROOT)
    except ValueError:
        pass
    line = shlex.join(["python", str(script), *argv[1:]])
    return f"mpirun -n {ranks} {line}" if ranks > 1 else line


def header(argv: list[str] | None = None, ranks: int | None = None) -> dict:
    """What the ``"run"`` entry of a result file holds (module docstring)."""
    if ranks is None:
        try:
            from mpi4py import MPI

            ranks = MPI.COMM_WORLD.size
        except ImportError:  # pragma: no cover
            ranks = 1
    return {
        "command": command(argv, ranks),
        "ranks": ranks,
        "machine": machine(),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "wall_s": round(time.perf_counter() - _T0, 1),
        "versions": versions(),
    }


def write(path: str | os.PathLike, results: dict, argv: list[str] | None = None) -> Path:
    """Write ``{"run": header(argv), **results}`` as indented JSON to ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"run": header(argv), **results}, indent=1) + "\n")
    return path
