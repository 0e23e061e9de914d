"""The plan viewer end to end: the API on loopback, real workers, a real headless Chromium.

The page is checked against independent computations, not against a golden image: what it
draws through a plan camera is compared pixel by pixel with a trimesh/Embree ray cast of the
same pinhole (SPEC §8 convention) and the face colours the page says it shows.
"""

from __future__ import annotations

import io
import itertools
import os
import shutil
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from tests.conftest import serving
from tests.test_service_jobs import submit, upload_sample, wait
from vpp_core.mesh.part import load_mesh
from vpp_core.report.scene import unpack
from vpp_core.samples import sample_stl

pytestmark = pytest.mark.slow
SENSOR = {"width_px": 480, "height_px": 300}
VIEWPORT = {"width": 1200, "height": 700}
BACKGROUND = (243, 244, 246)
"""The canvas clear colour (#f3f4f6)."""
CHROMIUM_FLAGS = [
    "--no-sandbox",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-quic",
]


def chromium_path() -> str | None:
    """VPP_CHROMIUM, else a chromium on PATH."""
    return (
        os.environ.get("VPP_CHROMIUM")
        or shutil.which("chromium")
        or shutil.which("chromium-browser")
    )


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """Headless Chromium driven by Playwright (skips with a message where either is missing)."""
    missing = pytest.fail if os.environ.get("VPP_REQUIRE_BROWSER") else pytest.skip
    try:
        from playwright import sync_api
    except ImportError:
        missing("no playwright: pip install -e '.[test]'")
    path = chromium_path()
    if not path:
        missing("no chromium: apt-get install chromium, or set VPP_CHROMIUM")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=path, args=CHROMIUM_FLAGS)
        yield b
        b.close()


@pytest.fixture
def live(api, start_workers) -> Iterator[tuple[Any, str]]:
    """(TestClient, base URL): the same app served by uvicorn on loopback, one worker."""
    with serving(api.app) as url:
        start_workers(1)
        yield api, url


class Page:
    """A viewer page with its console errors collected."""

    def __init__(self, browser: Any, url: str, wait_ready: bool = True, before: Any = None) -> None:
        self.page = browser.new_page(viewport=VIEWPORT, device_scale_factor=1)
        self.errors: list[str] = []
        self.page.on("console", lambda m: self.errors.extend([m.text] if m.type == "error" else []))
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        if before:
            before(self.page)  # routes and listeners that must see the first request
        self.page.goto(url)
        if wait_ready:
            self.ready()

    def ready(self) -> None:
        self.page.wait_for_function(
            "window.vppViewer && (window.vppViewer.ready || window.vppViewer.failed)",
            timeout=60_000,
        )
        assert self.js("window.vppViewer.failed") is None

    def js(self, expr: str, arg: Any = None) -> Any:
        return self.page.evaluate(expr, arg)

    def drawn(self) -> None:
        """Wait until a frame is drawn after now."""
        self.js("window.vppViewer.drawn()")

    def canvas_rgb(self) -> np.ndarray:
        from PIL import Image

        png = self.page.locator("#canvas").screenshot()
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def planned(client: Any, formulation: str = "density") -> tuple[str, str, dict[str, Any]]:
    """(mesh id, plan id, plan document) of the sample part, computed by the worker."""
    mesh = upload_sample(client)
    body = {"mesh_id": mesh, "sensor": SENSOR, "profile": "paper", "candidates": {"count": 40},
            "target": {"resolution_mm": 1.0, "formulation": formulation}}  # fmt: skip
    plan = submit(client, body)
    assert wait(client, plan)["status"] == "succeeded"
    return mesh, plan, client.get(f"/v1/plans/{plan}").json()


