"""The committed viewer bundle is what `npm run build` makes of viewer/ (like the OpenAPI drift)."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BUNDLE = ROOT / "service" / "static" / "viewer" / "viewer.js"


def test_the_committed_bundle_is_built_from_the_sources(tmp_path: Path) -> None:
    npm = shutil.which("npm")
    if not npm or not (ROOT / "viewer" / "node_modules").is_dir():
        pytest.skip("the viewer's build tools are not installed: npm ci --prefix viewer")
    out = tmp_path / "viewer.js"
    env = {**os.environ, "VPP_VIEWER_OUT": str(out)}
    subprocess.run(
        [npm, "run", "--silent", "build"], cwd=ROOT / "viewer", env=env, check=True, timeout=120
    )
    assert out.read_bytes() == BUNDLE.read_bytes(), (
        "service/static/viewer/viewer.js is stale: run `npm run build --prefix viewer`"
    )


def test_the_bundle_ships_with_the_package() -> None:
    """The page and its assets are package data, served with no network at run time."""
    assert BUNDLE.stat().st_size > 100_000
    html = (BUNDLE.parent / "index.html").read_text()
    for ref in ("/static/viewer/viewer.js", "/static/viewer/viewer.css"):
        assert ref in html and (BUNDLE.parent / ref.rsplit("/", 1)[1]).exists()
    assert "http://" not in html and "https://" not in html  # no CDN
