"""Issue 35 items 3-4: the TSP tour, the cycle time, the cycle_time objective, and the poses
exported for the cell (CSV, JSON, CLI, API), each checked against a direct computation."""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.distance import cdist
from scipy.spatial.transform import Rotation

from cli.main import main
from tests.conftest import plate_part
from vpp_core.camera.pose import make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.plan.cycle import Objective, make_tour
from vpp_core.plan.document import PlanDocument, PlanRequest, Target
from vpp_core.plan.pipeline import plan
from vpp_core.plan.route import route_cost, seed_route, solve_route
from vpp_core.plan.tour import path_length, visiting_order
from vpp_core.report.export import poses_csv, poses_json, quaternion, rotation

SMALL = Sensor(width_px=160, height_px=100, fov_x_deg=38.7, fov_y_deg=24.75)


def open_cost(points: np.ndarray) -> np.ndarray:
    """Distances with a free dummy depot last: the route is an open path."""
    cost = np.zeros((len(points) + 1,) * 2)
    cost[:-1, :-1] = cdist(points, points)
    return cost


def test_tsp_tour_never_longer_than_nearest_neighbour_two_opt() -> None:
    """Open paths: OR-Tools never longer than the old tour, and shorter on some instance."""
    shorter = 0
    for seed in range(4):
        pts = np.random.default_rng(seed).uniform(0, 400, (60, 3))
        order, solver = solve_route(open_cost(pts), seconds=0.4)
        assert solver == "ortools" and sorted(order.tolist()) == list(range(60))
        old = path_length(pts, visiting_order(pts))
        new = path_length(pts, order)
        assert new <= old + 1e-6
        shorter += new < old - 1e-6
    assert shorter >= 1


def test_tsp_tour_from_home_never_longer_than_its_start() -> None:
    """Closed tours from a home: never longer than nearest neighbour + 2-opt from home."""
    for seed in range(3):
        pts = np.random.default_rng(seed).uniform(0, 400, (40, 3))
        cost = np.zeros((41, 41))
        cost[:] = cdist(np.vstack([pts, [[0, 0, 500]]]), np.vstack([pts, [[0, 0, 500]]]))
        order, _ = solve_route(cost, seconds=0.3)
        assert route_cost(cost, order) <= route_cost(cost, seed_route(cost)) + 1e-6


def test_small_tours_are_exact() -> None:
    pts = np.random.default_rng(5).uniform(0, 100, (6, 3))
    order, solver = solve_route(open_cost(pts))
    best = min(path_length(pts, np.array(p)) for p in itertools.permutations(range(6)))
    assert solver == "exact" and path_length(pts, order) == pytest.approx(best)


def leg_time(d: float, v: float, a: float | None) -> float:
    """Rest-to-rest time of one leg, written out: triangle or trapezoid profile."""
    if a is None:
        return d / v
    if d < v * v / a:  # never reaches v: accelerate half way, brake half way
        return 2 * math.sqrt(d / a)
    return 2 * (v / a) + (d - v * v / a) / v


@pytest.mark.parametrize("accel", [None, 500.0])
def test_cycle_time_recomputed_from_poses_dwell_and_speed(accel: float | None) -> None:
    pts = np.random.default_rng(1).uniform(-200, 200, (30, 3))
    home = [0.0, 0.0, 600.0]
    obj = Objective(name="cycle_time", dwell_s=0.7, speed_mm_s=300, accel_mm_s2=accel, home=home)
    ids = np.arange(3, 30, 2)
    tour = make_tour(pts, ids, obj, seconds=0.2)
    assert sorted(tour.order) == ids.tolist()
    stops = [home, *pts[tour.order].tolist(), home]
    legs = [math.dist(a, b) for a, b in zip(stops[:-1], stops[1:], strict=True)]
    assert tour.length_mm == pytest.approx(sum(legs))
    want = 0.7 * len(ids) + sum(leg_time(d, 300, accel) for d in legs)
    assert tour.cycle_time_s == pytest.approx(want)


def test_quaternions_reproduce_camera_to_world() -> None:
    rng = np.random.default_rng(2)
    views = make_viewpoints(rng.normal(size=(200, 3)) * 100, rng.normal(size=(200, 3)))
    for m in views.camera_to_world():
        q = quaternion(m[:3, :3])
        assert np.allclose(rotation(q), m[:3, :3], atol=1e-12)
        ref = Rotation.from_matrix(m[:3, :3]).as_quat()  # x, y, z, w
        ref = np.roll(ref, 1) * np.sign(ref[3] or 1.0)
        assert np.allclose(q, ref, atol=1e-9)


@cache
def small_plan(name: str = "views", home: tuple[float, ...] | None = None) -> PlanDocument:
    """A plan of a 900 mm plate from 49 explicit cameras 400 mm above it (face rows)."""
    part = plate_part(side=900.0, n=16)
    xy = np.stack(np.meshgrid(np.linspace(-400, 400, 7), np.linspace(-400, 400, 7)), -1)
    views = [
        {"position": [float(x), float(y), 400.0], "gaze": [0.05 * x, 0.0, -400.0]}
        for x, y in xy.reshape(-1, 2)
    ]
    request = PlanRequest(
        sensor=SMALL,
        target=Target(resolution_mm=3.0),
        candidates=views,
        objective=Objective(name=name, home=list(home) if home else None, dwell_s=0.1),
    )
    return plan(part, request, threads=1)