def test_the_page_draws_the_plan_and_a_clicked_camera_shows_its_pose(live, browser) -> None:
    client, url = live
    mesh, plan, doc = planned(client)
    page = Page(browser, f"{url}/v1/plans/{plan}/view")
    k_views = len(doc["viewpoints"])
    assert k_views >= 2
    assert page.js("window.vppViewer.cameraCount()") == k_views
    assert page.page.locator(".cam-label").count() == k_views
    assert page.js("window.vppViewer.frustumSegments()") == 8 * k_views  # a pyramid each
    summary = page.js("window.vppViewer.summary")
    assert summary["viewpoints"] == f"{k_views} of {len(doc['candidates'])} candidates"
    assert doc["solver"]["status"] in summary["solver"]
    assert ("note" in summary) == bool((doc["diagnostics"] or {}).get("hint"))
    # the legend counts are the scene file's states
    _, arrays = unpack(client.get(f"/v1/plans/{plan}/scene").content)
    counts = np.bincount(arrays["state"], minlength=5).tolist()
    assert page.js("window.vppViewer.stateCounts") == counts
    assert page.page.locator("#legend").inner_text().count("\u00a0faces") >= 4  # no line break
    # faces of the fixed states wear their legend swatch; met and unmet faces none of them
    colours = np.array(page.js("window.vppViewer.faceColours()")).reshape(-1, 3)
    swatches = page.js(
        "[...document.querySelectorAll('#legend .state .swatch')]"
        ".map(e => getComputedStyle(e).backgroundColor.match(/\\d+/g).map(Number))"
    )
    assert len(swatches) == 3
    for state, rgb in zip((2, 3, 4), swatches, strict=True):
        assert (colours[arrays["state"] == state] == rgb).all()
        graded = np.isin(arrays["state"], [0, 1])
        assert not (colours[graded] == rgb).all(axis=1).any()

    # click a camera's pin in the canvas (labels hidden, so the 3D pick answers)
    page.js("window.vppViewer.show('labels', false); window.vppViewer.fit(true)")
    page.drawn()
    box = page.page.locator("#canvas").bounding_box()
    pins = [page.js("k => window.vppViewer.screenPosition(k)", k) for k in range(k_views)]
    k = _most_isolated(pins, box)
    page.page.mouse.click(box["x"] + pins[k][0], box["y"] + pins[k][1])
    assert page.js("window.vppViewer.selected()") == k
    v = doc["viewpoints"][k]
    shown = page.page.locator("#cam-position").inner_text()
    np.testing.assert_allclose(_numbers(shown), v["position"], atol=6e-4)
    np.testing.assert_allclose(
        _numbers(page.page.locator("#cam-gaze").inner_text()), v["gaze"], atol=6e-4
    )
    n_seen = int(arrays["view_offsets"][k + 1] - arrays["view_offsets"][k])
    assert page.page.locator("#cam-faces").inner_text().startswith(f"{n_seen}\u00a0faces")
    matrix = np.array(_numbers(page.page.locator("#cam-matrix").inner_text())).reshape(4, 4)
    np.testing.assert_allclose(matrix, v["camera_to_world"], atol=6e-5)

    # a number label is a camera too; the step buttons walk the visiting order
    page.js("window.vppViewer.show('labels', true)")
    other = (k + 1) % k_views
    page.page.locator(f".cam-label[data-k='{other}']").click()
    assert page.js("window.vppViewer.selected()") == other
    page.page.locator("#next").click()
    assert page.js("window.vppViewer.selected()") == (other + 1) % k_views
    assert page.errors == []
    _partial_rows(browser, f"{url}/v1/plans/{plan}", doc)


