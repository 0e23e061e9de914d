"""Per-face region labels: read from the mesh file or from an uploaded label array.

A label is an integer per face (-1: unlabelled), optionally with a name. Sources:

- PLY: a face property named one of LABEL_PROPERTIES (`label`, `region`, ...), integers
  (negative ones: unlabelled).
- OBJ: the `g` group of each face (else its `usemtl` material, else its `o` object); names are
  numbered 0, 1, ... in order of first appearance and keep their names.
- GLB/GLTF: the primitive (geometry) a face belongs to, numbered in order of their names.
- An uploaded array (JSON list of ints or a .npy file), one int per face in the file's face
  order (the planned face order: remeshing drops labels, splitting faces keeps them).

trimesh may reorder an OBJ's or glTF's faces when it joins groups and primitives into one
mesh; labels are mapped onto its faces by their corner coordinates (order and winding
ignored), so they follow the faces whatever order it chose.
"""

from __future__ import annotations

import hashlib
import io
import json
import re
from dataclasses import dataclass, field

import numpy as np
import trimesh
from numpy.typing import NDArray

from vpp_core.errors import MeshError

I64 = NDArray[np.int64]
F64 = NDArray[np.float64]

LABEL_PROPERTIES = ("label", "labels", "region", "region_id", "group", "segment", "part_id")
"""PLY face properties read as labels, first found wins."""
MAX_LABEL = 2**31 - 1
"""Largest accepted label value; -1 is unlabelled, other negatives are refused."""
LABELS_PREFIX = b"vpp-labels-v1"
"""Version tag hashed in front of a label set's arrays (its content id)."""


@dataclass(frozen=True, eq=False)
class FaceLabels:
    """Labels of a part's faces."""

    values: I64
    """(M,) int64 label per face, -1 unlabelled."""
    names: dict[int, str] = field(default_factory=dict)
    """Names of labels read from groups, materials or primitives."""
    source: str = "upload"
    """Where they came from: `upload`, `ply:<property>`, `obj:groups`, `obj:materials`, ..."""

    def content_id(self, mesh_id: str) -> str:
        """SHA-256 of the mesh id, the values and the names: two label sets of one mesh differ."""
        h = hashlib.sha256(LABELS_PREFIX + mesh_id.encode())
        h.update(np.ascontiguousarray(self.values, dtype="<i8").tobytes())
        h.update(json.dumps(sorted(self.names.items())).encode())
        return h.hexdigest()

    def label_of(self, key: int | str) -> int | None:
        """The label value of `key` (an int, or a name), None when no face carries it."""
        if isinstance(key, str):
            found = [k for k, name in self.names.items() if name == key]
            return found[0] if found else None
        return key if bool(np.any(self.values == key)) else None


def file_labels(data: bytes, fmt: str, vertices: F64, faces: I64) -> FaceLabels | None:
    """The labels a mesh file carries for the parsed (V, 3) vertices and (M, 3) faces, or None."""
    try:
        if fmt == "ply":
            return _ply_labels(data, len(faces))
        if fmt == "obj":
            return _obj_labels(data, vertices, faces)
        if fmt in ("glb", "gltf"):
            return _gltf_labels(data, fmt, vertices, faces)
    except MeshError:
        raise
    except Exception:  # labels are extra: a file trimesh read as a mesh stays a mesh
        return None
    return None


def parse_label_array(data: bytes, n_faces: int) -> I64:
    """(M,) int64 labels from a JSON list of ints or a .npy array; MeshError when malformed."""
    if data[:6] == b"\x93NUMPY":
        try:
            raw = np.load(io.BytesIO(data), allow_pickle=False)
        except Exception as exc:
            raise MeshError(f"labels: not a readable .npy array ({type(exc).__name__})") from exc
    else:
        try:
            raw = np.asarray(json.loads(data))
        except (ValueError, UnicodeDecodeError) as exc:
            raise MeshError("labels: neither a JSON array of integers nor a .npy file") from exc
    return checked_labels(raw, n_faces)


def checked_labels(raw: np.ndarray, n_faces: int) -> I64:
    """`raw` as (M,) int64 labels: one integer per face, each -1 or in [0, MAX_LABEL]."""
    arr = np.asarray(raw)
    if arr.ndim != 1 or len(arr) != n_faces:
        raise MeshError(f"labels: expected {n_faces} values (one per face), got shape {arr.shape}")
    if arr.dtype.kind == "f" and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr)):
        arr = arr.astype(np.int64)
    if arr.dtype.kind not in "iu":
        raise MeshError(f"labels: values must be integers, got {arr.dtype}")
    arr = arr.astype(np.int64)
    bad = np.flatnonzero((arr < -1) | (arr > MAX_LABEL))
    if len(bad):
        raise MeshError(
            f"labels: face {int(bad[0])} has label {int(arr[bad[0]])}; "
            f"labels are -1 (none) or 0..{MAX_LABEL}"
        )
    return arr


