"""vpp_core.robot against direct computations: forward kinematics written here from the URDF
XML (scipy rotations, not the package's chain), boxes placed on a link, the reach sphere,
joint limits, turntable angles and joint-space travel times."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import Counter

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

pytest.importorskip("roboticstoolbox")
pytest.importorskip("fcl")

from vpp_core.errors import RobotError  # noqa: E402
from vpp_core.robot.arms import arm_urdf  # noqa: E402
from vpp_core.robot.collision import Checker, Scene  # noqa: E402
from vpp_core.robot.jointtour import path_violations, travel_matrix  # noqa: E402
from vpp_core.robot.model import RobotSpec, TurntableSpec, load_robot  # noqa: E402
from vpp_core.robot.reach import REASONS, reachability  # noqa: E402
from vpp_core.robot.turntable import turntable_solve, turntable_views  # noqa: E402


def urdf_fk(text: str, tip: str, q: np.ndarray) -> np.ndarray:
    """Tip link pose (mm) in the root frame: URDF joints chained with scipy rotations."""
    doc = ET.fromstring(text)
    joints = {j.find("child").get("link"): j for j in doc.findall("joint")}
    path, link = [], tip
    while link in joints:
        path.append(joints[link])
        link = joints[link].find("parent").get("link")
    t, k = np.eye(4), 0
    for j in reversed(path):
        o = j.find("origin")
        step = np.eye(4)
        if o is not None:
            step[:3, :3] = Rotation.from_euler(
                "xyz", [float(v) for v in o.get("rpy", "0 0 0").split()]
            ).as_matrix()
            step[:3, 3] = [1000 * float(v) for v in o.get("xyz", "0 0 0").split()]
        t = t @ step
        if j.get("type") in ("revolute", "continuous"):
            axis = np.array([float(v) for v in j.find("axis").get("xyz").split()])
            m = np.eye(4)
            m[:3, :3] = Rotation.from_rotvec(axis / np.linalg.norm(axis) * q[k]).as_matrix()
            t, k = t @ m, k + 1
    return t


def rigid(rot: Rotation, xyz: list[float]) -> list[list[float]]:
    """A 4x4 transform as nested lists."""
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rot.as_matrix(), xyz
    return m.tolist()


def rz(deg: float) -> np.ndarray:
    """4x4 rotation about z."""
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("z", deg, degrees=True).as_matrix()
    return m


def poses_around(centre: np.ndarray, count: int, seed: int = 0) -> np.ndarray:
    """(count, 4, 4) cameras 250-350 mm above-ish `centre`, looking at it (OpenCV frame)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(count, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.5
    d /= np.linalg.norm(d, axis=1)[:, None]
    out = np.zeros((count, 4, 4))
    for i, v in enumerate(d):
        z = -v
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        out[i, :3, :3] = np.column_stack([x, np.cross(z, x), z])
        out[i, :3, 3] = centre + v * rng.uniform(250, 350)
        out[i, 3, 3] = 1
    return out


BASE = rigid(Rotation.from_euler("z", 30, degrees=True), [-100.0, 50.0, 0.0])
MOUNT = rigid(Rotation.from_euler("x", 10, degrees=True), [30.0, 0.0, 60.0])  # off the axis


@pytest.mark.parametrize("name, mount", [("ur5", MOUNT), ("panda", np.eye(4).tolist())])
def test_reported_joints_reproduce_the_camera_pose(name: str, mount: list[list[float]]) -> None:
    spec = RobotSpec(name=name, base_to_cell=BASE, flange_to_camera=mount, roll_free_deg=40)
    robot = load_robot(spec)
    text, tip, _ = arm_urdf(name)
    poses = poses_around(np.array([350.0, 100.0, 150.0]), 12)
    box = trimesh.creation.box([80, 80, 80])
    box.apply_translation([350, 100, 150])
    reach = reachability(robot, Scene([(box.vertices, box.faces)], floor_z=-1.0), poses)
    assert reach.reachable.sum() >= 6, reach.reasons()
    for i in np.flatnonzero(reach.reachable):
        q = reach.joints[i]
        assert np.all(q >= robot.lower - 1e-9) and np.all(q <= robot.upper + 1e-9)
        assert abs(reach.roll_deg[i]) <= 40 + 1e-9
        got = np.asarray(BASE) @ urdf_fk(text, tip, q) @ np.asarray(mount)
        want = poses[i] @ rz(reach.roll_deg[i])
        assert np.linalg.norm(got[:3, 3] - want[:3, 3]) < 0.1
        cos = (np.trace(got[:3, :3].T @ want[:3, :3]) - 1) / 2
        assert np.degrees(np.arccos(min(1.0, cos))) < 0.1


@pytest.mark.parametrize("mount", [np.eye(4).tolist(), MOUNT])
def test_roll_freedom_rolls_only_within_the_limit(mount: list[list[float]]) -> None:
    limits = [[-360, 360]] * 5 + [[-5, 5]]
    fixed = load_robot(RobotSpec(name="ur5", joint_limits=limits, flange_to_camera=mount))
    free = load_robot(
        RobotSpec(name="ur5", joint_limits=limits, flange_to_camera=mount, roll_free_deg=90)
    )
    text, tip, _ = arm_urdf("ur5")
    q0 = np.array([0.4, -1.3, 1.2, -1.5, -1.4, 0.0])  # wrist 3 at 0°
    pose = urdf_fk(text, tip, q0) @ np.asarray(mount)
    target = pose @ rz(60)  # the camera turned by 60° about its axis: wrist 3 far outside ±5°
    a, b = reachability(fixed, Scene(), target[None]), reachability(free, Scene(), target[None])
    assert a.reasons() == ["joint_limit"]
    assert b.reachable[0] and b.roll_deg[0] == pytest.approx(-60)
    got = urdf_fk(text, tip, b.joints[0]) @ np.asarray(mount)
    assert np.allclose(got, target @ rz(b.roll_deg[0]), atol=1e-4)


def test_pose_outside_the_reach_sphere_is_no_ik() -> None:
    robot = load_robot(RobotSpec(name="ur5"))
    far = poses_around(np.array([0.0, 0.0, 0.0]), 2)
    far[:, :3, 3] = [[2000.0, 0, 300], [0, -1500.0, 900]]  # UR5 reaches ~850 mm
    reach = reachability(robot, Scene(), far)
    assert reach.reasons() == ["no_ik", "no_ik"]
    assert np.isnan(reach.joints).all()


def test_link_through_a_box_is_a_collision() -> None:
    robot = load_robot(RobotSpec(name="ur5", base_to_cell=BASE))
    text, tip, _ = arm_urdf("ur5")
    q = np.array([0.3, -1.2, 1.0, -1.4, -1.5, 0.2])
    # the upper arm runs from the shoulder lift joint to the elbow joint: a box at its middle
    shoulder = np.asarray(BASE) @ urdf_fk(text, "upper_arm_link", q)
    elbow = np.asarray(BASE) @ urdf_fk(text, "forearm_link", q)  # the elbow joint's child
    middle = (shoulder[:3, 3] + elbow[:3, 3]) / 2
    box = trimesh.creation.box([30, 30, 30])
    box.apply_translation(middle)
    hit = Checker(robot, Scene([(box.vertices, box.faces)]))
    assert hit.colliding(q[None])[0]
    assert "upper_arm_link" in hit.which(q)
    box.apply_translation([0, 0, 1500])
    assert not Checker(robot, Scene([(box.vertices, box.faces)])).colliding(q[None])[0]
    # the floor: the same arm with its elbow below z = elbow height + 1 mm touches it
    assert Checker(robot, Scene(floor_z=float(elbow[2, 3]) + 1)).colliding(q[None])[0]
    assert not Checker(robot, Scene(floor_z=-2000.0)).colliding(q[None])[0]


def test_poses_only_reachable_through_a_box_are_collisions() -> None:
    robot = load_robot(RobotSpec(name="ur5"))
    poses = poses_around(np.array([350.0, 0.0, 200.0]), 6, seed=1)
    free = reachability(robot, Scene(), poses)
    wall = trimesh.creation.box([3000, 3000, 3000])  # the arm stands inside a block
    blocked = reachability(robot, Scene([(wall.vertices, wall.faces)]), poses)
    assert free.reachable.sum() >= 3
    served = np.flatnonzero(free.reachable)
    assert all(blocked.reasons()[i] == "collision" for i in served)
    assert free.key != blocked.key


def test_joint_limits_are_honoured() -> None:
    poses = poses_around(np.array([0.0, 400.0, 200.0]), 6, seed=2)  # +y: shoulder pan ~ +90°
    narrow = load_robot(RobotSpec(name="ur5", joint_limits=[[-10, 10]] + [[-360, 360]] * 5))
    reach = reachability(narrow, Scene(), poses)
    assert set(reach.reasons()) <= {"joint_limit", "no_ik"} and "joint_limit" in reach.reasons()
    wide = reachability(load_robot(RobotSpec(name="ur5")), Scene(), poses)
    assert wide.reachable.sum() >= 3
    ok = wide.joints[wide.reachable]
    assert (ok >= -2 * np.pi - 1e-9).all() and (ok <= 2 * np.pi + 1e-9).all()


URDF_2R = """<robot name="planar">
  <link name="base"/><link name="l1"><collision><origin xyz="0.15 0 0"/>
    <geometry><box size="0.3 0.04 0.04"/></geometry></collision></link>
  <link name="l2"/><link name="flange"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" velocity="1.0"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.3 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" velocity="2.0"/></joint>
  <joint name="tip" type="fixed"><parent link="l2"/><child link="flange"/>
    <origin xyz="0.2 0 0"/></joint>
</robot>"""


def test_uploaded_urdf_speeds_limits_and_errors() -> None:
    robot = load_robot(RobotSpec(urdf=URDF_2R))
    assert robot.chain.names == ["j1", "j2"] and robot.n == 2
    assert np.allclose(robot.speed, [1.0, 2.0]) and np.allclose(robot.upper, [3, 3])
    q = np.array([[0.0, 0.0], [1.0, -0.5], [0.2, 0.4]])
    cost = travel_matrix(q, robot.speed, home=np.zeros(2))
    assert cost[0, 1] == pytest.approx(max(1.0 / 1.0, 0.5 / 2.0))
    assert cost[1, 2] == pytest.approx(max(0.8 / 1.0, 0.9 / 2.0))
    assert cost[3, 1] == pytest.approx(1.0) and cost[2, 3] == pytest.approx(0.2)
    # a box on the first link's path: the straight move from j1 = -1 to j1 = +1 sweeps it
    box = trimesh.creation.box([20, 20, 20])
    box.apply_translation([200, 0, 0])
    checker = Checker(robot, Scene([(box.vertices, box.faces)]))
    legs = path_violations(checker, np.array([[-1.0, 0.0], [1.0, 0.0]]), np.radians(2))
    assert len(legs) == 1 and 0.4 < float(legs[0]["at"]) < 0.6
    with pytest.raises(RobotError, match="leaf"):
        load_robot(RobotSpec(urdf=URDF_2R.replace("</robot>", '<link name="x"/></robot>')))
    with pytest.raises(RobotError, match="not XML"):
        load_robot(RobotSpec(urdf="<robot"))
    with pytest.raises(RobotError, match="joint_limits"):
        load_robot(RobotSpec(urdf=URDF_2R, joint_limits=[[-1, 1]]))


def test_turntable_angles_reproduce_the_pose() -> None:
    cam = np.eye(4)
    cam[:3, :3] = np.column_stack([[0, 1, 0], [0, 0, -1], [-1, 0, 0]])  # looks along -x
    cam[:3, 3] = [400, 0, 100]
    spec = TurntableSpec(
        camera_to_cell=cam.tolist(), angle_step_deg=30, roll_free_deg=5,
        linear_axis={"direction": [0, 0, 1], "min_mm": 0, "max_mm": 200, "steps": 3},
    )  # fmt: skip
    part_to_cell = rigid(Rotation.from_euler("z", 10, degrees=True), [5.0, -3.0, 20.0])
    views = turntable_views(spec, part_to_cell)
    assert len(views.angle_deg) == 12 * 3
    solved = turntable_solve(spec, part_to_cell, views.camera_to_part)
    assert solved.reachable.all()
    assert np.allclose(np.mod(solved.angle_deg - views.angle_deg + 180, 360) - 180, 0, atol=1e-6)
    assert np.allclose(solved.offset_mm, views.offset_mm, atol=1e-6)
    # independently: the table turned by the angle about z through the origin, camera raised
    for i in range(len(views.angle_deg)):
        turn = np.eye(4)
        turn[:3, :3] = Rotation.from_euler("z", solved.angle_deg[i], degrees=True).as_matrix()
        placed = turn @ np.asarray(part_to_cell) @ views.camera_to_part[i]
        want = cam.copy()
        want[2, 3] += solved.offset_mm[i]
        assert np.allclose(placed, want, atol=1e-6)
    # a pose needing the camera higher than the axis goes / looking up is off the set
    high = views.camera_to_part[:1].copy()
    high[0, 2, 3] += 500
    tilted = views.camera_to_part[:1] @ np.asarray(
        rigid(Rotation.from_euler("x", 20, degrees=True), [0, 0, 0])
    )
    out = turntable_solve(spec, part_to_cell, np.concatenate([high, tilted]))
    assert [REASONS[r] for r in out.reason] == ["joint_limit", "no_ik"]


def test_folded_elbow_is_a_self_collision_and_the_camera_body_counts() -> None:
    robot = load_robot(RobotSpec(name="ur5", camera_box_mm=[60, 60, 150]))
    checker = Checker(robot, Scene())
    folded = np.array([0.0, -1.57, 3.1, 0.0, 0.0, 0.0])  # forearm back onto the upper arm
    bent = np.array([0.0, -1.57, 1.57, 0.0, 0.0, 0.0])
    assert checker.colliding(np.stack([folded, bent])).tolist() == [True, False]
    # a block 100 mm behind the optical centre (camera 200 mm in front of the flange): only the
    # camera's body (150 mm deep) reaches it
    text, tip, _ = arm_urdf("ur5")
    mount = np.eye(4)
    mount[2, 3] = 200.0
    camera = urdf_fk(text, tip, bent) @ mount
    block = trimesh.creation.box([20, 20, 20])
    block.apply_translation(camera[:3, 3] - 100.0 * camera[:3, 2])
    scene = Scene([(block.vertices, block.faces)])
    for box, hit in (([60, 60, 150], True), (None, False)):
        spec = RobotSpec(name="ur5", flange_to_camera=mount.tolist(), camera_box_mm=box)
        assert Checker(load_robot(spec), scene).colliding(bent[None])[0] == hit


def test_plan_gate_rolls_reports_joints_and_a_joint_space_tour() -> None:
    from vpp_core.camera.pose import make_viewpoints
    from vpp_core.errors import ViewpointError
    from vpp_core.plan.robotplan import RobotGate

    part_to_cell = np.asarray(rigid(Rotation.from_euler("z", 90, degrees=True), [400.0, 0, 50]))
    limits = [[-360, 360]] * 5 + [[-10, 10]]  # wrist 3 nearly fixed: views must roll
    spec = RobotSpec(
        name="ur5", roll_free_deg=90, roll_steps=37, joint_limits=limits,
        home_deg=[0, -90, 90, -90, -90, 0],
    )  # fmt: skip
    gate = RobotGate(spec, None, part_to_cell, Scene(floor_z=0.0))
    cams = poses_around(np.zeros(3), 8, seed=4)  # part frame: around the part's origin
    cams[0, :3, 3] = [0.0, 0.0, -300.0]  # under the floor once placed (cell z = -250)
    views = make_viewpoints(cams[:, :3, 3], cams[:, :3, 2], -cams[:, :3, 1])
    kept, idx, dropped = gate.filter(views)
    assert 0 not in idx and len(idx) >= 4
    turned = np.degrees(np.arccos(np.clip((kept.ups * views.ups[idx]).sum(axis=1), -1, 1)))
    assert (turned > 1).sum() >= 2  # rolled views carry their new up
    text, tip, _ = arm_urdf("ur5")
    joints = gate.joints_deg(kept)
    for k in range(len(kept)):
        got = urdf_fk(text, tip, np.radians(joints[k]))
        want = part_to_cell @ kept.camera_to_world()[k]
        assert np.abs(got - want).max() < 1e-3  # the traced (rolled) pose is the arm's
    assert sum(dropped.values()) == 8 - len(idx) and dropped["collision"] >= 1  # the one below
    fresh = RobotGate(spec, None, part_to_cell, Scene(floor_z=0.0))  # another process's gate
    again = fresh.joints_deg(kept)
    assert not np.isnan(again).any()
    for k in range(len(kept)):
        got = urdf_fk(text, tip, np.radians(again[k]))
        assert np.abs(got - part_to_cell @ kept.camera_to_world()[k]).max() < 1e-3
    out = gate.report([int(i) for i in idx], kept, 0.5, len(views), dropped)
    assert out.dropped == {r: dropped[r] for r in ("no_ik", "joint_limit", "collision")}
    tour = out.tour
    assert tour is not None and sorted(tour.order) == sorted(int(i) for i in idx)
    speed = np.degrees(gate.speeds())
    path = [np.asarray(spec.home_deg)] + [joints[list(idx).index(i)] for i in tour.order]
    path.append(np.asarray(spec.home_deg))
    legs = [np.max(np.abs(b - a) / speed) for a, b in zip(path[:-1], path[1:], strict=True)]
    assert tour.travel_s == pytest.approx(sum(legs), abs=1e-3)
    assert tour.cycle_time_s == pytest.approx(0.5 * len(idx) + sum(legs), abs=1e-3)
    with pytest.raises(ViewpointError, match="viewpoint 0 .*collision|viewpoint 0 .*no_ik"):
        gate.check_explicit(views)


def test_viewer_arm_frames_are_the_links_forward_kinematics() -> None:
    from vpp_core.report.armscene import arm_arrays

    part_to_cell = np.asarray(rigid(Rotation.from_euler("z", 20, degrees=True), [300.0, 20, 10]))
    q_deg = np.array([[10.0, -80, 70, -60, -90, 15], [0, -90, 90, -90, -90, 0]])
    spec = RobotSpec(name="ur5", base_to_cell=BASE, camera_box_mm=[50, 50, 50])
    a = arm_arrays(spec, part_to_cell, q_deg)
    text, _, _ = arm_urdf("ur5")
    links = load_robot(spec).chain.links
    assert a["arm_frames"].shape == (2, len(links), 4, 4)
    assert a["arm_link"].max() == len(links) - 1 and len(a["arm_link"]) == len(a["arm_vertices"])
    assert a["arm_faces"].max() < len(a["arm_vertices"])
    for k in range(2):
        for i, name in enumerate(links):
            want = (
                np.linalg.inv(part_to_cell)
                @ np.asarray(BASE)
                @ urdf_fk(text, name, np.radians(q_deg[k]))
            )
            assert np.abs(a["arm_frames"][k, i] - want).max() < 1e-2  # float32, mm


def test_plan_gate_turntable_views_carry_their_table_angle() -> None:
    from vpp_core.plan.robotplan import RobotGate

    cam = np.eye(4)
    cam[:3, :3] = np.column_stack([[0, 1, 0], [0, 0, -1], [-1, 0, 0]])  # looks along -x
    cam[:3, 3] = [400, 0, 100]
    table = TurntableSpec(camera_to_cell=cam.tolist(), angle_step_deg=90, speed_deg_s=45)
    gate = RobotGate(None, table, np.eye(4), Scene())
    views = gate.table_views()
    assert len(views) == 4
    joints = gate.joints_deg(views)
    assert np.allclose(np.sort(np.mod(joints[:, 0], 360)), [0, 90, 180, 270], atol=1e-6)
    out = gate.report(list(range(4)), views, 1.0, 4, Counter())
    assert out.kind == "turntable" and out.dropped == {"no_ik": 0, "joint_limit": 0, "collision": 0}
    # the open tour visits the quarter turns in order: 3 moves of 90 deg at 45 deg/s
    assert out.tour is not None and out.tour.travel_s == pytest.approx(6.0)
    assert out.tour.cycle_time_s == pytest.approx(10.0)