def _partial_rows(browser: Any, plan_url: str, doc: dict[str, Any]) -> None:
    """A default plan's partial cover and its judge at points are stated in the summary, with a
    tip: the plan document served to the page is this paper plan's with a `partial` section
    (the document's own shape, vpp_core.plan.document.PartialInfo) put in."""
    partial = {
        "min_coverage": 0.99,
        "coverable_area_mm2": 1000.0,
        "covered_area_mm2": 995.0,
        "covered_fraction": 0.995,
        "left_out": {"faces": 1, "area_mm2": 5.0, "ids": [0]},
        "points": {
            "points": 20_000,
            "seen_fraction": 0.9987,
            "reach_fraction": 0.9991,
            "added": [doc["viewpoints"][-1]["id"]],
        },
    }

    hint = "the part (1e+05 mm) has 795 times the area <b>its</b> candidates frame & so on"
    evil = '<img src=x onerror="window.pwned = 1">'
    region = {"name": evil, "ignored": False, "faces": 1, "area_mm2": 5.0}
    region |= {"resolution_mm": 0.1, "met_area": 1.0, "max_met_area": 1.0}

    def served(route: Any) -> None:
        response = route.fetch()
        served = response.json()
        served["partial"] = partial
        served["diagnostics"] = {**(served["diagnostics"] or {}), "hint": hint}
        served["metrics"]["regions"] = [region]
        route.fulfill(response=response, json=served)

    page = Page(browser, f"{plan_url}/view", before=lambda p: p.route(f"**{plan_url}", served))
    rows = page.js("Object.entries(window.vppViewer.summary)")
    names = [k for k, _ in rows]
    assert names.index("seen at points") == names.index("partial cover") + 1
    summary = dict(rows)
    assert summary["partial cover"] == "99.5\u00a0% of coverable area (asked 99.0\u00a0%)"
    assert summary["seen at points"] == (
        "99.9\u00a0% of 20,000\u00a0points (candidates 99.9\u00a0%); 1 view added for them"
    )
    tip = page.page.locator("#metrics th", has_text="seen at points").get_attribute("title")
    assert tip is not None and "spread evenly by area" in tip
    # the diagnostics' hint is the last row, numbers kept with their units; names and notes
    # from requests and uploads are shown as text, never run as markup
    assert names[-1] == "note"
    note = page.page.locator("#metrics td").last.inner_text()
    assert note == hint.replace("05 mm", "05\u00a0mm")
    assert page.page.locator("#metrics th", has_text="region ").inner_text() == f"region {evil}"
    assert page.page.locator("#metrics img, #metrics b").count() == 0
    assert page.js("window.pwned") is None
    assert page.errors == []


def test_looking_through_a_camera_shows_what_a_ray_cast_sees(live, browser) -> None:
    """Pixel by pixel: hit or not, and the colour of the face an independent ray cast finds."""
    client, url = live
    _, plan, doc = planned(client)
    page = Page(browser, f"{url}/v1/plans/{plan}/view")
    _, arrays = unpack(client.get(f"/v1/plans/{plan}/scene").content)
    part = load_mesh(sample_stl(), "stl")
    for k in range(min(2, len(doc["viewpoints"]))):
        look = page.js("k => window.vppViewer.look(k)", k)
        page.js("window.vppViewer.show('frusta', false); window.vppViewer.show('tour', false)")
        page.js("window.vppViewer.show('labels', false); window.vppViewer.setShading(false)")
        page.js("for (const id of ['frame', 'through']) document.getElementById(id).hidden = true")
        page.drawn()
        image = page.canvas_rgb()
        h, w, _ = image.shape
        assert (w, h) == (look["width"], look["height"])
        faces = _ray_cast(part, doc["viewpoints"][k], look["f"], w, h)
        drawn = (image != BACKGROUND).any(axis=2)
        hit = faces >= 0
        iou = (drawn & hit).sum() / (drawn | hit).sum()
        assert hit.sum() > 2000 and iou > 0.98, (k, iou)
        # the colours shown: the face's own where camera k sees it, faded elsewhere
        base = np.array(page.js("window.vppViewer.faceColours()")).reshape(-1, 3)
        shown = np.array(page.js("window.vppViewer.shownColours()")).reshape(-1, 3)
        mine = np.zeros(len(base), bool)
        mine[arrays["view_faces"][arrays["view_offsets"][k] : arrays["view_offsets"][k + 1]]] = 1
        assert (shown[mine] == base[mine]).all() and (shown[~mine] != base[~mine]).any(axis=1).all()
        # each pixel has the colour of the face the ray cast finds through it; where an edge
        # crosses the pixel, a blend of the colours found around it (antialiasing), but for a
        # few where the rasteriser leaves a crack between two faces that a ray cast never sees
        padded = np.pad(faces, 1, mode="edge")
        shifts = itertools.product(range(3), range(3))
        around = np.stack([padded[dy : dy + h, dx : dx + w] for dy, dx in shifts])  # (9, h, w)
        colours = np.where((around >= 0)[..., None], shown[around], BACKGROUND)
        lo, hi = colours.min(axis=0) - 2, colours.max(axis=0) + 2
        both = drawn & hit
        close = ((image >= lo) & (image <= hi)).all(axis=2)
        inner = both & (around == faces).all(axis=0)
        assert inner.sum() > 200 and close[inner].all(), (k, inner.sum(), close[inner].mean())
        assert close[both].mean() > 0.99, (k, close[both].mean())
    assert page.errors == []


