"""RQ job functions (thin) for what is derived from a mesh or a plan: studies, point clouds.

`study_job(study)` runs a resolution sweep or a decimation study in-process (its tracing on
this worker's threads) and stores its document, CSV and plots; `cloud_job(cloud)` simulates
a finished plan's point cloud and stores the PLY, its statistics and their plot. The document
(`.json`) is written last: its existence is what `succeeded` means.
"""

from __future__ import annotations

import io
import json
from typing import Any

from vpp_core.report.pointcloud import simulate_plan, write_ply
from vpp_core.report.studies import decimation_study, resolution_sweep, study_csv
from worker import artifacts as art
from worker.jobs import Context, run_job, stage_progress


def study_job(study: str) -> dict[str, Any]:
    """Compute and store the study `study` (its request is in the store)."""
    return run_job(_study, study)


def cloud_job(cloud: str) -> dict[str, Any]:
    """Simulate and store the point cloud `cloud` of a finished plan."""
    return run_job(_cloud, cloud)


def _study(ctx: Context, study: str) -> dict[str, Any]:
    if ctx.store.exists(art.study_key(study)):
        return {"study": study, "cached": True}
    mesh_id, request, kind, values = art.get_study_request(ctx.store, study)
    part = art.get_planned_part(ctx.store, mesh_id, request)
    run = resolution_sweep if kind == "resolution" else decimation_study
    doc = run(
        part,
        request,
        values,
        limits=ctx.settings.limits(),
        threads=ctx.settings.threads,
        progress=stage_progress(ctx.meta),
        cell=art.get_cell(ctx.store, request.setup),
    )
    from vpp_core.report.plots import study_plots  # matplotlib: preloaded by workers only

    plots = study_plots(doc)
    for name, png in plots.items():
        ctx.store.put(art.plot_key(f"studies/{study}", name), png)
    ctx.store.put(art.plot_key(f"studies/{study}", "plots.json"), json.dumps(list(plots)).encode())
    ctx.store.put(art.study_key(study, "csv"), study_csv(doc).encode())
    ctx.store.put(art.study_key(study), doc.model_dump_json().encode())
    ctx.meta.update(force=True, stage="done")
    return {"study": study, "rows": len(doc.rows)}


def _cloud(ctx: Context, cloud: str) -> dict[str, Any]:
    if ctx.store.exists(art.cloud_key(cloud)):
        return {"cloud": cloud, "cached": True}
    plan = art.get_cloud_plan(ctx.store, cloud)
    doc = art.get_plan(ctx.store, plan)
    mesh_id, _ = art.get_request(ctx.store, plan)
    part = art.get_part(ctx.store, mesh_id)
    ctx.meta.update(force=True, stage="point cloud", done=0, total=len(doc.viewpoints))
    points, counts, stats = simulate_plan(
        part,
        doc,
        max_points=ctx.settings.max_cloud_points,
        workers=ctx.settings.threads or -1,
        cell=art.get_cell(ctx.store, doc.setup),
    )
    ply = io.BytesIO()
    write_ply(ply, points, counts)
    ctx.store.put(art.cloud_key(cloud, "ply"), ply.getvalue())
    from vpp_core.report.plots import neighbours_png  # matplotlib: preloaded by workers only

    ctx.store.put(art.plot_key(f"clouds/{cloud}", "neighbours.png"), neighbours_png(stats))
    ctx.store.put(art.cloud_key(cloud), stats.model_dump_json().encode())
    ctx.meta.update(force=True, stage="done")
    return {"cloud": cloud, "points": stats.points}
