"""The plots as a person reads them: the viewer's colours, whole numbers of views, no blends."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from matplotlib.collections import PolyQuadMesh
from matplotlib.patches import Rectangle, StepPatch

from tests.test_plan_claims import stepped_part
from tests.test_studies import RESOLUTIONS, request
from vpp_core.report.plots import (
    PALETTE,
    bin_colours,
    histogram_figure,
    rgb,
    study_plots,
    sweep_figure,
)
from vpp_core.report.studies import resolution_sweep

PALETTE_JS = Path(__file__).resolve().parent.parent / "viewer" / "src" / "palette.js"


def _js_array(name: str) -> object:
    """The JSON value of `NAME = [...]` or `name: [...]` in palette.js."""
    text = PALETTE_JS.read_text()
    m = re.search(rf"\b{name}\s*[=:]\s*(\[[\d\s,\[\]]*\])", text)
    assert m, name
    return json.loads(m.group(1))


def test_the_plots_use_the_viewers_colours() -> None:
    assert _js_array("MET") == [list(c) for c in PALETTE["met"]]
    assert _js_array("UNMET") == [list(c) for c in PALETTE["unmet"]]
    for state in ("uncovered", "uncoverable", "excluded"):
        assert _js_array(state) == list(PALETTE[state]), state


def test_histogram_bins_wear_met_colours_below_the_target_and_unmet_ones_above() -> None:
    edges = np.linspace(0.0, 0.4, 21)
    colours = bin_colours(edges, 0.18)
    met_ramp = [rgb(c) for c in PALETTE["met"]]
    unmet_ramp = [rgb(c) for c in PALETTE["unmet"]]
    below = [c for c, hi in zip(colours, edges[1:], strict=True) if hi <= 0.18]
    above = [c for c, lo in zip(colours, edges[:-1], strict=True) if lo >= 0.2]
    assert below and above
    assert all(c[2] > c[0] for c in below)  # blue to green: more blue than red
    assert all(c[0] > c[2] for c in above)  # yellow to red
    assert below[0] == pytest.approx(met_ramp[0], abs=0.01)  # the finest bin: the darkest blue
    assert above[-1] == pytest.approx(unmet_ramp[-1], abs=0.05)  # the worst: darkest red


@pytest.fixture(scope="module")
def sweep():
    return resolution_sweep(stepped_part(), request(), RESOLUTIONS)


def test_the_sweep_counts_whole_views_names_its_part_and_shows_the_area_met(sweep) -> None:
    fig = sweep_figure(sweep, "bracket.stl")
    views, area = fig.axes
    views.figure.canvas.draw()
    ticks = [t for t in views.get_yticks() if views.get_ylim()[0] <= t <= views.get_ylim()[1]]
    assert ticks and all(float(t).is_integer() for t in ticks), ticks
    assert "bracket.stl" in fig.get_suptitle()
    # no request-target line: every line has as many points as there are resolutions
    assert all(len(line.get_xdata()) in (0, len(RESOLUTIONS)) for line in views.get_lines())
    met = {line.get_label(): list(line.get_ydata()) for line in area.get_lines()}
    for row in sweep.rows:
        got = met[f"{row.formulation}: area at r* ≤ r̄"]
        assert 100 * row.resolution.met_area in got
    # the formulations' markers differ in size, so one never hides the other
    sizes = {line.get_label(): line.get_markersize() for line in views.get_lines()}
    assert sizes["density"] != sizes["visibility"]


def test_study_histograms_are_outlines_and_a_plan_histogram_is_coloured_by_r(sweep) -> None:
    rows = [r for r in sweep.rows if r.resolution_mm == RESOLUTIONS[0]]
    two = histogram_figure([(r.formulation, r.histogram) for r in rows], RESOLUTIONS[0])
    patches = [p for p in two.axes[0].patches if isinstance(p, StepPatch)]
    assert len(patches) == 2 and not any(p.get_fill() for p in patches)  # no blended third colour
    one = histogram_figure([("density", rows[0].histogram)], RESOLUTIONS[0])
    bars = [p for p in one.axes[0].patches if isinstance(p, Rectangle)]
    edges = np.asarray(rows[0].histogram.edges_mm)
    expected = bin_colours(edges, RESOLUTIONS[0])
    np.testing.assert_allclose([p.get_facecolor()[:3] for p in bars], expected)
    assert not any(isinstance(c, PolyQuadMesh) for c in one.axes[0].collections)


def test_the_plots_render(sweep) -> None:
    pngs = study_plots(sweep, "bracket.stl")
    assert all(png.startswith(b"\x89PNG") for png in pngs.values())


def test_camera_numbers_sit_where_the_central_ray_meets_the_part() -> None:
    """cameras.png's close-up numbers each camera at its aim point on the part, not at the
    working distance along its gaze (off the part for a tilted or nearer camera)."""
    import trimesh

    from vpp_core.report.plots import _aim_points

    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    positions = np.array([[0.0, 0.0, 100.0], [0.0, 0.0, 100.0]])
    gazes = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # the second misses the box
    aims = _aim_points(box, positions, gazes, wd=300.0)
    np.testing.assert_allclose(aims[0], [0.0, 0.0, 5.0], atol=1e-9)  # the top face
    assert np.abs(aims[1]).max() <= 5.0 + 1e-9  # on the box, not 300 mm away


def _random_faces(n: int, target: float, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(state, r*) of n faces: every state, r* around the target (mm, float32 as stored)."""
    rng = np.random.default_rng(seed)
    state = rng.integers(0, 5, n).astype(np.uint8)
    r = (target * np.exp(rng.normal(0.0, 0.8, n))).astype(np.float32)
    r[state == 0] = np.minimum(r[state == 0], target)
    r[state == 1] = np.maximum(r[state == 1], target * 1.001)
    r[state >= 2] = np.inf
    return state, r


