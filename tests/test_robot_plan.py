"""Issue 36 in the plan: a robot or turntable in the setup, checked against direct computations.

Forward kinematics here is the URDF chained with scipy rotations (tests/test_robot.py's
`urdf_fk`), collisions are checked with trimesh's collision manager on the URDF's own
collision meshes posed by that FK, the floor by the posed vertices' heights.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh

pytest.importorskip("roboticstoolbox")
pytest.importorskip("fcl")

from cli.main import main  # noqa: E402
from tests.test_robot import urdf_fk  # noqa: E402
from tests.test_viewer import browser, live  # noqa: E402, F401  (the viewer's fixtures)
from vpp_core.camera.sensor import Sensor  # noqa: E402
from vpp_core.errors import ViewpointError  # noqa: E402
from vpp_core.mesh.part import Part, part_from_arrays  # noqa: E402
from vpp_core.plan.document import PlanDocument, PlanRequest  # noqa: E402
from vpp_core.plan.pipeline import plan  # noqa: E402
from vpp_core.robot.arms import arm_urdf  # noqa: E402
from vpp_core.samples import flanged_bushing  # noqa: E402

NEAR = Sensor(width_px=160, height_px=100, fov_x_deg=38.7, fov_y_deg=24.75, near_mm=200, far_mm=400)
MOUNT = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 60.0], [0, 0, 0, 1]]
PLACE = [[1, 0, 0, 400.0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]


def bushing() -> Part:
    mesh = flanged_bushing(24)
    return part_from_arrays(mesh.vertices, mesh.faces)


def request(setup: dict[str, Any] | None, **extra: Any) -> PlanRequest:
    body = {"profile": "paper", "sensor": NEAR.model_dump(), "candidates": {"count": 40}}
    return PlanRequest.model_validate({**body, **extra, "setup": setup})


def ur5_setup(**robot: Any) -> dict[str, Any]:
    arm = {
        "name": "ur5",
        "flange_to_camera": MOUNT,
        "roll_free_deg": 30,
        "camera_box_mm": [40, 40, 40],
    }
    return {
        "part_to_cell": PLACE,
        "floor": {"z_mm": 0, "clearance_mm": 30},
        "robot": {**arm, **robot},
    }


def posed_links(q_rad: np.ndarray) -> list[trimesh.Trimesh]:
    """The UR5's collision meshes (the URDF's files) posed by the independent FK, cell frame."""
    text, _, root = arm_urdf("ur5")
    out = []
    for link in ET.fromstring(text).findall("link"):
        mesh = link.find("collision/geometry/mesh")
        if mesh is None or link.get("name") in ("base_link", "world"):
            continue
        path = root / mesh.get("filename").split("package://example-robot-data/", 1)[1]
        m = trimesh.load(path, force="mesh")
        m.apply_scale(1000.0)
        m.apply_transform(urdf_fk(text, str(link.get("name")), q_rad))
        out.append(m)
    return out


def test_every_view_of_a_ur5_plan_is_reachable_and_touches_nothing() -> None:
    part = bushing()
    doc = plan(part, request(ur5_setup()), threads=1)
    free = plan(part, request({k: v for k, v in ur5_setup().items() if k != "robot"}), threads=1)
    assert doc.robot is not None and doc.robot.kind == "arm" and len(doc.viewpoints) > 0
    text, tip, _ = arm_urdf("ur5")
    placed = trimesh.Trimesh(part.vertices, part.faces, process=False)
    placed.apply_transform(np.asarray(PLACE))
    manager = trimesh.collision.CollisionManager()
    manager.add_object("part", placed)
    for v in doc.viewpoints:
        assert v.joints is not None and len(v.joints) == 6 and v.cell is not None
        q = np.radians(v.joints)
        camera = urdf_fk(text, tip, q) @ np.asarray(MOUNT)
        want = np.asarray(v.cell.camera_to_world)
        assert np.linalg.norm(camera[:3, 3] - want[:3, 3]) < 0.1
        cos = (np.trace(camera[:3, :3].T @ want[:3, :3]) - 1) / 2
        assert np.degrees(np.arccos(min(1.0, cos))) < 0.1
        for link in posed_links(q):
            assert link.vertices[:, 2].min() >= -1e-6  # above the floor
            assert not manager.in_collision_single(link)
    # the same candidates as the robot-free plan, less those the arm cannot take
    dropped = doc.robot.dropped
    assert len(doc.candidates) + sum(dropped.values()) == len(free.candidates)
    assert doc.robot.checked == len(free.candidates) and sum(dropped.values()) > 0
    tour = doc.robot.tour
    assert tour is not None and sorted(tour.order) == sorted(v.id for v in doc.viewpoints)
    # the viewer's arm: its last link at each view carries the camera to that view (part frame)
    from vpp_core.report.scene import arm_of

    frames = arm_of(doc)["arm_frames"]
    zero = np.zeros(6)
    flange = np.linalg.inv(urdf_fk(text, "wrist_3_link", zero)) @ urdf_fk(text, tip, zero)
    for k, v in enumerate(doc.viewpoints):
        camera = frames[k, -1] @ flange @ np.asarray(MOUNT)
        np.testing.assert_allclose(camera, np.asarray(v.camera_to_world), atol=0.05)
    assert tour.cycle_time_s == pytest.approx(tour.dwell_s * len(doc.viewpoints) + tour.travel_s)


def test_explicit_viewpoint_the_arm_cannot_take_is_refused_by_name() -> None:
    part = bushing()
    near = {"position": [0, 0, 300], "gaze": [0, 0, -1]}
    far = {"position": [2500, 0, 300], "gaze": [-1, 0, 0]}
    req = request(ur5_setup(), candidates=[near, far])
    with pytest.raises(ViewpointError, match=r"viewpoint 1 .*no_ik"):
        plan(part, req, threads=1)
    doc = plan(part, request(ur5_setup(), candidates=[near]), threads=1)
    assert doc.viewpoints[0].joints is not None


def test_turntable_views_are_the_table_turning_the_part() -> None:
    cam = np.eye(4)
    cam[:3, :3] = np.column_stack([[0, 1, 0], [0.3, 0, -1], [-1, 0, -0.3]])
    cam[:3, :3] /= np.linalg.norm(cam[:3, :3], axis=0)
    cam[:3, 3] = [300, 0, 110]
    table = {
        "camera_to_cell": cam.tolist(),
        "angle_step_deg": 45,
        "speed_deg_s": 90,
        "linear_axis": {"direction": [0, 0, 1], "min_mm": 0, "max_mm": 60, "steps": 2},
    }
    doc = plan(bushing(), request({"turntable": table}), threads=1)
    assert doc.robot is not None and doc.robot.kind == "turntable"
    assert doc.candidate_info.generated == 16 and len(doc.viewpoints) > 0
    for v in doc.viewpoints:
        angle, offset, roll = v.joints
        turn = trimesh.transformations.rotation_matrix(np.radians(angle), [0, 0, 1])
        want = cam.copy()
        want[2, 3] += offset
        np.testing.assert_allclose(turn @ np.asarray(v.camera_to_world), want, atol=1e-6)
        assert roll == pytest.approx(0.0, abs=1e-9)


def test_cli_setup_with_an_urdf_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "part.stl").write_bytes(
        trimesh.Trimesh(bushing().vertices, bushing().faces).export(file_type="stl")
    )
    text, _, _ = arm_urdf("ur5")
    (tmp_path / "cell").mkdir()
    (tmp_path / "cell" / "arm.urdf").write_text(text)
    setup = ur5_setup(name=None, urdf="arm.urdf", tip_link="tool0", link_radius_mm=40)
    (tmp_path / "cell" / "setup.json").write_text(json.dumps(setup))
    out = tmp_path / "plan.json"
    args = ["plan", str(tmp_path / "part.stl"), "--setup", str(tmp_path / "cell" / "setup.json")]
    sensor = tmp_path / "sensor.json"
    sensor.write_text(NEAR.model_dump_json())
    code = main(
        [
            *args,
            "--sensor",
            str(sensor),
            "--profile",
            "paper",
            "--candidates",
            "30",
            "-q",
            "-o",
            str(out),
        ]
    )
    assert code == 0, capsys.readouterr().err
    doc = PlanDocument.model_validate_json(out.read_text())
    assert doc.robot is not None and doc.robot.name == "urdf" and doc.viewpoints[0].joints
    assert doc.setup is not None and doc.setup.robot is not None
    assert (doc.setup.robot.urdf or "").startswith("<?xml") or (
        doc.setup.robot.urdf or ""
    ).lstrip().startswith("<")
    assert "joint-space tour" in capsys.readouterr().out
    (tmp_path / "cell" / "setup.json").write_text(
        json.dumps({**setup, "robot": {**setup["robot"], "urdf": "none.urdf"}})
    )
    assert main([*args, "-q", "-o", str(out)]) == 2
    assert "none.urdf" in capsys.readouterr().err


def test_service_robot_plan_and_an_explicit_viewpoint_it_refuses(
    api: Any, start_workers: Any
) -> None:
    from tests.test_service_jobs import same_plan, served_plan, submit
    from vpp_core.mesh.part import load_mesh

    data = trimesh.Trimesh(bushing().vertices, bushing().faces).export(file_type="stl")
    r = api.post("/v1/meshes", files={"file": ("bushing.stl", data)})
    assert r.status_code == 201, r.text
    body = {"mesh_id": r.json()["id"], **request(ur5_setup()).model_dump(mode="json")}
    far = [
        {"position": [0, 0, 300], "gaze": [0, 0, -1]},
        {"position": [2500, 0, 300], "gaze": [-1, 0, 0]},
    ]
    r = api.post("/v1/plans", json={**body, "candidates": far})
    assert r.status_code == 422 and r.headers["content-type"].startswith("application/problem+json")
    assert "viewpoint 1" in r.json()["detail"] and "no_ik" in r.json()["detail"]
    job = submit(api, body)
    start_workers(1)
    served = served_plan(api, job)
    local = plan(load_mesh(data, "stl"), request(ur5_setup()), threads=1)
    assert served.robot is not None and local.robot is not None
    served.robot.seconds = local.robot.seconds = 0.0
    same_plan(served, local)
    assert all(v.joints is not None for v in served.viewpoints)


def test_the_viewer_draws_the_arm_at_the_selected_viewpoint(
    live: Any,  # noqa: F811
    browser: Any,  # noqa: F811
) -> None:
    from tests.test_service_jobs import wait
    from tests.test_viewer import Page

    client, url = live
    data = trimesh.Trimesh(bushing().vertices, bushing().faces).export(file_type="stl")
    mesh = client.post("/v1/meshes", files={"file": ("bushing.stl", data)}).json()["id"]
    body = {"mesh_id": mesh, **request(ur5_setup()).model_dump(mode="json")}
    job = client.post("/v1/plans", json=body).json()["id"]
    assert wait(client, job)["status"] == "succeeded"
    doc = client.get(f"/v1/plans/{job}").json()
    page = Page(browser, f"{url}/v1/plans/{job}/view")
    assert page.js("window.vppViewer.arm()")["visible"] is False  # nothing selected
    k = len(doc["viewpoints"]) // 2
    page.js("k => window.vppViewer.select(k)", k)
    page.drawn()
    arm = page.js("window.vppViewer.arm()")
    assert arm["visible"] is True
    # part frame: the arm reaches from its base (cell origin = part frame (-400, 0, 0)) to the
    # camera it carries, 60 mm in front of the flange
    base = np.linalg.inv(np.asarray(PLACE))[:3, 3]
    camera = np.asarray(doc["viewpoints"][k]["position"])
    lo, hi = np.asarray(arm["min"]), np.asarray(arm["max"])
    assert (lo <= base + 1).all() and (hi >= base - 1).all()
    flange = camera - 60.0 * np.asarray(doc["viewpoints"][k]["gaze"])
    assert (lo <= flange + 1).all() and (hi >= flange - 1).all()
    page.js("window.vppViewer.select(null)")
    assert page.js("window.vppViewer.arm()")["visible"] is False
    # the joint-space cycle is the document's; the floor z = 0 of the cell is z = 0 here too
    t = doc["robot"]["tour"]
    assert page.js("window.vppViewer.summary")["joint cycle"] == (
        f"{t['cycle_time_s']:.2f}\u00a0s = {t['travel_s']:.2f}\u00a0s travel"
        f" + {t['dwell_s']:.2f}\u00a0s dwell"
    )
    floor = page.js("window.vppViewer.setup()")["floor"]
    assert floor["visible"] and floor["min"][2] == floor["max"][2] == pytest.approx(0, abs=1e-4)
    assert page.errors == []


def test_the_arms_scene_is_the_part_in_the_cell_its_fixtures_keep_outs_and_floor() -> None:
    from vpp_core.cell.geometry import resolve
    from vpp_core.cell.setup import Setup
    from vpp_core.plan.robotplan import gate_of, robot_scene

    block = trimesh.creation.box([50, 50, 20])
    SHIFT = [[1, 0, 0, 400], [0, 1, 0, 100], [0, 0, 1, 10], [0, 0, 0, 1]]  # noqa: N806
    setup = Setup.model_validate({
        **ur5_setup(),
        "fixtures": [{"mesh": "block.stl", "to_cell": SHIFT}],
        "keep_out": [{"box": {"min": [-100, 300, 0], "max": [100, 400, 500]}}],
    })  # fmt: skip
    cell = resolve(setup, lambda shape: (block.vertices, block.faces))
    part = bushing()
    scene = robot_scene(part, cell)
    assert scene.names == ["part", "fixtures[0]", "keep_out[0]"] and scene.floor_z == 0.0
    np.testing.assert_allclose(scene.meshes[0][0], part.vertices + [400.0, 0, 0])
    np.testing.assert_allclose(scene.meshes[1][0].min(axis=0), [375, 75, 0])
    np.testing.assert_allclose(scene.meshes[2][0].max(axis=0), [100, 400, 500])
    gate = gate_of(part, cell)
    assert gate is not None and gate.scene.key() == scene.key() and gate_of(part, cell) is gate
