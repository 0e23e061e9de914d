"""Regions of interest with their own targets (issue 35 item 2), checked against direct
computations: the cover rows per face target (SPEC §3: δ̄_f = 1 / r̄_f), selections, labels from
files and uploads, ignored faces, and a plan's claims re-computed face by face."""

from __future__ import annotations

import dataclasses
import io
import json

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
from pydantic import ValidationError

from tests.test_plan_claims import SMALL, _c2w, brute_or_milp_optimum, recount, stepped_part
from vpp_core.cover.density import cover_model
from vpp_core.cover.patches import make_patches
from vpp_core.errors import MeshError, RegionError
from vpp_core.mesh.part import load_mesh, part_from_arrays
from vpp_core.mesh.tessellate import load_part
from vpp_core.plan.document import (
    ExplicitCandidates,
    PlanDocument,
    PlanRequest,
    SolverSettings,
    Target,
    ViewpointIn,
)
from vpp_core.plan.regions import Region, face_targets


def s_rows(r: np.ndarray, areas: np.ndarray, res: np.ndarray) -> np.ndarray:
    """SPEC §3 S written out per face with its own target r̄_f: δ_ij = sqrt(R_ij / A_i),
    S_ij = min(1, δ_ij r̄_i) where Σ_j δ_ij ≥ 1 / r̄_i, else V_ij; unseen rows dropped."""
    out = []
    for i in range(len(r)):
        if not r[i].any():
            continue
        delta = np.sqrt(r[i] / areas[i])
        if delta.sum() >= (1 / res[i]) * (1 - 1e-9):
            out.append(np.minimum(1.0, delta * res[i]))
        else:
            out.append((r[i] > 0).astype(float))
    return np.array(out)


# ---------------------------------------------------------------- the rows, per face target


def test_half_the_resolution_doubles_the_density_a_row_asks_for():
    """δ̄ = 1/r̄ doubles at half the resolution, so a face needs 4× the rays per area (R/A) from
    one view; faces with different targets are judged each against its own."""
    areas = np.array([1.0, 1.0, 1.0, 1.0])
    # one view lands R rays on each face: δ = sqrt(R / A) = 10, 10, 20, 20 per mm
    counts = sp.csr_array(np.array([[100], [100], [400], [400]]))
    counted = np.ones(4, dtype=bool)
    res = np.array([0.1, 0.05, 0.05, 0.1])  # face 1 asks twice face 0's density
    model = cover_model(counts, areas, counted, res)
    s = model.matrix.toarray()[:, 0]
    # face 0: δ = 10 = 1/0.1 met, S = 1; face 1: δ = 10 < 20, V = 1 but no density row;
    # face 2: δ = 20 = 1/0.05 met with 4× the rays; face 3: 20 > 10, capped at 1
    assert model.density_rows.tolist() == [True, False, True, True]
    assert s == pytest.approx([1.0, 1.0, 1.0, 1.0])
    # two views of δ = 10 each: face at 0.05 reaches 20 only with both (S = 0.5 each)
    two = sp.csr_array(np.array([[100, 100], [100, 100]]))
    m2 = cover_model(two, np.ones(2), np.ones(2, bool), np.array([0.1, 0.05]))
    assert m2.matrix.toarray() == pytest.approx(np.array([[1.0, 1.0], [0.5, 0.5]]))
    # against the formula on random data, face by face
    rng = np.random.default_rng(4)
    r = rng.integers(0, 60, size=(40, 7)) * (rng.random((40, 7)) < 0.5)
    a = rng.uniform(0.5, 3, 40)
    res = rng.choice([0.1, 0.2, 0.4], 40)
    got = cover_model(sp.csr_array(r), a, np.ones(40, bool), res).matrix.toarray()
    assert got == pytest.approx(s_rows(r, a, res))


def test_patches_never_mix_targets_and_take_their_region_s_size():
    box = trimesh.creation.box([40, 40, 4]).subdivide().subdivide().subdivide()
    v, f = box.vertices, box.faces
    centres = v[f].mean(axis=1)
    part = part_from_arrays(v, f)
    groups = (centres[:, 0] > 0).astype(np.int64)  # two regions split at x = 0
    counted = part.counted
    p = make_patches(
        centres,
        part.normals,
        part.areas,
        counted,
        10.0,
        groups=groups,
        group_edges=np.array([10.0, 2.5]),
    )
    for patch in range(p.count):
        members = groups[p.of_face == patch]
        assert len(set(members.tolist())) == 1
    per_group = [len(np.unique(p.of_face[(groups == g) & counted])) for g in (0, 1)]
    assert per_group[1] > 3 * per_group[0]  # 4× smaller patches: ~16× more (areas are equal)