def test_face_colours_are_the_viewers_for_the_same_faces() -> None:
    """The plots colour a face as palette.js does (run by node on the same arrays)."""
    import shutil
    import subprocess

    from vpp_core.report.plots import face_colours

    node = shutil.which("node")
    if not node:
        pytest.skip("no node to run viewer/src/palette.js")
    script = (
        f"import {{ fitScale, faceColours }} from '{PALETTE_JS.as_posix()}';"
        "const d = JSON.parse(require('fs').readFileSync(0, 'utf8'));"
        "const r = Float32Array.from(d.r.map((x) => (x === null ? Infinity : x)));"
        "const s = fitScale(d.state, r, d.target);"
        "process.stdout.write(JSON.stringify(Array.from(faceColours(d.state, r, s))));"
    ).replace("require('fs')", "(await import('fs'))")
    state, r = _random_faces(500, 0.18)
    no_met = state != 0  # and plans with no met (no unmet) face: the scale's default ends
    for pick in (np.ones(len(state), bool), no_met, state != 1, state >= 2):
        data = {"state": state[pick].tolist(), "target": 0.18,
                "r": [None if not np.isfinite(x) else float(x) for x in r[pick]]}  # fmt: skip
        out = subprocess.run(
            [node, "--input-type=module", "-e", script],
            input=json.dumps(data), capture_output=True, text=True, timeout=60, check=True,
        )  # fmt: skip
        viewer = np.array(json.loads(out.stdout), dtype=np.uint8).reshape(-1, 3)
        np.testing.assert_array_equal(face_colours(state[pick], r[pick], 0.18), viewer)


def test_the_cameras_close_up_wears_the_r_colours() -> None:
    """cameras.png's part is coloured by r* as in the viewer (each face its colour times a grey
    light), not a grey blob; without the faces it stays grey."""
    from matplotlib.collections import PolyCollection

    from tests.conftest import plate_part
    from vpp_core.plan.document import CandidateGenerator, PlanRequest
    from vpp_core.plan.pipeline import plan
    from vpp_core.report.plots import cameras_figure, face_colours

    part = plate_part(n=6)
    doc = plan(part, PlanRequest(candidates=CandidateGenerator(count=6)))
    state, r = _random_faces(part.n_faces, doc.target.resolution_mm)

    def drawn(fig: object) -> np.ndarray:
        close = fig.axes[1]  # type: ignore[attr-defined]
        (part_faces,) = [c for c in close.collections if isinstance(c, PolyCollection)]
        return np.asarray(part_faces.get_facecolor())[:, :3]

    def hue(rgb: np.ndarray) -> list[tuple[float, ...]]:
        """Colours with the light divided out, as a sorted multiset."""
        return sorted(map(tuple, np.round(rgb / rgb.max(axis=1, keepdims=True), 2)))

    expected = face_colours(state, r, doc.target.resolution_mm) / 255.0
    coloured = drawn(cameras_figure(part, doc, (state, r)))
    assert hue(coloured) == hue(expected)
    grey = drawn(cameras_figure(part, doc))
    assert np.ptp(grey, axis=1).max() < 0.05  # no colour without the faces


def test_the_cli_colours_from_its_selection_as_the_service_does_from_r() -> None:
    """Without the candidates' R (the CLI), tracing the selected viewpoints again gives each
    face the state and r* that the service's scene gives from the whole R."""
    from vpp_core.mesh.part import load_mesh
    from vpp_core.plan.document import CandidateGenerator, PlanRequest, Target
    from vpp_core.plan.pipeline import candidates_for, finish
    from vpp_core.report.scene import plan_scene, selected_face_results, unpack
    from vpp_core.samples import sample_stl
    from vpp_core.trace.raytrace import make_backend, trace_counts

    part = load_mesh(sample_stl(), "stl")
    request = PlanRequest(
        profile="paper",
        candidates=CandidateGenerator(count=30),
        target=Target(resolution_mm=0.3, formulation="visibility"),
    )
    backend = make_backend(part)
    views, info = candidates_for(part, request, backend)
    trace = trace_counts(part, request.sensor, views, backend=backend)
    doc = finish(part, request, views, info, trace, backend=backend)
    scene = unpack(plan_scene(part, doc, trace.counts))[1]
    again = selected_face_results(part, doc)
    assert len(set(scene["state"].tolist())) >= 3  # met, unmet or uncovered, ...
    np.testing.assert_array_equal(again.state, scene["state"])
    np.testing.assert_array_equal(again.resolution_mm, scene["resolution_mm"])
