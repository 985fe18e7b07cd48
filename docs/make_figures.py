"""Make the figures of the documentation and of the README (committed under docs/figures/).

    python docs/make_figures.py                    # everything (runs every demo in --quick mode)
    python docs/make_figures.py --only overview method
    python docs/make_figures.py --only demos --demo-out /tmp/demos   # reuse finished runs

* ``overview.png``: a curved 2D mesh (a five-lobed star, degree 3) and a 3D one (a torus,
  clipped) made by ``mesh_domain``; it opens the README and the documentation.
* ``method/*.png``: the stages of the method on one domain (a three-lobed star on an
  equilateral background): the background and the signs of its vertices, the positively
  cut triangles and Gamma_h, the straight map M_h (``conform(..., relax=False)``), the
  relaxed mesh and the curved one (degree 3); ``docs/method.md`` shows each where the text
  explains the stage.
* ``demos/<demo>/*.png``: the figures of every demo, run with ``--quick --out DIR``
  (``--demo-out``: where the runs go; a demo whose ``summary.json`` is there already is not
  run again), downscaled where large, so that each PNG stays small.

``manifest.json`` lists every figure with the command that made it and a fingerprint of
what it shows (cell, vertex and edge counts; the PNG's size and SHA-256);
``tests/test_figures.py`` checks the figures against it and recomputes the fingerprints of
the overview and of the method's stages. Serial only (the figures are drawn on one rank).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from mpi4py import MPI  # noqa: E402

import numpy as np  # noqa: E402

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
FIGURES = DOCS / "figures"
MANIFEST = FIGURES / "manifest.json"
DPI = 110
#: Largest width and height (pixels) of a committed demo figure, and its largest size.
MAX_PIXELS = 1500
MAX_BYTES = 300_000


# --------------------------------------------------------------------------------------------
# The domains (tests/test_figures.py rebuilds them to recompute the fingerprints)
# --------------------------------------------------------------------------------------------


def star(lobes: int, amplitude: float):
    """The star ``r = 1 + amplitude cos(lobes t)`` as a PolarCurve."""
    import dolfinx_universal as du

    a, n = amplitude, lobes
    return du.PolarCurve(
        lambda t: 1.0 + a * np.cos(n * t),
        lambda t: -a * n * np.sin(n * t),
        lambda t: -a * n * n * np.cos(n * t),
    )


def overview_meshes(comm=MPI.COMM_WORLD):
    """The two meshes of ``overview.png``: a degree-3 star and a torus (degree 2)."""
    import dolfinx_universal as du

    md2 = du.mesh_domain(comm, star(5, 0.15), h=0.3, degree=3)
    md3 = du.mesh_domain(comm, du.Torus((0.0, 0.0, 0.0), 1.0, 0.35), h=0.35, degree=2)
    return md2, md3


#: The domain and background of the method's stages.
METHOD_BOX = ((-1.5, -1.75), (1.95, 1.75))
#: What the method's figures show of it.
METHOD_VIEW = ((-1.1, -1.25), (1.95, 1.25))  # room for the inset and legend
METHOD_H = 0.16
METHOD_DEGREE = 3


def method_meshes(comm=MPI.COMM_WORLD):
    """Background, M_h (not relaxed), the relaxed mesh and its curved version (degree 3)."""
    import dolfinx_universal as du

    boundary = star(3, 0.25)
    background = du.equilateral_mesh(comm, METHOD_BOX, METHOD_H)
    snapped = du.conform(background, boundary, relax=False)
    relaxed = du.conform(background, boundary)
    curved = du.curved_mesh(relaxed, METHOD_DEGREE)
    return background, snapped, relaxed, curved


def _counts(msh) -> dict:
    """Global cell and vertex counts of a mesh."""
    tdim = msh.topology.dim
    return {
        "cells": int(msh.topology.index_map(tdim).size_global),
        "vertices": int(msh.topology.index_map(0).size_global),
    }


def _gamma_h(cm) -> int:
    """The number of facets of Gamma_h (tagged IMMERSED), global."""
    import dolfinx_universal as du

    facets = cm.facet_tags.find(du.IMMERSED)  # builds the facets first
    imap = cm.mesh.topology.index_map(cm.mesh.topology.dim - 1)
    owned = facets < imap.size_local
    return int(cm.mesh.comm.allreduce(int(np.count_nonzero(owned))))


def overview_fingerprint(md2, md3) -> dict:
    return {
        "2d": {**_counts(md2.mesh), "degree": 3, "gamma_h": _gamma_h(md2.conforming)},
        "3d": {**_counts(md3.mesh), "degree": 2, "gamma_h": _gamma_h(md3.conforming)},
    }


def _positively_cut(cm) -> np.ndarray:
    """Local cells of ``cm.mesh`` with exactly two vertices on the outside (sign +1)."""
    cells = cm.mesh.topology.connectivity(2, 0).array.reshape(-1, 3)
    return np.count_nonzero(cm.sign[cells] > 0, axis=1) == 2


def method_fingerprint(background, snapped, relaxed, curved) -> dict:
    moved = int(np.count_nonzero(relaxed.moved & ~snapped.moved))
    return {
        "background": _counts(background),
        "positive_edges": {
            "kept_cells": _counts(snapped.mesh)["cells"],
            "positively_cut": int(np.count_nonzero(_positively_cut(snapped))),
            "gamma_h": _gamma_h(snapped),
        },
        "snapped": {**_counts(snapped.mesh), "moved_vertices": int(snapped.moved.sum())},
        "relaxed": {**_counts(relaxed.mesh), "moved_by_relaxation": moved},
        "curved": {**_counts(curved.mesh), "degree": METHOD_DEGREE},
    }


# --------------------------------------------------------------------------------------------
# Drawing
# --------------------------------------------------------------------------------------------


def _figure(ncols: int = 1, size=(5.0, 4.6), projection=None):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(size[0] * ncols, size[1]), layout="constrained")
    axes = [fig.add_subplot(1, ncols, i + 1, projection=projection) for i in range(ncols)]
    return fig, axes


def _save(fig, path: Path) -> None:
    """Write the figure, then keep the PNG small (:func:`shrink_png`)."""
    from dolfinx_universal.plotting import save

    raw = path.with_suffix(".raw.png")
    save(fig, raw, dpi=DPI)
    shrink_png(raw, path)
    raw.unlink()


def draw_overview(md2, md3, path: Path) -> None:
    from matplotlib.figure import Figure

    from dolfinx_universal.plotting import plot_conforming, plot_tetrahedra

    fig = Figure(figsize=(11.0, 5.0), layout="constrained")
    ax = fig.add_subplot(1, 2, 1)
    bx = fig.add_subplot(1, 2, 2, projection="3d")
    plot_conforming(
        ax,
        md2.conforming,
        mesh=md2.curved,
        show_background=True,
        legend="lower left",
        inset=(0.93, -0.15, 1.23, 0.15),
        title="2D: a star, triangles curved to degree 3",
    )
    ax.set_xlim(-1.3, 1.3), ax.set_ylim(-1.3, 1.3)
    plot_tetrahedra(
        md3.conforming,
        bx,
        view="clipped",
        normal=(0.0, 0.0, 1.0),  # the upper half removed: the cut shows the tetrahedra
        elev=32.0,
        azim=-62.0,
        colorbar=True,
        linewidth=0.1,
        title="3D: a torus, degree 2, clipped (colour: smallest dihedral angle)",
    )
    x = md3.mesh.geometry.x
    bx.set_box_aspect(np.ptp(x, axis=0), zoom=1.2)  # the torus fills its half
    bx.set_axis_off()
    _save(fig, path)


#: The zoom window shared by the method's figures: one tip of the star.
WINDOW = (0.9, -0.35, 1.38, 0.13)


def _exact(ax, boundary) -> None:
    from dolfinx_universal.plotting import BOUNDARY_COLOR, boundary_polyline

    line = boundary_polyline(boundary, 2000)
    ax.plot(line[:, 0], line[:, 1], color=BOUNDARY_COLOR, lw=0.9, zorder=5)


def _panel(path: Path, draw, title: str, handles=None) -> None:
    """One stage: ``draw(axes, linewidth)`` in the main axes (the view of METHOD_VIEW, the
    legend lower right) and in an inset (upper right) zooming on WINDOW."""
    from dolfinx_universal.plotting import add_inset

    fig, (ax,) = _figure(size=(6.4, 4.6))
    draw(ax, 0.4)
    (x0, y0), (x1, y1) = METHOD_VIEW
    ax.set_xlim(x0, x1), ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x"), ax.set_ylabel("y")
    ax.set_title(title)
    if handles is not None:
        ax.legend(handles=handles, loc="lower right", fontsize=7, framealpha=0.9)
    elif ax.get_legend() is not None:
        ax.get_legend().set_loc("lower right")

    def zoom(a):
        draw(a, 1.0)
        if a.get_legend() is not None:
            a.get_legend().remove()
        a.set_xlabel(""), a.set_ylabel(""), a.set_title("")

    add_inset(ax, WINDOW, zoom, size=0.32, loc="upper right")
    _save(fig, path)


def draw_background(background, cm, path: Path) -> None:
    """The background, Gamma, and the sign of every vertex."""
    from matplotlib.lines import Line2D

    from dolfinx_universal.plotting import BOUNDARY_COLOR, gather_cells, plot_mesh

    nodes = gather_cells(background)
    x = background.geometry.x[:, :2]
    inside = cm.boundary.signed_distance(x) < 0

    def draw(a, lw):
        plot_mesh(a, nodes, facecolors="none", edgecolor="0.55", linewidth=lw, axis_labels=False)
        a.scatter(*x[inside].T, s=14 * lw, color="#1f4e99", zorder=6, linewidths=0)
        a.scatter(*x[~inside].T, s=14 * lw, color="0.6", zorder=6, linewidths=0)
        _exact(a, cm.boundary)

    handles = [
        Line2D([], [], color=BOUNDARY_COLOR, lw=0.9, label=r"$\Gamma$"),
        Line2D([], [], ls="", marker="o", ms=3, color="#1f4e99", label=r"$s = -1$ (inside)"),
        Line2D([], [], ls="", marker="o", ms=3, color="0.6", label=r"$s = +1$"),
    ]
    _panel(path, draw, r"background $\mathcal{T}_h$, $\Gamma$ and the vertex signs", handles)


def draw_positive_edges(background, cm, path: Path) -> None:
    """The kept triangles and the positively cut ones at their background positions, and
    Gamma_h (the positive edges)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    import dolfinx_universal as du
    from dolfinx_universal.plotting import (
        BACKGROUND_EDGE,
        BOUNDARY_COLOR,
        CUT_FACE,
        GAMMA_H_COLOR,
        KEPT_FACE,
        gather_cells,
        plot_mesh,
    )

    msh = cm.mesh
    cells = msh.topology.connectivity(2, 0).array.reshape(-1, 3)
    at_background = cm.background_x[cells][:, :, :2]
    faces = list(np.where(_positively_cut(cm), CUT_FACE, KEPT_FACE))
    facets = cm.facet_tags.find(du.IMMERSED)
    msh.topology.create_connectivity(1, 0)
    f2v = msh.topology.connectivity(1, 0).array.reshape(-1, 2)
    gamma = cm.background_x[f2v[facets]][:, :, :2]
    bg_nodes = gather_cells(background)

    def draw(a, lw):
        plot_mesh(a, bg_nodes, None, edgecolor=BACKGROUND_EDGE, linewidth=lw, axis_labels=False)
        plot_mesh(a, at_background, None, faces, "k", lw, axis_labels=False)
        for seg in gamma:
            a.plot(seg[:, 0], seg[:, 1], color=GAMMA_H_COLOR, lw=4 * lw + 0.4, zorder=7)
        _exact(a, cm.boundary)

    handles = [
        Patch(facecolor=KEPT_FACE, edgecolor="k", lw=0.3, label=r"kept ($\mathcal{T}_h^{sub}$)"),
        Patch(facecolor=CUT_FACE, edgecolor="k", lw=0.3, label="positively cut"),
        Line2D([], [], color=GAMMA_H_COLOR, lw=2.0, label=r"$\Gamma_h$ (positive edges)"),
        Line2D([], [], color=BOUNDARY_COLOR, lw=0.9, label=r"$\Gamma$"),
    ]
    _panel(path, draw, r"kept triangles, positively cut ones, $\Gamma_h$", handles)


