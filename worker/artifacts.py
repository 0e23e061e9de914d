"""What the store holds and under which content keys: meshes, plan requests, candidates, R, plans.

meshes/<mesh id>.npz            the checked Part (arrays + id + warnings)
meshes/<mesh id>.json           its summary (what GET /v1/meshes/{id} answers)
labels/<labels id>.npz|.json    face labels of a mesh (uploaded, or read from its file) and their
                                summary; the id hashes mesh id + labels, so label sets of one
                                geometry never clash (the mesh id stays the geometry's)
requests/<plan id>.json         {"mesh_id", "request"}: what a plan job computes
traces/<trace id>/views.npz     candidate poses and their CandidateInfo
traces/<trace id>/chunks-<size>/<i>.npz  R of candidates [i·size, (i+1)·size)
traces/<trace id>/counts.npz    the assembled R (M faces × N candidates) and its ray figures
plans/<plan id>.json            the plan document (SPEC §8)
plans/<plan id>/<name>.png      its plots (histogram, cameras)
plans/<plan id>/scene.bin.gz    its per-face results for the viewer (vpp_core.report.scene), gzipped
studies/<study id>.json|.csv    a study's document and rows; studies/<study id>/<name>.png its plots
clouds/<cloud id>.ply|.json     a plan's simulated point cloud and its statistics (+ neighbours.png)

The plan id hashes the mesh id and the whole normalised request; the trace id only what R
depends on (mesh, sensor, candidates, backend), so another resolution, formulation or solver
setting reuses R.
"""

from __future__ import annotations

import gzip
import hashlib
import io
import json
import re
from dataclasses import replace
from typing import Any

import numpy as np
import scipy.sparse as sp

from vpp_core.camera.pose import Viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.cell.geometry import Cell, MeshLoader, resolve
from vpp_core.cell.setup import MeshShape, Setup
from vpp_core.errors import NotFoundError, SetupError
from vpp_core.mesh.labels import FaceLabels
from vpp_core.mesh.part import Part, with_labels
from vpp_core.mesh.refine import ELEMENT_LENGTH
from vpp_core.plan.document import CandidateInfo, CandidateOut, PlanDocument, PlanRequest
from vpp_core.trace.raytrace import Trace
from worker.store import Store


def digest(obj: Any) -> str:
    """SHA-256 hex of the canonical JSON of `obj` (sorted keys, no spaces)."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def plan_id(mesh_id: str, request: PlanRequest) -> str:
    """Content id of a plan: the mesh and every setting of the request, defaults filled in."""
    return digest(
        {
            "kind": "plan/1",
            "mesh_id": mesh_id,
            "request": _optional(request.model_dump(mode="json"), None),
        }
    )


def trace_id(mesh_id: str, request: PlanRequest, element_mm2: float | None = None) -> str:
    """Content id of R: mesh, sensor, candidates, backend and setup, which names its meshes by
    content id (not target or solver), and the area elements traced (`element_mm2`, mm²:
    vpp_core.plan.pipeline.elements_of); without a setup or elements, the id it had before."""
    dump = request.model_dump(mode="json", include={"sensor", "candidates", "backend", "setup"})
    return digest({"kind": "trace/1", "mesh_id": mesh_id, **_optional(dump, element_mm2)})


def _optional(dump: dict[str, Any], element_mm2: float | None) -> dict[str, Any]:
    """`dump` without its `setup` key when that is null, with `element_mm2` and the elements'
    length rule (vpp_core.mesh.refine.ELEMENT_LENGTH: R traced on elements split by area
    alone is not reused) where given (ids stay those of before setups and elements)."""
    out = {k: v for k, v in dump.items() if k != "setup" or v is not None}
    if element_mm2 is None:
        return out
    return {**out, "element_mm2": element_mm2, "element_length": ELEMENT_LENGTH}


def pool_trace_id(
    mesh_id: str,
    request: PlanRequest,
    candidates: list[CandidateOut],
    element_mm2: float | None = None,
) -> str:
    """Content id of R over a candidate pool the adaptive rounds grew: mesh, sensor, backend,
    the elements and every pose of the pool (the same pool is traced once)."""
    dump = request.model_dump(mode="json", include={"sensor", "backend", "setup"})
    poses = [c.model_dump(mode="json") for c in candidates]
    fields = _optional(dump, element_mm2)
    return digest({"kind": "pool/1", "mesh_id": mesh_id, **fields, "poses": poses})


def plan_trace_id(mesh_id: str, request: PlanRequest, doc: PlanDocument) -> str:
    """The id of the R a plan document was made from: its request's, or its grown pool's."""
    element_mm2 = doc_element_mm2(doc)
    if doc.candidate_info.added:
        return pool_trace_id(mesh_id, request, doc.candidates, element_mm2)
    return trace_id(mesh_id, request, element_mm2)


def doc_element_mm2(doc: PlanDocument) -> float | None:
    """The largest element area (mm²) the plan's R was traced on, None for the faces."""
    return doc.cover_rows.element_mm2 if doc.cover_rows else None


