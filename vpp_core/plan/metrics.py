"""Metrics of a selection J* (SPEC §5): coverage, resolution met, histogram, the paper's C_j.

Denominators are the *counted* faces (area > 0, not a duplicate of an earlier face) and
their area: a zero-area face can hold no defect and a duplicate must not count twice.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from pydantic import BaseModel

from vpp_core.cover.density import density_sum, meets

HIST_BINS = 30
HIST_SPAN = 3.0
"""Histogram of r* over [0, HIST_SPAN · r̄] in HIST_BINS bins, plus an overflow bin."""


class CoverageMetrics(BaseModel):
    """Fractions of counted faces / area seen by ≥ 1 selected view; max_* by any candidate."""

    faces: float
    area: float
    max_faces: float
    max_area: float


class Histogram(BaseModel):
    """Achieved resolution r* per face (mm): bin edges, face counts and area per bin."""

    edges_mm: list[float]
    faces: list[int]
    area_mm2: list[float]
    overflow_faces: int
    overflow_area_mm2: float
    unseen_faces: int
    unseen_area_mm2: float


class ResolutionMetrics(BaseModel):
    """Fractions of counted faces / area with r*_i ≤ r̄; max_* reachable with all candidates."""

    met_faces: float
    met_area: float
    max_met_faces: float
    max_met_area: float
    median_mm: float | None
    histogram: Histogram


class PaperMetrics(BaseModel):
    """The paper's eq. (3) C_j = (1/M) Σ_i V_ij per selected view, and eq. (4) their mean."""

    C_per_viewpoint: list[float]
    C_mean: float


class RegionMetrics(BaseModel):
    """One region's figures: fractions of its counted area (coverage_area: seen by a selected
    view; met_area: r*_f ≤ its own resolution_mm; max_met_area: with every candidate)."""

    name: str
    resolution_mm: float | None
    """The region's target (mm); None for an ignored region."""
    ignored: bool = False
    """Ignored regions count nowhere; their figures are what the plan happens to see."""
    faces: int
    """Faces of the region (after later regions took theirs), counted ones only."""
    area_mm2: float
    coverage_area: float
    met_area: float
    max_met_area: float
    coverage_faces: float
    met_faces: float
    met_area_mm2: float
    median_mm: float | None
    histogram: Histogram
    """r* of the region's faces over [0, 3 × its resolution]."""


class Metrics(BaseModel):
    """All metrics of a plan."""

    coverage: CoverageMetrics
    resolution: ResolutionMetrics
    paper: PaperMetrics
    regions: list[RegionMetrics] = []
    """Per region (the request's `regions`, then `default`: the faces no region selects);
    empty without regions."""


def evaluate(
    counts: sp.sparray,
    areas: np.ndarray,
    counted: np.ndarray,
    selected: np.ndarray,
    resolution_mm: float | np.ndarray,
    default_mm: float | None = None,
) -> Metrics:
    """Metrics of the views `selected` (K,) given R (M, N), areas (M,) mm² and counted (M,),
    against a target r̄ (mm: one for all, or (M,) each face's own; met = r*_i ≤ r̄_i); the
    histogram spans 3 × `default_mm` (default: r̄)."""
    r = sp.csc_array(counts)
    chosen = r[:, selected]
    best, achieved = density_sum(r, areas), density_sum(chosen, areas)
    seen_any, seen_sel = seen(r), seen(chosen)
    target = 1.0 / np.asarray(resolution_mm, dtype=np.float64)
    span = float(resolution_mm) if default_mm is None else default_mm
    w = areas * counted
    return Metrics(
        coverage=CoverageMetrics(
            faces=_frac(seen_sel, counted),
            area=_frac(seen_sel, w),
            max_faces=_frac(seen_any, counted),
            max_area=_frac(seen_any, w),
        ),
        resolution=ResolutionMetrics(
            met_faces=_frac(meets(achieved, target), counted),
            met_area=_frac(meets(achieved, target), w),
            max_met_faces=_frac(meets(best, target), counted),
            max_met_area=_frac(meets(best, target), w),
            median_mm=_median_resolution(achieved, counted & seen_sel),
            histogram=histogram(achieved, w, counted, span),
        ),
        paper=_paper(r, selected),
    )