def draw_conforming(cm, path: Path, title: str, mesh=None) -> None:
    from dolfinx_universal.plotting import plot_conforming

    def draw(a, lw):
        plot_conforming(
            a, cm, mesh=mesh, show_background=True, legend=True, inset=False, linewidth=lw
        )

    _panel(path, draw, title)


# --------------------------------------------------------------------------------------------
# Manifest
# --------------------------------------------------------------------------------------------


def png_info(path: Path) -> dict:
    """Pixel size, bytes and SHA-256 of a PNG."""
    from PIL import Image

    with Image.open(path) as im:
        width, height = im.size
    data = path.read_bytes()
    return {
        "width": width,
        "height": height,
        "bytes": len(data),
        "sha256": hashlib.sha256(data).hexdigest(),
    }


def load_manifest() -> dict:
    if MANIFEST.exists():
        return json.loads(MANIFEST.read_text(encoding="utf-8"))
    return {"figures": {}}


def record(manifest: dict, path: Path, command: str, fingerprint: dict | None = None) -> None:
    rel = path.relative_to(DOCS).as_posix()
    entry = {"command": command, "png": png_info(path)}
    if fingerprint is not None:
        entry["fingerprint"] = fingerprint
    manifest["figures"][rel] = entry


# --------------------------------------------------------------------------------------------
# The three groups
# --------------------------------------------------------------------------------------------

