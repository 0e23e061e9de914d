"""The plan document's record of the regions: members per region and the `regions` block."""

from __future__ import annotations

import numpy as np

from vpp_core.errors import VppError
from vpp_core.plan.document import PlanDocument, PlanRequest, RegionsInfo, Uncoverable
from vpp_core.plan.regions import DEFAULT_NAME, FaceTargets, Region


def region_members(
    targets: FaceTargets, regions: list[Region], default_mm: float
) -> list[tuple[str, float | None, np.ndarray]]:
    """(name, resolution mm or None when ignored, (M,) bool faces) per region, then the
    default (the faces no region selects, at `default_mm`)."""
    out: list[tuple[str, float | None, np.ndarray]] = [
        (r.name, None if r.ignore else r.resolution_mm, targets.region == k)
        for k, r in enumerate(regions)
    ]
    out.append((DEFAULT_NAME, default_mm, targets.region < 0))
    return out


def run_lengths(values: np.ndarray) -> list[int]:
    """[value, run, value, run, ...] of an (M,) int array, in order."""
    if not len(values):
        return []
    starts = np.flatnonzero(np.r_[True, values[1:] != values[:-1]])
    runs = np.diff(np.r_[starts, len(values)])
    return np.column_stack([values[starts], runs]).ravel().tolist()


def regions_info(targets: FaceTargets, request: PlanRequest) -> RegionsInfo:
    """The document's `regions` block: normalised regions, per-face region ids (run-length
    coded), the ignored faces, the labels' source and the warnings."""
    whole = targets.whole
    ignored = np.flatnonzero(targets.ignored & whole.counted)
    labels = whole.labels
    return RegionsInfo(
        regions=request.regions,
        default_resolution_mm=request.target.resolution_mm,
        face_region=run_lengths(targets.region),
        ignored=Uncoverable(
            faces=len(ignored), area_mm2=float(whole.areas[ignored].sum()), ids=ignored.tolist()
        ),
        labels=None
        if labels is None
        else {"source": labels.source, "names": {str(k): v for k, v in labels.names.items()}},
        warnings=list(targets.warnings),
    )


def face_regions(doc: PlanDocument, n_faces: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """From a plan document: (M,) region index (-1 default), (M,) target r̄_f (mm) and (M,)
    ignored, decoded from its `regions` block (no regions: all default)."""
    default = doc.target.resolution_mm
    info = doc.regions
    if info is None:
        return np.full(n_faces, -1), np.full(n_faces, default), np.zeros(n_faces, bool)
    region = np.repeat(np.array(info.face_region[::2]), np.array(info.face_region[1::2]))
    if len(region) != n_faces:
        raise VppError(f"plan regions cover {len(region)} faces, the mesh has {n_faces}")
    res = np.array([r.resolution_mm or default for r in info.regions] + [default])
    ignore = np.array([r.ignore for r in info.regions] + [False])
    return region, res[region], ignore[region]
