"""vpp_core: the pure numerical library of viewpoint planning (arrays and models in and out).

The stages of a plan are its subpackages, in the order the data flows and the imports go:

    mesh        bytes → Part (checked, canonical, in mm); remesh, area elements
    camera      the pinhole sensor and viewpoints (poses)
    robot       reachability of camera poses by an arm or turntable, joint-space travel
    cell        the part in its cell: setup model, floor/fixture occluders, camera constraints
    trace       ray backends and pixel windows → R (faces × candidates ray counts); with a
                setup, its floor and fixtures in the scene
    candidates  where cameras may stand (uses trace to test that a gaze sees its target)
    cover       R → S or V (density), and the set cover: reductions, bounds, MIP, search
    plan        the pipeline, metrics, diagnostics, tour and the plan document
    report      studies, the point cloud, plots and the viewer's scene

A stage imports only the stages above it in this list and the shared leaves `errors` (the one
error hierarchy), `jit` (numba helpers) and `samples` (the sample part and synthetic covers).
The `[tool.importlinter]` contract in pyproject.toml enforces it (tests/test_layout.py).
No module here imports Redis, RQ or a web framework (ruff's banned-api rules).
"""