# ---------------------------------------------------------------- selections


def test_selections_by_faces_box_sphere_and_label_later_ones_win():
    box = trimesh.creation.box([10, 10, 10]).subdivide()
    part = part_from_arrays(box.vertices, box.faces)
    m = part.n_faces
    from vpp_core.mesh.labels import FaceLabels
    from vpp_core.mesh.part import with_labels

    labels = np.arange(m) % 3
    part = with_labels(part, FaceLabels(labels, {2: "two"}))
    centroids = part.vertices[part.faces].mean(axis=1)
    regions = [
        Region(name="lab", label="two", resolution_mm=0.3),
        Region(name="top", box={"min": [-9, -9, 4.9], "max": [9, 9, 5.1]}, resolution_mm=0.1),
        Region(name="ball", sphere={"centre": [5, 5, 5], "radius_mm": 4}, ignore=True),
        Region(name="ids", faces=[0, 1, 2], resolution_mm=0.05),
    ]
    t = face_targets(part, 0.2, regions)
    want = np.full(m, -1)
    want[labels == 2] = 0
    want[np.abs(centroids[:, 2] - 5) < 0.1] = 1
    want[np.linalg.norm(centroids - 5, axis=1) <= 4] = 2
    want[[0, 1, 2]] = 3
    assert t.region.tolist() == want.tolist()
    res = np.array([0.3, 0.1, 0.2, 0.05])[want]
    assert t.resolution_mm == pytest.approx(np.where(want < 0, 0.2, res))
    assert t.ignored.tolist() == (want == 2).tolist()
    assert t.part.counted.tolist() == (want != 2).tolist() and t.whole.counted.all()
    # an empty selection is a warning, not an error
    t2 = face_targets(
        part, 0.2, [Region(name="far", box={"min": [50] * 3, "max": [60] * 3}, ignore=True)]
    )
    assert t2.warnings == ("region 'far' selects no counted face",)


@pytest.mark.parametrize(
    "region, message",
    [
        ({"name": "a", "faces": [1], "resolution_mm": 0.1, "ignore": True}, "not both"),
        ({"name": "a", "faces": [1], "resolution_mm": 0}, "greater than 0"),
        ({"name": "a", "faces": [1], "resolution_mm": -1}, "greater than 0"),
        ({"name": "a", "faces": [1]}, "needs resolution_mm or ignore"),
        ({"name": "a", "resolution_mm": 0.1}, "exactly one of"),
        ({"name": "a", "faces": [1], "label": 2, "resolution_mm": 0.1}, "exactly one of"),
        ({"name": "a", "faces": [-1], "resolution_mm": 0.1}, "greater than or equal to 0"),
        ({"name": "a", "box": {"min": [1, 0, 0], "max": [0, 1, 1]}, "ignore": True}, "must not"),
        ({"name": "a", "sphere": {"centre": [0, 0, 0], "radius_mm": 0}, "ignore": True}, "greater"),
        ({"name": "default", "faces": [1], "ignore": True}, "reserved"),
    ],
)
def test_malformed_regions_are_refused(region, message):
    with pytest.raises(ValidationError, match=message):
        PlanRequest(regions=[region])


def test_regions_that_do_not_fit_the_mesh_are_refused():
    box = trimesh.creation.box()
    part = part_from_arrays(box.vertices, box.faces)
    with pytest.raises(RegionError, match="face id 12 out of range"):
        face_targets(part, 0.2, [Region(name="a", faces=[12], ignore=True)])
    with pytest.raises(RegionError, match="no face labels"):
        face_targets(part, 0.2, [Region(name="a", label=1, ignore=True)])
    with pytest.raises(RegionError, match="nothing is left"):
        face_targets(
            part, 0.2, [Region(name="a", box={"min": [-1] * 3, "max": [1] * 3}, ignore=True)]
        )
    with pytest.raises(ValidationError, match="unique"):
        PlanRequest(regions=[{"name": "a", "faces": [0], "ignore": True}] * 2)


# ---------------------------------------------------------------- labels


def two_boxes() -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
    a = trimesh.creation.box([10, 10, 10])
    b = trimesh.creation.box([4, 4, 4])
    b.apply_translation([20, 0, 0])
    return a, b


