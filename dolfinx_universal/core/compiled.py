"""C kernels of the vertex relaxation, compiled at first use with cffi.

The relaxation (:mod:`dolfinx_universal.conforming.relax`,
:mod:`dolfinx_universal.conforming.relax_tet` for
tetrahedra) makes dozens of colour passes per update, each rating a few thousand
candidates: in numpy every pass paid tens of array calls and the gathers of its
candidates, and those per-call costs, not the arithmetic, were most of the relaxation's
time. Here, on triangles, a sweep's colour passes (ratings, decisions, steps), the star
minima and the compass candidates are C loops; on tetrahedra, each colour's visit (ascent
directions, line searches, compass, the slides' candidates and their exact ratings), the
colouring and the set-up of the stars. Others build curved geometries: the affine nodes a
moving update rewrites (each once), the entity nodes and the dofmap of a degree-q geometry,
the curved map's affine images and blend on tetrahedra, the distinct points it projects and
the writes of the curved cells' nodes.

The kernels evaluate the same floating-point operations in the same order as the numpy
code they replace (no contraction into fused multiply-adds, ``-ffp-contract=off``; square
roots and quotients correctly rounded, ``hypot`` from the same libm, the tetrahedra's cube
root from IEEE operations in both), so both give bitwise the same ratings, hence the same
meshes: the numpy code stays as the reference, the fallback and the path of the colour
passes on several ranks (tests compare the two). Where a kernel skips work the numpy code
does (a tetrahedron candidate's remaining ratings once it cannot be chosen), the choices
are the same.

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
#include <stdlib.h>
#include <string.h>

/* shape_quality of the counter-clockwise triangle (p, a, b), lab = |b - a|: the operations
   of relax_tri._star_quality, in its order; -1 where not positively oriented. */
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
   serial colour passes of relax_tri._Compass.move, decisions included): the entries of colour
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

/* ---- Tetrahedra: the directional relaxation of relax_tet (same operations, same order) ---- */

/* relax_tet.cube_root: the exponent's bits over 3, then three Halley steps (x > 0, finite). */
static inline double cube_root(double x)
{
    int small = x < 2.2250738585072014e-308;
    double xs = small ? x * 18014398509481984.0 : x; /* 2^54 */
    uint64_t bits;
    memcpy(&bits, &xs, sizeof bits);
    bits = bits / 3 + 0x2A9F7893782DA1CEull;
    double t;
    memcpy(&t, &bits, sizeof t);
    double x2 = xs + xs;
    for (int i = 0; i < 3; ++i)
    {
        double t3 = t * t;
        t3 *= t;
        double num = t3 + x2;
        t3 += t3;
        t3 += xs;
        num /= t3;
        t *= num;
    }
    return small ? t * 3.814697265625e-06 : t; /* 2^-18 */
}

/* relax_tet.rating_quality of one rating. */
static inline double rating_quality(double r)
{
    if (r == INFINITY)
        return INFINITY;
    if (!(r > 0.0))
        return -1.0;
    return cube_root(r);
}

/* relax_tet._rating: s^2 / L^3 where s > 0 (and that positive), else -1. */
static inline double rating(double s, double L)
{
    double r = L * L;
    r *= L;
    r = (s * s) / r;
    return (s > 0.0) & (r > 0.0) ? r : -1.0;
}

/* relax_tet.star_terms of one entry (vertex ip, facet ia, ib, ic of the points y) into
   t[k * stride] for k = ux, uy, uz, nx, ny, nz, lsq, s, L. */
static inline void star_terms(const double *y, int64_t ip, int64_t ia, int64_t ib,
                              int64_t ic, double k15, double *t, int64_t stride)
{
    const double *pa = y + 3 * ia, *pb = y + 3 * ib, *pc = y + 3 * ic, *pp = y + 3 * ip;
    double ax = pa[0], ay = pa[1], az = pa[2];
    double bx = pb[0] - ax, by = pb[1] - ay, bz = pb[2] - az;
    double cx = pc[0] - ax, cy = pc[1] - ay, cz = pc[2] - az;
    double nx = (bz * cy - by * cz) * k15;
    double ny = (bx * cz - bz * cx) * k15;
    double nz = (by * cx - bx * cy) * k15;
    double lsq = bx * bx + by * by + bz * bz + cx * cx + cy * cy + cz * cz;
    lsq -= bx * cx + by * cy + bz * cz;
    lsq *= 8.0 / 9.0;
    lsq = lsq > 2.2250738585072014e-308 ? lsq : 2.2250738585072014e-308;
    bx += cx;
    by += cy;
    bz += cz;
    double ux = pp[0] - ax - bx / 3.0;
    double uy = pp[1] - ay - by / 3.0;
    double uz = pp[2] - az - bz / 3.0;
    t[0] = ux;
    t[stride] = uy;
    t[2 * stride] = uz;
    t[3 * stride] = nx;
    t[4 * stride] = ny;
    t[5 * stride] = nz;
    t[6 * stride] = lsq;
    t[7 * stride] = ux * nx + uy * ny + uz * nz;
    t[8 * stride] = ux * ux + uy * uy + uz * uz + lsq;
}

/* relax_tet.line_rating of entry j of the terms w at step length t along (dx, dy, dz). */
static inline double line_rating(const double *w, int64_t j, int64_t stride, double dx,
                                double dy, double dz, double t)
{
    double sig = dx * w[3 * stride + j] + dy * w[4 * stride + j] + dz * w[5 * stride + j];
    double beta2 = dx * w[j] + dy * w[stride + j] + dz * w[2 * stride + j];
    beta2 *= 2.0;
    double st = t * sig;
    st += w[7 * stride + j];
    double den = beta2 + t;
    den *= t;
    den += w[8 * stride + j];
    return rating(st, den);
}

/* A rating below which a candidate's quality is below qmax - tie for certain: the cube of
   that, less 1e-12 relative (cube_root errs by a few ulps); -inf where qmax - tie <= 0. A
   candidate whose worst rating falls below it cannot be the first within tie of the best,
   so its other entries are not rated: the choices are those of rating them all. The
   candidates' loops rate first the entry that was the worst of the previous candidate
   (j0): a poor candidate is then found out after one entry. */
static inline double below(double qmax, double tie)
{
    double q = qmax - tie;
    return q > 0.0 ? q * q * q * (1.0 - 1e-12) : -INFINITY;
}

/* The worst line_rating over the ne entries at step t along d, from entry *jw on (set to
   the worst), stopping below out. */
static inline double line_minimum(const double *w, int64_t ne, int64_t stride, double dx,
                                  double dy, double dz, double t, double out, int64_t *jw)
{
    double m = INFINITY;
    for (int64_t i = 0, j0 = *jw; i < ne && m >= out; ++i)
    {
        int64_t j = i == 0 ? j0 : i == j0 ? 0 : i;
        double r = line_rating(w, j, stride, dx, dy, dz, t);
        if (r < m)
        {
            m = r;
            *jw = j;
        }
    }
    return m;
}

/* The first of the qualities q[0..n) within tie of their maximum. */
static inline int64_t first_best(const double *q, int64_t n, double tie)
{
    double mx = -INFINITY;
    for (int64_t c = 0; c < n; ++c)
        mx = q[c] > mx ? q[c] : mx;
    mx -= tie;
    for (int64_t c = 0; c < n; ++c)
        if (q[c] >= mx)
            return c;
    return 0;
}

/* A vertex's move: its position, its star's ratings and its next step (_Directional._apply). */
static inline void dvr_move(double *y, int64_t p, const double *pos, const int64_t *cell_idx,
                            const int64_t *csub, int64_t e0, int64_t ne, const double *rnew,
                            double *rcell, uint8_t *again, double *step, double hmin,
                            double hmax, double tb)
{
    y[3 * p] = pos[0];
    y[3 * p + 1] = pos[1];
    y[3 * p + 2] = pos[2];
    for (int64_t j = 0; j < ne; ++j) /* the star's new ratings; its vertices work again */
    {
        int64_t c = cell_idx[e0 + j];
        rcell[c] = rnew[j];
        for (int k = 0; k < 4; ++k)
            if (csub[4 * c + k] >= 0)
                again[csub[4 * c + k]] = 1;
    }
    double a = 1.5 * fabs(tb);
    a = a < hmin ? hmin : a;
    *step = a > hmax ? hmax : a;
}

/* The slides' candidates of a vertex on Gamma at y with normal n (_Directional.
   slide_candidates in the world's frame; tangent_directions' operations): the fractions
   slide_steps of the best step tb along the direction d, then nt directions cos t1 + sin t2
   in the tangent plane at the step; into pc (ns, 3) and their steps tg (ns). */
static inline void slide_candidates(const double *y, const double *n, double dx, double dy,
                                    double dz, double tb, double step,
                                    const double *slide_steps, int64_t nss,
                                    const double *tcos, const double *tsin, int64_t nt,
                                    double *pc, double *tg)
{
    double d[3] = {dx, dy, dz};
    for (int64_t k = 0; k < nss; ++k)
    {
        tg[k] = tb * slide_steps[k];
        for (int i = 0; i < 3; ++i)
            pc[3 * k + i] = y[i] + tg[k] * d[i];
    }
    if (!nt)
        return;
    double nn = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    double u[3] = {n[0] / nn, n[1] / nn, n[2] / nn};
    int a = 0; /* the axis least aligned with the normal (the first of equals) */
    for (int i = 1; i < 3; ++i)
        if (fabs(u[i]) < fabs(u[a]))
            a = i;
    double t1[3] = {-u[a] * u[0], -u[a] * u[1], -u[a] * u[2]};
    t1[a] += 1.0;
    double tn = sqrt(t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2]);
    for (int i = 0; i < 3; ++i)
        t1[i] /= tn;
    double t2[3] = {u[1] * t1[2] - u[2] * t1[1], u[2] * t1[0] - u[0] * t1[2],
                    u[0] * t1[1] - u[1] * t1[0]};
    for (int64_t k = 0; k < nt; ++k)
    {
        tg[nss + k] = step;
        for (int i = 0; i < 3; ++i)
            pc[3 * (nss + k) + i] = y[i] + step * (tcos[k] * t1[i] + tsin[k] * t2[i]);
    }
}

/* One visit of the vertices S[0..nS) of a colour (_Directional.visit on one rank): each
   vertex with its worst rating in (0, active) takes its ascent direction, the best of the
   line steps along it, and, inside and stuck, the best of the compass candidates (nd
   directions times ncs steps); it moves (inside vertices) if that beats staying by more
   than tie. Vertices on Gamma with a direction are returned in G (their direction, best
   line step and quality) for the slides (dvr_slides). The entries of movable vertex v are
   vfirst[v]..vfirst[v] + vcount[v]; w is scratch of 9 * stride doubles, stride at least
   the largest star. Returns the number of moves, -1 for more than 64 candidates. */
int64_t dvr_visit(double *y, const int64_t *pv,
                  const int64_t *f0, const int64_t *f1, const int64_t *f2,
                  const int64_t *cell_idx, const int64_t *csub, double *rcell,
                  const int64_t *vfirst, const int64_t *vcount, const uint8_t *gamma,
                  const double *nrm, double *step, const double *hmin, const double *hmax,
                  const int64_t *S, int64_t nS, const double *line_steps, int64_t nl,
                  const double *dirs, int64_t nd, const double *compass_steps, int64_t ncs,
                  const double *slide_steps, int64_t nss, const double *tcos,
                  const double *tsin, int64_t nt, double k15, double tie, double near_worst,
                  double active, double *w, int64_t stride, uint8_t *again, int64_t *G,
                  double *gdv, double *gtb, double *gq0, double *gpc, double *gtg, int64_t *nG)
{
    double qc[64], rnew[stride > 0 ? stride : 1];
    if (nl > 64 || nd * ncs > 64)
        return -1;
    int64_t moves = 0, ng = 0;
    for (int64_t i = 0; i < nS; ++i)
    {
        int64_t v = S[i], e0 = vfirst[v], ne = vcount[v], p = pv[e0];
        double r0 = INFINITY;
        for (int64_t j = 0; j < ne; ++j)
        {
            double r = rcell[cell_idx[e0 + j]];
            r0 = r < r0 ? r : r0;
        }
        if (!(r0 < active && r0 > 0.0))
            continue;
        double q0 = rating_quality(r0);
        for (int64_t j = 0; j < ne; ++j)
            star_terms(y, p, f0[e0 + j], f1[e0 + j], f2[e0 + j], k15, w + j, stride);
        /* The ascent direction: the near-worst entries' weighted unit gradients. */
        double lim = q0 + near_worst;
        lim = lim * lim * lim;
        double dx = 0.0, dy = 0.0, dz = 0.0;
        for (int64_t j = 0; j < ne; ++j)
        {
            double r = rcell[cell_idx[e0 + j]];
            if (!(r < lim))
                continue;
            double q = rating_quality(r);
            double a = (2.0 / 3.0) / w[7 * stride + j], b = 2.0 / w[8 * stride + j];
            double gx = a * w[3 * stride + j] - b * w[j];
            double gy = a * w[4 * stride + j] - b * w[stride + j];
            double gz = a * w[5 * stride + j] - b * w[2 * stride + j];
            double gn = sqrt(gx * gx + gy * gy + gz * gz);
            double wt = 1.0 - (q - q0) / near_worst;
            wt = (wt > 0.0) & (gn > 0.0) ? wt / gn : 0.0;
            dx += wt * gx;
            dy += wt * gy;
            dz += wt * gz;
        }
        if (gamma[v]) /* in the tangent plane */
        {
            const double *nn = nrm + 3 * p;
            double d = dx * nn[0] + dy * nn[1] + dz * nn[2];
            dx -= d * nn[0];
            dy -= d * nn[1];
            dz -= d * nn[2];
        }
        double dn = sqrt(dx * dx + dy * dy + dz * dz);
        if (dn > 0.0)
        {
            dx /= dn;
            dy /= dn;
            dz /= dn;
        }
        /* The line search. */
        double qmax = -INFINITY;
        int64_t jw = 0;
        for (int64_t k = 0; k < nl; ++k)
        {
            double out = below(qmax, tie);
            double m = line_minimum(w, ne, stride, dx, dy, dz, line_steps[k] * step[v], out, &jw);
            qc[k] = m < out ? -INFINITY : rating_quality(m);
            qmax = qc[k] > qmax ? qc[k] : qmax;
        }
        int64_t best = first_best(qc, nl, tie);
        double qb = qc[best], tb = line_steps[best] * step[v];
        int gain = (qb > q0 + tie) & (dn > 0.0);
        double ex = dx, ey = dy, ez = dz; /* the direction of the chosen candidate */
        if (gamma[v])
        {
            if (dn > 0.0)
            {
                G[ng] = v;
                gdv[3 * ng] = dx;
                gdv[3 * ng + 1] = dy;
                gdv[3 * ng + 2] = dz;
                gtb[ng] = tb;
                gq0[ng] = q0;
                if (gpc)
                    slide_candidates(y + 3 * p, nrm + 3 * p, dx, dy, dz, tb, step[v],
                                     slide_steps, nss, tcos, tsin, nt, gpc + 3 * (nss + nt) * ng,
                                     gtg + (nss + nt) * ng);
                ++ng;
            }
            continue;
        }
        if (!gain && ncs > 0) /* stuck: the compass */
        {
            int64_t nc = nd * ncs;
            qmax = -INFINITY;
            for (int64_t c = 0; c < nc; ++c)
            {
                const double *d = dirs + 3 * (c % nd);
                double t = compass_steps[c / nd] * step[v], out = below(qmax, tie);
                double m = line_minimum(w, ne, stride, d[0], d[1], d[2], t, out, &jw);
                qc[c] = m < out ? -INFINITY : rating_quality(m);
                qmax = qc[c] > qmax ? qc[c] : qmax;
            }
            int64_t bc = first_best(qc, nc, tie);
            if (qc[bc] > q0 + tie)
            {
                gain = 1;
                tb = compass_steps[bc / nd] * step[v];
                ex = dirs[3 * (bc % nd)];
                ey = dirs[3 * (bc % nd) + 1];
                ez = dirs[3 * (bc % nd) + 2];
            }
        }
        if (!gain)
            continue;
        double pos[3] = {y[3 * p] + tb * ex, y[3 * p + 1] + tb * ey, y[3 * p + 2] + tb * ez};
        for (int64_t j = 0; j < ne; ++j)
            rnew[j] = line_rating(w, j, stride, ex, ey, ez, tb);
        dvr_move(y, p, pos, cell_idx, csub, e0, ne, rnew, rcell, again, step + v,
                 hmin[v], hmax[v], tb);
        ++moves;
    }
    *nG = ng;
    return moves;
}

/* The rating of entry j of the faces w (centroid, n, lsq at k * stride for k = 0-2, 3-5, 6)
   with its vertex at p (_Directional._slides: tet.star_quality's operations). */
static inline double face_rating(const double *w, int64_t j, int64_t stride, const double *p)
{
    double qx = p[0] - w[j], qy = p[1] - w[stride + j], qz = p[2] - w[2 * stride + j];
    double s = qx * w[3 * stride + j];
    s += qy * w[4 * stride + j];
    s += qz * w[5 * stride + j];
    double L = qx * qx;
    L += qy * qy;
    L += qz * qz;
    L += w[6 * stride + j];
    return rating(s, L);
}

/* The slides of the vertices on Gamma G[0..nG) (_Directional._slides on one rank): their
   candidates pp (nG, ns, 3), projected onto Gamma with normals pn, at steps tg (nG, ns),
   rated exactly (no candidate may stretch an edge of Gamma_h, rows cap_ptr[v]..cap_ptr[v
   + 1] of cap_w and cap_len2, beyond its cap); the first within tie of the best moves its
   vertex if it beats q0 by more than tie. Returns the number of moves, -1 for more than 64
   candidates. */
int64_t dvr_slides(double *y, const int64_t *pv,
                   const int64_t *f0, const int64_t *f1, const int64_t *f2,
                   const int64_t *cell_idx, const int64_t *csub, const uint8_t *flat,
                   double *rcell, const int64_t *vfirst, const int64_t *vcount,
                   double *nrm, double *step, const double *hmin, const double *hmax,
                   const int64_t *cap_ptr, const int64_t *cap_w, const double *cap_len2,
                   const int64_t *G, int64_t nG, const double *q0, const double *pp,
                   const double *pn, const double *tg, int64_t ns, double k15, double tie,
                   double *w, int64_t stride, uint8_t *again)
{
    double qc[64], rmin[64], rnew[stride > 0 ? stride : 1];
    if (ns > 64)
        return -1;
    int64_t moves = 0;
    for (int64_t g = 0; g < nG; ++g)
    {
        int64_t v = G[g], e0 = vfirst[v], ne = vcount[v], p = pv[e0];
        const double *cand = pp + 3 * ns * g;
        for (int64_t j = 0; j < ne; ++j)
        {
            star_terms(y, p, f0[e0 + j], f1[e0 + j], f2[e0 + j], k15, w + j, stride);
            w[j] = y[3 * p] - w[j]; /* the facet's centroid g = p - u */
            w[stride + j] = y[3 * p + 1] - w[stride + j];
            w[2 * stride + j] = y[3 * p + 2] - w[2 * stride + j];
        }
        double qmax = -INFINITY;
        int64_t jw = 0;
        for (int64_t c = 0; c < ns; ++c)
        {
            double m = INFINITY, out = below(qmax, tie);
            for (int64_t i = 0, j0 = jw; i < ne && m >= out; ++i)
            {
                int64_t j = i == 0 ? j0 : i == j0 ? 0 : i;
                double r = flat[e0 + j] ? -1.0 : face_rating(w, j, stride, cand + 3 * c);
                if (r < m)
                {
                    m = r;
                    jw = j;
                }
            }
            if (m < out)
            {
                qc[c] = -INFINITY;
                continue;
            }
            rmin[c] = m;
            for (int64_t k = cap_ptr[v]; k < cap_ptr[v + 1]; ++k)
            {
                const double *pu = y + 3 * cap_w[k];
                double ex = cand[3 * c] - pu[0], ey = cand[3 * c + 1] - pu[1];
                double ez = cand[3 * c + 2] - pu[2];
                if (ex * ex + ey * ey + ez * ez > cap_len2[k])
                    rmin[c] = -1.0;
            }
            qc[c] = rating_quality(rmin[c]);
            qmax = qc[c] > qmax ? qc[c] : qmax;
        }
        int64_t b = first_best(qc, ns, tie);
        if (!(qc[b] > q0[g] + tie))
            continue;
        const double *pos = cand + 3 * b;
        for (int64_t j = 0; j < ne; ++j)
            rnew[j] = flat[e0 + j] ? -1.0 : face_rating(w, j, stride, pos);
        nrm[3 * p] = pn[3 * (ns * g + b)];
        nrm[3 * p + 1] = pn[3 * (ns * g + b) + 1];
        nrm[3 * p + 2] = pn[3 * (ns * g + b) + 2];
        dvr_move(y, p, pos, cell_idx, csub, e0, ne, rnew, rcell, again, step + v,
                 hmin[v], hmax[v], tg[ns * g + b]);
        ++moves;
    }
    return moves;
}

/* 0 .. m - 1 sorted by key (values 0 .. nkeys - 1), stably, into out (a counting sort;
   start: nkeys + 1 scratch). */
static void sort_by_key(const int64_t *key, int64_t m, int64_t nkeys, int64_t *start,
                        int64_t *out)
{
    for (int64_t c = 0; c <= nkeys; ++c)
        start[c] = 0;
    for (int64_t v = 0; v < m; ++v)
        ++start[key[v] + 1];
    for (int64_t c = 0; c < nkeys; ++c)
        start[c + 1] += start[c];
    for (int64_t v = 0; v < m; ++v)
        out[start[key[v]]++] = v;
}

/* The colours of the movable vertices and their star entries (relax_common.vertex_colours_graph
   and relax_tet._TetStars on one rank). csub (k, 4): the cells' corners in the numbering of the
   m movable vertices, -1 for the others; order: the vertices by decreasing priority.
   The Jones-Plassmann rounds: a vertex's round is one more than the latest of its
   neighbours of higher priority (0 without), and it takes the lowest colour that no
   neighbour of an earlier round has (neighbours of one round never share a colour: one of
   each pair has the higher priority). Then the entries (cell, corner) sorted by colour,
   vertex and cell into ecell, ecorner (n = the corners >= 0), and for each cell the entry
   of its first such corner in cfirst (filled with -1 by the caller: -1 stays at cells
   without one). vptr (m + 1), vcell (n), nptr (m + 1), nbr (3 n),
   rnd (m), byrnd (m), tmp (m + 1) are scratch. Returns the number of colours, -1 for more
   than 62. */
int64_t dvr_colour(const int64_t *csub, int64_t k, int64_t m, const double *priority,
                   const int64_t *order, int64_t *colour, int64_t *vptr, int64_t *vcell,
                   int64_t *nptr, int64_t *nbr, int64_t *rnd, int64_t *byrnd, int64_t *tmp,
                   int64_t *ecell, int64_t *ecorner, int64_t *cfirst)
{
    for (int64_t v = 0; v <= m; ++v)
        vptr[v] = 0;
    for (int64_t i = 0; i < 4 * k; ++i)
        if (csub[i] >= 0)
            ++vptr[csub[i] + 1];
    for (int64_t v = 0; v < m; ++v)
        vptr[v + 1] += vptr[v];
    for (int64_t v = 0; v < m; ++v) /* each vertex's corners 4 c + j, ascending (rnd: next) */
        rnd[v] = vptr[v];
    for (int64_t i = 0; i < 4 * k; ++i)
    {
        int64_t v = csub[i];
        if (v >= 0)
            vcell[rnd[v]++] = i;
        if (v >= 0 && cfirst[i / 4] == -1)
            cfirst[i / 4] = -2 - (i % 4); /* the cell's first corner j, as -2 - j */
    }
    /* each vertex's distinct neighbours (tmp: the last vertex that listed each), compact:
       the passes in priority order below read them from cache */
    nptr[0] = 0;
    for (int64_t v = 0; v < m; ++v)
        tmp[v] = -1;
    for (int64_t v = 0; v < m; ++v)
    {
        int64_t cnt = nptr[v];
        for (int64_t e = vptr[v]; e < vptr[v + 1]; ++e)
            for (int j = 0; j < 4; ++j)
            {
                int64_t u = csub[vcell[e] - vcell[e] % 4 + j];
                if (u >= 0 && u != v && tmp[u] != v)
                {
                    tmp[u] = v;
                    nbr[cnt++] = u;
                }
            }
        nptr[v + 1] = cnt;
    }
    int64_t nrounds = 0;
    for (int64_t i = 0; i < m; ++i) /* rounds, by decreasing priority */
    {
        int64_t v = order[i], r = 0;
        double pv = priority[v];
        for (int64_t e = nptr[v]; e < nptr[v + 1]; ++e)
        {
            int64_t u = nbr[e];
            if (priority[u] > pv && rnd[u] + 1 > r)
                r = rnd[u] + 1;
        }
        rnd[v] = r;
        nrounds = r + 1 > nrounds ? r + 1 : nrounds;
    }
    /* the vertices by round, then first fit */
    int64_t ncol = 0;
    sort_by_key(rnd, m, nrounds, tmp, byrnd);
    for (int64_t i = 0; i < m; ++i)
    {
        int64_t v = byrnd[i];
        uint64_t used = 0;
        for (int64_t e = nptr[v]; e < nptr[v + 1]; ++e)
        {
            int64_t u = nbr[e];
            if (rnd[u] < rnd[v])
                used |= (uint64_t)1 << colour[u];
        }
        int64_t c = 0;
        while (c < 62 && (used >> c) & 1)
            ++c;
        if (c >= 62)
            return -1;
        colour[v] = c;
        ncol = c + 1 > ncol ? c + 1 : ncol;
    }
    /* the entries by colour, vertex, cell (byrnd: the vertices by colour) */
    sort_by_key(colour, m, ncol, tmp, byrnd);
    int64_t n = 0;
    for (int64_t i = 0; i < m; ++i)
    {
        int64_t v = byrnd[i];
        for (int64_t e = vptr[v]; e < vptr[v + 1]; ++e)
        {
            int64_t c = vcell[e] / 4, j = vcell[e] % 4;
            ecell[n] = c;
            ecorner[n] = j;
            if (cfirst[c] == -2 - j)
                cfirst[c] = n;
            ++n;
        }
    }
    return ncol;
}

/* The orientation of the k cells from the entries first[0..nf) (one per cell; relax_tet.
   _TetStars._orient): the sign of s of its star terms. The entries e < ne of negatively
   oriented cells swap f1 and f2, those of flat ones (sign 0) are marked in flat; each cell
   is rated from its first entry (turned where s < 0) into rcell. */
void dvr_orient(const double *y, const int64_t *pv, const int64_t *f0, int64_t *f1,
                int64_t *f2, const int64_t *cell_idx, const int64_t *first, int64_t nf,
                int64_t ne, int64_t k, double k15, uint8_t *flat, double *rcell)
{
    double t[9];
    double *orient = (double *)calloc(k > 0 ? k : 1, sizeof(double));
    if (!orient)
        return;
    for (int64_t i = 0; i < nf; ++i)
    {
        int64_t e = first[i];
        star_terms(y, pv[e], f0[e], f1[e], f2[e], k15, t, 1);
        double s = t[7];
        orient[cell_idx[e]] = s > 0.0 ? 1.0 : s < 0.0 ? -1.0 : s == 0.0 ? 0.0 : NAN;
    }
    for (int64_t e = 0; e < ne; ++e)
    {
        double o = orient[cell_idx[e]];
        if (o < 0.0)
        {
            int64_t a = f1[e];
            f1[e] = f2[e];
            f2[e] = a;
        }
        flat[e] = o == 0.0;
    }
    for (int64_t i = 0; i < nf; ++i)
    {
        int64_t e = first[i];
        star_terms(y, pv[e], f0[e], f1[e], f2[e], k15, t, 1);
        rcell[cell_idx[e]] = flat[e] ? -1.0 : rating(t[7], t[8]);
    }
    free(orient);
}

/* The affine images under y (rows of gdim) of the nodes of the m cells redo
   (moving.MovingDomain._write_affine_nodes): each node once, from the cell and slot of
   code[node] = cell * ndofs + slot, lam's row of the slot summed in vertex order (nv
   vertices) into x (rows of 3); mark flags the nodes written, listed in touched. Returns
   their number. */
int64_t affine_nodes(const int64_t *redo, int64_t m, const int32_t *dofmap, int64_t ndofs,
                     const int32_t *c2v, int64_t nv, const int64_t *code, const double *lam,
                     const double *y, int64_t gdim, double *x, uint8_t *mark,
                     int64_t *touched)
{
    int64_t n = 0;
    for (int64_t i = 0; i < m; ++i)
    {
        const int32_t *dofs = dofmap + redo[i] * ndofs;
        for (int64_t j = 0; j < ndofs; ++j)
        {
            int64_t node = dofs[j];
            if (mark[node])
                continue;
            mark[node] = 1;
            touched[n++] = node;
            const double *w = lam + (code[node] % ndofs) * nv;
            const int32_t *v = c2v + (code[node] / ndofs) * nv;
            for (int64_t d = 0; d < gdim; ++d)
            {
                double acc = w[0] * y[v[0] * gdim + d];
                for (int64_t k = 1; k < nv; ++k)
                    acc += w[k] * y[v[k] * gdim + d];
                x[node * 3 + d] = acc;
            }
        }
    }
    return n;
}

/* The affine images out (m, np, 3) of the np barycentric points w (rows of nv <= 4) in the m
   cells (rows of nv vertex indices into src, rows of 3): each sum from 0.0 over the
   vertices in order, as numpy's einsum sums it (_curved_tet.map_nodes). */
void contract_cells(const int64_t *cells, int64_t m, int64_t nv, const double *w, int64_t np,
                    const double *src, double *out)
{
    double v[4 * 3];
    for (int64_t i = 0; i < m; ++i)
    {
        for (int64_t k = 0; k < nv; ++k)
            for (int64_t d = 0; d < 3; ++d)
                v[k * 3 + d] = src[cells[i * nv + k] * 3 + d];
        double *o = out + i * np * 3;
        for (int64_t p = 0; p < np; ++p)
        {
            const double *wp = w + p * nv;
            for (int64_t d = 0; d < 3; ++d)
            {
                double acc = 0.0;
                for (int64_t k = 0; k < nv; ++k)
                    acc += wp[k] * v[k * 3 + d];
                o[p * 3 + d] = acc;
            }
        }
    }
}

/* The blend of _curved_tet.map_nodes for the m cells rows (of cells, nv vertices each) of
   one pattern: delta_r = pi[i, r] - (affine image under y of points[r]) for its nr points,
   then node p of the cell in nodes (rows of np nodes of 3) becomes pi[i, direct[p]] where
   direct[p] >= 0, else itself plus the sum from 0.0 of its terms w * delta_r (term_r,
   term_w from start[p] to start[p + 1], r increasing: the nonzero weights of the pattern;
   the zero ones add 0.0, which changes no sum). delta: scratch of nr * 3. */
void blend_nodes(const int64_t *rows, int64_t m, const int64_t *cells, int64_t nv,
                 const double *y, const double *points, int64_t nr, const double *pi,
                 int64_t np, const int64_t *direct, const int64_t *start,
                 const int64_t *term_r, const double *term_w, double *nodes, double *delta)
{
    double v[4 * 3];
    for (int64_t i = 0; i < m; ++i)
    {
        for (int64_t k = 0; k < nv; ++k)
            for (int64_t d = 0; d < 3; ++d)
                v[k * 3 + d] = y[cells[rows[i] * nv + k] * 3 + d];
        const double *q = pi + i * nr * 3;
        for (int64_t r = 0; r < nr; ++r)
            for (int64_t d = 0; d < 3; ++d)
            {
                double acc = 0.0;
                for (int64_t k = 0; k < nv; ++k)
                    acc += points[r * nv + k] * v[k * 3 + d];
                delta[r * 3 + d] = q[r * 3 + d] - acc;
            }
        double *o = nodes + rows[i] * np * 3;
        for (int64_t p = 0; p < np; ++p)
        {
            if (direct[p] >= 0)
            {
                for (int64_t d = 0; d < 3; ++d)
                    o[p * 3 + d] = q[direct[p] * 3 + d];
                continue;
            }
            for (int64_t d = 0; d < 3; ++d)
            {
                double acc = 0.0;
                for (int64_t t = start[p]; t < start[p + 1]; ++t)
                    acc += term_w[t] * delta[term_r[t] * 3 + d];
                o[p * 3 + d] = o[p * 3 + d] + acc;
            }
        }
    }
}

/* Writes the nodes (blocks of ndofs rows of gdim) of blocks which[i] into the rows of 3 of
   x that the dofmap (rows of ndofs) gives cell cells[i], in order i = 0..m-1 (a later
   write of a shared node wins, as in numpy's assignment). */
void write_cell_nodes(const int64_t *cells, const int64_t *which, int64_t m,
                      const int32_t *dofmap, int64_t ndofs, const double *nodes, int64_t gdim,
                      double *x)
{
    for (int64_t i = 0; i < m; ++i)
    {
        const int32_t *dofs = dofmap + cells[i] * ndofs;
        const double *v = nodes + which[i] * ndofs * gdim;
        for (int64_t p = 0; p < ndofs; ++p)
            for (int64_t d = 0; d < gdim; ++d)
                x[(int64_t)dofs[p] * 3 + d] = v[p * gdim + d];
    }
}

/* The distinct rows (bitwise) of x (n < 2^31 rows of dim <= 4 doubles), by open addressing
   in table (size a power of 2 above n, filled with -1): first lists the first row of each in
   order of appearance, inverse[i] the position of row i's in first. Returns their number
   (core.arrays.project_together). */
int64_t distinct_rows(const double *x, int64_t n, int64_t dim, int32_t *table, int64_t size,
                      int64_t *first, int64_t *inverse)
{
    int64_t count = 0;
    for (int64_t i = 0; i < n; ++i)
    {
        uint64_t h = 0x9E3779B97F4A7C15ull;
        for (int64_t d = 0; d < dim; ++d)
        {
            uint64_t b;
            memcpy(&b, x + i * dim + d, sizeof b);
            h = (h ^ b) * 0xBF58476D1CE4E5B9ull;
            h ^= h >> 31;
        }
        int64_t slot = (int64_t)(h & (uint64_t)(size - 1));
        for (;;)
        {
            int64_t j = table[slot];
            if (j < 0)
            {
                table[slot] = (int32_t)i;
                first[count] = i;
                inverse[i] = count++;
                break;
            }
            if (memcmp(x + j * dim, x + i * dim, dim * sizeof(double)) == 0)
            {
                inverse[i] = inverse[j];
                break;
            }
            slot = (slot + 1) & (size - 1);
        }
    }
    return count;
}

/* The slot columns of a degree-q dofmap (core.lagrange.lagrange_geometry): row i of dofmap
   (width columns, from column nv) is the row of slots (width - nv columns) of the code of
   cell i's vertices c2v (nv each), sum over i < j of nv^i where gv[c2v[i]] > gv[c2v[j]],
   else nv^j (core.lagrange._code). */
void dofmap_slots(int64_t m, int64_t nv, const int32_t *c2v, const int64_t *gv,
                  const int32_t *slots, int32_t *dofmap, int64_t width)
{
    int64_t pw[5] = {1, 0, 0, 0, 0};
    for (int64_t k = 1; k < nv; ++k)
        pw[k] = pw[k - 1] * nv;
    int64_t ns = width - nv;
    for (int64_t c = 0; c < m; ++c)
    {
        int64_t g[4];
        for (int64_t k = 0; k < nv; ++k)
            g[k] = gv[c2v[c * nv + k]];
        int64_t code = 0;
        for (int64_t i = 0; i < nv; ++i)
            for (int64_t j = i + 1; j < nv; ++j)
                code += g[i] > g[j] ? pw[i] : pw[j];
        const int32_t *row = slots + code * ns;
        int32_t *out = dofmap + c * width + nv;
        for (int64_t k = 0; k < ns; ++k)
            out[k] = row[k];
    }
}

/* Adds (add = 1) or writes the first node of each of the ne entities per cell conn (rows
   of ne; NULL: entity c of cell c) to its n columns from column of the m rows of dofmap
   (width columns): n e + own for an owned entity (e < size), n e + ghost else
   (core.lagrange.lagrange_geometry's first_node). */
void dofmap_block(int64_t m, const int32_t *conn, int64_t ne, int64_t n, int64_t size,
                  int64_t own, int64_t ghost, int32_t *dofmap, int64_t width, int64_t column,
                  int64_t add)
{
    for (int64_t c = 0; c < m; ++c)
    {
        int32_t *out = dofmap + c * width + column;
        for (int64_t j = 0; j < ne; ++j)
        {
            int64_t e = conn ? conn[c * ne + j] : c;
            int32_t base = (int32_t)(n * e + (e < size ? own : ghost));
            for (int64_t k = 0; k < n; ++k)
                out[j * n + k] = add ? out[j * n + k] + base : base;
        }
    }
}

/* The nodes of n entities of nv vertices (core.lagrange.lagrange_geometry): each entity's
   vertices e2v ordered by their global indices gv, then for each of its ns slots key's row
   summed in that order from the vertex positions xv (rows of 3) into the rows of 3 of
   owned (entities e < size: row e * ns + slot) or ghost (row (e - size) * ns + slot). */
void entity_nodes(const int32_t *e2v, int64_t n, int64_t nv, const int64_t *gv,
                  const double *xv, const double *key, int64_t ns, int64_t size,
                  double *owned, double *ghost)
{
    for (int64_t e = 0; e < n; ++e)
    {
        int32_t v[4];
        for (int64_t k = 0; k < nv; ++k)
        {
            int32_t a = e2v[e * nv + k];
            int64_t j = k;
            for (; j > 0 && gv[v[j - 1]] > gv[a]; --j)
                v[j] = v[j - 1];
            v[j] = a;
        }
        double *out = e < size ? owned + e * ns * 3 : ghost + (e - size) * ns * 3;
        for (int64_t slot = 0; slot < ns; ++slot)
        {
            const double *w = key + slot * nv;
            for (int64_t d = 0; d < 3; ++d)
            {
                double acc = w[0] * xv[v[0] * 3 + d];
                for (int64_t k = 1; k < nv; ++k)
                    acc += w[k] * xv[v[k] * 3 + d];
                out[slot * 3 + d] = acc;
            }
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
