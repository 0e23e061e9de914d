"""Robot reachability measured: IK libraries compared, then N candidates through vpp_core.robot.

1. IK per pose on the bundled UR5 and Panda: roboticstoolbox-python's compiled `ETS.ik_LM`
   against ikpy's `inverse_kinematics_frame` (scipy least squares; skipped when ikpy is not
   installed), on targets made by forward kinematics of random joint vectors within the
   limits: microseconds per solve from one start, success from 1 and from 4 starts
   (accepted when the numpy FK of the answer is within 0.01 mm / 0.01°), worst error.
2. `reachability` of N camera poses around the sample bushing standing on the floor in
   front of the arm (cameras 150-400 mm off the surface, looking at it; a camera 60 mm in
   front of the flange, rolls ±30° in 7 steps, 4 seeds): seconds and the reasons.

One JSON line per measurement; `uptime` first (2-core machines are shared).

    python bench/robot.py [--candidates 2000] [--ik-poses 200] [--arms ur5,panda]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
import trimesh

from vpp_core.camera.pose import make_viewpoints
from vpp_core.robot import kinematics as kin
from vpp_core.robot.arms import arm_urdf
from vpp_core.robot.collision import Scene
from vpp_core.robot.model import Robot, RobotSpec, load_robot
from vpp_core.robot.reach import reachability
from vpp_core.robot.urdf import flange_frames
from vpp_core.samples import flanged_bushing


def targets(robot: Robot, count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(joint vectors, tip poses mm) of random joint vectors within the limits (±π)."""
    rng = np.random.default_rng(seed)
    lo, hi = np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi)
    q = rng.uniform(lo, hi, (count, robot.n))
    return q, flange_frames(robot.chain, q)


def accepted(robot: Robot, q: np.ndarray | None, target: np.ndarray) -> tuple[bool, float]:
    """(within 0.01 mm / 0.01° by the numpy FK, position error mm)."""
    if q is None:
        return False, float("nan")
    dp, da = kin.pose_error(robot, q[None], target[None])
    return bool(dp[0] <= kin.CHECK_MM and da[0] <= kin.CHECK_DEG), float(dp[0])


Attempt = Callable[[Any, np.ndarray], tuple[bool, float]]
"""(a prepared target, a start joint vector) -> (accepted, position error mm)."""


def tally(
    library: str, targets: Iterable[Any], n: int, starts: np.ndarray, attempt: Attempt
) -> dict[str, Any]:
    """Each of the `n` targets (prepared as the loop reaches them, inside the timing) tried
    from each start in turn until `attempt` accepts: time per solve, success from 1 and from
    len(starts) starts, worst accepted error."""
    one, many, errors, solves = 0, 0, [], 0
    t0 = time.perf_counter()
    for target in targets:
        for k, start in enumerate(starts):
            solves += 1
            ok, err = attempt(target, start)
            if ok:
                one += k == 0
                many += 1
                errors.append(err)
                break
    dt = time.perf_counter() - t0
    return {
        "library": library, "us_per_solve": 1e6 * dt / solves,
        "ok_1_start": one / n, f"ok_{len(starts)}_starts": many / n,
        "max_err_mm": max(errors, default=float("nan")),
    }  # fmt: skip