def obj_text(groups: list[tuple[str, str, trimesh.Trimesh]]) -> bytes:
    """OBJ with `g` groups and `usemtl` materials, faces of the groups interleaved."""
    lines: list[str] = []
    faces = []
    base = 0
    for g, mtl, mesh in groups:
        lines += [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in mesh.vertices]
        faces.append([(g, mtl, f + base + 1) for f in mesh.faces])
        base += len(mesh.vertices)
    for k in range(max(len(f) for f in faces)):  # interleave: a face of each group in turn
        for per in faces:
            if k < len(per):
                g, mtl, f = per[k]
                mtl = f"{mtl}{k % 2}"  # materials alternate within each group
                lines += [f"g {g}", f"usemtl {mtl}", f"f {f[0]} {f[1]} {f[2]}"]
    return ("\n".join(lines) + "\n").encode()


def test_labels_from_obj_groups_follow_the_faces():
    a, b = two_boxes()
    # materials cross the groups, so trimesh regroups the faces by material: the labels must
    # follow the faces, not their order
    data = obj_text([("body", "steel", a), ("boss", "steel", b)])
    part = load_mesh(data, "obj")
    assert part.labels is not None and part.labels.source == "obj:groups"
    names = part.labels.names
    centroids = part.vertices[part.faces].mean(axis=1)
    got = [names[v] for v in part.labels.values]
    assert got == ["boss" if c[0] > 15 else "body" for c in centroids]
    # the same file with usemtl only: materials
    mats = b"\n".join(line for line in data.split(b"\n") if not line.startswith(b"g "))
    part2 = load_mesh(mats, "obj")
    assert part2.labels is not None and part2.labels.source == "obj:materials"
    assert set(part2.labels.names.values()) == {"steel0", "steel1"}
    assert part.faces.tolist() != np.vstack([a.faces, b.faces + 8]).tolist()  # reordered
    # regions select by group name
    t = face_targets(part, 0.2, [Region(name="boss", label="boss", resolution_mm=0.05)])
    assert ((t.resolution_mm == 0.05) == (centroids[:, 0] > 15)).all()


def test_labels_from_a_ply_face_property_and_a_glb_primitive():
    a, b = two_boxes()
    mesh = trimesh.util.concatenate([a, b])
    label = np.r_[np.full(len(a.faces), 7), np.full(len(b.faces), 3)]
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(mesh.vertices)}\nproperty double x\nproperty double y\n"
        f"property double z\nelement face {len(mesh.faces)}\n"
        "property list uchar int vertex_indices\nproperty int label\nend_header\n"
    )
    rec = np.empty(len(mesh.faces), dtype=[("n", "u1"), ("v", "<i4", (3,)), ("l", "<i4")])
    rec["n"], rec["v"], rec["l"] = 3, mesh.faces, label
    data = header.encode() + mesh.vertices.astype("<f8").tobytes() + rec.tobytes()
    part = load_mesh(data, "ply")
    assert part.labels is not None and part.labels.source == "ply:label"
    assert part.labels.values.tolist() == label.tolist()  # PLY keeps the face order
    glb = trimesh.Scene({"lid": a, "knob": b}).export(file_type="glb")
    part = load_mesh(glb, "glb")
    assert part.labels is not None and part.labels.source == "gltf:primitives"
    centroids = part.vertices[part.faces].mean(axis=1)
    got = [part.labels.names[v] for v in part.labels.values]
    assert got == ["knob" if c[0] > 15 else "lid" for c in centroids]


def test_uploaded_label_arrays_json_and_npy():
    a, _ = two_boxes()
    stl = a.export(file_type="stl")
    values = np.arange(12) % 2
    buf = io.BytesIO()
    np.save(buf, values.astype(np.int32))
    for blob in (json.dumps(values.tolist()).encode(), buf.getvalue()):
        part = load_part(stl, "stl", "mm", labels=blob)
        assert part.labels is not None and part.labels.values.tolist() == values.tolist()
    for bad, msg in [
        (b"[1, 2]", "expected 12 values"),
        (b'["a"] ', "expected 12"),
        (json.dumps([0.5] * 12).encode(), "integers"),
        (json.dumps([-2] * 12).encode(), "-1 \\(none\\)"),
        (b"\x93NUMPY garbage", "npy"),
        (b"{not json", "JSON array"),
    ]:
        with pytest.raises(MeshError, match=msg):
            load_part(stl, "stl", "mm", labels=bad)
    # split faces keep their labels
    part = load_part(
        stl, "stl", "mm", labels=json.dumps(values.tolist()).encode(), max_face_area_mm2=5.0
    )
    assert part.labels is not None and part.n_faces > 12
    assert set(part.labels.values.tolist()) == {0, 1}


