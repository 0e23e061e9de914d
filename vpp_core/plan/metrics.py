"""Metrics of a selection J* (SPEC §5): coverage, resolution met, histogram, the paper's C_j.

Denominators are the *counted* faces (area > 0, not a duplicate of an earlier face) and
their area: a zero-area face can hold no defect and a duplicate must not count twice.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from pydantic import BaseModel

from vpp_core.cover.density import density_matrix, meets

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


class Metrics(BaseModel):
    """All metrics of a plan."""

    coverage: CoverageMetrics
    resolution: ResolutionMetrics
    paper: PaperMetrics


def evaluate(
    counts: sp.sparray,
    areas: np.ndarray,
    counted: np.ndarray,
    selected: np.ndarray,
    resolution_mm: float,
) -> Metrics:
    """Metrics of the views `selected` (K,) given R (M, N), areas (M,) mm² and counted (M,)."""
    r = sp.csc_array(counts)
    delta = density_matrix(r, areas)
    best = np.asarray(delta.sum(axis=1)).ravel()
    achieved = np.asarray(delta[:, selected].sum(axis=1)).ravel()
    seen_any = seen(r, np.arange(r.shape[1]))
    seen_sel = seen(r, selected)
    target = 1.0 / resolution_mm
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
            histogram=histogram(achieved, w, counted, resolution_mm),
        ),
        paper=_paper(r, selected),
    )


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


def seen(r: sp.csc_array, columns: np.ndarray) -> np.ndarray:
    """(M,) bool: face hit by at least one valid ray of the given views."""
    sub = sp.csr_array(r[:, columns])
    return np.asarray(np.diff(sub.indptr) > 0)


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
