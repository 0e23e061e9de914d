"""The `compiling` stage: numba compiling the ray tracer's kernels on a fresh install is said,
not shown as a trace stuck at 0 (vpp_core.plan.warm)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import plate_part
from vpp_core.plan import pipeline
from vpp_core.plan import warm as warm_module
from vpp_core.plan.document import CandidateGenerator, PlanRequest

ROOT = Path(__file__).resolve().parent.parent
WARM = """
import json, sys
from vpp_core.plan.warm import warm
seen = []
seconds = warm("packets", lambda *stage: seen.append(stage))
print(json.dumps({"seen": seen, "seconds": seconds}))
"""


def warm_in_subprocess(cache: Path) -> dict[str, Any]:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", WARM], env=env, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr
    return dict(json.loads(out.stdout.splitlines()[-1]))


@pytest.mark.slow
def test_a_fresh_cache_says_compiling_and_the_next_process_does_not(tmp_path: Path) -> None:
    """With an empty numba cache the kernels compile (seconds): `compiling` 0/1 then 1/1; a
    second process finds them in the cache and says nothing. The packets backend: the cheapest
    to compile of those with kernels; the patch rows' and the cover search's kernels too."""
    first = warm_in_subprocess(tmp_path / "numba")
    assert first["seen"] == [["compiling", 0, 1], ["compiling", 1, 1]], first
    assert first["seconds"] > warm_module.NOTICE_S
    assert any((tmp_path / "numba").rglob("*.nbi"))  # numba's cache index, written
    for kernel in ("patches._averaged", "patches._greedy_alive", "rowweight._walk"):
        assert any((tmp_path / "numba").rglob(f"{kernel}-*.nbi")), kernel  # rows', cover's
    second = warm_in_subprocess(tmp_path / "numba")
    assert second["seen"] == [] and second["seconds"] < warm_module.NOTICE_S, second


class Stop(Exception):
    pass


def test_a_plan_says_compiling_before_its_candidates(monkeypatch: pytest.MonkeyPatch) -> None:
    """The pipeline warms the kernels before its first stage and passes the stage on (here made
    slow by a notice threshold of 0 s); a process that has warmed them says nothing more."""
    monkeypatch.setattr(warm_module, "NOTICE_S", 0.0)
    monkeypatch.setattr(warm_module, "_warmed", set())
    seen: list[tuple[str, int, int]] = []

    def candidates(*args: Any) -> Any:
        raise Stop  # the stages after this one are not the point

    monkeypatch.setattr(pipeline, "candidates_for", candidates)
    part = plate_part()
    request = PlanRequest(candidates=CandidateGenerator(count=4))
    with pytest.raises(Stop):
        pipeline.plan(part, request, progress=lambda *s: seen.append(s))
    assert seen[:3] == [("compiling", 0, 1), ("compiling", 1, 1), ("candidates", 0, 1)], seen
    seen.clear()
    with pytest.raises(Stop):
        pipeline.plan(part, request, progress=lambda *s: seen.append(s))
    assert seen == [("candidates", 0, 1)]


def test_a_failed_warm_up_is_logged_and_leaves_the_plan_to_compile(monkeypatch, caplog) -> None:
    """Warming is a notice, not a stage that can fail a plan: an error in it (a numba cache
    half written by the warming process beside it, say) is logged and the backend is not
    taken as warm."""
    warming = warm_module

    def broken(name: str) -> None:
        raise RuntimeError("cache index half written")

    monkeypatch.setattr(warming, "trace_tiny", broken)
    monkeypatch.setattr(warming, "_warmed", set())
    with caplog.at_level("WARNING", logger="vpp_core.plan.warm"):
        assert warming.warm("raster") >= 0.0
    assert "cache index half written" in caplog.text
    assert "raster" not in warming._warmed


def test_cameras_given_as_matrices_use_the_warmed_kernels() -> None:
    """numba compiles a kernel again for each new argument layout: cameras whose positions were
    a 4 × 4 matrix's column (strided; a turntable's or an explicit pose's) compiled the raster
    kernels a second time, 22 s of a fresh install's first turntable plan; so did a part with
    writable normals. Traced from such cameras and such a part, no kernel of the tracers gains a
    signature that the warm-up did not give it."""
    import dataclasses

    import numpy as np

    from vpp_core.camera.pose import make_viewpoints
    from vpp_core.camera.sensor import Sensor
    from vpp_core.trace import packets, pixels, raster
    from vpp_core.trace.raytrace import make_backend, trace_counts

    kernels = [
        k
        for module in (raster, packets, pixels)
        for k in vars(module).values()
        if hasattr(k, "signatures") and k.__module__ == module.__name__
    ]
    assert len(kernels) >= 5
    for backend in ("raster", "packets"):
        warm_module.trace_tiny(backend)
    warmed = {k: set(k.signatures) for k in kernels}
    m = np.tile(np.eye(4), (2, 1, 1))
    m[:, :3, 3] = [[0.0, 0.0, -500.0], [0.0, 10.0, -480.0]]
    m[:, :3, 2] = [0.0, 0.0, 1.0]  # camera z: the gaze
    views = make_viewpoints(m[:, :3, 3], m[:, :3, 2], -m[:, :3, 1])
    part, sensor = warm_module.tetrahedron(), Sensor(width_px=32, height_px=24)
    for backend in ("raster", "packets"):
        trace_counts(part, sensor, views, backend=make_backend(part, backend), threads=1)
    dense = raster.RasterBackend(part, max_faces_per_pixel=0.0)
    trace_counts(part, sensor, views, backend=dense, threads=1)
    # a Part's arrays are read-only, except where one was made otherwise (the cell's scene)
    writable = dataclasses.replace(part, normals=np.array(part.normals))
    trace_counts(writable, sensor, views, backend=make_backend(writable, "raster"), threads=1)
    assert {k: set(k.signatures) for k in kernels} == warmed