# ---------------------------------------------------------------- plans


@pytest.fixture(scope="module")
def part():
    return stepped_part()


def test_plan_claims_hold_face_by_face_with_each_face_s_own_target(part):
    """A paper plan with a fine region and an ignored one: R recounted independently, every face
    judged against its own target, ignored faces in no row and no denominator, the count the
    optimum of the per-face S, and metrics.regions recomputed."""
    from vpp_core.plan.pipeline import plan

    regions = [
        {"name": "top", "box": {"min": [-61, -41, 9], "max": [61, 41, 11]}, "resolution_mm": 0.6},
        {"name": "tower", "box": {"min": [9, -16, 9], "max": [41, 16, 71]}, "ignore": True},
    ]
    request = PlanRequest(
        profile="paper",
        sensor=SMALL,
        target=Target(resolution_mm=1.2),
        candidates={"count": 30, "seed": 3},
        regions=regions,
    )
    doc = PlanDocument.model_validate_json(plan(part, request).model_dump_json())
    r = recount(part, SMALL, np.array([_c2w(c) for c in doc.candidates])).toarray()
    chosen = [v.id for v in doc.viewpoints]
    centroids = part.vertices[part.faces].mean(axis=1)
    inside = lambda lo, hi: np.all((centroids >= lo) & (centroids <= hi), axis=1)  # noqa: E731
    top = inside([-61, -41, 9], [61, 41, 11])
    tower = inside([9, -16, 9], [41, 16, 71])
    top &= ~tower  # the later region wins
    res = np.where(top, 0.6, 1.2)
    counted = part.counted & ~tower
    assert top.any() and tower.any()
    with np.errstate(divide="ignore"):
        delta = np.sqrt(r / part.areas[:, None])
    reach = delta.sum(axis=1) >= (1 / res) * (1 - 1e-9)
    met = delta[:, chosen].sum(axis=1) >= (1 / res) * (1 - 1e-9)
    assert (reach & top & counted).any() and not (reach & ~met & counted).any()
    w = part.areas * counted
    assert doc.metrics.resolution.met_area == pytest.approx((w * met).sum() / w.sum(), abs=1e-3)
    seen = r[:, chosen].any(axis=1)
    assert doc.metrics.coverage.area == pytest.approx((w * seen).sum() / w.sum(), abs=1e-3)
    assert doc.solver.status == "optimal"
    s = s_rows(r[counted], part.areas[counted], res[counted])
    assert doc.solver.objective == len(chosen) == brute_or_milp_optimum(s)
    by = {m.name: m for m in doc.metrics.regions}
    assert set(by) == {"top", "tower", "default"} and by["tower"].ignored
    for name, mask in (("top", top), ("default", ~top & ~tower)):
        wm = part.areas * (mask & part.counted)
        assert by[name].faces == int((mask & part.counted).sum())
        assert by[name].area_mm2 == pytest.approx(wm.sum())
        assert by[name].met_area == pytest.approx((wm * met).sum() / wm.sum(), abs=1e-3)
        assert by[name].max_met_area == pytest.approx((wm * reach).sum() / wm.sum(), abs=1e-3)
        assert by[name].coverage_area == pytest.approx((wm * seen).sum() / wm.sum(), abs=1e-3)
    info = doc.regions
    assert info is not None and info.ignored.ids == np.flatnonzero(tower & part.counted).tolist()
    codes = np.repeat(info.face_region[::2], info.face_region[1::2])
    assert codes.tolist() == np.where(tower, 1, np.where(top, 0, -1)).tolist()
    assert doc.mesh.area_mm2 == pytest.approx(part.area_mm2)  # the mesh stays whole


def plate_and_chip():
    """A 20 mm plate at z = 0 and a 4 mm chip 300 mm away at z = 0: two views needed."""
    a = trimesh.creation.box([20, 20, 2])
    b = trimesh.creation.box([4, 4, 2])
    b.apply_translation([300, 0, 0])
    mesh = trimesh.util.concatenate([a, b])
    return part_from_arrays(mesh.vertices, mesh.faces)