def test_plan_reports_tour_and_cycle_time() -> None:
    doc = small_plan("views", (0.0, 0.0, 1200.0))
    assert doc.tour is not None and doc.tour.order == [v.id for v in doc.viewpoints]
    pos = np.array([v.position for v in doc.viewpoints])
    assert doc.tour_length_mm == pytest.approx(path_length(pos, np.arange(len(pos))))
    stops = np.vstack([[0, 0, 1200], pos, [0, 0, 1200]])
    legs = np.linalg.norm(np.diff(stops, axis=0), axis=1)
    assert doc.tour.length_mm == pytest.approx(legs.sum())
    assert doc.tour.cycle_time_s == pytest.approx(0.1 * len(pos) + legs.sum() / 250.0)


def test_cycle_time_objective_never_slower_than_views() -> None:
    """The kept cover's tour is no slower than the fewest-views cover's nearest neighbour +
    2-opt tour (which the search starts from), and covers as much."""
    home = (1500.0, 0.0, 400.0)
    fewest = small_plan("views", home)
    timed = small_plan("cycle_time", home)
    assert timed.tour is not None and timed.tour.cover in ("views", "weighted")
    pos = np.array([v.position for v in sorted(fewest.viewpoints, key=lambda v: v.id)])
    cost = np.vstack([pos, home])  # views in id order, as the cover hands them to the tour
    cost = cdist(cost, cost) / 250.0
    start = 0.1 * len(pos) + route_cost(cost, seed_route(cost))
    assert timed.tour.cycle_time_s <= start + 1e-9
    assert timed.metrics.coverage.area == pytest.approx(fewest.metrics.coverage.area)


@pytest.mark.parametrize("unit", ["mm", "m"])
def test_csv_and_json_round_trip(unit: str) -> None:
    doc = small_plan()
    scale = 1.0 if unit == "mm" else 1e-3
    rows = list(csv.DictReader(io.StringIO(poses_csv(doc, unit))))  # type: ignore[arg-type]
    body = json.loads(poses_json(doc, unit))  # type: ignore[arg-type]
    assert len(rows) == len(body["poses"]) == len(doc.viewpoints) > 1
    for i, (row, pose, v) in enumerate(zip(rows, body["poses"], doc.viewpoints, strict=True)):
        m = np.asarray(v.camera_to_world)
        xyz = [float(row[k]) for k in "xyz"]
        q = [float(row[k]) for k in ("qw", "qx", "qy", "qz")]
        assert int(row["index"]) == pose["index"] == i and pose["id"] == v.id
        assert np.allclose(np.array(xyz) / scale, v.position, rtol=1e-15, atol=1e-12)
        assert np.allclose(rotation(np.array(q)), m[:3, :3], atol=1e-12)
        assert [pose["position"][k] for k in "xyz"] == xyz
        assert [pose["orientation"][k] for k in "wxyz"] == q
    assert body["unit"] == unit and body["frame"] == "cell"


def test_cli_export(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    doc = small_plan()
    path = tmp_path / "plan.json"
    path.write_text(doc.model_dump_json())
    assert main(["export", str(path), "--format", "csv", "--unit", "m"]) == 0
    assert capsys.readouterr().out == poses_csv(doc, "m")
    out = tmp_path / "poses.json"
    assert main(["export", str(path), "--format", "json", "--frame", "part", "-o", str(out)]) == 0
    assert json.loads(out.read_text()) == json.loads(poses_json(doc, "mm", "part"))
    (tmp_path / "bad.json").write_text("{}")
    assert main(["export", str(tmp_path / "bad.json")]) == 2


def test_api_poses_routes(api: Any) -> None:
    from worker import artifacts

    doc = small_plan()
    plan_id = "ab" * 32
    api.app.state.store.put(artifacts.plan_key(plan_id), doc.model_dump_json().encode())
    r = api.get(f"/v1/plans/{plan_id}/poses.csv?unit=m")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    assert r.text == poses_csv(doc, "m")
    r = api.get(f"/v1/plans/{plan_id}/poses.json")
    assert r.status_code == 200 and r.json() == json.loads(poses_json(doc, "mm"))
    for path in ("/v1/plans/" + "cd" * 32 + "/poses.csv", "/v1/plans/nope/poses.json"):
        r = api.get(path)
        assert r.status_code == 404
        assert r.headers["content-type"].startswith("application/problem+json")
    r = api.get(f"/v1/plans/{plan_id}/poses.csv?unit=inch")
    assert r.status_code == 422
    assert r.headers["content-type"].startswith("application/problem+json")


def test_api_plan_request_takes_the_objective(api: Any) -> None:
    from vpp_core.samples import sample_stl

    mesh = api.post("/v1/meshes", files={"file": ("b.stl", sample_stl())}).json()["id"]
    body: dict[str, Any] = {"mesh_id": mesh, "profile": "paper", "candidates": {"count": 20}}
    objective = {"name": "cycle_time", "dwell_s": 0.5, "speed_mm_s": 200, "home": [0, 0, 600]}
    r = api.post("/v1/plans", json={**body, "objective": objective})
    assert r.status_code == 202, r.text
    plain = api.post("/v1/plans", json=body).json()["id"]
    assert r.json()["id"] != plain  # the objective is part of the plan's identity
    r = api.post("/v1/plans", json={**body, "objective": {**objective, "speed_mm_s": 0}})
    assert r.status_code == 422
    assert r.headers["content-type"].startswith("application/problem+json")