def test_the_formulation_toggle_computes_and_shows_the_other_plan(live, browser) -> None:
    client, url = live
    _, plan, doc = planned(client, "density")
    page = Page(browser, f"{url}/v1/plans/{plan}/view")
    related = {r["formulation"]: r for r in page.js("window.vppViewer.related")}
    assert related["density"]["id"] == plan and not related["visibility"]["available"]
    page.js("window.vppViewer.look(0)")
    page.page.locator("#formulations button[data-formulation=visibility]").click()
    page.page.wait_for_function(f"window.vppViewer.plan === '{related['visibility']['id']}'")
    # while it computes: nothing of the old plan is shown as the new one's
    left = page.js(
        "({doc: window.vppViewer.doc?.target.formulation ?? null,"
        " active: document.querySelector('#formulations button.active').dataset.formulation,"
        " frame: !document.getElementById('frame').hidden,"
        " selected: window.vppViewer.selected()})"
    )
    assert left["doc"] in (None, "visibility") and left["active"] == "visibility", left
    assert not left["frame"] and left["selected"] is None, left
    # ... nor its cameras, colours or slider: the part alone, grey, the toggle saying it computes
    pending = page.page.wait_for_function(
        "(() => { const v = window.vppViewer;"
        " if (v.ready || document.getElementById('metrics').innerHTML !== '') return null;"
        " return {cameras: v.cameraCount(), drawn: v.frustumSegments(),"
        " colours: new Set(v.shownColours()).size, labels: Object.keys(v.labelBoxes()).length,"
        " step: document.getElementById('step-label').textContent,"
        " slider: document.getElementById('step').disabled,"
        " button: document.querySelector('#formulations button.active').textContent}; })()",
        timeout=30_000,
    ).json_value()
    assert pending == {"cameras": 0, "drawn": 0, "colours": 1, "labels": 0, "step": "– / 0",
                       "slider": True, "button": "visibility (computing…)"}, pending  # fmt: skip
    page.page.locator("#next").click()  # nothing to step through: nothing happens, no error
    assert page.js("window.vppViewer.selected()") is None
    page.ready()
    other = client.get(f"/v1/plans/{related['visibility']['id']}").json()
    assert other["target"]["formulation"] == "visibility"
    assert page.js("window.vppViewer.cameraCount()") == len(other["viewpoints"])
    assert page.page.url.endswith(f"/v1/plans/{related['visibility']['id']}/view")
    active = page.page.locator("#formulations button.active").inner_text()
    assert active == "visibility"
    page.page.locator("#formulations button[data-formulation=density]").click()
    page.page.wait_for_function(f"window.vppViewer.plan === '{plan}'")
    page.ready()
    assert page.js("window.vppViewer.cameraCount()") == len(doc["viewpoints"])
    assert page.errors == []


