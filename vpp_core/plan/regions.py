"""Regions of interest: faces selected by label, face ids, a box or a sphere, each region with
its own target resolution (mm) or ignored.

A face belongs to a box or a sphere when its centroid (the mean of its corners, part frame,
mm) lies inside (boundary included). Regions are applied in order, so where they overlap the
later one wins; faces no region selects take the request's default target. Ignored faces are
not counted at all: no cover row, not in any coverage denominator, listed in the plan's
`regions` as ignored.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Annotated

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

from vpp_core.errors import RegionError
from vpp_core.mesh.part import Part
from vpp_core.mesh.refine import Elements

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
MAX_REGIONS = 256
"""Regions per request at most."""
DEFAULT_NAME = "default"
"""The name the metrics give the faces no region selects."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class RegionBox(_Strict):
    """An axis-aligned box in the part frame (mm)."""

    min: Vec3
    max: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> RegionBox:
        if any(a > b for a, b in zip(self.min, self.max, strict=True)):
            raise ValueError(f"box min {self.min} must not exceed max {self.max} on any axis")
        return self


class RegionSphere(_Strict):
    """A ball in the part frame: centre (mm) and radius (mm)."""

    centre: Vec3
    radius_mm: float = Field(gt=0)


class Region(_Strict):
    """One region: a name, exactly one selection, and its `resolution_mm` or `ignore: true`."""

    name: str = Field(min_length=1, max_length=100)
    faces: list[Annotated[int, Field(ge=0)]] | None = Field(
        None, description="face ids (0-based, in the mesh's face order)"
    )
    box: RegionBox | None = Field(None, description="faces whose centroid lies in this box")
    sphere: RegionSphere | None = Field(None, description="faces whose centroid lies in this ball")
    label: int | str | None = Field(
        None,
        description="faces carrying this label: an integer, or a group / material / primitive "
        "name read from the file",
    )
    resolution_mm: float | None = Field(None, gt=0, le=1e4)
    ignore: bool = False

    @model_validator(mode="after")
    def _one_of_each(self) -> Region:
        chosen = [k for k in ("faces", "box", "sphere", "label") if getattr(self, k) is not None]
        if len(chosen) != 1:
            raise ValueError(
                f"region {self.name!r} needs exactly one of faces, box, sphere, label "
                f"(got {', '.join(chosen) or 'none'})"
            )
        if self.ignore and self.resolution_mm is not None:
            raise ValueError(f"region {self.name!r}: give resolution_mm or ignore, not both")
        if not self.ignore and self.resolution_mm is None:
            raise ValueError(f"region {self.name!r} needs resolution_mm or ignore: true")
        return self


def check_regions(regions: list[Region]) -> None:
    """ValueError on more than MAX_REGIONS regions or repeated names."""
    if len(regions) > MAX_REGIONS:
        raise ValueError(f"{len(regions)} regions exceed the limit of {MAX_REGIONS}")
    if any(r.name == DEFAULT_NAME for r in regions):
        raise ValueError(f"the region name {DEFAULT_NAME!r} is reserved for the unselected faces")
    names = [r.name for r in regions]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"region names must be unique: {', '.join(map(repr, dup))}")


def finest(default_mm: float, regions: list[Region]) -> float:
    """The finest resolution (mm) asked anywhere: the default and every region not ignored."""
    return min([default_mm, *(r.resolution_mm for r in regions if r.resolution_mm)])


@dataclass(frozen=True, eq=False)
class FaceTargets:
    """Each face's region and target, and the part with ignored faces no longer counted."""

    part: Part
    """The part as planned: `counted` without the ignored faces."""
    whole: Part
    """The part as loaded."""
    region: NDArray[np.int64]
    """(M,) index into the request's regions, -1 for the default target."""
    resolution_mm: NDArray[np.float64]
    """(M,) target resolution r̄_f of each face, mm (the default's for ignored faces)."""
    ignored: NDArray[np.bool_]
    """(M,) faces an ignoring region selects."""
    warnings: tuple[str, ...] = ()

    @property
    def uniform(self) -> bool:
        """True when every face has the same target and none is ignored (no regions)."""
        return bool(not self.ignored.any() and np.all(self.resolution_mm == self.resolution_mm[0]))

    def region_rows(
        self, face_row: NDArray[np.int64], faces: NDArray[np.int64], rows: int
    ) -> NDArray[np.bool_]:
        """(rows,) bool: cover rows holding faces of a region with its own target (a cover
        model's `faces` and their `face_row`)."""
        out = np.zeros(rows, dtype=bool)
        out[face_row[(self.region[faces] >= 0) & ~self.ignored[faces]]] = True
        return out

    def of_elements(self, elements: Elements) -> FaceTargets:
        """The same targets on the part's area `elements`: each element its face's."""
        parent = elements.parent
        ignored = self.ignored[parent]
        whole = elements.part
        counted = whole.counted & ~ignored
        counted.setflags(write=False)
        planned = replace(whole, counted=counted) if ignored.any() else whole
        res = self.resolution_mm[parent]
        return FaceTargets(planned, whole, self.region[parent], res, ignored, self.warnings)

    def groups(self) -> NDArray[np.int64]:
        """(M,) group of each face (0, 1, ...): faces of one group share a target."""
        _, inverse = np.unique(self.region, return_inverse=True)
        return np.asarray(inverse, dtype=np.int64).reshape(-1)