def two_views() -> ExplicitCandidates:
    """Two cameras 400 mm above plate_and_chip looking down: over the chip and 300 mm aside."""
    return ExplicitCandidates(
        viewpoints=[
            ViewpointIn(position=[0, 0, 400], gaze=[0, 0, -1]),
            ViewpointIn(position=[300, 0, 400], gaze=[0, 0, -1]),
        ]
    )


def test_an_ignored_region_forces_no_view_and_leaves_the_denominators():
    from vpp_core.plan.pipeline import plan

    part = plate_and_chip()
    views = two_views()
    base = dict(
        profile="paper",
        sensor=SMALL,
        target=Target(resolution_mm=3.0),
        candidates=views,
        solver=SolverSettings(time_limit_s=10),
    )
    doc = plan(part, PlanRequest(**base))
    assert len(doc.viewpoints) == 2
    chip = part.vertices[part.faces].mean(axis=1)[:, 0] > 100
    region = {"name": "chip", "box": {"min": [290, -10, -10], "max": [310, 10, 10]}, "ignore": True}
    doc = plan(part, PlanRequest(**base, regions=[region]))
    assert [v.id for v in doc.viewpoints] == [0]
    # the plate's top is all the first view sees: coverage over the plate's area only
    top = part.counted & ~chip & (part.normals[:, 2] > 0.9)
    plate_area = part.areas[part.counted & ~chip].sum()
    assert doc.metrics.coverage.area == pytest.approx(part.areas[top].sum() / plate_area)
    assert doc.regions is not None and doc.regions.ignored.faces == int((chip & part.counted).sum())
    assert doc.uncoverable.faces == int((part.counted & ~chip & (part.normals[:, 2] < 0.9)).sum())


# ---------------------------------------------------------------- the service


def bushing_labels() -> np.ndarray:
    """1 on the sample bushing's bore wall (radius 8 mm), 0 elsewhere."""
    from vpp_core.samples import sample_stl

    part = load_mesh(sample_stl(), "stl")
    c = part.vertices[part.faces].mean(axis=1)
    bore = (np.hypot(c[:, 0], c[:, 1]) < 8.5) & (c[:, 2] > 1) & (c[:, 2] < 39)
    return bore.astype(np.int64)


@pytest.mark.slow
def test_service_round_trip_with_uploaded_labels(api, start_workers):
    from tests.test_service_jobs import same_plan, served_plan, submit
    from vpp_core.mesh.labels import FaceLabels
    from vpp_core.mesh.part import with_labels
    from vpp_core.plan.pipeline import plan
    from vpp_core.samples import sample_stl

    labels = bushing_labels()
    up = api.post(
        "/v1/meshes",
        files={"file": ("b.stl", sample_stl()), "labels": ("l.json", json.dumps(labels.tolist()))},
    )
    assert up.status_code == 201, up.text
    mesh, lab = up.json()["id"], up.json()["labels"]
    assert lab["source"] == "upload" and lab["labelled_faces"] == len(labels)
    assert {v["label"]: v["faces"] for v in lab["values"]} == {
        0: int((labels == 0).sum()),
        1: int(labels.sum()),
    }
    # the same geometry with other labels: the same mesh, another label set
    other = api.post(  # a plain form field this time
        "/v1/meshes",
        files={"file": ("b.stl", sample_stl())},
        data={"labels": json.dumps((1 - labels).tolist())},
    )
    assert other.json()["id"] == mesh and other.json()["labels"]["id"] != lab["id"]
    assert api.get(f"/v1/meshes/{mesh}/labels/{lab['id']}").json() == lab
    assert api.get(f"/v1/meshes/{mesh}").json().get("labels") is None
    body = {
        "mesh_id": mesh,
        "profile": "paper",
        "sensor": SMALL.model_dump(),
        "target": {"resolution_mm": 1.2},
        "candidates": {"count": 30, "seed": 1},
        "regions": [{"name": "bore", "label": 1, "resolution_mm": 0.6}],
        "labels_id": lab["id"],
    }
    bad = [
        ({"regions": [{"name": "x", "faces": [10**6], "ignore": True}]}, "out of range"),
        ({"labels_id": None}, "names no labels"),
        ({"regions": [{"name": "x", "label": 5, "ignore": True}]}, "unknown label 5"),
        ({"labels_id": "0" * 64}, "no such labels"),
        ({"regions": [{"name": "x", "label": 1, "ignore": True, "resolution_mm": 1}]}, "not both"),
        ({"regions": [{"name": "x", "label": 1, "resolution_mm": -1}]}, "greater than 0"),
    ]
    for change, message in bad:
        r = api.post("/v1/plans", json={**body, **change})
        assert r.status_code == 422, (change, r.text)
        assert r.headers["content-type"] == "application/problem+json" and message in r.text
    job = submit(api, body)
    start_workers(1)
    served = served_plan(api, job)
    request = PlanRequest.model_validate({k: v for k, v in body.items() if k != "mesh_id"})
    part = with_labels(load_mesh(sample_stl(), "stl"), FaceLabels(labels))
    local = plan(part, request, threads=1)
    same_plan(served, local)
    by = {m.name: m for m in served.metrics.regions}
    assert by["bore"].faces == int(labels.sum()) and by["bore"].resolution_mm == 0.6


