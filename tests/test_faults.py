"""Faults with real processes and real signals (issue 8): workers SIGKILLed mid-chunk and
mid-plan, Redis stopped and restarted (with and without persistence), the API restarted, a
writer SIGKILLed mid-write, a full disk. Each test prints its measured figures as `FIGURE ...`
lines (`pytest -s tests/test_faults.py`); docs/reliability.md ("Faults") quotes them.

The workers are `python -m worker` processes; Redis for the restart tests is a redis-server of
our own on a free port (never the shared one). Heartbeats and sweeps are fast here
(VPP_DEAD_WORKER_S=3, VPP_SWEEP_S=1) so that the bounds are seconds.
"""

from __future__ import annotations

import os
import resource
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import pytest
from redis import Redis
from rq.exceptions import NoSuchJobError
from rq.job import Job
from rq.registry import StartedJobRegistry
from rq.worker import Worker

from tests.test_service_jobs import same_plan, submit, upload_sample, wait
from vpp_core.mesh.part import load_mesh
from vpp_core.plan.document import PlanDocument, PlanRequest
from vpp_core.plan.pipeline import plan
from vpp_core.samples import sample_stl
from worker.pool import PARENT_ENV, WorkerPool, die_with_parent, stop_workers, worker_env
from worker.store import FileStore

pytestmark = pytest.mark.slow

SLOW = {
    "profile": "paper",  # faults, not plan quality: the quick, deterministic strict face cover
    "sensor": {"width_px": 3840, "height_px": 2400},
    "candidates": {"count": 60, "seed": 7},
    "backend": "embree",
}
"""3 chunks of 20 views at 9 Mpx with Embree: about 1 s of tracing each on one thread."""
SMALL = {
    "profile": "paper",
    "sensor": {"width_px": 320, "height_px": 200},
    "candidates": {"count": 30, "seed": 1},
}
"""A plan of about a second."""
DEAD_WORKER_S = int(os.environ.get("VPP_FAULTS_DEAD_WORKER_S", "3"))
"""VPP_DEAD_WORKER_S of these tests (set VPP_FAULTS_DEAD_WORKER_S=30 to measure the default)."""
SWEEP_S = int(os.environ.get("VPP_FAULTS_SWEEP_S", "1"))
"""VPP_SWEEP_S of these tests (the default is 15)."""
SWEPT_S = DEAD_WORKER_S + SWEEP_S + 10
"""Longest wait for a dead worker's job to be swept back (the bound, plus slack)."""
FAST = {
    "VPP_CHUNK_VIEWS": "20",
    "VPP_DEAD_WORKER_S": str(DEAD_WORKER_S),
    "VPP_SWEEP_S": str(SWEEP_S),
}


def figure(name: str, value: float, unit: str = "s") -> None:
    print(f"FIGURE {name}: {value:.2f} {unit}")


def until(check: Callable[[], Any], timeout: float, what: str, every: float = 0.02) -> Any:
    """The first truthy `check()`, polled every `every` s; AssertionError after `timeout`."""
    deadline = time.monotonic() + timeout
    while not (value := check()):
        assert time.monotonic() < deadline, f"{what}: not after {timeout} s"
        time.sleep(every)
    return value


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def children(pid: int) -> list[int]:
    """Pids whose parent is `pid` (a worker's work horse)."""
    found = []
    for entry in os.listdir("/proc"):
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except (OSError, ValueError):
            continue
        if entry.isdigit() and int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            found.append(int(entry))
    return found


@pytest.fixture(scope="module")
def reference() -> PlanDocument:
    """The SLOW plan computed in-process, undisturbed."""
    request = PlanRequest.model_validate(SLOW)
    return plan(load_mesh(sample_stl(), "stl"), request, threads=1)