def test_the_page_of_a_running_plan_waits_for_it_and_an_unknown_one_says_so(live, browser) -> None:
    client, url = live
    page = Page(browser, f"{url}/v1/plans/{'0' * 64}/view", wait_ready=False)
    page.page.wait_for_function("window.vppViewer.failed", timeout=10_000)
    assert "no job" in page.js("window.vppViewer.failed") or "not" in page.js(
        "window.vppViewer.failed"
    )
    assert page.page.locator("#status.error").is_visible()


def test_the_page_of_a_queued_plan_is_told_its_progress_and_polls_only_without_the_stream(
    api, start_workers, browser
) -> None:
    """While the plan waits for a worker the page follows its events (GET /v1/jobs/{id}/events)
    and asks for the job once; a page whose event stream fails polls every second instead and
    still shows the plan."""
    client = api
    with serving(api.app) as url:
        mesh = upload_sample(client)
        body = {"mesh_id": mesh, "sensor": SENSOR, "candidates": {"count": 40},
                "target": {"resolution_mm": 1.0}, "profile": "paper"}  # fmt: skip
        plan = submit(client, body)  # no worker yet: queued
        gets: dict[str, list[str]] = {"pushed": [], "polled": []}

        def counting(name: str, block: bool) -> Any:
            def before(page: Any) -> None:
                job = f"/v1/jobs/{plan}"
                page.on(
                    "request", lambda r: gets[name].extend([r.url] if r.url.endswith(job) else [])
                )
                if block:
                    page.route(f"**{job}/events", lambda route: route.abort())

            return before

        view = f"{url}/v1/plans/{plan}/view"
        pushed = Page(browser, view, wait_ready=False, before=counting("pushed", False))
        polled = Page(browser, view, wait_ready=False, before=counting("polled", True))
        time.sleep(3.5)  # queued meanwhile
        assert "queued" in pushed.page.locator("#status").inner_text()
        start_workers(1)
        pushed.ready()
        polled.ready()
        assert len(gets["pushed"]) == pushed.js("window.vppViewer.polls") == 1, gets
        assert pushed.js("window.vppViewer.pushed") >= 2  # queued ... done
        assert pushed.js("window.vppViewer.polling") is False
        assert polled.js("window.vppViewer.polling") is True
        assert len(gets["polled"]) >= 4, gets  # 3.5 s queued at one poll a second, and more
        assert pushed.js("window.vppViewer.cameraCount()") > 0
        assert polled.js("window.vppViewer.cameraCount()") == pushed.js(
            "window.vppViewer.cameraCount()"
        )
        assert pushed.errors == []


def test_with_api_keys_the_page_asks_for_one_and_sends_it(
    svc_env, monkeypatch, start_workers, browser
) -> None:
    from fastapi.testclient import TestClient

    from service.app import create_app
    from worker.settings import Settings

    key = "viewer-test-key-0123456789"
    monkeypatch.setenv("VPP_API_KEYS", key)
    with TestClient(create_app(Settings())) as client, serving(client.app) as url:
        client.headers["Authorization"] = f"Bearer {key}"
        start_workers(1)
        _, plan, doc = planned(client)
        page = browser.new_page(viewport=VIEWPORT)
        page.goto(f"{url}/v1/plans/{plan}/view")  # the shell needs no key; its data does
        page.wait_for_function("window.vppViewer.failed", timeout=10_000)
        assert page.locator("#key-form").is_visible()
        page.fill("#key", "not-the-key")
        page.click("#key-form button")
        page.wait_for_function("window.vppViewer.failed", timeout=10_000)
        assert page.locator("#key-form").is_visible()  # refused (403): asked again
        page.fill("#key", key)
        page.click("#key-form button")
        page.wait_for_function("window.vppViewer.ready", timeout=30_000)
        assert page.evaluate("window.vppViewer.cameraCount()") == len(doc["viewpoints"])
        assert page.locator("#key-form").is_hidden()