def _ply_labels(data: bytes, n_faces: int) -> FaceLabels | None:
    """The first integer face property of LABEL_PROPERTIES in a PLY file."""
    mesh = trimesh.load(io.BytesIO(data), file_type="ply", process=False, force="mesh")
    face = mesh.metadata.get("_ply_raw", {}).get("face", {}).get("data", {})
    fields = face.dtype.names or () if isinstance(face, np.ndarray) else tuple(face)
    for name in LABEL_PROPERTIES:
        if name in fields:  # ASCII: a dict of arrays; binary: a structured array
            values = np.asarray(face[name]).reshape(-1)
            if values.dtype.kind in "iu":  # a file's negative labels (-1, -100, ...) mean none
                values = np.where(values < 0, -1, values)
            return FaceLabels(checked_labels(values, n_faces), {}, f"ply:{name}")
    return None


_OBJ_TAGGED = re.compile(rb"^[ \t]*(?:g|o|usemtl)[ \t]", re.MULTILINE)
_OBJ_LINE = re.compile(r"^[ \t]*(v|f|g|o|usemtl)[ \t]+(.*)$", re.MULTILINE)


def _obj_labels(data: bytes, vertices: F64, faces: I64) -> FaceLabels | None:
    """Each face's `g` group (else `usemtl` material, else `o` object), mapped onto trimesh's
    faces by their corners."""
    if not _OBJ_TAGGED.search(data):  # no groups, materials or objects: nothing to parse
        return None
    text = data.decode("utf-8", errors="replace")
    coords: list[list[float]] = []
    tris: list[list[int]] = []
    current = {"g": "", "usemtl": "", "o": ""}
    tags: list[tuple[str, str, str]] = []
    for kind, rest in _OBJ_LINE.findall(text):
        if kind == "v":
            coords.append([float(x) for x in rest.split()[:3]])
        elif kind == "f":
            idx = [int(w.split("/")[0]) for w in rest.split()]
            idx = [i - 1 if i > 0 else len(coords) + i for i in idx]
            for k in range(1, len(idx) - 1):  # fan, as trimesh triangulates polygons
                tris.append([idx[0], idx[k], idx[k + 1]])
                tags.append((current["g"], current["usemtl"], current["o"]))
        else:
            current[kind] = rest.strip()
    for col, source in ((0, "obj:groups"), (1, "obj:materials"), (2, "obj:objects")):
        names = [t[col] for t in tags]
        if any(names):
            return _mapped(np.array(coords)[np.array(tris)], names, vertices[faces], source)
    return None


def _gltf_labels(data: bytes, fmt: str, vertices: F64, faces: I64) -> FaceLabels | None:
    """Each face's primitive (geometry name), mapped onto the joined mesh's faces by corners."""
    scene = trimesh.load(io.BytesIO(data), file_type=fmt, process=False, force="scene")
    if not isinstance(scene, trimesh.Scene):
        return None
    parts = [g for g in scene.dump(concatenate=False) if isinstance(g, trimesh.Trimesh)]
    if len(parts) < 2:
        return None
    corners = np.vstack([np.asarray(g.vertices)[np.asarray(g.faces)] for g in parts])
    names = [str(g.metadata.get("name", i)) for i, g in enumerate(parts) for _ in g.faces]
    return _mapped(corners, names, vertices[faces], "gltf:primitives")


def _mapped(corners: F64, names: list[str], targets: F64, source: str) -> FaceLabels:
    """Labels of `targets` (M, 3, 3) corners: the name of the source triangle (K, 3, 3) with the
    same corners; names numbered in order of first appearance, '' left unlabelled."""
    order = {n: i for i, n in enumerate(dict.fromkeys(n for n in names if n))}
    codes = np.array([order.get(n, -1) for n in names], dtype=np.int64)
    lookup = dict(zip(_keys(corners), codes.tolist(), strict=True))
    values = np.array([lookup.get(k, -1) for k in _keys(targets)], dtype=np.int64)
    return FaceLabels(values, {i: n for n, i in order.items()}, source)


def _keys(corners: F64) -> list[bytes]:
    """A key per triangle (K, 3, 3): its corners' float64 bytes, corners sorted."""
    c = np.ascontiguousarray(corners, dtype="<f8").reshape(len(corners), 3, 3) + 0.0
    order = np.lexsort((c[:, :, 2], c[:, :, 1], c[:, :, 0]), axis=1)
    s = np.take_along_axis(c, order[:, :, None], axis=1)
    return [row.tobytes() for row in np.ascontiguousarray(s)]