def test_point_cloud_and_scene_report_per_region():
    """The cloud's points carry their face's region and count neighbours within its own r̄; the
    viewer's scene judges each face against its own target and shows ignored ones excluded."""
    from scipy.spatial import cKDTree

    from vpp_core.plan.pipeline import plan
    from vpp_core.report.pointcloud import simulate_plan, write_ply
    from vpp_core.report.scene import EXCLUDED, MET, UNMET, plan_scene, unpack
    from vpp_core.trace.raytrace import trace_counts

    part = plate_part_fine()
    view = ExplicitCandidates(viewpoints=[ViewpointIn(position=[0, 0, 400], gaze=[0, 0, -1])])
    regions = [
        {"name": "fine", "box": {"min": [-11, -11, -1], "max": [0, 11, 1]}, "resolution_mm": 0.3},
        {"name": "skip", "box": {"min": [-11, 5, -1], "max": [11, 11, 1]}, "ignore": True},
    ]
    request = PlanRequest(
        profile="paper",
        sensor=SMALL,
        target=Target(resolution_mm=1.5),
        candidates=view,
        regions=regions,
    )
    doc = plan(part, request)
    c = part.vertices[part.faces].mean(axis=1)
    region = np.where(c[:, 1] >= 5, 1, np.where(c[:, 0] <= 0, 0, -1))
    cloud, counts, stats = simulate_plan(part, doc, max_points=10**6)
    assert cloud.face is not None and cloud.region is not None
    assert cloud.region.tolist() == region[cloud.face].tolist()
    radius = np.where(region == 0, 0.3, 1.5)[cloud.face]
    tree = cKDTree(cloud.points.astype(np.float64))
    pick = np.random.default_rng(0).choice(len(counts), 300, replace=False)
    for i in pick:
        want = len(tree.query_ball_point(cloud.points[i].astype(np.float64), radius[i])) - 1
        assert counts[i] == want
    by = {r.name: r for r in stats.regions}
    assert by["fine"].points == int((cloud.region == 0).sum()) > 0
    assert by["default"].points == int((cloud.region == -1).sum()) > 0
    buf = io.BytesIO()
    write_ply(buf, cloud, counts)
    assert b"property int region\n" in buf.getvalue()[:400]
    # the scene: met per face against its own target; ignored faces excluded
    counts_r = trace_counts(part, SMALL, explicit_viewpoints_of(doc)).counts
    meta, arrays = unpack(plan_scene(part, doc, counts_r))
    assert arrays["region"].tolist() == (region + 1).tolist()
    assert [r["name"] for r in meta["regions"]] == ["fine", "skip"]
    delta = np.asarray(np.sqrt(counts_r.toarray()[:, 0] / part.areas))
    res = np.where(region == 0, 0.3, 1.5)
    state = arrays["state"]
    assert (state[region == 1] == EXCLUDED).all()
    live = region != 1
    assert ((state[live] == MET) == (delta[live] >= 1 / res[live] * (1 - 1e-9))).all()
    assert (state[live & (delta < 1 / res)] == UNMET).all() and (state == UNMET).any()


def plate_part_fine():
    from tests.conftest import plate

    v, f = plate(side=20.0, n=8)
    return part_from_arrays(v, f)


def explicit_viewpoints_of(doc):
    from vpp_core.plan.pipeline import explicit_viewpoints

    return explicit_viewpoints(doc.viewpoints)