def _ray_cast(part: Any, view: dict[str, Any], f: float, w: int, h: int) -> np.ndarray:
    """(h, w) int: first face hit through each canvas pixel centre, -1 for none (trimesh)."""
    c2w = np.array(view["camera_to_world"])
    u, v = np.meshgrid(np.arange(w) + 0.5 - w / 2, np.arange(h) + 0.5 - h / 2)
    cam = np.stack([u / f, v / f, np.ones_like(u)], axis=-1).reshape(-1, 3)
    dirs = cam @ c2w[:3, :3].T
    origins = np.broadcast_to(c2w[:3, 3], dirs.shape)
    first = part.trimesh().ray.intersects_first(origins, dirs)
    return np.asarray(first).reshape(h, w)


def _numbers(text: str) -> list[float]:
    import re

    return [float(x) for x in re.findall(r"-?\d+\.\d+(?:e-?\d+)?", text)]


def _most_isolated(pins: list[Any], box: dict[str, float]) -> int:
    """The camera whose pin is on the canvas and farthest from every other pin."""
    pts = np.array([p if p else (np.nan, np.nan) for p in pins], float)
    inside = (pts[:, 0] > 5) & (pts[:, 0] < box["width"] - 5)
    inside &= (pts[:, 1] > 5) & (pts[:, 1] < box["height"] - 5)
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    np.fill_diagonal(d, np.inf)
    score = np.where(inside, np.nanmin(d, axis=1), -1)
    return int(np.argmax(score))


def _label_layout(page: Page) -> tuple[dict[str, list[float]], list[float], dict[str, float]]:
    """(shown labels' boxes by camera, the part's projected box, the canvas box) in canvas px."""
    page.drawn()
    boxes = page.js("window.vppViewer.labelBoxes()")
    return boxes, page.js("window.vppViewer.partBox()"), page.page.locator("#canvas").bounding_box()


def _assert_legible(boxes: dict[str, list[float]], canvas: dict[str, float]) -> None:
    """Every label inside the canvas, no two touching."""
    for k, (x, y, w, h) in boxes.items():
        assert x >= 0 and y >= 0 and x + w <= canvas["width"] and y + h <= canvas["height"], k
    for (a, (ax, ay, aw, ah)), (b, (bx, by, bw, bh)) in itertools.combinations(boxes.items(), 2):
        assert ax + aw <= bx or bx + bw <= ax or ay + ah <= by or by + bh <= ay, (a, b)


def test_the_page_opens_legible_and_leaves_nothing_behind(live, browser) -> None:
    """The part fills a good share of the canvas; every camera's number is on screen, on the
    part where it looks, and clear of the others, so after *fit all* and an orbit. Looking
    through a camera shows it alone and says which; *clear* leaves no frame, caption, slider
    place or hidden camera behind. The summary keeps numbers with their units and explains
    its jargon (one plan for the three: browser tests are costly)."""
    client, url = live
    _, plan, doc = planned(client)
    page = Page(browser, f"{url}/v1/plans/{plan}/view")
    boxes, part, canvas = _label_layout(page)
    share = max((part[2] - part[0]) / canvas["width"], (part[3] - part[1]) / canvas["height"])
    assert share > 0.6, share
    assert part[0] >= 0 and part[1] >= 0 and part[2] <= canvas["width"], part
    assert part[3] <= canvas["height"], part
    assert sorted(map(int, boxes)) == list(range(len(doc["viewpoints"])))
    _assert_legible(boxes, canvas)
    page.page.locator("#fit").click()
    boxes, _, _ = _label_layout(page)
    assert len(boxes) == len(doc["viewpoints"])
    _assert_legible(boxes, canvas)
    page.js("window.vppViewer.orbit(7)")
    # while the eye moves the canvas draws half its pixels; all of them once it stops
    pixels = "(c => [c.width, c.clientWidth])(document.getElementById('canvas'))"
    moving = page.js(pixels)
    assert moving[0] == round(moving[1] / 2), moving
    page.page.wait_for_function(f"(([w, c]) => w === c)({pixels})", timeout=5_000)
    _assert_legible(_label_layout(page)[0], canvas)
    _look_then_clear(page, len(doc["viewpoints"]))
    _summary_text(page)
    # a canvas too small for every number: those left out are counted, the rest still legible
    page.page.set_viewport_size({"width": 410, "height": 120})  # canvas 30 × 120 px
    page.js("window.vppViewer.fit(false)")
    boxes, _, canvas = _label_layout(page)
    _assert_legible(boxes, canvas)
    hidden = len(doc["viewpoints"]) - len(boxes)
    assert hidden > 0
    note = page.page.locator("#labels-note").inner_text()
    assert note.startswith(f"{hidden} of {len(doc['viewpoints'])} numbers hidden"), note
    assert page.errors == []