class Workers:
    """`python -m worker` processes by name, their horses found through /proc."""

    def __init__(self, url: str, log: Path) -> None:
        self.url, self.log = url, log.open("ab")
        self.procs: dict[str, subprocess.Popen[bytes]] = {}

    def start(self, name: str, preexec: Callable[[], None] | None = None) -> None:
        cmd = [sys.executable, "-m", "worker", "--url", self.url, "--name", name]
        env = {**worker_env(1, 1), PARENT_ENV: str(os.getpid())}
        self.procs[name] = subprocess.Popen(
            cmd, env=env, stdout=self.log, stderr=subprocess.STDOUT, preexec_fn=preexec
        )

    def horse(self, name: str) -> int | None:
        kids = children(self.procs[name].pid)
        return kids[0] if kids else None

    def kill(self, pid: int) -> None:
        os.kill(pid, signal.SIGKILL)

    def alive(self) -> list[str]:
        return [n for n, p in self.procs.items() if p.poll() is None]

    def stop(self) -> None:
        horses = [h for p in self.procs.values() for h in children(p.pid)]
        stop_workers(list(self.procs.values()), wait_s=5)
        for pid in horses:  # one left behind by a worker that started again (lost Redis)
            try:
                if b"worker" in Path(f"/proc/{pid}/cmdline").read_bytes():
                    os.kill(pid, signal.SIGKILL)
            except (FileNotFoundError, ProcessLookupError):
                pass
        self.log.close()


