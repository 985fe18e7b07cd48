"""C kernels of the 2D vertex relaxation, compiled at first use with cffi.

The relaxation (:mod:`dolfinx_universal.relax`) makes dozens of colour passes per update,
each rating a few thousand candidates: in numpy every pass paid about twenty array calls
and the gathers of its candidates, and those per-call costs, not the arithmetic, were most
of the relaxation's time. Here a sweep's colour passes (ratings, decisions, steps), the
star minima and the compass candidates are C loops.

The kernels evaluate the same floating-point operations in the same order as the numpy
code they replace (no contraction into fused multiply-adds, ``-ffp-contract=off``; square
roots and quotients correctly rounded, ``hypot`` from the same libm), so both give bitwise
the same ratings, hence the same meshes: the numpy code stays as the reference, the
fallback and the path of the colour passes on several ranks (tests compare the two).

The C compiler is the one DOLFINx itself needs (FFCx compiles every form through cffi), so
this adds no dependency. The module is built once per source and Python version into a
cache folder (``$DOLFINX_UNIVERSAL_CACHE``, else ``$XDG_CACHE_HOME/dolfinx_universal`` or
``~/.cache/dolfinx_universal``; a temporary folder where that cannot be written) and moved
there atomically, so that ranks and processes building it at once do not collide.
``DOLFINX_UNIVERSAL_COMPILED=0`` turns the kernels off; where the build fails the numpy
code runs, with a warning.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.machinery
import importlib.util
import io
import os
import re
import sys
import sysconfig
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["relax_kernels", "pointer"]

_SOURCE = r"""
#include <math.h>
#include <stdint.h>

/* shape_quality of the counter-clockwise triangle (p, a, b), lab = |b - a|: the operations
   of relax._star_quality, in its order; -1 where not positively oriented. */
static inline double star_quality(double px, double py, double ax, double ay, double bx,
                                  double by, double lab, double angle_scale,
                                  double radius_scale4)
{
    double ux = ax - px, uy = ay - py, vx = bx - px, vy = by - py;
    double cross = ux * vy - uy * vx;
    if (!(cross > 0.0))
        return -1.0;
    double su = sqrt(ux * ux + uy * uy), sv = sqrt(vx * vx + vy * vy);
    double m = su < sv ? su : sv;
    m = m < lab ? m : lab;
    double angle = cross * m * angle_scale;
    double radius = cross * cross * radius_scale4 / (su + sv + lab);
    return (angle < radius ? angle : radius) / (su * sv * lab);
}

/* The quality of entry e with its vertex at (px, py), with its flags and edge caps. */
static inline double entry_quality(const double *y, int64_t a, int64_t b, double lab,
                                   uint8_t flat, double cap_a, double cap_b, double px,
                                   double py, double angle_scale, double radius_scale4)
{
    double q = star_quality(px, py, y[2 * a], y[2 * a + 1], y[2 * b], y[2 * b + 1], lab,
                            angle_scale, radius_scale4);
    if (flat)
        q = -1.0;
    if (cap_a < INFINITY && hypot(px - y[2 * a], py - y[2 * a + 1]) > cap_a)
        q = -1.0;
    if (cap_b < INFINITY && hypot(px - y[2 * b], py - y[2 * b + 1]) > cap_b)
        q = -1.0;
    return q;
}

/* For the entries E[0..n) (whole vertex segments, `first` marking each segment's first
   entry), the worst quality over each segment of every candidate of its vertex: out
   (segments, nc), the candidates cand (rows, nc, 2) at row[ev[e]]. */
void rate_candidates(const double *y, const int64_t *ea, const int64_t *eb,
                     const int64_t *ev, const uint8_t *flat, const double *cap_a,
                     const double *cap_b, const int64_t *row, const double *cand, int64_t nc,
                     const int64_t *E, int64_t n, const uint8_t *first, double angle_scale,
                     double radius_scale4, double *out)
{
    double *o = out - nc;
    for (int64_t i = 0; i < n; ++i)
    {
        int64_t e = E[i], a = ea[e], b = eb[e];
        if (first[e])
        {
            o += nc;
            for (int64_t c = 0; c < nc; ++c)
                o[c] = INFINITY;
        }
        double lab = hypot(y[2 * b] - y[2 * a], y[2 * b + 1] - y[2 * a + 1]);
        const double *p = cand + 2 * nc * row[ev[e]];
        for (int64_t c = 0; c < nc; ++c)
        {
            double q = entry_quality(y, a, b, lab, flat[e], cap_a[e], cap_b[e], p[2 * c],
                                     p[2 * c + 1], angle_scale, radius_scale4);
            o[c] = q < o[c] ? q : o[c];
        }
    }
}