HERE = "python docs/make_figures.py"


def make_overview(manifest: dict) -> None:
    md2, md3 = overview_meshes()
    path = FIGURES / "overview.png"
    draw_overview(md2, md3, path)
    record(manifest, path, f"{HERE} --only overview", overview_fingerprint(md2, md3))


METHOD_FIGURES = ("background", "positive_edges", "snapped", "relaxed", "curved")


def make_method(manifest: dict) -> None:
    background, snapped, relaxed, curved = method_meshes()
    out = FIGURES / "method"
    fp = method_fingerprint(background, snapped, relaxed, curved)
    draw_background(background, snapped, out / "background.png")
    draw_positive_edges(background, snapped, out / "positive_edges.png")
    draw_conforming(snapped, out / "snapped.png", r"$M_h$: $\Gamma_h$ snapped onto $\Gamma$")
    draw_conforming(relaxed, out / "relaxed.png", "relaxed")
    draw_conforming(
        relaxed, out / "curved.png", f"curved, degree {METHOD_DEGREE} (map I)", mesh=curved
    )
    for name in METHOD_FIGURES:
        record(manifest, out / f"{name}.png", f"{HERE} --only method", {name: fp[name]})


def shrink_png(src: Path, dst: Path) -> None:
    """Copy a PNG, downscaled to at most MAX_PIXELS, as the smallest of: the file itself
    (when it fits), the RGB image and its 256-colour version; smaller again while it
    exceeds MAX_BYTES."""
    import io

    from PIL import Image

    dst.parent.mkdir(parents=True, exist_ok=True)
    original = src.read_bytes()
    with Image.open(src) as im:
        im = im.convert("RGB")
    fits = max(im.size) <= MAX_PIXELS
    scale = min(1.0, MAX_PIXELS / max(im.size))
    while True:
        size = (max(1, round(im.width * scale)), max(1, round(im.height * scale)))
        small = im.resize(size, Image.LANCZOS) if scale < 1.0 else im
        candidates = [original] if fits and scale == 1.0 else []
        for image in (small, small.quantize(256, method=Image.Quantize.MEDIANCUT)):
            buffer = io.BytesIO()
            image.save(buffer, format="PNG", optimize=True)
            candidates.append(buffer.getvalue())
        best = min(candidates, key=len)
        if len(best) <= MAX_BYTES or scale < 0.3:
            dst.write_bytes(best)
            return
        scale *= 0.8