def test_a_resolution_sweep_keeps_each_region_s_own_target(part):
    """The sweep varies the default target only; each row equals the plan of that request."""
    from vpp_core.plan.pipeline import plan
    from vpp_core.report.studies import check_study, resolution_sweep

    region = {
        "name": "top",
        "box": {"min": [-61, -41, 9], "max": [61, 41, 11]},
        "resolution_mm": 0.6,
    }
    request = PlanRequest(
        profile="paper",
        sensor=SMALL,
        target=Target(resolution_mm=1.2),
        candidates={"count": 20, "seed": 3},
        regions=[region],
    )
    study = resolution_sweep(part, request, [1.0, 2.0])
    for row in study.rows:
        by = {m.name: m for m in row.regions}
        assert by["top"].resolution_mm == 0.6 and by["default"].resolution_mm == row.resolution_mm
    row = next(r for r in study.rows if r.formulation == "density" and r.resolution_mm == 2.0)
    target = request.target.model_copy(update={"resolution_mm": 2.0})  # as the sweep's row
    alone = plan(part, request.model_copy(update={"target": target}))
    assert row.viewpoints == len(alone.viewpoints)
    assert row.resolution.met_area == pytest.approx(alone.metrics.resolution.met_area)
    by_ids = request.model_copy(update={"regions": [Region(name="a", faces=[1], ignore=True)]})
    with pytest.raises(RegionError, match="decimation study plans on new faces"):
        check_study("decimation", [0.5], by_ids)


# ---------------------------------------------------------------- the command line


def test_cli_plans_with_regions_and_labels_and_refuses_bad_ones(tmp_path, capsys):
    from cli.main import main
    from tests.test_cli import vpp, vpp_in

    v, f = plate_mesh()
    mesh = tmp_path / "plate.stl"
    trimesh.Trimesh(v, f, process=False).export(mesh)
    views = tmp_path / "views.json"
    views.write_text(json.dumps([{"position": [0, 0, 500], "gaze": [0, 0, -1]}]))
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps([1] + [0] * (len(f) - 1)))
    regions = tmp_path / "regions.json"
    one, none = "one [/x]", "[/y] none"  # names that are not rich markup, printed as they are
    far = {"min": [1e3] * 3, "max": [1e3 + 1] * 3}
    body = [{"name": one, "label": 1, "resolution_mm": 0.09}]
    regions.write_text(json.dumps([*body, {"name": none, "box": far, "ignore": True}]))
    out = tmp_path / "plan.json"
    common = ("--candidates-file", views, "--profile", "paper", "-q")
    run = vpp_in(capsys, "plan", mesh, *common, "--regions", regions, "--labels", labels, "-o", out)
    assert run.returncode == 0, run.stderr
    doc = json.loads(out.read_text())
    by = {r["name"]: r for r in doc["metrics"]["regions"]}
    assert by[one]["faces"] == 1 and by[one]["resolution_mm"] == 0.09
    assert doc["regions"]["face_region"] == [0, 1, -1, len(f) - 1]
    assert "regions (each face against its own target)" in run.stdout
    assert one in run.stdout and none in run.stdout  # in the table, and in the warning
    assert any(none in w for w in doc["regions"]["warnings"])
    bad = [
        ([{"name": "x", "faces": [len(f)], "ignore": True}], "out of range"),
        ([{"name": "x", "label": 7, "ignore": True}], "unknown label 7"),
        ([{"name": "x", "faces": [0], "ignore": True, "resolution_mm": 1}], "not both"),
        ([{"name": "x", "faces": [0], "resolution_mm": 0}], "greater than 0"),
        ({"name": "x"}, "regions"),
    ]
    capsys.readouterr()
    for body, match in bad:  # in this process: the same main() as above, 2 s less each
        regions.write_text(json.dumps(body))
        code = main(
            list(map(str, ("plan", mesh, *common, "--regions", regions, "--labels", labels)))
        )
        err = capsys.readouterr().err
        assert code == 2, (body, err)
        assert len(err.strip().splitlines()) == 1 and match in err, err
    labels.write_text("[1, 2]")
    run = vpp("plan", mesh, *common, "--labels", labels)  # and one as a user runs it
    assert run.returncode == 2 and "expected" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1, run.stderr


def plate_mesh():
    from tests.conftest import plate

    return plate(side=20.0, n=2)