def _look_then_clear(page: Page, n_views: int) -> None:
    """Look through camera 2, then clear the selection: what each leaves on the page."""
    page.page.locator(".cam-label[data-k='1']").click()
    page.page.locator("#look").click()
    page.drawn()
    assert page.page.locator("#frame").is_visible()
    caption = page.page.locator("#through").inner_text()
    assert f"viewpoint 2 of {n_views}" in caption, caption
    assert page.js("window.vppViewer.labelBoxes()") == {}  # no other camera's number
    assert page.js("window.vppViewer.drawnCameras()") == {"frusta": False, "tour": False}
    page.page.locator("#clear").click()
    page.drawn()
    assert page.js("window.vppViewer.selected()") is None
    assert page.page.locator("#frame").is_hidden() and page.page.locator("#through").is_hidden()
    assert page.page.locator("#step").input_value() == "0"
    assert page.page.locator("#look").is_disabled()
    assert page.js("window.vppViewer.drawnCameras()") == {"frusta": True, "tour": True}
    assert len(page.js("window.vppViewer.labelBoxes()")) == n_views


def test_colours_spread_over_the_plans_range_and_problems_only_pales_the_rest(
    live, browser
) -> None:
    """A plan meeting r̄ with room to spare is not one flat colour: the met faces' colours run
    from the finest to the coarsest r*; *problems only* pales exactly the met faces."""
    client, url = live
    mesh = upload_sample(client)
    # the default profile: the paper plan's problem faces all face away from the opening view
    body = {"mesh_id": mesh, "sensor": SENSOR, "candidates": {"count": 40},
            "solver": {"time_limit_s": 10},
            "target": {"resolution_mm": 5.0, "formulation": "visibility"}}  # fmt: skip
    plan = submit(client, body)
    assert wait(client, plan)["status"] == "succeeded"
    page = Page(browser, f"{url}/v1/plans/{plan}/view")
    _, arrays = unpack(client.get(f"/v1/plans/{plan}/scene").content)
    met = arrays["state"] == 0
    assert met.mean() > 0.5
    colours = np.array(page.js("window.vppViewer.faceColours()")).reshape(-1, 3)
    r = arrays["resolution_mm"][met]
    fine, coarse = colours[met][r <= np.quantile(r, 0.05)], colours[met][r >= np.quantile(r, 0.95)]
    assert np.abs(fine.mean(axis=0) - coarse.mean(axis=0)).max() > 60, (fine[:3], coarse[:3])
    assert fine.mean() < coarse.mean()  # dark for the finest, light towards r̄
    page.js("window.vppViewer.problemsOnly(true)")
    shown = np.array(page.js("window.vppViewer.shownColours()")).reshape(-1, 3)
    ghost = shown[met][0]
    assert (shown[met] == ghost).all() and (shown[~met] == colours[~met]).all()
    assert not (colours == ghost).all(axis=1).any()  # a colour of its own
    assert page.page.locator("#legend .when-problems").first.is_visible()
    # each problem face has a dot in its colour (unlit: exact, unlike the shaded faces),
    # however small, seen wherever nothing is in front of it (an independent trimesh ray cast)
    problems = np.flatnonzero(np.isin(arrays["state"], [1, 2, 3]))
    marks = page.js("window.vppViewer.problemMarks()")
    assert len(problems) > 0 and sorted(m["face"] for m in marks) == problems.tolist()
    page.drawn()
    image = page.canvas_rgb()
    h, w, _ = image.shape
    inside = [m for m in marks if 1 <= m["xy"][0] < w - 1 and 1 <= m["xy"][1] < h - 1]
    clear = _unoccluded(load_mesh(sample_stl(), "stl").trimesh(), inside)
    assert clear, "no problem face in sight"
    dotted = [m for m in clear if _dot_at(image, m["xy"], m["rgb"])]
    assert len(dotted) >= 0.9 * len(clear), (len(dotted), len(clear))
    page.js("window.vppViewer.problemsOnly(false)")
    assert page.js("window.vppViewer.problemMarks()") == []
    assert page.errors == []


