"""V, δ, S (SPEC §3) against the formulas written out densely, and the metrics' sums."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from vpp_core.cover.density import cover_model, density_sum
from vpp_core.plan.metrics import evaluate, seen


def random_counts(seed: int, m: int = 60, n: int = 8) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    r = rng.integers(0, 40, (m, n)) * (rng.random((m, n)) < 0.35)
    areas = rng.uniform(0.5, 20.0, m)
    areas[:3] = 0.0  # zero-area faces
    r[3:6] = 0  # unseen faces
    return r.astype(np.int32), areas


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("res", [0.15, 0.4, 1.0])
def test_s_matches_the_spec_formula(seed, res):
    r, areas = random_counts(seed)
    counted = areas > 0
    model = cover_model(sp.csc_array(r), areas, counted, res, "density")
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(areas[:, None] > 0, np.sqrt(r / areas[:, None]), 0.0)
    target = 1 / res
    v = (r > 0).astype(float)
    s = np.where((delta.sum(1) >= target)[:, None], np.minimum(1, delta / target), v)
    seen = r.any(axis=1)
    assert model.faces.tolist() == np.flatnonzero(seen).tolist()
    assert np.allclose(model.matrix.toarray(), s[seen])
    assert model.uncoverable.tolist() == np.flatnonzero(counted & ~seen).tolist()
    assert model.matrix.max() <= 1.0 and model.matrix.min() >= 0.0
    dense = (delta.sum(1) >= target * (1 - 1e-9)) & (areas > 0)
    assert np.array_equal(model.density_rows, dense[seen])
    assert np.all(model.matrix.data > 0)  # no stored zeros


def test_visibility_rows_are_zero_one():
    r, areas = random_counts(1)
    model = cover_model(sp.csc_array(r), areas, areas > 0, 0.2, "visibility")
    seen = r.any(axis=1)
    assert np.array_equal(model.matrix.toarray(), (r[seen] > 0).astype(float))
    assert not model.density_rows.any()


def test_zero_area_faces_get_a_visibility_row_only():
    r = np.array([[5, 0], [0, 9]], dtype=np.int32)
    areas = np.array([0.0, 1.0])
    model = cover_model(sp.csc_array(r), areas, areas > 0, 0.5, "density")
    assert model.matrix.toarray().tolist() == [[1.0, 0.0], [0.0, 1.0]]
    assert model.density_rows.tolist() == [False, True]


def test_density_is_sqrt_counts_over_area():
    r = np.array([[4, 0], [0, 9]], dtype=np.int32)
    r, areas = sp.csc_array(r), np.array([1.0, 4.0])
    d = [density_sum(r[:, [j]], areas).tolist() for j in range(2)]  # δ by columns
    assert np.array(d).T.tolist() == [[2.0, 0.0], [0.0, 1.5]]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_density_sums_and_seen_faces_agree_with_the_dense_formulas(seed):
    # the metrics add δ over R's entries without converting R by rows: Σ_j sqrt(R_ij / A_i)
    # per face (0 on zero-area faces) and "a view's ray landed" per face, written out densely;
    # and those of δ built as a csr matrix (diag(1/A) R, square-rooted) summed by rows
    r, areas = random_counts(seed)
    sparse = sp.csc_array(r)
    dense = np.where(areas[:, None] > 0, np.sqrt(r / np.where(areas > 0, areas, 1.0)[:, None]), 0)
    cols = np.array([1, 4, 6])
    assert np.allclose(density_sum(sparse, areas), dense.sum(axis=1), rtol=1e-14, atol=0)
    assert np.allclose(density_sum(sparse[:, cols], areas), dense[:, cols].sum(axis=1))
    by_rows = sp.csr_array(sp.diags_array(1 / np.where(areas > 0, areas, np.inf)) @ sparse)
    by_rows.data = np.sqrt(by_rows.data)
    assert np.allclose(density_sum(sparse, areas), by_rows.sum(axis=1), rtol=1e-14, atol=0)
    assert seen(sparse[:, cols]).tolist() == (r[:, cols] > 0).any(axis=1).tolist()
    assert seen(sparse).tolist() == (r > 0).any(axis=1).tolist()
    stored_zero = sp.csc_array((np.array([0, 3]), np.array([0, 1]), np.array([0, 2])), (2, 1))
    assert seen(stored_zero).tolist() == [False, True]  # a stored 0 is no ray


def test_metrics_on_a_hand_example():
    # faces: 0 seen by view 0 (δ=2), 1 by views 0+1 (δ=1+1), 2 by view 1 (δ=0.5), 3 unseen
    r = np.array([[4, 0], [1, 1], [0, 1], [0, 0]], dtype=np.int32)
    areas = np.array([1.0, 1.0, 4.0, 2.0])
    counted = np.ones(4, bool)
    m = evaluate(sp.csc_array(r), areas, counted, np.array([0]), resolution_mm=0.5)
    assert m.coverage.faces == pytest.approx(2 / 4) and m.coverage.area == pytest.approx(2 / 8)
    assert m.coverage.max_faces == pytest.approx(3 / 4)
    assert m.coverage.max_area == pytest.approx(6 / 8)
    # target δ̄ = 2: view 0 alone gives face 0 δ 2 (met) and face 1 δ 1 (not met)
    assert m.resolution.met_faces == pytest.approx(1 / 4)
    assert m.resolution.max_met_faces == pytest.approx(2 / 4)  # faces 0 and 1 with both views
    assert m.paper.C_per_viewpoint == [pytest.approx(2 / 4)]
    h = m.resolution.histogram
    assert sum(h.faces) + h.overflow_faces + h.unseen_faces == 4
    assert sum(h.area_mm2) + h.overflow_area_mm2 + h.unseen_area_mm2 == pytest.approx(8.0)
    assert m.resolution.median_mm == pytest.approx(0.75)  # r* = 0.5 and 1.0


def test_a_patch_centre_beside_or_behind_a_view_gets_a_finite_density_and_no_nan():
    """A patch larger than the stand-off can have its centre beside or behind a view that
    lands rays on it (a part many metres across): its ray density there is finite and huge,
    so the view samples a vanishing share of it, and a row no view samples any share of gets
    S = 0, not NaN."""
    import warnings

    from vpp_core.camera.pose import make_viewpoints
    from vpp_core.camera.sensor import Sensor
    from vpp_core.cover.density import Cameras, s_entries

    sensor = Sensor()
    cams = Cameras(make_viewpoints(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]])), sensor)
    ahead, beside, behind = [0.0, 0.0, 400.0], [500.0, 0.0, 0.0], [0.0, 0.0, -400.0]
    normals = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    counts = sp.csr_array(([10.0, 10.0], [0, 0], [0, 1, 2]), shape=(2, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no division by zero, no overflow
        rho = cams.ray_density(np.array([ahead, beside, behind]), normals, np.zeros(3, int))
        s = s_entries(counts, np.ones(2), np.full(2, 0.18), np.array([0.5, 0.0]))
    assert rho[0] == pytest.approx(sensor.fx * sensor.fy / 400.0**2)  # head-on: f² / z²
    assert np.all(np.isfinite(rho)) and rho[1] > 1e12 * rho[0] and rho[2] > 1e12 * rho[0]
    assert np.all(np.isfinite(s)) and s[0] > 0 and s[1] == 0.0
