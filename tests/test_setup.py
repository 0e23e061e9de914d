"""Issue 35 item 1: the part in its cell (setup), checked against direct computations.

The re-traces here are independent of the planner's: rays built in float64 from the
document's camera_to_world, cast with trimesh against the part plus a floor and fixture the
test builds itself (its own floor square, its own transforms), SPEC §3 rules applied here.
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh
from pydantic import ValidationError
from scipy.spatial.transform import Rotation

from cli.main import main
from tests.pixelrays import camera_rays, valid_counts
from vpp_core.camera.sensor import Sensor
from vpp_core.cell.geometry import resolve
from vpp_core.cell.setup import MeshShape, Setup
from vpp_core.errors import SetupError, ViewpointError
from vpp_core.mesh.part import Part, load_mesh, part_from_arrays
from vpp_core.plan.document import PlanDocument, PlanRequest
from vpp_core.plan.pipeline import plan
from vpp_core.report.export import pose_rows, quaternion
from vpp_core.trace.raytrace import make_backend, trace_counts

SMALL = Sensor(width_px=160, height_px=100, fov_x_deg=38.7, fov_y_deg=24.75)


def box_mesh(extents: list[float], centre: list[float], subdivide: int = 0) -> trimesh.Trimesh:
    """A box of `extents` mm centred at `centre`, its faces split `subdivide` times."""
    mesh = trimesh.creation.box(extents)
    for _ in range(subdivide):
        mesh = mesh.subdivide()
    mesh.apply_translation(centre)
    return mesh


def as_part(mesh: trimesh.Trimesh) -> Part:
    return part_from_arrays(mesh.vertices, mesh.faces)


def stl(mesh: trimesh.Trimesh) -> bytes:
    out = io.BytesIO()
    mesh.export(out, file_type="stl")
    return out.getvalue()


def rigid(rot_deg: tuple[float, float, float], shift: list[float]) -> np.ndarray:
    """4×4 rotation (xyz Euler, degrees) then translation (mm)."""
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("xyz", rot_deg, degrees=True).as_matrix()
    m[:3, 3] = shift
    return m


def apply(m: np.ndarray, points: Any) -> np.ndarray:
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    return np.asarray(p @ m[:3, :3].T + m[:3, 3])


def request(setup: dict | None, **extra: Any) -> PlanRequest:
    body = {"profile": "paper", "sensor": SMALL.model_dump(), "candidates": {"count": 40}}
    return PlanRequest.model_validate({**body, **extra, "setup": setup})


def recount(part: Part, sensor: Sensor, c2w: np.ndarray, occluders: list[np.ndarray]) -> np.ndarray:
    """Independent R (M, N): float64 pixel rays, trimesh first hits on the part and the
    occluder triangles (k, 3, 3) (part frame), SPEC §3 rules; occluder hits count nowhere."""
    tris = [part.vertices[part.faces], *occluders]
    allv = np.vstack([t.reshape(-1, 3) for t in tris])
    mesh = trimesh.Trimesh(allv, np.arange(len(allv)).reshape(-1, 3), process=False)
    cam = camera_rays(sensor)
    cols = []
    for m in c2w:
        dirs = cam @ m[:3, :3].T
        origin = np.tile(m[:3, 3], (len(dirs), 1))
        tri, ray, loc = mesh.ray.intersects_id(
            origin, dirs, multiple_hits=False, return_locations=True
        )
        on_part = tri < part.n_faces
        tri, ray, loc = tri[on_part], ray[on_part], loc[on_part]
        cols.append(valid_counts(part, sensor, m, dirs, (tri, ray, loc)))
    return np.column_stack(cols)


def floor_triangles(part_to_cell: np.ndarray, z: float, half: float = 5000.0) -> np.ndarray:
    """(2, 3, 3) a floor square of the cell (z, ±half mm) in the part frame."""
    corners = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    p = apply(np.linalg.inv(part_to_cell), corners)
    return np.array([p[[0, 1, 2]], p[[0, 2, 3]]])


def c2w_of(items: list[Any]) -> np.ndarray:
    """(N, 4, 4) camera-to-world of document poses from position, gaze, up (computed here)."""
    out = []
    for c in items:
        z = np.asarray(c.gaze) / np.linalg.norm(c.gaze)
        y = np.asarray(c.up)
        x = np.cross(y, z)
        m = np.eye(4)
        m[:3, :3] = np.column_stack([x, y, z])
        m[:3, 3] = c.position
        out.append(m)
    return np.array(out)


def check_claims(part: Part, doc: PlanDocument, occluders: list[np.ndarray]) -> np.ndarray:
    """The document's uncoverable faces are those no candidate sees in an independent
    re-trace with the occluders (a face on which the two disagree gets at most 2 rays);
    the independent R."""
    r = recount(part, doc.sensor, c2w_of(doc.candidates), occluders)
    seen = r.sum(axis=1)
    unc = np.zeros(part.n_faces, dtype=bool)
    unc[doc.uncoverable.ids] = True
    counted = part.counted
    assert (seen[unc] <= 2).all(), seen[unc]
    assert ((seen > 2) | unc | ~counted).all()
    return r


# ------------------------------------------------------------------ validation


@pytest.mark.parametrize(
    "setup, words",
    [
        ({"part_to_cell": (2 * np.eye(4)).tolist()}, "not rigid"),
        ({"part_to_cell": rigid((0, 0, 0), [0, 0, 0])[:, ::-1].tolist()}, "not rigid"),
        ({"part_to_cell": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]}, "last row"),
        ({"floor": {"z_mm": float("nan")}}, "finite"),
        ({"floor": {"clearance_mm": -1}}, "greater than or equal"),
        ({"workspace": {"box": {"min": [0, 0, 0], "max": [1, 1, 0]}}}, "below max"),
        (
            {
                "workspace": {
                    "cylinder": {"centre": [0, 0], "radius_mm": 0, "z_min_mm": 0, "z_max_mm": 1}
                }
            },
            "greater than 0",
        ),
        (
            {
                "workspace": {
                    "cylinder": {"centre": [0, 0], "radius_mm": 5, "z_min_mm": 2, "z_max_mm": 1}
                }
            },
            "below z_max",
        ),
        ({"keep_out": [{"box": {"min": [0, 0, 0], "max": [0, 1, 1]}}]}, "below max"),
        ({"fixtures": [{"mesh": "f.stl", "to_cell": np.eye(3).tolist()}]}, "4"),
        ({"flor": {}}, "Extra inputs"),
    ],
)
def test_setup_is_validated_strictly(setup: dict, words: str) -> None:
    with pytest.raises(ValidationError) as exc:
        Setup.model_validate(setup)
    assert words in str(exc.value)


def test_setup_defaults_and_mesh_without_loader() -> None:
    s = Setup.model_validate({})
    assert s.part_to_cell == np.eye(4).tolist() and s.floor is None and not s.fixtures
    assert Setup.model_validate({"floor": {}}).floor.model_dump() == {"z_mm": 0, "clearance_mm": 50}
    with pytest.raises(SetupError, match=r"fixtures\[0\]\.mesh 'f.stl'"):
        resolve(Setup.model_validate({"fixtures": [{"mesh": "f.stl"}]}))


def test_cli_bad_setup_is_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    part = tmp_path / "p.stl"
    part.write_bytes(stl(box_mesh([40, 40, 4], [0, 0, 2])))
    bad = tmp_path / "setup.json"
    bad.write_text(json.dumps({"part_to_cell": (2 * np.eye(4)).tolist()}))
    assert main(["plan", str(part), "--setup", str(bad), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "part_to_cell" in err[0] and "not rigid" in err[0]
    missing = tmp_path / "missing.json"
    missing.write_text(json.dumps({"fixtures": [{"mesh": "nope.stl"}]}))
    assert main(["plan", str(part), "--setup", str(missing), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope.stl" in err[0]


# ------------------------------------------------------------------ plate on a floor

# the plate is modelled standing (40 x 4 x 40 mm, thin along y, mesh frame); part_to_cell
# turns it flat (+90° about x: y -> z) and lifts it so that its bottom is on the floor z = 0
PLATE_TO_CELL = rigid((90, 0, 0), [100.0, -30.0, 2.0])


def test_plate_on_floor_bottom_is_setup_occluded_and_no_camera_below() -> None:
    mesh = box_mesh([40, 4, 40], [0, 0, 0])
    part = as_part(mesh)
    setup = {"part_to_cell": PLATE_TO_CELL.tolist(), "floor": {"z_mm": 0, "clearance_mm": 50}}
    doc = plan(part, request(setup))
    bottom = np.flatnonzero(
        apply(np.c_[PLATE_TO_CELL[:, :3], [0, 0, 0, 1]], part.normals)[:, 2] < -0.99
    )
    assert len(bottom) == 2
    assert set(bottom) <= set(doc.setup_occluded.ids) <= set(doc.uncoverable.ids)
    assert doc.setup_occluded.area_mm2 >= 1600 - 1e-6
    cams = apply(PLATE_TO_CELL, [c.position for c in doc.candidates])
    assert len(cams) >= 5 and cams[:, 2].min() >= 50 - 1e-9
    check_claims(part, doc, [floor_triangles(PLATE_TO_CELL, 0.0)])
    # without the setup the bottom is seen: the claim above is the setup's doing
    free = plan(part, request(None))
    assert not set(bottom) & set(free.uncoverable.ids)
    assert free.setup is None and free.setup_occluded is None


def test_cell_poses_are_part_to_cell_applied() -> None:
    part = as_part(box_mesh([40, 4, 40], [0, 0, 0]))
    setup = {"part_to_cell": PLATE_TO_CELL.tolist(), "floor": {}}
    doc = plan(part, request(setup, candidates={"count": 20}))
    assert doc.setup is not None and doc.setup.part_to_cell == PLATE_TO_CELL.tolist()
    rows_cell, rows_part = pose_rows(doc, "mm", "cell"), pose_rows(doc, "mm", "part")
    for v, rc, rp in zip(doc.viewpoints, rows_cell, rows_part, strict=True):
        c2w = np.asarray(v.camera_to_world)
        want = PLATE_TO_CELL @ c2w
        assert v.cell is not None
        np.testing.assert_allclose(v.cell.camera_to_world, want, atol=1e-9)
        np.testing.assert_allclose(v.cell.position, apply(PLATE_TO_CELL, v.position)[0], atol=1e-9)
        np.testing.assert_allclose(v.cell.gaze, PLATE_TO_CELL[:3, :3] @ v.gaze, atol=1e-12)
        np.testing.assert_allclose(v.cell.up, PLATE_TO_CELL[:3, :3] @ v.up, atol=1e-12)
        np.testing.assert_allclose(rc[1:4], want[:3, 3], atol=1e-9)
        np.testing.assert_allclose(rc[4:], quaternion(want[:3, :3]), atol=1e-12)
        np.testing.assert_allclose(rp[1:4], v.position, atol=1e-12)


# ------------------------------------------------------------------ a fixture block


def fixture_setup() -> tuple[trimesh.Trimesh, trimesh.Trimesh, dict, np.ndarray]:
    """A 40 x 40 x 4 mm plate (faces ~5 mm) on the floor, and a 20 x 40 x 20 mm block (its own
    mesh frame centred) resting on the left half of its top face."""
    plate = box_mesh([40, 40, 4], [0, 0, 0], subdivide=3)
    block = box_mesh([20, 40, 20], [0, 0, 0])
    part_to_cell = rigid((0, 0, 30), [0, 0, 2])
    block_to_cell = part_to_cell @ rigid((0, 0, 0), [-10, 0, 12])
    setup = {
        "part_to_cell": part_to_cell.tolist(),
        "floor": {"z_mm": 0, "clearance_mm": 50},
        "fixtures": [{"mesh": "block.stl", "to_cell": block_to_cell.tolist(), "clearance_mm": 30}],
    }
    return plate, block, setup, block_to_cell


def test_fixture_block_hides_half_a_face_independent_retrace() -> None:
    plate, block, setup, block_to_cell = fixture_setup()
    part = as_part(plate)
    block_part = load_mesh(stl(block), "stl")
    cell = resolve(Setup.model_validate(setup), lambda s: (block_part.vertices, block_part.faces))
    doc = plan(part, request(setup, candidates={"count": 60}), cell=cell)
    t = np.asarray(setup["part_to_cell"])
    block_in_part = np.linalg.inv(t) @ block_to_cell
    block_tris = apply(block_in_part, block_part.vertices[block_part.faces]).reshape(-1, 3, 3)
    r = check_claims(part, doc, [floor_triangles(t, 0.0), block_tris])
    centres = part.vertices[part.faces].mean(axis=1)
    top = part.normals[:, 2] > 0.99
    under, free = top & (centres[:, 0] < 0), top & (centres[:, 0] > 0)
    assert under.sum() == free.sum() > 10
    unc = np.zeros(part.n_faces, dtype=bool)
    unc[doc.uncoverable.ids] = True
    occ = np.zeros(part.n_faces, dtype=bool)
    occ[doc.setup_occluded.ids] = True
    assert unc[under].all() and occ[under].all() and (r[under].sum(axis=1) == 0).all()
    assert not unc[free].any() and (r[free].sum(axis=1) > 0).all()
    # no camera inside the block or nearer than its 30 mm clearance: the distance to the box
    # (20 x 40 x 20 mm, centred in its own frame) computed in that frame
    cams = apply(t, [c.position for c in doc.candidates])
    local = np.abs(apply(np.linalg.inv(block_to_cell), cams)) - [10, 20, 10]
    dist = np.linalg.norm(np.maximum(local, 0), axis=1)
    assert dist.min() >= 30 - 1e-6
    assert cams[:, 2].min() >= 50 - 1e-9


def test_backends_agree_with_the_setup_in_the_scene() -> None:
    plate, block, setup, _ = fixture_setup()
    part = as_part(plate)
    block_part = load_mesh(stl(block), "stl")
    cell = resolve(Setup.model_validate(setup), lambda s: (block_part.vertices, block_part.faces))
    from vpp_core.plan.cellplan import scene_occluders

    occ = scene_occluders(part, SMALL, cell)
    doc = plan(part, request(setup, candidates={"count": 30}, backend="embree"), cell=cell)
    from vpp_core.plan.pipeline import explicit_viewpoints

    views = explicit_viewpoints(doc.candidates)
    r = [
        trace_counts(part, SMALL, views, backend=make_backend(part, name, occ)).counts.toarray()
        for name in ("raster", "packets", "embree")
    ]
    plain = trace_counts(part, SMALL, views, backend=make_backend(part, "embree")).counts
    total = r[2].sum()
    for other in r[:2]:
        assert np.abs(other - r[2]).sum() <= 1e-3 * total  # pixel centres on edges only
    assert plain.sum() > total  # the block and floor do block rays


# ------------------------------------------------------------------ where cameras may be


def in_cylinder(p: np.ndarray, centre: list[float], r: float, z0: float, z1: float) -> np.ndarray:
    return (
        (np.hypot(p[:, 0] - centre[0], p[:, 1] - centre[1]) <= r + 1e-9)
        & (p[:, 2] >= z0)
        & (p[:, 2] <= z1)
    )


@pytest.mark.parametrize("workspace", ["box", "cylinder"])
def test_workspace_and_keep_out_hold_for_every_camera_adaptive_too(
    workspace: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    from vpp_core.plan import adaptive

    aimed: list[np.ndarray] = []  # every adaptive camera, kept in the pool or taken back
    real = adaptive.aimed_views

    def spy(*args: Any, **kwargs: Any) -> Any:
        views = real(*args, **kwargs)
        aimed.append(views.positions)
        return views

    monkeypatch.setattr(adaptive, "aimed_views", spy)
    mesh = trimesh.util.concatenate(
        [box_mesh([60, 40, 10], [0, 0, 5]), box_mesh([20, 20, 30], [10, 0, 25])]
    )
    part = as_part(mesh)
    shift = [200.0, 100.0, 0.0]
    ws = (
        {"box": {"min": [-150, -200, 50], "max": [550, 400, 700]}}
        if workspace == "box"
        else {"cylinder": {"centre": [200, 100], "radius_mm": 420, "z_min_mm": 50, "z_max_mm": 700}}
    )
    keep = [{"box": {"min": [100, 0, 300], "max": [300, 200, 1000]}}]  # right above the part
    setup = {
        "part_to_cell": rigid((0, 0, 0), shift).tolist(),
        "floor": {"z_mm": 0, "clearance_mm": 40},
        "workspace": ws,
        "keep_out": keep,
    }
    req = PlanRequest.model_validate(
        {
            "sensor": SMALL.model_dump(),
            "candidates": {"count": 40, "standoff_mm": 450},
            "target": {"resolution_mm": 0.5},
            "solver": {"time_limit_s": 5},  # the cameras are the point, not the cover
            "setup": setup,
        }
    )
    doc = plan(part, req)
    assert sum(map(len, aimed)) > 0  # the adaptive rounds placed cameras too
    own = np.vstack([[c.position for c in doc.candidates], *aimed])
    cams = apply(rigid((0, 0, 0), shift), own.tolist())
    assert cams[:, 2].min() >= 40 - 1e-9
    if workspace == "box":
        assert ((cams >= [-150, -200, 50]) & (cams <= [550, 400, 700])).all()
    else:
        assert in_cylinder(cams, [200, 100], 420, 50, 700).all()
    inside = ((cams > [100, 0, 300]) & (cams < [300, 200, 1000])).all(axis=1)
    assert not inside.any()
    # without the keep-out, cameras would stand there: the test tests something
    free = plan(
        part, req.model_copy(update={"setup": Setup.model_validate({**setup, "keep_out": []})})
    )
    cams = apply(rigid((0, 0, 0), shift), [c.position for c in free.candidates])
    assert (((cams > [100, 0, 300]) & (cams < [300, 200, 1000])).all(axis=1)).any()


def test_view_sphere_keeps_only_allowed_cameras() -> None:
    from vpp_core.candidates.sphere import view_sphere
    from vpp_core.cell.reach import predicate

    part = as_part(box_mesh([40, 40, 4], [0, 0, 2]))
    cell = resolve(Setup.model_validate({"floor": {"clearance_mm": 100}}))
    views = view_sphere(part, SMALL, 200, allowed=predicate(cell))
    everywhere = view_sphere(part, SMALL, 200)
    assert (views.positions[:, 2] >= 100).all()
    assert len(views) == int((everywhere.positions[:, 2] >= 100).sum()) < 200


def test_explicit_viewpoint_under_the_floor_is_refused_with_its_name() -> None:
    part = as_part(box_mesh([40, 40, 4], [0, 0, 2]))
    views = [
        {"position": [0, 0, 500], "gaze": [0, 0, -1]},
        {"position": [0, 0, -300], "gaze": [0, 0, 1]},
    ]
    req = request({"floor": {"z_mm": 0, "clearance_mm": 50}}, candidates=views)
    with pytest.raises(ViewpointError, match=r"viewpoint 1 .*floor"):
        plan(part, req)
    keep = request(
        {"keep_out": [{"box": {"min": [-10, -10, 400], "max": [10, 10, 600]}}]}, candidates=views
    )
    with pytest.raises(ViewpointError, match=r"viewpoint 0 .*keep_out\[0\] box"):
        plan(part, keep)
    assert len(plan(part, request(None, candidates=views)).candidates) == 2


def test_cli_plan_with_setup_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plate, block, setup, _ = fixture_setup()
    (tmp_path / "plate.stl").write_bytes(stl(plate))
    (tmp_path / "cell").mkdir()
    (tmp_path / "cell" / "block.stl").write_bytes(stl(block))
    (tmp_path / "cell" / "setup.json").write_text(json.dumps(setup))
    out = tmp_path / "plan.json"
    args = ["plan", str(tmp_path / "plate.stl"), "--setup", str(tmp_path / "cell" / "setup.json")]
    code = main([*args, "--profile", "paper", "--candidates", "30", "-q", "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    doc = PlanDocument.model_validate_json(out.read_text())
    assert doc.setup is not None and doc.setup.fixtures[0].mesh == "block.stl"
    assert doc.setup_occluded is not None and doc.setup_occluded.touching > 0
    assert "setup_occluded" in capsys.readouterr().out
    csv_out = tmp_path / "poses.csv"
    assert main(["export", str(out), "--frame", "cell", "-o", str(csv_out)]) == 0
    first = csv_out.read_text().splitlines()[1].split(",")
    np.testing.assert_allclose([float(x) for x in first[1:4]], doc.viewpoints[0].cell.position)


# ------------------------------------------------------------------ no setup: as before


def test_no_setup_plans_as_before() -> None:
    from worker import artifacts as art

    part = as_part(box_mesh([40, 40, 4], [0, 0, 2]))
    a, b = plan(part, request(None)), plan(part, request({}))
    drop = {"timings_s": True, "rays": {"cast_per_s", "trace_s"}, "solver": {"time_s"}}
    drop |= {"tour": {"time_s"}, "setup": True, "setup_occluded": True}
    drop |= {"viewpoints": {"__all__": {"cell"}}}
    assert a.model_dump(exclude=drop) == b.model_dump(exclude=drop)
    assert (
        a.setup is None and a.setup_occluded is None and all(v.cell is None for v in a.viewpoints)
    )
    assert b.setup_occluded is not None and b.setup_occluded.faces == 0
    # content ids: without a setup exactly those of before setups; a setup enters them
    req = request(None)
    old = art.digest(
        {
            "kind": "trace/1",
            "mesh_id": part.id,
            **req.model_dump(mode="json", include={"sensor", "candidates", "backend"}),
        }
    )
    assert art.trace_id(part.id, req) == old
    floor = request({"floor": {}})
    other = request({"floor": {"z_mm": -1}})
    assert len({art.trace_id(part.id, r) for r in (req, floor, other)}) == 3
    assert len({art.plan_id(part.id, r) for r in (req, floor, other)}) == 3


# ------------------------------------------------------------------ the service


def test_service_round_trip_with_a_fixture_mesh_id(api: Any, start_workers: Any) -> None:
    plate, block, setup, _ = fixture_setup()
    ids = {}
    for name, mesh in (("plate", plate), ("block", block)):
        r = api.post("/v1/meshes", files={"file": (f"{name}.stl", stl(mesh))})
        assert r.status_code == 201, r.text
        ids[name] = r.json()["id"]
    setup["fixtures"][0]["mesh"] = ids["block"]
    body = {
        "mesh_id": ids["plate"],
        "profile": "paper",
        "sensor": SMALL.model_dump(),
        "candidates": {"count": 30},
        "setup": setup,
    }
    unknown = json.loads(json.dumps(body))
    unknown["setup"]["fixtures"][0]["mesh"] = "0" * 64
    r = api.post("/v1/plans", json=unknown)
    assert r.status_code in (404, 422) and "0" * 64 in r.json()["detail"]
    assert r.headers["content-type"].startswith("application/problem+json")
    under = {**body, "candidates": [{"position": [0, 0, -100], "gaze": [0, 0, 1]}]}
    r = api.post("/v1/plans", json=under)
    assert r.status_code == 422 and "viewpoint 0" in r.json()["detail"]
    assert "floor" in r.json()["detail"]
    from tests.test_service_jobs import same_plan, served_plan, submit

    job = submit(api, body)
    start_workers(1)
    served = served_plan(api, job)
    local_part = load_mesh(stl(plate), "stl")
    block_part = load_mesh(stl(block), "stl")
    req = PlanRequest.model_validate({k: v for k, v in body.items() if k != "mesh_id"})
    cell = resolve(req.setup, lambda s: (block_part.vertices, block_part.faces))
    local = plan(local_part, req, threads=1, cell=cell)
    same_plan(served, local)
    assert served.setup_occluded is not None and served.setup_occluded.touching > 0
    poses = api.get(f"/v1/plans/{job}/poses.json?frame=cell").json()
    np.testing.assert_allclose(
        [poses["poses"][0]["position"][k] for k in "xyz"], served.viewpoints[0].cell.position
    )


def test_setup_mesh_shape_units_in_the_store_must_be_mm() -> None:
    from worker import artifacts as art

    class Empty:
        def exists(self, key: str) -> bool:
            return False

    with pytest.raises(SetupError, match="units"):
        art.mesh_loader(Empty())(MeshShape(mesh="a" * 64, units="cm"))  # type: ignore[arg-type]


def test_predicate_against_direct_distances_to_a_fixture_and_a_keep_out_mesh() -> None:
    from vpp_core.cell.reach import allowed_mask, first_violation

    block = box_mesh([20, 40, 20], [0, 0, 0])
    to_cell = rigid((0, 0, 45), [50, 0, 10])
    ball = trimesh.creation.icosphere(3, 30.0)
    setup = Setup.model_validate(
        {
            "fixtures": [{"mesh": "block", "to_cell": to_cell.tolist(), "clearance_mm": 25}],
            "keep_out": [{"box": {"min": [0, 0, 0], "max": [1, 1, 1]}}, {"mesh": "ball"}],
        }
    )
    meshes = {"block": block, "ball": ball}
    cell = resolve(setup, lambda s: (meshes[s.mesh].vertices, meshes[s.mesh].faces))
    p = np.random.default_rng(1).uniform([-60, -80, -40], [120, 80, 60], (4000, 3))
    local = np.abs(apply(np.linalg.inv(to_cell), p)) - [10, 20, 10]
    inside_block = (local < 0).all(axis=1)
    dist_block = np.linalg.norm(np.maximum(local, 0), axis=1)
    in_ball = np.linalg.norm(p, axis=1) < 30 * np.cos(np.pi / 5 / 8)  # inside the polyhedron
    out_ball = np.linalg.norm(p, axis=1) > 30.0
    want = ~inside_block & (dist_block >= 25) & ~((p > 0) & (p < 1)).all(axis=1)
    got = allowed_mask(cell, p)
    sure = in_ball | out_ball
    assert (got[sure] == (want & ~in_ball)[sure]).all()
    assert (~got[inside_block]).all() and got.sum() > 1000 and (~got & ~in_ball).sum() > 100
    names = first_violation(cell, np.array([[0.5, 0.5, 0.5], [0, 0, 0], [50, 0, 10], [50, 0, 46]]))
    assert names == [
        "keep_out[0] box",
        "keep_out[1] mesh",
        "fixtures[0] (clearance 25 mm)",
        None,
    ]
    with pytest.raises(ViewpointError, match=r"viewpoint 0 .*fixtures\[0\]"):
        req = request(None, candidates=[{"position": [50, 0, 30], "gaze": [0, 0, -1]}])
        plan(as_part(box_mesh([4, 4, 4], [0, 0, 200])), req, cell=cell)


def centroid_seen(part: Part, sensor: Sensor, cams: list[Any], faces: np.ndarray) -> np.ndarray:
    """(len(faces),) bool: some camera's ray to the face's centroid is valid on the part
    alone (in the image, depth, incidence, first hit), cast with trimesh here."""
    mesh = trimesh.Trimesh(part.vertices, part.faces, process=False)
    out = np.zeros(len(faces), dtype=bool)
    for m in c2w_of(cams):
        c = part.vertices[part.faces[faces]].mean(axis=1)
        d = c - m[:3, 3]
        cam = d @ m[:3, :3]
        z = cam[:, 2]
        unit = d / np.linalg.norm(d, axis=1)[:, None]
        ok = (z >= sensor.near_mm) & (z <= sensor.far_mm)
        ok &= np.abs(cam[:, 0]) <= z * sensor.width_px / 2 / sensor.fx
        ok &= np.abs(cam[:, 1]) <= z * sensor.height_px / 2 / sensor.fy
        ok &= np.abs((unit * part.normals[faces]).sum(axis=1)) >= math.cos(math.radians(75))
        first = mesh.ray.intersects_first(np.tile(m[:3, 3], (len(d), 1)), unit)
        out |= ok & (first == faces)
    return out


def test_setup_occluded_unreachable_faces() -> None:
    """Faces not touching the setup that it hides: the wall and the floor's clearance keep
    every camera that would see them away."""
    part = as_part(box_mesh([40, 40, 20], [0, 0, 10], subdivide=1))
    wall = box_mesh([4, 200, 150], [0, 0, 0])  # 5 mm beside the +x face, standing on the floor
    setup = {
        "part_to_cell": rigid((0, 0, 0), [0, 0, 15]).tolist(),  # bottom 15 mm above the floor
        "floor": {"z_mm": 0, "clearance_mm": 5},
        "fixtures": [{"mesh": "wall", "to_cell": rigid((0, 0, 0), [27, 0, 75]).tolist()}],
    }
    cell = resolve(Setup.model_validate(setup), lambda s: (wall.vertices, wall.faces))
    doc = plan(part, request(setup, candidates={"count": 60}), cell=cell)
    occ = doc.setup_occluded
    assert occ is not None and occ.touching == 0
    normals = part.normals
    plus_x, bottom = np.flatnonzero(normals[:, 0] > 0.99), np.flatnonzero(normals[:, 2] < -0.99)
    ids = set(occ.ids)
    assert set(plus_x) <= ids and set(bottom) <= ids <= set(doc.uncoverable.ids)
    assert occ.blocked == 0 and occ.unreachable == len(plus_x) + len(bottom) == occ.faces
    # independently: none of the plan's candidates sees these faces even on the part alone
    # (the wall stops the generator's aim at +x, the floor's clearance cameras below), and a
    # plan without the setup has candidates that do
    assert not centroid_seen(part, SMALL, doc.candidates, np.r_[plus_x, bottom]).any()
    free = plan(part, request(None, candidates={"count": 60}))
    assert centroid_seen(part, SMALL, free.candidates, np.r_[plus_x, bottom]).all()
    cams = np.array([c.position for c in doc.candidates]) + [0, 0, 15]
    assert cams[:, 2].min() >= 5


def test_setup_occluded_blocked_faces() -> None:
    """A plan with explicit viewpoints: a clamp bar over the plate hides a strip of the top
    face from the one camera that sees it without the bar (blocked)."""
    part = as_part(box_mesh([40, 40, 4], [0, 0, 2], subdivide=3))
    bar = box_mesh([6, 60, 6], [0, 0, 0])
    setup = {
        "floor": {},
        "fixtures": [
            {"mesh": "bar", "to_cell": rigid((0, 0, 0), [0, 0, 30]).tolist(), "clearance_mm": 5}
        ],
    }
    cell = resolve(Setup.model_validate(setup), lambda s: (bar.vertices, bar.faces))
    views = [{"position": [0, 0, 500], "gaze": [0, 0, -1]}]
    doc = plan(part, request(setup, candidates=views), cell=cell)
    occ = doc.setup_occluded
    assert occ is not None and occ.blocked > 0 and occ.touching > 0  # bottom and sides touch
    top = np.flatnonzero(part.normals[:, 2] > 0.99)
    shade = np.array([i for i in occ.ids if i in set(top)])
    assert len(shade) == occ.blocked
    # independently: the camera sees them on the part alone, and not with the bar in the scene
    assert centroid_seen(part, SMALL, doc.candidates, shade).all()
    bar_tris = bar.vertices[bar.faces] + [0, 0, 30]
    r = recount(part, SMALL, c2w_of(doc.candidates), [bar_tris, floor_triangles(np.eye(4), 0.0)])
    assert (r[shade].sum(axis=1) == 0).all() and (r[np.setdiff1d(top, shade)].sum(axis=1) > 0).all()


def test_point_cloud_and_study_trace_the_setup() -> None:
    from vpp_core.report.pointcloud import simulate_plan
    from vpp_core.report.studies import resolution_sweep

    plate, block, setup, _ = fixture_setup()
    part = as_part(plate)
    block_part = load_mesh(stl(block), "stl")
    cell = resolve(Setup.model_validate(setup), lambda s: (block_part.vertices, block_part.faces))
    doc = plan(part, request(setup, candidates={"count": 30}), cell=cell)
    top = lambda pts: pts[(np.abs(pts[:, 2] - 2) < 1e-3) & (pts[:, 0] < -0.5)]  # noqa: E731
    with_setup, _, _ = simulate_plan(part, doc, max_points=10**6, cell=cell)
    without, _, _ = simulate_plan(part, doc.model_copy(update={"setup": None}), max_points=10**6)
    assert len(top(with_setup.points)) == 0 and len(top(without.points)) > 100
    sweep = resolution_sweep(part, request(setup, candidates={"count": 30}), [0.5], cell=cell)
    free = resolution_sweep(part, request(None, candidates={"count": 30}), [0.5])
    assert sweep.request.setup is not None
    for a, b in zip(sweep.rows, free.rows, strict=True):
        assert a.coverage.area < 0.5 < 0.8 < b.coverage.area  # the bottom, under the block
