"""Per-pixel agreement of the `raster` backend with Embree on every shared mesh (test figures).

    python bench/agreement.py [--candidates 20]

For each mesh of ../shared/meshes (units from its MANIFEST.csv), `--candidates` generated
viewpoints of the paper's camera; per view the rasteriser's first face per pixel against
Embree's on the rays `trace_counts` casts (tests/test_raster.py does the same and asserts):
hit pixels, disagreeing pixels (as a fraction), the largest distance of a disagreement from
a triangle edge that is not a depth tie (pixels), then R from both backends: the sum of
|difference| and how many entries of more than 100 rays differ by more than 0.1 %.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.conftest import MANIFEST_UNITS, MESHES, manifest_rows  # noqa: E402
from tests.test_raster import PAPER, compare_views  # noqa: E402
from vpp_core.candidates import GeneratorSettings, generate  # noqa: E402
from vpp_core.mesh import load_mesh  # noqa: E402
from vpp_core.raytrace import make_backend, trace_counts  # noqa: E402


def main() -> int:
    """Print one row per shared mesh."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--candidates", type=int, default=20)
    args = ap.parse_args()
    rows = manifest_rows()
    if not rows:
        print(f"no shared meshes at {MESHES}", file=sys.stderr)
        return 0
    print(
        f"{'mesh':<34} {'faces':>7} {'hit px':>10} {'differ':>7} {'share':>9} {'edge px':>8} "
        f"{'sum|dR|':>8} {'>0.1%':>6}"
    )
    for row in rows:
        path = MESHES / row["file"]
        part = load_mesh(path.read_bytes(), path.suffix, MANIFEST_UNITS[row["units_guess"]])
        views = generate(part, PAPER, GeneratorSettings(count=args.candidates, seed=0)).views
        hits, bad, _, worst = compare_views(part, PAPER, views)
        r = [
            trace_counts(part, PAPER, views, backend=make_backend(part, n)).counts.toarray()
            for n in ("raster", "embree")
        ]
        diff = np.abs(r[0].astype(np.int64) - r[1])
        big = np.maximum(r[0], r[1]) > 100
        over = int((diff[big] > 1e-3 * r[1][big]).sum())
        print(
            f"{row['file'][:34]:<34} {part.n_faces:>7} {hits:>10} {bad:>7} {bad / hits:>9.2e} "
            f"{worst:>8.1e} {int(diff.sum()):>8} {over:>6}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