/* The moves of the active vertices of the given colours, one colour after the other (the
   serial colour passes of relax._Compass.move, decisions included): the entries of colour
   k are bounds[k]..bounds[k+1], in vertex segments. Each active vertex rates its candidates
   (the worst over its entries), takes the first within `tie` of the best if that beats
   staying (candidate 0) by more than `tie`, and scales its step (by `grow` after a move at
   the full step, `hold` after another move, `shrink` where nothing helped); vertices of
   one colour share no triangle, so rating them one after the other sees what the numpy code's
   simultaneous rating sees. Returns the number of moves, -1 for more than 64 candidates. */
int64_t move_colours(double *y, const int64_t *ea, const int64_t *eb, const int64_t *ev,
                     const uint8_t *flat, const double *cap_a, const double *cap_b,
                     const int64_t *bounds, const int64_t *colours, int64_t ncolours,
                     const uint8_t *active, const int64_t *row, const double *cand,
                     const double *cand_n, int64_t nc, const int64_t *verts,
                     const int64_t *is_gamma, const uint8_t *full_step, double *step,
                     const double *hmax, double *nrm, uint8_t *changed, double tie,
                     double grow, double hold, double shrink, double angle_scale,
                     double radius_scale4)
{
    double q[64];
    int64_t moves = 0;
    if (nc > 64)
        return -1;
    for (int64_t k = 0; k < ncolours; ++k)
    {
        int64_t e = bounds[colours[k]], end = bounds[colours[k] + 1];
        while (e < end)
        {
            int64_t i = ev[e], s = e;
            while (e < end && ev[e] == i)
                ++e;
            if (!active[i])
                continue;
            const double *p = cand + 2 * nc * row[i];
            for (int64_t c = 0; c < nc; ++c)
                q[c] = INFINITY;
            for (int64_t f = s; f < e; ++f)
            {
                int64_t a = ea[f], b = eb[f];
                double lab = hypot(y[2 * b] - y[2 * a], y[2 * b + 1] - y[2 * a + 1]);
                for (int64_t c = 0; c < nc; ++c)
                {
                    double r = entry_quality(y, a, b, lab, flat[f], cap_a[f], cap_b[f],
                                             p[2 * c], p[2 * c + 1], angle_scale,
                                             radius_scale4);
                    q[c] = r < q[c] ? r : q[c];
                }
            }
            double best_q = -INFINITY;
            for (int64_t c = 0; c < nc; ++c)
                best_q = q[c] > best_q ? q[c] : best_q;
            int64_t best = 0; /* numpy's argmax of the flags: the first, 0 if none */
            while (best < nc && !(q[best] >= best_q - tie))
                ++best;
            if (best == nc)
                best = 0;
            double factor = shrink;
            if (q[best] > q[0] + tie)
            {
                int64_t v = verts[i];
                y[2 * v] = p[2 * best];
                y[2 * v + 1] = p[2 * best + 1];
                if (is_gamma[i] && cand_n)
                {
                    const double *pn = cand_n + 2 * nc * row[i];
                    nrm[2 * v] = pn[2 * best];
                    nrm[2 * v + 1] = pn[2 * best + 1];
                }
                changed[v] = 1;
                factor = full_step[nc * is_gamma[i] + best] ? grow : hold;
                ++moves;
            }
            double grown = factor * step[i];
            step[i] = grown < hmax[i] ? grown : hmax[i];
        }
    }
    return moves;
}

/* The entries with a corner among the `changed` vertices re-rated into qe, and the worst
   quality over each vertex's entries into star (filled with inf by the caller): the
   numpy code's re-rating of the touched entries and its minimum over each segment. */
void star_minima(const double *y, const int64_t *pv, const int64_t *ea, const int64_t *eb,
                 const int64_t *ev, const uint8_t *flat, const double *cap_a,
                 const double *cap_b, int64_t n, const uint8_t *changed, double angle_scale,
                 double radius_scale4, double *qe, double *star)
{
    for (int64_t e = 0; e < n; ++e)
    {
        int64_t a = ea[e], b = eb[e], v = pv[e];
        if (changed[v] | changed[a] | changed[b])
        {
            double lab = hypot(y[2 * b] - y[2 * a], y[2 * b + 1] - y[2 * a + 1]);
            qe[e] = entry_quality(y, a, b, lab, flat[e], cap_a[e], cap_b[e], y[2 * v],
                                  y[2 * v + 1], angle_scale, radius_scale4);
        }
        double *m = star + ev[e];
        *m = qe[e] < *m ? qe[e] : *m;
    }
}

/* The worst quality over each vertex's entries with every corner at x (no flags, no caps:
   the background's stars), into star (filled with inf by the caller). */
