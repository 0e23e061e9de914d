"""How fast the plan viewer opens and draws a real plan, in headless Chromium.

    python bench/viewer.py [MESH] [--units mm] [--candidates 500] [--resolution 0.18]
                           [--formulation density|visibility] [--fit-part] [--tilt 0]
                           [--bundles OLD.js NEW.js]
                           [--repeat 3] [--screenshot shot.png] [--redis-url URL]

Plans MESH (default: the sample bushing) through the API (uvicorn on loopback, one RQ worker,
paper sensor), then per repetition opens /v1/plans/{id}/view in a fresh browser context (no
cache) and measures:

- `open_s`: navigation to `vppViewer.ready` (plan document, geometry and scene fetched,
  parsed and drawn); `page_load_s` the same from the page's own clock;
- the bytes of the bundle and the two binary resources, whole and as sent (gzipped);
- `part_share`: the part's projected box over the canvas (the larger of width and height
  shares) as the page opens; `labels_shown`: camera numbers on screen, none over another;
- `select_ms`: one camera selected (the part recoloured) and drawn;
- `frame_ms`: mean over a full orbit of 60 drawn frames as the page opens (the part framed);
  `frame_ms_no_labels` with the number labels hidden; `frame_ms_fit_all` after *fit all* (the
  part small among its cameras: fewer pixels to fill). Chromium runs WebGL on SwiftShader
  (the CPU) here: a GPU draws faster.

One JSON line per repetition on stdout; with --bundles, the repetitions of each bundle in turn
on the same plan (an A/B of two builds: `VPP_VIEWER_OUT=/tmp/old.js npm run build` in an old
checkout of viewer/). --screenshot saves the page with the camera looking
most nearly the eye's way selected (--fit-part: the part framed, not the whole scene).

Redis: redis://127.0.0.1:6379/11 (db 11 flushed before and after) or --redis-url.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

FLAGS = ["--no-sandbox", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--disable-quic"]  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?")
    ap.add_argument("--units", default="mm")
    ap.add_argument("--candidates", type=int, default=500)
    ap.add_argument("--tilt", type=float, default=0.0)
    ap.add_argument("--resolution", type=float, default=0.18)
    ap.add_argument("--formulation", choices=["density", "visibility"], default="density")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--screenshot")
    ap.add_argument("--fit-part", action="store_true", help="screenshot framing the part only")
    ap.add_argument("--redis-url", default="redis://127.0.0.1:6379/11")
    ap.add_argument("--bundles", nargs="+", type=Path, metavar="JS",
                    help="viewer bundles to compare on the same plan, in turn (A/B)")  # fmt: skip
    args = ap.parse_args()
    with served_plan(args) as (url, plan, doc):
        for bundle in args.bundles or [None]:
            if bundle is not None:
                serve_bundle(bundle)
                print(f"# bundle {bundle}", flush=True)
            run(args, url, plan, doc)


def serve_bundle(path: Path) -> None:
    """Serve `path` as /static/viewer/viewer.js from now on (an older build, say)."""
    import gzip

    from service.routers import viewer

    data = path.read_bytes()
    answer = (data, gzip.compress(data, 9, mtime=0), f'"{path.stat().st_mtime_ns}"')
    viewer._bundle = lambda name: answer  # type: ignore[assignment]


@contextmanager
def served_plan(args: argparse.Namespace) -> Iterator[tuple[str, str, dict[str, Any]]]:
    """(base URL, plan id, plan document) of args.mesh planned by the API on loopback with one
    worker, a temporary store and args.redis_url (flushed before and after); args: mesh, units,
    candidates, tilt, resolution (mm), formulation."""
    with tempfile.TemporaryDirectory() as store:
        os.environ.update(VPP_REDIS_URL=args.redis_url, VPP_STORE_URL=store, VPP_QUEUE="vpp-bench")
        from redis import Redis  # noqa: TID251

        Redis.from_url(args.redis_url).flushdb()
        try:
            with _serving() as url:
                yield url, *_plan(url, args)
        finally:
            Redis.from_url(args.redis_url).flushdb()


@contextmanager
def _serving() -> Iterator[str]:
    """The API served by uvicorn on a free loopback port, with one RQ worker: its base URL."""
    import uvicorn

    from service.app import create_app
    from worker.pool import start_workers, stop_workers
    from worker.settings import Settings

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(create_app(Settings()), port=port, log_level="error"))
    threading.Thread(target=server.run, daemon=True).start()
    while not server.started:
        time.sleep(0.05)
    procs = start_workers(os.environ["VPP_REDIS_URL"], 1, prefix="bench", log=sys.stderr.buffer)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        stop_workers(procs, wait_s=5)
        server.should_exit = True


def _plan(url: str, args: argparse.Namespace) -> tuple[str, dict[str, Any]]:
    """Upload args.mesh, plan it and wait: (plan id, plan document with "plan_s" added)."""
    import httpx

    from vpp_core.samples import sample_stl

    client = httpx.Client(base_url=url, timeout=120)
    name = Path(args.mesh).name if args.mesh else "bushing.stl"
    data = Path(args.mesh).read_bytes() if args.mesh else sample_stl()
    r = client.post("/v1/meshes", files={"file": (name, data)}, data={"units": args.units})
    r.raise_for_status()
    target = {"resolution_mm": args.resolution, "formulation": args.formulation}
    candidates = {"count": args.candidates, "tilt_deg": args.tilt}
    body = {"mesh_id": r.json()["id"], "candidates": candidates, "target": target}
    plan = client.post("/v1/plans", json=body).json()["id"]
    t0 = time.perf_counter()
    while (job := client.get(f"/v1/jobs/{plan}").json())["status"] in ("queued", "running"):
        time.sleep(0.5)
    if job["status"] != "succeeded":
        raise SystemExit(f"the plan's job {job['status']}: {job.get('error')}")
    doc = client.get(f"/v1/plans/{plan}").json()
    return plan, {**doc, "plan_s": time.perf_counter() - t0, "file_name": name}


def run(args: argparse.Namespace, url: str, plan: str, doc: dict[str, Any]) -> None:
    """Measure the bytes on the wire, then each repetition in a fresh browser context."""
    import httpx
    from playwright.sync_api import sync_playwright

    client = httpx.Client(base_url=url, timeout=120)
    gz = {"Accept-Encoding": "gzip"}
    sizes = {}
    for what, path in (
        ("geometry", f"/v1/meshes/{doc['mesh']['id']}/geometry"),
        ("scene", f"/v1/plans/{plan}/scene"),
        ("bundle", "/static/viewer/viewer.js"),
    ):
        r = client.get(path, headers=gz)
        sizes[f"{what}_bytes"] = len(r.content)
        sizes[f"{what}_wire_bytes"] = r.num_bytes_downloaded
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=FLAGS)
        for rep in range(args.repeat):
            measure(browser, url, plan, doc, sizes, doc["plan_s"], doc["file_name"], rep, args)
        browser.close()


def measure(browser, url, plan, doc, sizes, plan_s, name, rep, args) -> None:  # type: ignore[no-untyped-def]
    context = browser.new_context(viewport={"width": 1400, "height": 820})
    page = context.new_page()
    errors: list[str] = []
    page.on("console", lambda m: errors.extend([m.text] if m.type == "error" else []))
    t0 = time.perf_counter()
    page.goto(f"{url}/v1/plans/{plan}/view")
    page.wait_for_function("window.vppViewer && window.vppViewer.ready", timeout=300_000)
    open_s = time.perf_counter() - t0
    framing = page.evaluate(
        "(() => { if (!window.vppViewer.partBox) return {share: NaN, labels: null};"
        " const b = window.vppViewer.partBox();"
        " const c = document.getElementById('canvas');"
        " return {share: Math.max((b[2] - b[0]) / c.clientWidth,"
        " (b[3] - b[1]) / c.clientHeight),"
        " labels: Object.keys(window.vppViewer.labelBoxes()).length}; })()"
    )
    select_ms = page.evaluate(
        "async () => { const t = performance.now(); window.vppViewer.select(0);"
        " await window.vppViewer.drawn(); return performance.now() - t; }"
    )
    frame_ms = page.evaluate("window.vppViewer.orbit(60)")
    page.evaluate("window.vppViewer.show('labels', false)")
    bare_ms = page.evaluate("window.vppViewer.orbit(60)")
    page.evaluate("window.vppViewer.show('labels', true)")
    page.evaluate("window.vppViewer.fit(true)")  # the part small among its cameras
    fit_all_ms = page.evaluate("window.vppViewer.orbit(60)")
    if args.screenshot and rep == 0:  # the camera looking most nearly the eye's way, selected
        page.evaluate("window.vppViewer.orbit(8)")
        if args.fit_part:
            page.evaluate("window.vppViewer.fit(false)")
        page.evaluate("window.vppViewer.select(window.vppViewer.facing())")
        page.evaluate("window.vppViewer.drawn()")
        page.screenshot(path=args.screenshot)
    line = {
        "mesh": name,
        "faces": doc["mesh"]["faces"],
        "viewpoints": len(doc["viewpoints"]),
        "plan_s": round(plan_s, 2),
        **sizes,
        "open_s": round(open_s, 3),
        "part_share": round(framing["share"], 3),
        "labels_shown": framing["labels"],
        "page_load_s": page.evaluate("window.vppViewer.loadSeconds"),
        "select_ms": round(select_ms, 1),
        "frame_ms": round(frame_ms, 1),
        "frame_ms_no_labels": round(bare_ms, 1),
        "frame_ms_fit_all": round(fit_all_ms, 1),
        "console_errors": errors,
    }
    print(json.dumps(line), flush=True)
    context.close()


if __name__ == "__main__":
    main()
