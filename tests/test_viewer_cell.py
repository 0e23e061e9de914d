"""The viewer shows the cell (issue 35, issue 38 item 3): the setup's floor, fixtures and
keep-out volumes where the setup puts them, and the tour's cycle time.

Where they should be is computed here from the setup's own transforms (the test's floor plane,
block and box mapped into the part frame with numpy), not from the service's geometry.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.test_service_jobs import submit, upload_sample, wait
from tests.test_setup import SMALL, apply, fixture_setup, rigid, stl
from tests.test_viewer import Page, browser, live  # noqa: F401  (fixtures)
from vpp_core.report.scene import unpack
from worker import artifacts as art

pytestmark = pytest.mark.slow
KEEP_OUT = {"min": [60.0, -20.0, 0.0], "max": [80.0, 20.0, 40.0]}
"""A keep-out box beside the plate (cell frame, mm)."""
OBJECTIVE = {"name": "views", "dwell_s": 0.5, "speed_mm_s": 200.0}


def cell_plan(client: Any) -> tuple[str, dict[str, Any], dict[str, Any], np.ndarray, np.ndarray]:
    """(plan id, document, setup, plate vertices, block vertices in the part frame): the plate
    on the floor under a block fixture, turned 30° about z in the cell, with a keep-out box."""
    plate, block, setup, block_to_cell = fixture_setup()
    part_to_cell = rigid((0, 0, 30), [5, -3, 2])
    block_to_cell = part_to_cell @ np.linalg.inv(np.asarray(setup["part_to_cell"])) @ block_to_cell
    ids = {}
    for name, mesh in (("plate", plate), ("block", block)):
        r = client.post("/v1/meshes", files={"file": (f"{name}.stl", stl(mesh))})
        assert r.status_code == 201, r.text
        ids[name] = r.json()["id"]
    setup["part_to_cell"] = part_to_cell.tolist()
    setup["fixtures"][0].update(mesh=ids["block"], to_cell=block_to_cell.tolist())
    setup["keep_out"] = [{"box": KEEP_OUT}]
    body = {"mesh_id": ids["plate"], "profile": "paper", "sensor": SMALL.model_dump(),
            "candidates": {"count": 30}, "setup": setup, "objective": OBJECTIVE}  # fmt: skip
    plan = submit(client, body)
    assert wait(client, plan)["status"] == "succeeded"
    doc = client.get(f"/v1/plans/{plan}").json()
    block_in_part = np.linalg.inv(part_to_cell) @ block_to_cell
    return plan, doc, setup, np.asarray(plate.vertices), apply(block_in_part, block.vertices)


def box_of(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return points.min(axis=0), points.max(axis=0)


def test_the_floor_fixture_and_keep_out_box_are_drawn_where_the_setup_puts_them(
    live: Any,  # noqa: F811
    browser: Any,  # noqa: F811
) -> None:
    client, url = live
    plan, doc, setup, plate, block = cell_plan(client)
    page = Page(browser, f"{url}/v1/plans/{plan}/view")
    drawn = page.js("window.vppViewer.setup()")
    assert drawn is not None and drawn["shown"]
    assert page.page.locator("#setup-toggle").is_visible()
    # the fixture: the block's own vertices mapped cell → part by the test
    lo, hi = box_of(block)
    np.testing.assert_allclose(drawn["fixtures"]["min"], lo, atol=1e-3)
    np.testing.assert_allclose(drawn["fixtures"]["max"], hi, atol=1e-3)
    # the keep-out box: its 8 corners (cell frame) in the part frame
    to_part = np.linalg.inv(np.asarray(setup["part_to_cell"]))
    corners = [[KEEP_OUT[m][k] for m, k in zip(c, range(3), strict=True)]
               for c in np.array(np.meshgrid(*[["min", "max"]] * 3)).T.reshape(-1, 3)]  # fmt: skip
    lo, hi = box_of(apply(to_part, corners))
    np.testing.assert_allclose(drawn["keep_out"]["min"], lo, atol=1e-3)
    np.testing.assert_allclose(drawn["keep_out"]["max"], hi, atol=1e-3)
    # the floor: the plane z = 0 of the cell is z = -2 of the part (the plate's bottom), flat,
    # under the part, the block and every camera
    floor = drawn["floor"]
    assert floor["visible"]
    np.testing.assert_allclose([floor["min"][2], floor["max"][2]], [-2.0, -2.0], atol=1e-3)
    assert plate[:, 2].min() == pytest.approx(-2.0, abs=1e-4)
    cams = np.array([v["position"] for v in doc["viewpoints"]])
    for points in (plate, block, cams):
        assert (points[:, :2] >= np.array(floor["min"][:2]) - 1e-3).all()
        assert (points[:, :2] <= np.array(floor["max"][:2]) + 1e-3).all()
    # compact: float32 triangles in the scene file
    _, arrays = unpack(client.get(f"/v1/plans/{plan}/scene").content)
    assert arrays["setup_floor"].shape == (2, 3, 3) and arrays["setup_fixtures"].dtype == np.float32
    assert arrays["setup_keep_out"].shape == (12, 3, 3)
    # a scene not stored (an older plan's) is rebuilt from R by the API, the setup with it
    stored = Path(os.environ["VPP_STORE_URL"]) / art.scene_key(plan)
    stored.unlink()
    _, rebuilt = unpack(client.get(f"/v1/plans/{plan}/scene").content)
    assert stored.is_file()
    for name in ("setup_floor", "setup_fixtures", "setup_keep_out"):
        np.testing.assert_array_equal(rebuilt[name], arrays[name])
    # the toggle hides it
    page.page.locator("#show-setup").uncheck()
    assert not page.js("window.vppViewer.setup()")["shown"]
    # the cycle time: dwell at each view plus travel at the objective's speed
    tour, k = doc["tour"], len(doc["viewpoints"])
    assert tour["dwell_s"] == pytest.approx(OBJECTIVE["dwell_s"] * k)
    assert tour["travel_s"] == pytest.approx(tour["length_mm"] / OBJECTIVE["speed_mm_s"])
    text = page.js("window.vppViewer.summary")["cycle time"]
    assert text == (
        f"{tour['cycle_time_s']:.2f}\u00a0s = {tour['travel_s']:.2f}\u00a0s travel"
        f" + {tour['dwell_s']:.2f}\u00a0s dwell"
    )
    assert "cycle time" in page.page.locator("#metrics").inner_text()
    assert page.errors == []


def test_no_setup_draws_none_and_a_robot_tour_shows_its_joint_cycle(
    live: Any,  # noqa: F811
    browser: Any,  # noqa: F811
) -> None:
    """The bushing without a setup: no floor, fixture or toggle. The joint-space tour of a
    robot plan (doc.robot.tour, injected into the document the page reads) is shown."""
    client, url = live
    mesh = upload_sample(client)
    body = {"mesh_id": mesh, "sensor": SMALL.model_dump(), "profile": "paper",
            "candidates": {"count": 20}, "target": {"resolution_mm": 1.0}}  # fmt: skip
    plan = submit(client, body)
    assert wait(client, plan)["status"] == "succeeded"
    _, arrays = unpack(client.get(f"/v1/plans/{plan}/scene").content)
    assert not [name for name in arrays if name.startswith("setup_")]
    robot_tour = {"cycle_time_s": 12.345, "travel_s": 9.345, "dwell_s": 3.0}

    def before(page: Any) -> None:
        def with_robot(route: Any) -> None:
            doc = json.loads(route.fetch().text())
            doc["robot"] = {"tour": robot_tour}
            route.fulfill(json=doc)

        page.route(f"**/v1/plans/{plan}", with_robot)

    page = Page(browser, f"{url}/v1/plans/{plan}/view", before=before)
    assert page.js("window.vppViewer.setup()") is None
    assert not page.page.locator("#setup-toggle").is_visible()
    summary = page.js("window.vppViewer.summary")
    assert summary["joint cycle"] == "12.35\u00a0s = 9.35\u00a0s travel + 3.00\u00a0s dwell"
    doc = client.get(f"/v1/plans/{plan}").json()
    assert summary["cycle time"].startswith(f"{doc['tour']['cycle_time_s']:.2f}\u00a0s = ")
    assert page.errors == []


def test_box_triangles_close_the_box() -> None:
    """The keep-out box's 12 triangles: a closed surface of the box's volume, facing out."""
    import trimesh

    from vpp_core.report.scene import box_triangles

    tri = box_triangles(np.array([[1.0, 2.0, 3.0], [4.0, 6.0, 8.0]]))
    mesh = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(36).reshape(-1, 3), process=True)
    assert mesh.is_watertight and mesh.volume == pytest.approx(3 * 4 * 5)