def face_targets(part: Part, default_mm: float, regions: list[Region] | None) -> FaceTargets:
    """Resolve `regions` on `part` (later regions win) into per-face targets (see module doc)."""
    m = part.n_faces
    region = np.full(m, -1, dtype=np.int64)
    warnings: list[str] = []
    centroids = part.vertices[part.faces].mean(axis=1)
    for k, r in enumerate(regions or []):
        chosen = _selected(part, centroids, r)
        if not (chosen & part.counted).any():
            warnings.append(f"region {r.name!r} selects no counted face")
        region[chosen] = k
    res = np.full(m, float(default_mm))
    ignored = np.zeros(m, dtype=bool)
    for k, r in enumerate(regions or []):
        mine = region == k
        ignored[mine] = r.ignore
        if r.resolution_mm is not None:
            res[mine] = r.resolution_mm
    counted = part.counted & ~ignored
    if not counted.any():
        raise RegionError("the regions ignore every counted face: nothing is left to plan")
    counted.setflags(write=False)
    res.setflags(write=False)
    planned = replace(part, counted=counted) if ignored.any() else part
    return FaceTargets(planned, part, region, res, ignored, tuple(warnings))


def _selected(part: Part, centroids: NDArray[np.float64], r: Region) -> NDArray[np.bool_]:
    """(M,) bool: the faces region `r` selects (RegionError where it does not fit the part)."""
    m = part.n_faces
    out = np.zeros(m, dtype=bool)
    if r.faces is not None:
        ids = np.asarray(r.faces, dtype=np.int64)
        if len(ids) and ids.max() >= m:
            raise RegionError(
                f"region {r.name!r}: face id {int(ids.max())} out of range (the mesh has {m} "
                f"faces, ids 0..{m - 1})"
            )
        out[ids] = True
    elif r.box is not None:
        lo, hi = np.array(r.box.min), np.array(r.box.max)
        out = np.all((centroids >= lo) & (centroids <= hi), axis=1)
    elif r.sphere is not None:
        d = np.linalg.norm(centroids - np.array(r.sphere.centre), axis=1)
        out = d <= r.sphere.radius_mm
    else:
        out = _label_mask(part, r)
    return out


def _label_mask(part: Part, r: Region) -> NDArray[np.bool_]:
    """(M,) bool: the faces carrying region `r`'s label."""
    labels = part.labels
    assert r.label is not None
    if labels is None:
        raise RegionError(
            f"region {r.name!r} selects label {r.label!r} but the mesh has no face labels "
            "(a PLY face property, OBJ groups, glTF primitives, or a labels array uploaded "
            "with the mesh, passed as labels_id)"
        )
    value = labels.label_of(r.label)
    if value is None:
        known = sorted(set(np.unique(labels.values).tolist()) - {-1})
        names = [f"{k} ({labels.names[k]})" if k in labels.names else str(k) for k in known]
        raise RegionError(
            f"region {r.name!r}: unknown label {r.label!r}; the mesh's labels are "
            f"{', '.join(names[:20]) or 'none'}"
        )
    return np.asarray(labels.values == value)


def mandatory_weights(
    weights: NDArray[np.float64], mandatory: NDArray[np.bool_], fraction: float
) -> tuple[NDArray[np.float64], float]:
    """Row weights and fraction for a partial cover (vpp_core.cover.partial) that satisfies
    every `mandatory` row and `fraction` of the other rows' weight: each mandatory row weighs
    more than what may be left out, (1 - f) of the others' total, and the fraction is set so
    that exactly that much may be left out, which then only the other rows can give."""
    if fraction >= 1.0 or not mandatory.any():
        return weights, fraction
    slack = (1.0 - fraction) * float(weights[~mandatory].sum())
    out = weights.copy()
    out[mandatory] = np.maximum(weights[mandatory], 0.0) + 2.0 * slack + 1.0
    total = float(out.sum())
    return out, (1.0 - slack / total if total > 0 else 1.0)