@pytest.fixture
def env(svc_env: dict[str, str], monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    for k, v in FAST.items():
        monkeypatch.setenv(k, v)
    return {**svc_env, **FAST}


@pytest.fixture
def workers(env: dict[str, str], tmp_path: Path) -> Iterator[Workers]:
    w = Workers(env["VPP_REDIS_URL"], tmp_path / "workers.log")
    yield w
    w.stop()
    print((tmp_path / "workers.log").read_text(errors="replace")[-4000:])


@contextmanager
def make_api() -> Iterator[Any]:
    """A TestClient of the app on the current VPP_* environment."""
    from fastapi.testclient import TestClient

    from service.app import create_app
    from worker.settings import Settings

    with TestClient(create_app(Settings())) as client:
        yield client


def start_two(workers: Workers, conn: Redis, plan_job: str) -> tuple[str, str]:
    """Workers w0 and w1; (the one running the plan job, the other)."""
    workers.start("w0")
    workers.start("w1")
    name = until(lambda: Job.fetch(plan_job, connection=conn).worker_name, 30, "plan started")
    return name, "w1" if name == "w0" else "w0"


def chunk_running_on(conn: Redis, queue: str, name: str) -> Job | None:
    """A ray-tracing chunk job running on worker `name`, past its first 0.3 s."""
    for job_id in StartedJobRegistry(queue, connection=conn).get_job_ids(cleanup=False):
        try:
            job = Job.fetch(job_id, connection=conn)
        except NoSuchJobError:  # ended meanwhile
            continue
        started = job.started_at and time.time() - job.started_at.timestamp() > 0.3
        if "-c" in job_id and job.worker_name == name and started:
            return job
    return None


def chunk_stored(api: Any, job: str) -> bool:
    """Whether the job is tracing and one of its chunks is done (in the store)."""
    state = api.get(f"/v1/jobs/{job}").json()
    tracing = state["progress"].get("stage") == "trace"
    return tracing and any(c["status"] == "succeeded" for c in state["chunks"])


# ------------------------------------------------------------------- 1. a chunk's worker dies


def test_a_chunk_whose_horse_is_killed_is_retried_and_the_plan_is_unchanged(
    env, workers, redis_db, reference
) -> None:
    with make_api() as api:
        job = submit(api, {"mesh_id": upload_sample(api), **SLOW})
        _, name = start_two(workers, redis_db, job)  # `name` only runs chunks
        chunk = until(lambda: chunk_running_on(redis_db, env["VPP_QUEUE"], name), 60, "chunk")
        horse = workers.horse(name)
        assert horse is not None and chunk.get_status() == "started"
        workers.kill(horse)
        killed = time.monotonic()
        until(lambda: chunk.get_status() != "started", 10, "the worker saw its horse die")
        requeued = time.monotonic() - killed
        chunk.refresh()
        assert chunk.retries_left == 1 and chunk.get_status() in ("queued", "started")
        done = wait(api, job, timeout=90)
        figure("horse SIGKILL -> chunk back on the queue", requeued)
        figure("horse SIGKILL -> plan succeeded", time.monotonic() - killed)
        assert done["status"] == "succeeded", done
        index = int(chunk.id.rsplit("-c", 1)[1])
        assert done["chunks"][index].get("retries") == 1, done["chunks"]
        served = PlanDocument.model_validate_json(api.get(done["result_url"]).content)
        same_plan(served, reference)
        assert sorted(workers.alive()) == ["w0", "w1"]  # only the horse died


def test_a_chunk_whose_whole_worker_is_killed_is_swept_and_retried(
    env, workers, redis_db, reference
) -> None:
    with make_api() as api:
        job = submit(api, {"mesh_id": upload_sample(api), **SLOW})
        _, name = start_two(workers, redis_db, job)
        chunk = until(lambda: chunk_running_on(redis_db, env["VPP_QUEUE"], name), 60, "chunk")
        horse = workers.horse(name)
        assert horse is not None
        workers.kill(workers.procs[name].pid)  # the worker and its horse: a lost machine
        workers.kill(horse)
        killed = time.monotonic()
        until(lambda: chunk.get_status() != "started", SWEPT_S, "the sweep found the dead worker")
        figure("worker+horse SIGKILL -> chunk swept back on the queue", time.monotonic() - killed)
        chunk.refresh()
        assert chunk.retries_left == 1
        done = wait(api, job, timeout=90)
        figure("worker+horse SIGKILL -> plan succeeded", time.monotonic() - killed)
        assert done["status"] == "succeeded", done
        same_plan(PlanDocument.model_validate_json(api.get(done["result_url"]).content), reference)


# --------------------------------------------------------------- 2. the plan job's worker dies


def test_a_plan_whose_worker_is_killed_is_retried_and_resumes(
    env, workers, redis_db, reference
) -> None:
    with make_api() as api:
        job = submit(api, {"mesh_id": upload_sample(api), **SLOW})
        name, _ = start_two(workers, redis_db, job)
        until(lambda: chunk_stored(api, job), 60, "a chunk traced")
        horse = workers.horse(name)
        assert horse is not None
        workers.kill(workers.procs[name].pid)
        workers.kill(horse)
        killed = time.monotonic()
        plan_job = Job.fetch(job, connection=redis_db)

        def moved() -> bool:
            plan_job.refresh()
            return plan_job.get_status() != "started" or plan_job.worker_name != name

        until(moved, SWEPT_S, "the plan job swept back on the queue")
        figure("plan worker+horse SIGKILL -> plan job back on the queue", time.monotonic() - killed)
        done = wait(api, job, timeout=90)
        figure("plan worker+horse SIGKILL -> plan succeeded", time.monotonic() - killed)
        assert done["status"] == "succeeded", done
        assert any(c["worker"] == "store" for c in done["chunks"]), done["chunks"]  # resumed
        same_plan(PlanDocument.model_validate_json(api.get(done["result_url"]).content), reference)


def test_without_retries_a_killed_plan_fails_with_a_reason_and_a_resubmission_resumes(
    env, workers, redis_db, monkeypatch
) -> None:
    monkeypatch.setenv("VPP_JOB_RETRIES", "0")
    with make_api() as api:
        body = {"mesh_id": upload_sample(api), **SLOW}
        job = submit(api, body)
        workers.start("w0")
        until(lambda: chunk_stored(api, job), 60, "a chunk traced")
        horse = workers.horse("w0")
        assert horse is not None
        workers.kill(horse)
        killed = time.monotonic()
        failed = wait(api, job, timeout=10)
        figure("plan horse SIGKILL (no retries) -> reported failed", time.monotonic() - killed)
        assert failed["status"] == "failed", failed
        assert "worker died" in failed["error"]["detail"], failed["error"]
        assert submit(api, body) == job
        done = wait(api, job, timeout=90)
        assert done["status"] == "succeeded", done
        assert any(c["worker"] == "store" for c in done["chunks"]), done["chunks"]


def test_a_killed_worker_process_is_started_again_by_its_pool(env, tmp_path) -> None:
    with (tmp_path / "pool.log").open("ab") as log, make_api() as api:
        pool = WorkerPool(env["VPP_REDIS_URL"], 1, threads=1, prefix="pool", log=log)
        pool.watch()  # what `vpp serve` and `vpp worker` do
        try:
            first = pool.procs[0]
            first.send_signal(signal.SIGKILL)
            killed = time.monotonic()
            # the pool looks every CHECK_S (1 s); 1.0 s measured alone, but once in the full
            # suite on the 2-core machine no look saw the death within 5 s: room for a loaded one
            until(lambda: pool.procs[0] is not first, 30, "a new worker process")
            figure("worker process SIGKILL -> replaced by its pool", time.monotonic() - killed)
            job = submit(api, {"mesh_id": upload_sample(api), **SMALL})
            assert wait(api, job, timeout=60)["status"] == "succeeded"
            assert pool.restarts == 1 and pool.procs[0].poll() is None
        finally:
            pool.stop(wait_s=5)


def test_a_worker_ends_when_the_process_that_started_it_is_killed(env) -> None:
    """`start_worker` spawns without preexec_fn; the worker sets its own parent-death signal."""
    code = "import sys, time; from worker.pool import start_workers; "
    code += "print(start_workers(sys.argv[1], 1, threads=1)[0].pid, flush=True); time.sleep(120)"
    cmd = [sys.executable, "-c", code, env["VPP_REDIS_URL"]]
    with subprocess.Popen(cmd, stdout=subprocess.PIPE) as parent:
        try:
            assert parent.stdout is not None
            pid = int(parent.stdout.readline())
            until(lambda: _worker_registered(env["VPP_REDIS_URL"], pid), 30, "the worker up")
        finally:
            parent.kill()
    try:
        until(lambda: not _running(pid), 20, "the orphaned worker gone")
    finally:  # a failure here must not leave it sweeping the test db under later tests
        if _running(pid):
            os.kill(pid, signal.SIGKILL)


def test_a_stop_signal_that_a_library_swallows_still_stops_the_worker(env) -> None:
    """RQ stops an idle worker by raising StopRequested from its SIGTERM handler; a signal that
    lands inside one of redis-py's `except Exception: pass` lost it, and the worker (whose
    parent had died) swept its queues for minutes. Here the first sweep gets the signal there."""
    from worker.__main__ import make_worker
    from worker.settings import get_settings

    conn = Redis.from_url(env["VPP_REDIS_URL"])
    worker = make_worker(conn, get_settings(), None)
    sweep, signalled = worker.run_maintenance_tasks, []

    def swept_with_the_signal_lost() -> None:
        if not signalled:  # one signal, as a parent's death sends
            signalled.append(time.monotonic())
            try:
                os.kill(os.getpid(), signal.SIGTERM)  # handled here, between two bytecodes
                time.sleep(0.1)
            except Exception:  # noqa: BLE001 - what the library does
                pass
        sweep()

    worker.run_maintenance_tasks = swept_with_the_signal_lost  # type: ignore[method-assign]
    handlers = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    bound_s = 2 * SWEEP_S + 5
    again = threading.Timer(bound_s, os.kill, (os.getpid(), signal.SIGTERM))  # a cold stop
    again.start()
    try:
        worker.work(with_scheduler=False)
    except SystemExit:
        pytest.fail(f"the worker was still running {bound_s} s after its stop signal")
    finally:
        again.cancel()
        signal.signal(signal.SIGTERM, handlers[0])
        signal.signal(signal.SIGINT, handlers[1])
    assert signalled and time.monotonic() - signalled[0] < bound_s


def _worker_registered(url: str, pid: int) -> bool:
    return any(w.pid == pid for w in Worker.all(connection=Redis.from_url(url)))


def _running(pid: int) -> bool:
    """Whether process `pid` exists and is no zombie."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


# ---------------------------------------------------------------- 3. Redis stops and restarts


class OwnRedis:
    """A redis-server of this test on a free port, in `folder`, stopped and started at will."""

    def __init__(self, folder: Path, persist: bool) -> None:
        self.port, self.folder, self.persist = free_port(), folder, persist
        self.args = ["--port", str(self.port), "--dir", str(folder), "--save", ""]
        self.args += ["--appendonly", "yes" if persist else "no", "--daemonize", "no"]
        self.url = f"redis://127.0.0.1:{self.port}/0"
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        exe = shutil.which("redis-server") or "/usr/bin/redis-server"
        with (self.folder / "redis.log").open("ab") as log:
            self.proc = subprocess.Popen([exe, *self.args], stdout=log, stderr=subprocess.STDOUT)
        until(self._pings, 10, "redis-server started")

    def _pings(self) -> bool:
        try:
            return bool(Redis.from_url(self.url, socket_connect_timeout=0.5).ping())
        except OSError:
            return False
        except Exception:  # LOADING while it reads its AOF
            return False

    def stop(self, sig: int = signal.SIGTERM) -> None:
        assert self.proc is not None
        self.proc.send_signal(sig)
        self.proc.wait(10)


@pytest.fixture(params=[True, False], ids=["aof", "no-persistence"])
def own_redis(request, tmp_path: Path) -> Iterator[OwnRedis]:
    server = OwnRedis(tmp_path, persist=request.param)
    server.start()
    yield server
    if server.proc is not None and server.proc.poll() is None:
        server.stop(signal.SIGKILL)


def test_redis_down_and_back(own_redis, env, tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("VPP_REDIS_URL", own_redis.url)
    persist = own_redis.persist
    workers = Workers(own_redis.url, tmp_path / "workers.log")
    try:
        with make_api() as api:
            mesh = upload_sample(api)
            small = submit(api, {"mesh_id": mesh, **SMALL})
            workers.start("w0")
            workers.start("w1")
            assert wait(api, small, timeout=60)["status"] == "succeeded"
            running = submit(api, {"mesh_id": mesh, **SLOW})
            queued = submit(api, {"mesh_id": mesh, **SMALL, "target": {"resolution_mm": 0.3}})
            until(lambda: chunk_stored(api, running), 60, "a chunk traced")
            own_redis.stop(signal.SIGTERM if persist else signal.SIGKILL)
            down = time.monotonic()
            ready = api.get("/readyz")
            assert ready.status_code == 503 and ready.headers["Retry-After"], ready.text
            for r in (
                api.get(f"/v1/jobs/{running}"),
                api.post(
                    "/v1/plans", json={"mesh_id": mesh, **SMALL, "target": {"resolution_mm": 1}}
                ),
                api.delete(f"/v1/jobs/{queued}"),
            ):
                assert r.status_code == 503 and r.headers["Retry-After"], r.text
                assert r.headers["content-type"] == "application/problem+json"
            assert api.get(f"/v1/plans/{small}").status_code == 200  # the store has it
            figure("Redis down -> readyz, GET, POST, DELETE answered 503", time.monotonic() - down)
            time.sleep(2)
            own_redis.start()
            back = time.monotonic()
            assert api.get("/readyz").status_code == 200
            states = {}
            for job, what in ((running, "the running job"), (queued, "the other job")):
                states[job] = wait(api, job, timeout=90)
                figure(f"Redis back -> {what} {states[job]['status']}", time.monotonic() - back)
            assert api.get(f"/v1/jobs/{small}").json()["status"] == "succeeded"
            assert sorted(workers.alive()) == ["w0", "w1"]  # they waited and reconnected
            if persist:  # every job finishes
                assert [s["status"] for s in states.values()] == ["succeeded"] * 2, states
            else:  # every job is reported lost, with what to do; a resubmission resumes
                lost = [s for s in states.values() if s["status"] == "failed"]
                assert all(s["error"]["type"] == "JobLost" for s in lost), states
                assert states[running] in lost, states  # the other one may have finished
                assert submit(api, {"mesh_id": mesh, **SLOW}) == running
                done = wait(api, running, timeout=90)
                figure("resubmitted after Redis lost it -> succeeded", time.monotonic() - back)
                assert done["status"] == "succeeded", done
                assert any(c["worker"] == "store" for c in done["chunks"]), done["chunks"]
    finally:
        workers.stop()
        print((tmp_path / "workers.log").read_text(errors="replace")[-4000:])


# ------------------------------------------------------------------------ 4. the API restarts


def test_the_api_restarted_loses_nothing(env, workers, tmp_path) -> None:
    port = free_port()
    cmd = [sys.executable, "-m", "uvicorn", "service.app:create_app", "--factory"]
    cmd += ["--host", "127.0.0.1", "--port", str(port), "--log-level", "warning"]
    base = f"http://127.0.0.1:{port}"

    def serve() -> subprocess.Popen[bytes]:
        proc = subprocess.Popen(cmd, env=dict(os.environ), preexec_fn=die_with_parent)
        until(lambda: _answers(base), 30, "uvicorn started", every=0.1)
        return proc

    api_proc = serve()
    try:
        with httpx.Client(base_url=base, timeout=10) as api:
            mesh = upload_sample(api)
            workers.start("w0")
            jobs = [
                submit(api, {"mesh_id": mesh, **SMALL, "candidates": {"count": n}})
                for n in (30, 40)
            ]
            until(lambda: api.get(f"/v1/jobs/{jobs[0]}").json()["status"] == "running", 30, "")
            api_proc.send_signal(signal.SIGKILL)  # work goes on without the API
            api_proc.wait(10)
            killed = time.monotonic()
            api_proc = serve()
            figure("API SIGKILL -> answering again", time.monotonic() - killed)
            for job in jobs:
                got = wait(api, job, timeout=60)
                assert got["status"] == "succeeded", got
    finally:
        api_proc.kill()
        api_proc.wait(10)


def _answers(base: str) -> bool:
    try:
        return httpx.get(f"{base}/readyz", timeout=1).status_code == 200
    except httpx.HTTPError:
        return False


# -------------------------------------------------------------------------- 5. the store


WRITER = (
    "import sys; from worker.store import FileStore; "
    "FileStore(sys.argv[1]).put(sys.argv[2], b'n' * int(sys.argv[3]))"
)
"""A process that stores argv[3] bytes under key argv[2] in the store at argv[1]."""


def test_a_writer_killed_mid_write_leaves_the_old_value_and_no_servable_half(tmp_path) -> None:
    store = FileStore(tmp_path / "store")
    size = 256 * 2**20
    for attempt in range(5):
        key = f"traces/{attempt}/counts.npz"
        store.put(key, b"old")
        writer = subprocess.Popen([sys.executable, "-c", WRITER, str(store.root), key, str(size)])
        folder = store.root / key.rsplit("/", 1)[0]
        tmp = until(lambda f=folder: _partial(f), 30, "a temp file", every=0.001)
        writer.send_signal(signal.SIGKILL)
        writer.wait()
        assert store.get(key) in (b"old", b"n" * size)  # never a part
        if store.get(key) == b"old":
            break  # killed before the rename: what this test is about
    else:
        pytest.skip("the writer always finished before it could be killed")
    assert tmp[0].exists() and 0 < tmp[0].stat().st_size <= size  # the half file is left over
    with pytest.raises(ValueError):  # ... and is no key: nothing can serve it
        store.get(f"traces/{attempt}/{tmp[0].name}")
    left = tmp[0].stat().st_size / 2**20
    figure(f"writer SIGKILLed (attempt {attempt}), its temp file left with", left, "MiB")


def _partial(folder: Path) -> list[Path]:
    """The temporary files in `folder` that hold some bytes."""
    found = []
    for path in folder.glob(".tmp-*"):
        try:
            if path.stat().st_size:
                found.append(path)
        except FileNotFoundError:  # renamed meanwhile
            pass
    return found


def _small_files() -> None:
    """A worker that may write no file over 512 KiB: write() fails with EFBIG (no SIGXFSZ)."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (2**19, 2**19))


def test_a_full_disk_fails_that_job_with_a_reason_and_nothing_else(env, workers) -> None:
    with make_api() as api:
        mesh = upload_sample(api)
        first = submit(api, {"mesh_id": mesh, **SMALL})
        workers.start("small-disk", preexec=_small_files)
        assert wait(api, first, timeout=60)["status"] == "succeeded"
        r = api.post(f"/v1/plans/{first}/point-cloud")  # megabytes of PLY: over the limit
        assert r.status_code == 202, r.text
        cloud = wait(api, r.json()["id"], timeout=60)
        assert cloud["status"] == "failed", cloud
        assert cloud["error"]["type"] == "UnavailableError", cloud["error"]
        assert "cannot write clouds/" in cloud["error"]["detail"], cloud["error"]
        assert "File too large" in cloud["error"]["detail"], cloud["error"]
        assert api.get("/readyz").status_code == 200
        other = submit(api, {"mesh_id": mesh, **SMALL, "target": {"resolution_mm": 0.3}})
        assert wait(api, other, timeout=60)["status"] == "succeeded"  # same worker, next job
        assert workers.alive() == ["small-disk"]