def region_metrics(
    counts: sp.sparray,
    areas: np.ndarray,
    counted: np.ndarray,
    selected: np.ndarray,
    members: list[tuple[str, float | None, np.ndarray]],
) -> list[RegionMetrics]:
    """Per region (name, its resolution mm or None when ignored, (M,) bool faces): its
    coverage and met fractions, each face against the region's own target (counted faces
    only; an ignored region's faces are judged against nothing but seen or not)."""
    r = sp.csc_array(counts)
    chosen = r[:, selected]
    best, achieved = density_sum(r, areas), density_sum(chosen, areas)
    seen_sel = seen(chosen)
    out = []
    for name, res, faces in members:
        mine = faces & counted
        w = areas * mine
        met = meets(achieved, 1.0 / res) if res else np.zeros(len(areas), bool)
        met_best = meets(best, 1.0 / res) if res else np.zeros(len(areas), bool)
        out.append(
            RegionMetrics(
                name=name,
                resolution_mm=res,
                ignored=res is None,
                faces=int(mine.sum()),
                area_mm2=float(w.sum()),
                coverage_area=_frac(seen_sel, w),
                met_area=_frac(met, w),
                max_met_area=_frac(met_best, w),
                coverage_faces=_frac(seen_sel, mine),
                met_faces=_frac(met, mine),
                met_area_mm2=float(w[met].sum()),
                median_mm=_median_resolution(achieved, mine & seen_sel),
                histogram=histogram(achieved, w, mine, res or 1.0),
            )
        )
    return out


def resolution_mm(density: np.ndarray) -> np.ndarray:
    """(M,) achieved resolution r* = 1/δ* in mm, inf where δ* = 0."""
    with np.errstate(divide="ignore"):
        return np.where(density > 0, 1.0 / np.maximum(density, 1e-300), np.inf)


def histogram(
    achieved: np.ndarray, weights: np.ndarray, counted: np.ndarray, resolution: float
) -> Histogram:
    """Histogram of r* over counted faces, by count and by area (mm²)."""
    r = resolution_mm(achieved)[counted]
    w = weights[counted]
    edges = np.linspace(0.0, HIST_SPAN * resolution, HIST_BINS + 1)
    finite = np.isfinite(r)
    inside = finite & (r <= edges[-1])
    faces, _ = np.histogram(r[inside], bins=edges)
    area, _ = np.histogram(r[inside], bins=edges, weights=w[inside])
    over = finite & ~inside
    return Histogram(
        edges_mm=edges.tolist(),
        faces=faces.tolist(),
        area_mm2=area.tolist(),
        overflow_faces=int(over.sum()),
        overflow_area_mm2=float(w[over].sum()),
        unseen_faces=int((~finite).sum()),
        unseen_area_mm2=float(w[~finite].sum()),
    )


def seen(r: sp.csc_array) -> np.ndarray:
    """(M,) bool: face hit by at least one valid ray of the views R (M, K) holds (csc: its
    columns, say R[:, selected], sliced by the caller)."""
    hit = np.zeros(r.shape[0], dtype=bool)
    hit[r.indices[r.data != 0]] = True
    return hit


def _frac(mask: np.ndarray, weights: np.ndarray) -> float:
    """Weighted fraction of `mask` (weights bool or float); 0 when the total is 0."""
    total = float(np.sum(weights))
    return float(np.sum(weights * mask)) / total if total > 0 else 0.0


def _median_resolution(achieved: np.ndarray, faces: np.ndarray) -> float | None:
    """Median r* (mm) over the given faces; None when there are none."""
    return float(np.median(resolution_mm(achieved[faces]))) if faces.any() else None


def _paper(r: sp.csc_array, selected: np.ndarray) -> PaperMetrics:
    """C_j (eq. 3) over all M faces for each selected view, and C (eq. 4)."""
    nnz = np.diff(r.indptr)[selected] if len(selected) else np.empty(0)
    per_view = (nnz / max(r.shape[0], 1)).tolist()
    return PaperMetrics(
        C_per_viewpoint=per_view, C_mean=float(np.mean(per_view)) if per_view else 0.0
    )
