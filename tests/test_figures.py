"""The documentation's figures are there, listed, small and current.

``docs/make_figures.py`` writes every figure under ``docs/figures/`` and a manifest with the
command that made each one and a fingerprint of what it shows. These tests check that every
figure the pages and the README name exists, that the manifest and the PNGs match (no
figure made by hand, none left over), and recompute the fingerprints of the cheap ones
(the overview and the method's stages: cell, vertex and Gamma_h counts) from the package:
a change of the meshes that the figures show makes them fail until the figures are made
again (``python docs/make_figures.py --only overview method``).
"""

from __future__ import annotations

import hashlib
import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
FIGURES = DOCS / "figures"
MANIFEST = FIGURES / "manifest.json"

pytestmark = pytest.mark.skip_in_parallel

# A figure named by a page: Markdown images, MyST figure/image directives, HTML <img>.
_REFERENCE = re.compile(
    r"(?:\]\(|\{figure\}\s+|\{image\}\s+|src=\")/?((?:docs/)?figures/[^\s)\"]+\.png)"
)


def _manifest() -> dict:
    return json.loads(MANIFEST.read_text(encoding="utf-8"))["figures"]


def _pages() -> list[Path]:
    pages = [p for p in DOCS.glob("*.md")] + [ROOT / "README.md"]
    return [p for p in pages if p.exists()]


def _make_figures():
    sys.path.insert(0, str(DOCS))
    try:
        import make_figures
    finally:
        sys.path.remove(str(DOCS))
    return make_figures


def test_referenced_figures_exist():
    seen = 0
    for page in _pages():
        for ref in _REFERENCE.findall(page.read_text(encoding="utf-8")):
            path = ROOT / ref if ref.startswith("docs/") else DOCS / ref
            assert path.is_file(), f"{page.name} shows {ref}, which does not exist"
            seen += 1
    assert seen > 0
    index = (DOCS / "index.md").read_text(encoding="utf-8")
    assert "figures/overview.png" in index
    method = (DOCS / "method.md").read_text(encoding="utf-8")
    for name in _make_figures().METHOD_FIGURES:
        assert f"figures/method/{name}.png" in method


def test_manifest_lists_every_png():
    listed = _manifest()
    pngs = {p.relative_to(DOCS).as_posix() for p in FIGURES.rglob("*.png")}
    assert pngs == set(listed), (
        f"not in the manifest: {sorted(pngs - set(listed))}; "
        f"missing files: {sorted(set(listed) - pngs)}"
    )
    for rel, entry in listed.items():
        data = (DOCS / rel).read_bytes()
        assert hashlib.sha256(data).hexdigest() == entry["png"]["sha256"], rel
        assert len(data) < 300_000, f"{rel}: {len(data)} bytes"
        assert entry["command"]


def test_demo_figures_belong_to_demos():
    demos = {p.stem for p in (ROOT / "demos").glob("*.py")}
    folders = {p.name for p in (FIGURES / "demos").iterdir() if p.is_dir()}
    assert folders <= demos, f"figures of no demo: {sorted(folders - demos)}"
    assert folders, "no demo figures"


def test_method_fingerprints_current():
    mf = _make_figures()
    fp = mf.method_fingerprint(*mf.method_meshes())
    listed = _manifest()
    for name in mf.METHOD_FIGURES:
        assert listed[f"figures/method/{name}.png"]["fingerprint"] == {name: fp[name]}, name


def test_overview_fingerprint_current():
    mf = _make_figures()
    fp = mf.overview_fingerprint(*mf.overview_meshes())
    assert _manifest()["figures/overview.png"]["fingerprint"] == fp
