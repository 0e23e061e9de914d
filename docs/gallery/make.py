"""Regenerate the viewer gallery: one screenshot per state of the plan viewer, in headless Chromium.

    python docs/gallery/make.py [MESH] [--units in] [--candidates 300] [--tilt 30]
                                [--resolution 0.18] [--formulation density|visibility]
                                [--out docs/gallery] [--redis-url URL]

Plans MESH (default: /work/shared/meshes/featuretype.STL, inches, 300 candidates, tilt 30°)
through the API (uvicorn on loopback, one RQ worker, the paper's sensor), opens
/v1/plans/{id}/view at 1600 × 1000 and saves under --out:

- `opened.png`: the page as it opens (the part framed, every selected camera numbered);
- `selected.png`: the camera looking most nearly the eye's way selected, its faces highlighted;
- `through.png`: looking through that camera, its sensor frame drawn;
- `problems.png`: *problems only*: the faces that miss the target, are uncovered or left out.

The README's screenshot is `docs/gallery/selected.png`. Redis: db 11 (flushed before and after).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from bench.viewer import FLAGS, served_plan  # noqa: E402

VIEWPORT = {"width": 1600, "height": 1000}
MESH = Path("/work/shared/meshes/featuretype.STL")


def main() -> None:
    """Parse the arguments, plan, and save the four screenshots."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", default=str(MESH))
    ap.add_argument("--units", default="in")
    ap.add_argument("--candidates", type=int, default=300)
    ap.add_argument("--tilt", type=float, default=30.0)
    ap.add_argument("--resolution", type=float, default=0.18)
    ap.add_argument("--formulation", choices=["density", "visibility"], default="density")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "gallery")
    ap.add_argument("--redis-url", default="redis://127.0.0.1:6379/11")
    args = ap.parse_args()
    with served_plan(args) as (url, plan, _doc):
        shoot(url, plan, args.out)


def shoot(url: str, plan: str, out: Path) -> None:
    """Open the plan's page and save one PNG per state under `out`."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=FLAGS)
        page = browser.new_page(viewport=VIEWPORT, device_scale_factor=1)
        page.goto(f"{url}/v1/plans/{plan}/view")
        page.wait_for_function("window.vppViewer && window.vppViewer.ready", timeout=300_000)
        shots = {
            "opened.png": "null",
            "selected.png": "window.vppViewer.select(window.vppViewer.facing())",
            "through.png": "document.getElementById('look').click()",
            "problems.png": "document.getElementById('clear').click();"
            " document.getElementById('fit-part').click(); window.vppViewer.problemsOnly(true)",
        }
        for name, action in shots.items():
            page.evaluate(action)
            page.evaluate("window.vppViewer.drawn()")
            page.screenshot(path=str(out / name))
            print(out / name, flush=True)
        browser.close()


if __name__ == "__main__":
    main()