def mesh_key(mesh_id: str) -> str:
    return f"meshes/{mesh_id}.npz"


def request_key(plan: str) -> str:
    return f"requests/{plan}.json"


def plan_key(plan: str) -> str:
    return f"plans/{plan}.json"


def study_id(mesh_id: str, request: PlanRequest, kind: str, values: list[float]) -> str:
    """Content id of a study: mesh, request, kind and its resolutions or ratios."""
    dump = request.model_dump(mode="json")
    return digest(
        {"kind": f"study/1/{kind}", "mesh_id": mesh_id, "request": dump, "values": values}
    )


def cloud_id(plan: str) -> str:
    """Content id of a plan's point cloud."""
    return digest({"kind": "cloud/1", "plan": plan})


def plot_key(owner: str, name: str) -> str:
    """A PNG of a plan ('plans/<id>') or a study ('studies/<id>') or a cloud ('clouds/<id>')."""
    return f"{owner}/{name}"


def scene_key(plan: str) -> str:
    return f"plans/{plan}/scene.bin.gz"


def study_key(study: str, suffix: str = "json") -> str:
    return f"studies/{study}.{suffix}"


def cloud_key(cloud: str, suffix: str = "json") -> str:
    return f"clouds/{cloud}.{suffix}"


def done_keys(job_id: str) -> tuple[str, str, str]:
    """The keys whose existence means the job `job_id` (plan, study or cloud) has succeeded;
    ids of different kinds never collide (the kind is hashed in)."""
    return plan_key(job_id), study_key(job_id), cloud_key(job_id)


def views_key(trace: str) -> str:
    return f"traces/{trace}/views.npz"


def chunk_key(trace: str, size: int, index: int) -> str:
    return f"traces/{trace}/chunks-{size}/{index:05d}.npz"


def summary_key(mesh_id: str) -> str:
    return f"meshes/{mesh_id}.json"


def counts_key(trace: str) -> str:
    return f"traces/{trace}/counts.npz"


