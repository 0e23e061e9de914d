"""Per-pixel agreement of the `raster` or `packets` backend with Embree rays on every shared
mesh (the figures of tests/test_raster.py and tests/test_packets.py).

    python bench/agreement.py [--candidates 20] [--backend raster|packets] [--embree 3|4]

For each mesh of ../shared/meshes (units from its MANIFEST.csv), `--candidates` generated
viewpoints of the paper's camera; per view the backend's first face per pixel against
Embree's on the rays `trace_counts` casts (tests/test_raster.py does the same and asserts):
hit pixels, disagreeing pixels (as a fraction), the largest distance of a disagreement from
a triangle edge that is not a depth tie (pixels), then R from both backends: the sum of
|difference| and how many entries of more than 100 rays differ by more than 0.1 %.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.conftest import MANIFEST_UNITS, MESHES, manifest_rows  # noqa: E402
from tests.test_packets import first_ids  # noqa: E402
from tests.test_raster import PAPER, IdsOf, compare_views, raster_ids  # noqa: E402
from vpp_core.camera.pose import Viewpoints  # noqa: E402
from vpp_core.candidates.generator import GeneratorSettings, generate  # noqa: E402
from vpp_core.mesh.part import Part, load_mesh  # noqa: E402
from vpp_core.trace.packets import PacketBackend  # noqa: E402
from vpp_core.trace.raster import RasterBackend  # noqa: E402
from vpp_core.trace.rays import Block  # noqa: E402
from vpp_core.trace.raytrace import make_backend, trace_counts  # noqa: E402


def ids_of(backend: str, embree: int | None, part: Part, views: Viewpoints) -> IdsOf:
    """The backend's first face per pixel of view j's window."""
    if backend == "raster":
        return lambda j, window: raster_ids(part, PAPER, views, j, window)
    packets = PacketBackend(part, embree)

    def ids(j: int, window: tuple[int, int, int, int]) -> np.ndarray:
        block = Block(PAPER, views.positions[j], views.rotations()[j], window[:2], window[2:])
        return first_ids(packets, block)

    return ids


def main() -> int:
    """Print one row per shared mesh."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--candidates", type=int, default=20)
    ap.add_argument("--backend", choices=("raster", "packets"), default="raster")
    ap.add_argument("--embree", type=int, choices=(3, 4), help="packets: Embree version")
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
        ids = ids_of(args.backend, args.embree, part, views)
        hits, bad, _, worst = compare_views(part, PAPER, views, ids)
        backends = [
            PacketBackend(part, args.embree)
            if args.backend == "packets"
            else RasterBackend(part, max_faces_per_pixel=math.inf),
            make_backend(part, "embree"),
        ]
        r = [trace_counts(part, PAPER, views, backend=b).counts.toarray() for b in backends]
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