def _unoccluded(mesh: Any, marks: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The marks that the eye sees: no face of `mesh` between it and the mark."""
    if not marks:
        return []
    eye = np.array(marks[0]["eye"])
    to = np.array([m["world"] for m in marks]) - eye
    dist = np.linalg.norm(to, axis=1)
    locations, index, _ = mesh.ray.intersects_location(
        np.broadcast_to(eye, to.shape), to / dist[:, None], multiple_hits=False
    )
    nearest = np.full(len(marks), np.inf)
    np.minimum.at(nearest, index, np.linalg.norm(locations - eye, axis=1))
    return [m for m, d, n in zip(marks, dist, nearest, strict=True) if n >= d - 1e-3 * d]


def _dot_at(image: np.ndarray, xy: list[float], rgb: list[int]) -> bool:
    """Whether the 3 × 3 pixels around xy hold the colour rgb (± 2 per channel, unlit)."""
    x, y = int(xy[0]), int(xy[1])
    patch = image[max(y - 1, 0) : y + 2, max(x - 1, 0) : x + 2].reshape(-1, 3)
    return bool((np.abs(patch - rgb) <= 2).all(axis=1).any())


def _summary_text(page: Page) -> None:
    """No number parted from its unit, no label over two lines, the jargon explained."""
    import re

    cells = page.page.locator("#metrics td").all_inner_texts()
    assert cells and not any(re.search(r"\d (%|mm)", c) for c in cells), cells
    lines = page.js(
        "[...document.querySelectorAll('#metrics th')].map(e => { const r = document.createRange();"
        " r.selectNodeContents(e); return new Set([...r.getClientRects()].map(q => q.top)).size; })"
    )
    assert lines and set(lines) == {1}, lines  # no label over two lines
    assert page.page.locator("#metrics th", has_text="mean C").get_attribute("title")
    page.js("window.vppViewer.select(0)")
    assert page.page.locator("#cam-faces .tip").get_attribute("title")


def test_the_bundle_and_the_geometry_are_gzipped_on_the_wire(api) -> None:
    """Sent gzipped to a client that takes gzip, whole to one that does not; JSON answers too
    (the plan document the page loads: /openapi.json stands for them here)."""
    client = api
    mesh = upload_sample(client)
    for path in ("/static/viewer/viewer.js", f"/v1/meshes/{mesh}/geometry", "/openapi.json"):
        plain = client.get(path, headers={"Accept-Encoding": "identity"})
        packed = client.get(path, headers={"Accept-Encoding": "gzip"})
        assert plain.status_code == packed.status_code == 200
        assert "content-encoding" not in plain.headers
        assert packed.headers["content-encoding"] == "gzip"
        assert packed.content == plain.content  # decoded by the client
        assert int(packed.headers["content-length"]) < 0.6 * len(plain.content), path