def _npz(**arrays: Any) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _unnpz(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def put_part(store: Store, part: Part) -> None:
    """Store the checked part under its content id."""
    store.put(
        mesh_key(part.id),
        _npz(
            vertices=part.vertices,
            faces=part.faces,
            areas=part.areas,
            normals=part.normals,
            counted=part.counted,
            representative=part.representative,
            meta=np.array(json.dumps({"id": part.id, "warnings": list(part.warnings)})),
        ),
    )


def get_part(store: Store, mesh_id: str) -> Part:
    """The stored part (NotFoundError when no mesh has this id)."""
    z = _unnpz(store.get(mesh_key(mesh_id)))
    meta = json.loads(str(z.pop("meta")))
    for a in z.values():
        a.setflags(write=False)
    return Part(
        vertices=z["vertices"],
        faces=z["faces"],
        areas=z["areas"],
        normals=z["normals"],
        counted=z["counted"],
        representative=z["representative"],
        id=meta["id"],
        warnings=tuple(meta["warnings"]),
    )


def labels_key(labels_id: str, ext: str = "npz") -> str:
    return f"labels/{labels_id}.{ext}"


def put_labels(store: Store, part: Part) -> str:
    """Store the part's face labels (and their summary) under their content id; the id."""
    labels = part.labels
    assert labels is not None
    labels_id = labels.content_id(part.id)
    if not store.exists(labels_key(labels_id)):
        store.put(labels_key(labels_id, "json"), json.dumps(labels_summary(part)).encode())
        names = json.dumps({str(k): v for k, v in labels.names.items()})
        meta = json.dumps({"mesh_id": part.id, "source": labels.source, "names": names})
        store.put(labels_key(labels_id), _npz(values=labels.values, meta=np.array(meta)))
    return labels_id


def labels_summary(part: Part) -> dict[str, Any]:
    """{id, mesh_id, source, labelled_faces, values: [{label, name, faces, area_mm2}]}."""
    labels = part.labels
    assert labels is not None
    values, counts = np.unique(labels.values, return_counts=True)
    area = {int(v): float(part.areas[labels.values == v].sum()) for v in values}
    return {
        "id": labels.content_id(part.id),
        "mesh_id": part.id,
        "source": labels.source,
        "labelled_faces": int((labels.values >= 0).sum()),
        "values": [
            {
                "label": int(v),
                "name": labels.names.get(int(v)),
                "faces": int(n),
                "area_mm2": area[int(v)],
            }
            for v, n in zip(values, counts, strict=True)
            if v >= 0
        ],
    }


def get_labels_summary(store: Store, labels_id: str) -> dict[str, Any]:
    """The summary put_labels stored (NotFoundError when unknown)."""
    out: dict[str, Any] = json.loads(store.get(labels_key(labels_id, "json")))
    return out


def get_labels(store: Store, labels_id: str) -> FaceLabels:
    """The stored face labels `labels_id` (NotFoundError when unknown)."""
    z = _unnpz(store.get(labels_key(labels_id)))
    meta = json.loads(str(z["meta"]))
    names = {int(k): v for k, v in json.loads(meta["names"]).items()}
    return FaceLabels(z["values"].astype(np.int64), names, meta["source"])


def get_planned_part(store: Store, mesh_id: str, request: PlanRequest) -> Part:
    """The stored part with the face labels the request names (request.labels_id)."""
    part = get_part(store, mesh_id)
    return with_labels(part, get_labels(store, request.labels_id)) if request.labels_id else part


def put_request(store: Store, plan: str, mesh_id: str, request: PlanRequest) -> None:
    """Store what the plan job `plan` must compute."""
    body = {"mesh_id": mesh_id, "request": request.model_dump(mode="json")}
    store.put(request_key(plan), json.dumps(body).encode())


def put_study_request(
    store: Store, study: str, mesh_id: str, request: PlanRequest, kind: str, values: list[float]
) -> None:
    """Store what the study job `study` must compute."""
    body = {
        "mesh_id": mesh_id,
        "request": request.model_dump(mode="json"),
        "study": {"kind": kind, "values": values},
    }
    store.put(request_key(study), json.dumps(body).encode())


def get_study_request(store: Store, study: str) -> tuple[str, PlanRequest, str, list[float]]:
    """(mesh id, request, kind, values) of the study job `study`."""
    body = json.loads(store.get(request_key(study)))
    spec = body["study"]
    return (
        body["mesh_id"],
        PlanRequest.model_validate(body["request"]),
        spec["kind"],
        spec["values"],
    )


def put_cloud_request(store: Store, cloud: str, plan: str) -> None:
    """Store which plan the point cloud job `cloud` simulates."""
    store.put(request_key(cloud), json.dumps({"plan": plan}).encode())


def get_cloud_plan(store: Store, cloud: str) -> str:
    """The plan id of the point cloud job `cloud`."""
    return str(json.loads(store.get(request_key(cloud)))["plan"])


def get_request(store: Store, plan: str) -> tuple[str, PlanRequest]:
    """(mesh id, request) of the plan job `plan`."""
    body = json.loads(store.get(request_key(plan)))
    return body["mesh_id"], PlanRequest.model_validate(body["request"])


def put_views(
    store: Store,
    trace: str,
    sensor: Sensor,
    views: Viewpoints,
    info: CandidateInfo,
    setup: Setup | None = None,
) -> None:
    """Store the sensor, candidates and setup (its floor and fixtures occlude) of a trace."""
    data = _npz(
        positions=views.positions,
        gazes=views.gazes,
        ups=views.ups,
        info=np.array(info.model_dump_json()),
        sensor=np.array(sensor.model_dump_json()),
        setup=np.array("null" if setup is None else setup.model_dump_json()),
    )
    store.put(views_key(trace), data)


def get_setup(store: Store, trace: str) -> Setup | None:
    """The setup a trace's rays were traced in (None: none, or stored before setups)."""
    z = _unnpz(store.get(views_key(trace)))
    text = str(z["setup"]) if "setup" in z else "null"
    return None if text == "null" else Setup.model_validate_json(text)


def mesh_loader(store: Store) -> MeshLoader:
    """A setup's mesh reader over the store: `mesh` is an uploaded mesh's id (already in mm);
    an unknown id is NotFoundError naming it."""

    def load(shape: MeshShape) -> tuple[np.ndarray, np.ndarray]:
        if shape.units != "mm":
            raise SetupError(
                f"setup mesh {shape.mesh}: an uploaded mesh is in mm already; leave units mm"
            )
        if not re.fullmatch(r"[0-9a-f]{64}", shape.mesh) or not store.exists(mesh_key(shape.mesh)):
            raise NotFoundError(
                f"setup mesh {shape.mesh!r}: no such mesh; upload it with POST /v1/meshes"
            )
        part = get_part(store, shape.mesh)
        return part.vertices, part.faces

    return load


def get_cell(store: Store, setup: Setup | None) -> Cell | None:
    """The setup with its meshes read from the store (None: no setup)."""
    return resolve(setup, mesh_loader(store))


def get_views(store: Store, trace: str) -> tuple[Sensor, Viewpoints, CandidateInfo]:
    """The sensor and candidates of a trace."""
    z = _unnpz(store.get(views_key(trace)))
    info = CandidateInfo.model_validate_json(str(z["info"]))
    sensor = Sensor.model_validate_json(str(z["sensor"]))
    return sensor, Viewpoints(z["positions"], z["gazes"], z["ups"]), info


def trace_bytes(trace: Trace) -> bytes:
    """R (and the elements' R, where traced) and its figures as npz bytes."""
    c, e = trace.counts, trace.elements
    figures = [trace.rays_cast, trace.pixels]
    elements = {}
    if e is not None and trace.element_mm2 is not None:
        elements = dict(
            e_data=e.data,
            e_indices=e.indices,
            e_indptr=e.indptr,
            e_shape=np.array(e.shape),
            element_mm2=np.array(trace.element_mm2),
        )
    return _npz(
        data=c.data,
        indices=c.indices,
        indptr=c.indptr,
        shape=np.array(c.shape),
        figures=np.array(figures, np.int64),
        seconds=np.array(trace.seconds),
        backend=np.array(trace.backend),
        **elements,
    )


def trace_from_bytes(data: bytes) -> Trace:
    """Inverse of trace_bytes."""
    z = _unnpz(data)
    counts = _csc(z, "")
    rays_cast, pixels = (int(x) for x in z["figures"])
    trace = Trace(counts, rays_cast, pixels, str(z["backend"]), float(z["seconds"]))
    if "element_mm2" not in z:
        return trace
    return replace(trace, elements=_csc(z, "e_"), element_mm2=float(z["element_mm2"]))


def _csc(z: Any, prefix: str) -> sp.csc_array:
    """The csc array stored under `prefix` (data, indices, indptr, shape) in npz `z`."""
    shape = (int(z[prefix + "shape"][0]), int(z[prefix + "shape"][1]))
    arrays = (z[prefix + "data"], z[prefix + "indices"], z[prefix + "indptr"])
    return sp.csc_array(arrays, shape=shape)


def get_trace(store: Store, trace: str) -> Trace:
    """The assembled R of a trace and its figures."""
    return trace_from_bytes(store.get(counts_key(trace)))


def get_plan(store: Store, plan: str) -> PlanDocument:
    """The stored plan document."""
    return PlanDocument.model_validate_json(store.get(plan_key(plan)))


def put_scene(store: Store, plan: str, scene: bytes) -> bytes:
    """Store a plan's packed scene gzipped (level 1: about 2.7× smaller, 0.4 s for 32 MB)."""
    data = gzip.compress(scene, compresslevel=1, mtime=0)
    store.put(scene_key(plan), data)
    return data


def put_plan(store: Store, plan: str, doc: PlanDocument) -> None:
    """Store the plan document."""
    store.put(plan_key(plan), doc.model_dump_json().encode())