void background_minima(const double *x, const int64_t *pv, const int64_t *ea,
                       const int64_t *eb, const int64_t *ev, int64_t n, double angle_scale,
                       double radius_scale4, double *star)
{
    for (int64_t e = 0; e < n; ++e)
    {
        int64_t a = ea[e], b = eb[e], v = pv[e];
        double lab = hypot(x[2 * b] - x[2 * a], x[2 * b + 1] - x[2 * a + 1]);
        double q = star_quality(x[2 * v], x[2 * v + 1], x[2 * a], x[2 * a + 1], x[2 * b],
                                x[2 * b + 1], lab, angle_scale, radius_scale4);
        double *m = star + ev[e];
        *m = q < *m ? q : *m;
    }
}

/* The compass candidates of the vertices act[0..n): cand (n, nc, 2) = y[verts[i]] +
   step[i] * offsets (nc, 2), as the numpy code's broadcast sum. */
void compass_candidates(const double *y, const int64_t *verts, const int64_t *act,
                        int64_t n, const double *step, const double *offsets, int64_t nc,
                        double *cand)
{
    for (int64_t i = 0; i < n; ++i)
    {
        int64_t v = verts[act[i]];
        double s = step[act[i]], y0 = y[2 * v], y1 = y[2 * v + 1];
        double *c = cand + 2 * nc * i;
        for (int64_t k = 0; k < nc; ++k)
        {
            c[2 * k] = y0 + s * offsets[2 * k];
            c[2 * k + 1] = y1 + s * offsets[2 * k + 1];
        }
    }
}
"""

_CDEF = "\n".join(
    f"{signature};" for signature in re.findall(r"^(?:void|int64_t) \w+\([^)]*\)", _SOURCE, re.M)
)
"""The declarations cffi needs: the signatures of the kernels (the non-static functions)."""


_FLAGS = [] if sys.platform == "win32" else ["-O2", "-ffp-contract=off"]
"""No fused multiply-adds (aarch64 compilers contract by default): bitwise numpy's results."""

_loaded: dict[str, Any] = {}


def _cache_dir() -> Path:
    env = os.environ.get("DOLFINX_UNIVERSAL_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "dolfinx_universal"


def _build(name: str, folder: Path) -> Path:
    """Compile the module ``name`` into ``folder`` (atomically) and return its path."""
    import cffi

    ffi = cffi.FFI()
    ffi.cdef(_CDEF)
    ffi.set_source(name, _SOURCE, extra_compile_args=_FLAGS)
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            built = Path(ffi.compile(tmpdir=tmp, verbose=False))
        target = folder / built.name
        os.replace(built, target)
    return target


def _load(path: Path, name: str) -> Any:
    loader = importlib.machinery.ExtensionFileLoader(name, str(path))
    spec = importlib.util.spec_from_file_location(name, str(path), loader=loader)
    assert spec is not None
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    return module


def relax_kernels() -> Any | None:
    """The compiled module (``.lib``, ``.ffi``) of the relaxation's kernels, built at the
    first call; ``None`` where they are turned off or cannot be built."""
    if os.environ.get("DOLFINX_UNIVERSAL_COMPILED", "1") == "0":
        return None
    if "relax" in _loaded:
        return _loaded["relax"]
    key = hashlib.sha256((_CDEF + _SOURCE + " ".join(_FLAGS)).encode()).hexdigest()[:16]
    name = f"_dolfinx_universal_relax_{key}"
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    user = os.environ.get("USER", "user")
    folders = (_cache_dir(), Path(tempfile.gettempdir()) / f"dolfinx_universal-{user}")
    module, error = None, None
    for folder in folders:  # the cache, else a temporary folder (an unwritable cache)
        try:
            path = folder / (name + suffix)
            if not path.exists():
                path = _build(name, folder)
            module = _load(path, name)
            break
        except Exception as err:  # no compiler, no cffi, no writable folder: numpy instead
            error = err
    if module is None:
        warnings.warn(
            f"dolfinx_universal: the relaxation's C kernels could not be built ({error}); "
            "using the numpy code (the same meshes, slower)",
            RuntimeWarning,
            stacklevel=2,
        )
    _loaded["relax"] = module
    return module


def pointer(ffi: Any, array: np.ndarray, ctype: str) -> Any:
    """A cffi ``ctype[]`` over the data of a C-contiguous ``array`` (no copy), passed where
    the kernels take ``ctype *``; it keeps ``array`` alive as long as it lives."""
    if not array.flags.c_contiguous:
        raise ValueError("the kernels need C-contiguous arrays")
    return ffi.from_buffer(ctype + "[]", array)
