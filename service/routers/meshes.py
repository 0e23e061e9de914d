"""/v1/meshes: upload a part once, refer to it by its content id."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, File, Form, Header, Response, UploadFile

from service import planning
from service.deps import SettingsDep, StoreDep
from service.models import LabelsSummary, MeshSummary, Problem
from service.routers.plans import named_forever
from vpp_core.errors import TooLargeError

COPY_CHUNK = 1 << 20
"""Bytes per read and write when a big upload is copied for its parsing child."""

router = APIRouter(prefix="/v1/meshes", tags=["meshes"])
ERRORS = {c: {"model": Problem, "content": {"application/problem+json": {}}} for c in (413, 422)}


@router.post("", status_code=201, response_model=MeshSummary, responses=ERRORS)  # type: ignore[arg-type]
def upload_mesh(
    response: Response,
    store: StoreDep,
    settings: SettingsDep,
    file: Annotated[
        UploadFile,
        File(
            description="STL, OBJ, PLY, OFF, GLB or GLTF",
            json_schema_extra={"format": "binary"},  # what client generators read as a file
        ),
    ],
    units: Annotated[str, Form(description="units of the file: mm, cm, m, in")] = "mm",
    format: Annotated[
        str | None, Form(description="format when the filename does not tell")
    ] = None,
    max_face_area_mm2: Annotated[
        float | None,
        Form(
            gt=0,
            allow_inf_nan=False,
            description="split faces larger than this (mm²), or with an edge longer than "
            "2·sqrt(this) mm, before storing: area elements for CAD exports with big facets "
            "and slivers (docs/cad-meshes.md); 1 for the paper camera",
        ),
    ] = None,
    remesh_mm: Annotated[
        float | None,
        Form(
            gt=0,
            allow_inf_nan=False,
            description="remesh isotropically with edges of about this many mm (sharp "
            "features kept) before storing: the view count then belongs to the surface, not "
            "to how it was exported (docs/cad-meshes.md); 1 for the paper camera",
        ),
    ] = None,
    labels: Annotated[
        UploadFile | str | None,
        File(
            description="region labels, one int per face of the file in its face order (-1: "
            "none): a JSON array (file or plain field) or a .npy file; they replace labels the "
            "file carries (PLY face property, OBJ groups, glTF primitives). The answer's "
            "`labels.id` names them for plan requests (`labels_id`); the mesh id stays the "
            "geometry's",
            json_schema_extra={"format": "binary"},
        ),
    ] = None,
) -> MeshSummary:
    """Upload a mesh; the same geometry again gives the same id and stores nothing new."""
    label_bytes = _label_bytes(labels, settings.max_upload_bytes)
    with upload_source(file, settings.max_upload_bytes, settings.parse_child_bytes) as data:
        summary = planning.upload_mesh(
            store,
            settings,
            data,
            file.filename,
            format,
            units,
            max_face_area_mm2,
            remesh_mm,
            label_bytes,
        )
    response.headers["Location"] = f"/v1/meshes/{summary.id}"
    response.headers["ETag"] = f'"{summary.id}"'
    return summary


def _label_bytes(labels: UploadFile | str | None, max_bytes: int) -> bytes | None:
    """The `labels` part's bytes: an uploaded file, or a plain form field (a JSON array)."""
    if labels is None or labels == "":
        return None
    if isinstance(labels, str):
        if len(labels) > max_bytes:
            raise TooLargeError(f"labels of {len(labels)} bytes exceed the limit of {max_bytes}")
        return labels.encode()
    return read_spooled(labels, max_bytes)


def read_spooled(upload: UploadFile, max_bytes: int) -> bytes:
    """The uploaded file's bytes, read in one go from the temporary file it was streamed to (one
    buffer of its size); TooLargeError when it is over `max_bytes`, unread."""
    size = _spooled_size(upload, max_bytes)
    return upload.file.read(size)


@contextmanager
def upload_source(upload: UploadFile, max_bytes: int, child_bytes: int) -> Iterator[bytes | Path]:
    """The uploaded file's bytes (`read_spooled`), or from `child_bytes` on the path of a named
    copy of it, deleted afterwards, for a child process to parse (service/parsing.py): the
    API then never holds the file (the copy goes in COPY_CHUNK pieces, each with the GIL
    released while it is read and written)."""
    size = _spooled_size(upload, max_bytes)
    if size < child_bytes:
        yield upload.file.read(size)
        return
    with tempfile.NamedTemporaryFile(prefix="vpp-upload-") as copy:
        shutil.copyfileobj(upload.file, copy, COPY_CHUNK)
        copy.flush()
        yield Path(copy.name)


def _spooled_size(upload: UploadFile, max_bytes: int) -> int:
    """The spooled file's size, rewound to its start; TooLargeError over `max_bytes`."""
    spool = upload.file
    spool.seek(0, os.SEEK_END)
    size = spool.tell()
    if size > max_bytes:
        raise TooLargeError(f"upload of {size} bytes exceeds the limit of {max_bytes} bytes")
    spool.seek(0)
    return size


@router.get("/{mesh_id}", response_model=MeshSummary, responses={404: {"model": Problem}})
def get_mesh(mesh_id: str, store: StoreDep, response: Response) -> MeshSummary:
    """The summary of an uploaded mesh."""
    summary = planning.get_mesh(store, mesh_id)
    response.headers["ETag"] = f'"{summary.id}"'
    return summary


@router.get(
    "/{mesh_id}/labels/{labels_id}",
    response_model=LabelsSummary,
    responses={404: {"model": Problem}},
)
def get_labels(mesh_id: str, labels_id: str, store: StoreDep) -> LabelsSummary:
    """A label set of the mesh: where it came from and the faces and area of each label."""
    return planning.get_labels(store, mesh_id, labels_id)


PLY = "application/vnd.ply"
"""No IANA type for PLY; this is the one in common use."""


@router.get(
    "/{mesh_id}/mesh.ply",
    response_class=Response,
    responses={
        200: {"content": {PLY: {}}},
        304: {"description": "Not modified"},
        404: {"model": Problem},
    },
)
def get_mesh_ply(
    mesh_id: str, store: StoreDep, if_none_match: Annotated[str | None, Header()] = None
) -> Response:
    """The stored mesh, as planned (after `remesh_mm`, `max_face_area_mm2`): exact binary PLY."""
    return named_forever(
        (mesh_id, "mesh"), if_none_match, partial(planning.mesh_ply, store, mesh_id), PLY
    )