def test_default_profile_patches_hold_one_target_each_and_meet_it(part):
    """Patch rows (the default profile): no patch mixes regions, ignored faces are in none, and
    every patch that all candidates bring to its own target is brought there by the plan
    (R recounted independently, summed per patch, stray entries of < 3 rays dropped)."""
    from tests.test_plan_claims import patch_planes, patch_rows, pinhole_share, traced_rows
    from vpp_core.plan.pipeline import plan

    regions = [
        {"name": "top", "box": {"min": [-61, -41, 9], "max": [61, 41, 11]}, "resolution_mm": 0.8},
        {"name": "tower", "box": {"min": [9, -16, 9], "max": [41, 16, 71]}, "ignore": True},
    ]
    request = PlanRequest(
        sensor=SMALL,
        target=Target(resolution_mm=1.6, min_coverage=1.0),
        candidates={"count": 30, "seed": 3, "adaptive": False},
        regions=regions,
    )
    doc = PlanDocument.model_validate_json(plan(part, request).model_dump_json())
    assert doc.regions is not None and doc.cover_rows is not None
    geo, parent, re, _ = traced_rows(part, doc)  # the faces, or the elements the rows are of
    region = np.repeat(doc.regions.face_region[::2], doc.regions.face_region[1::2])[parent]
    of = np.asarray(doc.cover_rows.patch_of_face)
    assert (of[region == 1] == -1).all()
    for p in np.unique(of[of >= 0]):
        assert len(set(region[of == p].tolist())) == 1
    counted = geo.counted & (region != 1)
    rp, ap = patch_rows(re, geo.areas, counted, of.tolist())
    res = np.zeros(len(ap))
    res[of[counted]] = np.where(region == 0, 0.8, 1.6)[counted]
    chosen = [v.id for v in doc.viewpoints]
    c2w = [_c2w(c) for c in doc.candidates]
    planes = patch_planes(dataclasses.replace(geo, counted=counted), of)
    f = np.where(rp > 0, pinhole_share(rp, ap, *planes, c2w, SMALL), 1.0)  # sampled share
    u = np.where(rp > 0, f, 0.0).max(axis=1, keepdims=True)
    delta = np.sqrt(rp / (f * ap[:, None]))
    s = np.minimum(1.0, f / np.where(u > 0, u, 1.0) * np.minimum(1.0, delta * res[:, None]))
    reach = s.sum(axis=1) >= 1 - 1e-9
    met = s[:, chosen].sum(axis=1) >= 1 - 1e-9
    assert (reach & (res == 0.8)).any() and not (reach & ~met).any()
    assert doc.cover_rows.met_area == pytest.approx((ap * met).sum() / ap.sum(), abs=1e-3)


def test_a_partial_cover_never_leaves_out_a_region_with_its_own_target():
    """min_coverage applies to the default-target area: a small region is covered in full."""
    from vpp_core.plan.pipeline import plan

    part = plate_and_chip()
    views = two_views()
    base = dict(
        profile="paper",
        sensor=SMALL,
        target=Target(resolution_mm=3.0, min_coverage=0.9),
        candidates=views,
    )
    chip = part.vertices[part.faces].mean(axis=1)[:, 0] > 100
    seen_area = part.areas[part.counted & (part.normals[:, 2] > 0.9)].sum()
    assert part.areas[chip & (part.normals[:, 2] > 0.9)].sum() < 0.1 * seen_area
    doc = plan(part, PlanRequest(**base))
    assert [v.id for v in doc.viewpoints] == [0]  # the chip's 4 % may be left out
    region = {
        "name": "chip",
        "box": {"min": [290, -10, -10], "max": [310, 10, 10]},
        "resolution_mm": 3.0,
    }
    doc = plan(part, PlanRequest(**base, regions=[region]))
    assert sorted(v.id for v in doc.viewpoints) == [0, 1]
    by = {m.name: m for m in doc.metrics.regions}
    assert by["chip"].met_area == pytest.approx(by["chip"].max_met_area) and by["chip"].met_area > 0
    assert doc.partial is not None
    assert doc.partial.covered_area_mm2 <= doc.partial.coverable_area_mm2 + 1e-9


def test_mandatory_weights_leave_out_only_other_rows():
    """Brute force over every subset of satisfied rows: the transformed partial-cover constraint
    holds exactly when every mandatory row is satisfied and the others reach f of their area."""
    import itertools

    from vpp_core.plan.regions import mandatory_weights

    rng = np.random.default_rng(2)
    for _ in range(20):
        w = rng.uniform(0.1, 5, 7)
        must = rng.random(7) < 0.4
        f = float(rng.uniform(0.5, 0.99))
        w2, f2 = mandatory_weights(w, must, f)
        for bits in itertools.product([0, 1], repeat=7):
            z = np.array(bits, bool)
            ok = (z[must].all()) and w[~must & z].sum() >= f * w[~must].sum() - 1e-9
            assert (w2[z].sum() >= f2 * w2.sum() - 1e-9) == ok
