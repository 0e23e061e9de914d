"""/v1/studies: submit a study (202 + job); its document, rows as CSV and plots as PNG."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request, Response

from service import planning, submissions
from service.deps import QueueDep, SettingsDep, StoreDep
from service.models import JobAccepted, Problem, StudyPlots, StudySubmit
from service.routers.plans import IMMUTABLE, accepted
from vpp_core.report.studies import Study
from worker import artifacts as art

router = APIRouter(prefix="/v1/studies", tags=["studies"])
PNG: dict[int | str, dict[str, Any]] = {
    200: {"content": {"image/png": {}}},
    404: {"model": Problem},
}


@router.post("", status_code=202, response_model=JobAccepted, responses={422: {"model": Problem}})
def submit_study(
    body: StudySubmit,
    request: Request,
    response: Response,
    store: StoreDep,
    queue: QueueDep,
    settings: SettingsDep,
) -> JobAccepted:
    """Run a resolution sweep or a decimation study; identical requests share one job."""
    study = submissions.submit(
        request,
        "study",
        body.callback,
        lambda: (planning.submit_study(store, queue, settings, body), body.mesh_id),
    )
    return accepted(study, response, store, queue, settings)


@router.get("/{study_id}", response_model=Study, responses={404: {"model": Problem}})
def get_study(study_id: str, store: StoreDep) -> Response:
    """The study document `{kind, rows, ...}` once its job has succeeded; immutable."""
    key = art.study_key(planning.content_id(study_id, "study"))
    data = planning.stored(store, key, f"study {study_id}")
    return Response(data, media_type="application/json", headers={"Cache-Control": IMMUTABLE})


@router.get(
    "/{study_id}/rows.csv",
    response_class=Response,
    responses={200: {"content": {"text/csv": {}}}, 404: {"model": Problem}},
)
def get_study_csv(study_id: str, store: StoreDep) -> Response:
    """The study's rows as CSV."""
    key = art.study_key(planning.content_id(study_id, "study"), "csv")
    data = planning.stored(store, key, f"study {study_id}")
    return Response(data, media_type="text/csv", headers={"Cache-Control": IMMUTABLE})


@router.get("/{study_id}/plots", response_model=StudyPlots, responses={404: {"model": Problem}})
def list_study_plots(study_id: str, store: StoreDep) -> StudyPlots:
    """Links to the study's PNG plots."""
    names = planning.study_plot_names(store, study_id)
    return StudyPlots(plots=[f"/v1/studies/{study_id}/plots/{n}" for n in names])


@router.get("/{study_id}/plots/{name}", response_class=Response, responses=PNG)
def get_study_plot(study_id: str, name: str, store: StoreDep) -> Response:
    """One PNG plot of the study (sweep.png or decimation.png, histogram-*.png)."""
    name = planning.plot_name(name, planning.study_plot_names(store, study_id))
    data = planning.stored(store, art.plot_key(f"studies/{study_id}", name), f"plot {name}")
    return Response(data, media_type="image/png", headers={"Cache-Control": IMMUTABLE})