def make_demos(manifest: dict, demo_out: Path, names: list[str] | None = None) -> None:
    demos = sorted(p for p in (ROOT / "demos").glob("*.py") if not p.name.startswith("_"))
    for demo in demos:
        if names and demo.stem not in names:
            continue
        run = demo_out / demo.stem
        command = f"python demos/{demo.name} --quick --out DIR"
        if not (run / "summary.json").exists():
            print(f"running {command.replace('DIR', str(run))}", flush=True)
            subprocess.run(
                [sys.executable, str(demo), "--quick", "--out", str(run)], check=True, cwd=ROOT
            )
        target = FIGURES / "demos" / demo.stem
        if target.exists():
            shutil.rmtree(target)
        for key in [k for k in manifest["figures"] if k.startswith(f"figures/demos/{demo.stem}/")]:
            del manifest["figures"][key]
        summary = json.loads((run / "summary.json").read_text(encoding="utf-8"))
        for png in sorted(run.glob("*.png")):
            dst = target / png.name
            shrink_png(png, dst)
            record(
                manifest,
                dst,
                command,
                {"quick": bool(summary.get("parameters", {}).get("quick", True))},
            )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", choices=("overview", "method", "demos"))
    parser.add_argument("--demos", nargs="+", help="only these demos (file stems)")
    parser.add_argument("--demo-out", type=Path, default=ROOT / "out" / "figures")
    args = parser.parse_args(argv)
    if MPI.COMM_WORLD.size != 1:
        raise SystemExit("make_figures.py runs in serial")
    groups = args.only or ["overview", "method", "demos"]
    manifest = load_manifest()
    if "overview" in groups:
        make_overview(manifest)
    if "method" in groups:
        make_method(manifest)
    if "demos" in groups:
        make_demos(manifest, args.demo_out, args.demos)
    manifest["figures"] = dict(sorted(manifest["figures"].items()))
    FIGURES.mkdir(parents=True, exist_ok=True)
    MANIFEST.write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {MANIFEST}")


if __name__ == "__main__":
    main()