def bench_rtb(robot: Robot, poses: np.ndarray, starts: np.ndarray) -> dict[str, Any]:
    """roboticstoolbox ik_LM: time per solve, success from 1 and from len(starts) starts."""
    ets = kin.ets_of(robot)

    def prepare(target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        metres = target.copy()
        metres[:3, 3] /= 1000
        return target, metres

    def attempt(prepared: tuple[np.ndarray, np.ndarray], start: np.ndarray) -> tuple[bool, float]:
        target, metres = prepared
        return accepted(robot, kin.solve(ets, metres, start), target)

    prepared = (prepare(target) for target in poses)
    return tally("roboticstoolbox-python ik_LM", prepared, len(poses), starts, attempt)


def bench_ikpy(name: str, robot: Robot, q_true: np.ndarray, starts: np.ndarray) -> dict[str, Any]:
    """ikpy inverse_kinematics_frame on targets made by ikpy's own forward kinematics of the
    same joint vectors (its chain ends at the URDF's first leaf, not necessarily the flange),
    accepted by ikpy's FK within 0.01 mm / 0.01°."""
    import tempfile

    import ikpy.chain

    text, _, _ = arm_urdf(name)
    with tempfile.NamedTemporaryFile("w", suffix=".urdf", delete=False) as f:
        f.write(text)
    chain = ikpy.chain.Chain.from_urdf_file(f.name, base_elements=[robot.chain.links[0]])
    os.unlink(f.name)
    mask = np.array([link.joint_type != "fixed" for link in chain.links])
    chain.active_links_mask = mask
    active = np.flatnonzero(mask)[: robot.n]

    def full(q: np.ndarray) -> np.ndarray:
        """`q` on the chain's active links, zeros elsewhere."""
        vector = np.zeros(len(chain.links))
        vector[active] = q
        return vector

    def attempt(target: np.ndarray, start: np.ndarray) -> tuple[bool, float]:
        got = chain.forward_kinematics(
            chain.inverse_kinematics_frame(
                target, initial_position=full(start), orientation_mode="all"
            )
        )
        dp = 1000 * np.linalg.norm(got[:3, 3] - target[:3, 3])
        cos = np.clip((np.trace(got[:3, :3].T @ target[:3, :3]) - 1) / 2, -1, 1)
        ok = dp <= kin.CHECK_MM and np.degrees(np.arccos(cos)) <= kin.CHECK_DEG
        return bool(ok), float(dp)

    targets = (chain.forward_kinematics(full(q)) for q in q_true)
    return tally("ikpy inverse_kinematics_frame", targets, len(q_true), starts, attempt)


def bushing_scene() -> tuple[trimesh.Trimesh, Scene]:
    """The sample bushing standing on the floor (z = 0) at x = 450 mm in front of the arm."""
    part = flanged_bushing()
    part.apply_translation([450.0, 0.0, -part.bounds[0][2]])
    return part, Scene([(part.vertices, part.faces)], floor_z=0.0)


def candidates(part: trimesh.Trimesh, count: int) -> np.ndarray:
    """(count, 4, 4) cameras 150-400 mm off random surface points, looking at them."""
    rng = np.random.default_rng(0)
    points, face = trimesh.sample.sample_surface(part, count, seed=0)
    normals = part.face_normals[face]
    positions = points + normals * rng.uniform(150, 400, (count, 1))
    return make_viewpoints(positions, -normals).camera_to_world()


def main() -> None:
    """Run both measurements and print JSON lines."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--candidates", type=int, default=2000)
    ap.add_argument("--ik-poses", type=int, default=200)
    ap.add_argument("--ikpy-poses", type=int, default=30)
    ap.add_argument("--arms", default="ur5,panda")
    args = ap.parse_args()
    print(json.dumps({"uptime": os.popen("uptime").read().strip()}))
    t0 = time.perf_counter()
    import fcl  # noqa: F401
    import roboticstoolbox  # noqa: F401

    print(json.dumps({"import_roboticstoolbox_fcl_s": round(time.perf_counter() - t0, 2)}))
    for name in args.arms.split(","):
        robot = load_robot(RobotSpec(name=name))  # type: ignore[arg-type]
        q_true, poses = targets(robot, args.ik_poses)
        starts = kin.seeds(robot, 4)
        print(json.dumps({"arm": name, **bench_rtb(robot, poses, starts)}))
        try:
            print(
                json.dumps(
                    {"arm": name, **bench_ikpy(name, robot, q_true[: args.ikpy_poses], starts)}
                )
            )
        except ImportError:
            print(json.dumps({"arm": name, "library": "ikpy", "skipped": "not installed"}))
    part, scene = bushing_scene()
    cams = candidates(part, args.candidates)
    mount = np.eye(4)
    mount[2, 3] = 60.0
    for name in args.arms.split(","):
        spec = RobotSpec(name=name, flange_to_camera=mount.tolist(), roll_free_deg=30, ik_seeds=4)  # type: ignore[arg-type]
        robot = load_robot(spec)
        t0 = time.perf_counter()
        reach = reachability(robot, scene, cams)
        dt = time.perf_counter() - t0
        print(json.dumps({
            "arm": name, "candidates": len(cams), "seconds": round(dt, 2),
            "reachable": int(reach.reachable.sum()), **reach.dropped(),
            "rolled": int((np.abs(np.nan_to_num(reach.roll_deg)) > 0).sum()),
        }))  # fmt: skip
    print(json.dumps({"uptime": os.popen("uptime").read().strip()}))


if __name__ == "__main__":
    main()
