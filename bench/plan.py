"""Benchmark the whole `vpp plan` pipeline on real meshes; one JSON line per mesh.

    python bench/plan.py [MESH...] [--units U] [--candidates 500] [--solver milp|greedy]
                         [--time-limit 60] [--resolution 0.18] [--threads T] [--out DIR]

Without MESH, every mesh in `../shared/meshes/` (relative to the repository root) is run,
with `--units` per mesh from the `units_guess` column of `MANIFEST.csv` there (mm, m,
inch -> in, "inch?" -> in, "mm?" -> mm, anything else -> mm); when that folder is absent
the benchmark says so and exits 0. Explicit MESH files take their units from a MANIFEST.csv
beside them when it lists them, else mm; `--units` overrides both.

Each mesh runs `vpp plan MESH --units U --candidates N -q -o DIR/<name>.json` as a child
process (the paper's camera, default sensor); its peak RSS comes from `wait4` on that child.
The JSON lines go to stdout, the human table at the end to stderr (so stdout stays JSONL).
A failing run (non-zero exit) records its last stderr line and the benchmark goes on.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
SHARED_MESHES = ROOT.parent / "shared" / "meshes"
MESH_SUFFIXES = {".stl", ".obj", ".ply", ".off", ".glb", ".gltf"}
UNITS_GUESS = {"mm": "mm", "mm?": "mm", "m": "m", "m?": "m", "cm": "cm", "cm?": "cm"}
UNITS_GUESS |= {"inch": "in", "inch?": "in", "in": "in", "in?": "in"}
STAGES = ("load", "candidates", "trace", "matrices", "solve", "metrics")


def manifest_units(folder: Path) -> dict[str, str]:
    """File name -> vpp `--units` from folder/MANIFEST.csv (empty when absent)."""
    table = folder / "MANIFEST.csv"
    if not table.is_file():
        return {}
    with table.open(newline="") as fh:
        return {
            row["file"]: UNITS_GUESS.get(row.get("units_guess", "").strip().lower(), "mm")
            for row in csv.DictReader(fh)
            if row.get("file")
        }


def default_meshes() -> list[Path]:
    """Every mesh file directly in ../shared/meshes (sorted by name), or [] when absent."""
    if not SHARED_MESHES.is_dir():
        return []
    return sorted(
        (p for p in SHARED_MESHES.iterdir() if p.is_file() and p.suffix.lower() in MESH_SUFFIXES),
        key=lambda p: p.name.lower(),
    )


def vpp_command() -> list[str]:
    """The `vpp` console script of this interpreter's environment (or `python -m cli.main`)."""
    beside = Path(sys.executable).parent / "vpp"
    if beside.is_file() and os.access(beside, os.X_OK):
        return [str(beside)]
    found = shutil.which("vpp")
    return [found] if found else [sys.executable, "-m", "cli.main"]


def run_child(cmd: list[str], timeout: float | None) -> tuple[int, float, float, str, bool]:
    """Run cmd; (exit code, wall s, peak RSS MiB of that child, stderr text, timed out)."""
    with tempfile.TemporaryFile() as err, tempfile.TemporaryFile() as out:
        start = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, cwd=ROOT, start_new_session=True)
        killed = threading.Event()

        def kill() -> None:
            killed.set()
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass

        timer = threading.Timer(timeout, kill) if timeout else None
        if timer:
            timer.start()
        try:
            _, status, usage = os.wait4(proc.pid, 0)
        finally:
            if timer:
                timer.cancel()
        wall = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
        err.seek(0)
        text = err.read().decode(errors="replace")
    return proc.returncode, wall, usage.ru_maxrss / 1024, text, killed.is_set()


def _r(x: float | None, nd: int = 6) -> float | None:
    return None if x is None else round(float(x), nd)


def record(doc: dict[str, Any]) -> dict[str, Any]:
    """The benchmark figures of one plan document."""
    s, m, rays, info = doc["solver"], doc["metrics"], doc["rays"], doc["candidate_info"]
    return {
        "faces": doc["mesh"]["faces"],
        "counted_faces": doc["mesh"]["counted_faces"],
        "area_mm2": _r(doc["mesh"]["area_mm2"], 3),
        "timings_s": {k: doc["timings_s"].get(k) for k in STAGES},
        "viewpoints": len(doc["viewpoints"]),
        "candidates": info["generated"],
        "candidates_requested": info["requested"],
        "candidates_dropped": info.get("dropped"),
        "spacing_mm": _r(info.get("spacing_mm"), 4),
        "solver": {
            "name": s["name"],
            "status": s["status"],
            "objective": s["objective"],
            "bound": s["bound"],
            "gap": _r(s["gap"]),
            "time_s": _r(s["time_s"], 3),
            "rows": s["rows"],
            "cols": s["cols"],
        },
        "coverage": {"area": _r(m["coverage"]["area"]), "max_area": _r(m["coverage"]["max_area"])},
        "resolution": {
            "met_area": _r(m["resolution"]["met_area"]),
            "max_met_area": _r(m["resolution"]["max_met_area"]),
            "median_mm": _r(m["resolution"]["median_mm"]),
        },
        "uncoverable": {
            "faces": doc["uncoverable"]["faces"],
            "area_mm2": _r(doc["uncoverable"]["area_mm2"], 4),
        },
        "rays": {
            "pixels": rays["pixels"],
            "cast": rays["cast"],
            "valid": rays["valid"],
            "cast_per_s": round(rays["cast_per_s"]),
        },
        "warnings": doc["mesh"].get("warnings", []),
    }


def bench_mesh(mesh: Path, units: str, args: argparse.Namespace, out_dir: Path) -> dict[str, Any]:
    """Plan one mesh in a child process; its JSON record (with `error` when it failed)."""
    target = out_dir / f"{mesh.stem}.json"
    target.unlink(missing_ok=True)
    cmd = [*vpp_command(), "plan", str(mesh.resolve()), "--units", units]
    cmd += ["--candidates", str(args.candidates), "--solver", args.solver]
    cmd += ["--time-limit", str(args.time_limit), "--resolution", str(args.resolution)]
    if args.threads:
        cmd += ["--threads", str(args.threads)]
    cmd += ["-q", "-o", str(target)]
    code, wall, rss, stderr, timed_out = run_child(cmd, args.timeout)
    line: dict[str, Any] = {
        "mesh": mesh.name,
        "units": units,
        "exit": code,
        "wall_s": round(wall, 3),
        "peak_rss_mib": round(rss, 1),
    }
    if code != 0 or not target.is_file():
        lines = [s for s in stderr.splitlines() if s.strip()]
        why = f"killed after the --timeout of {args.timeout:g} s" if timed_out else None
        line["error"] = why or (lines[-1] if lines else f"exit {code}, no plan written")
        return line
    line |= record(json.loads(target.read_text()))
    line["plan"] = str(target)
    return line


def _f(x: Any, fmt: str) -> str:
    return "-" if x is None else format(x, fmt)


def table(lines: list[dict[str, Any]]) -> str:
    """A fixed-width human table of the records."""
    head = (
        "mesh", "faces", "u", "cand", "view", "status", "obj", "bound", "gap", "cov%", "max%",
        "res%", "maxres%", "uncov", "Mray/s", "load", "cands", "trace", "matr", "solve",
        "metr", "wall", "MiB",
    )  # fmt: skip
    rows: list[tuple[str, ...]] = [head]
    for r in lines:
        if "error" in r:
            rows.append((r["mesh"][:28], "-", r["units"], "FAILED: " + r["error"][:150]))
            continue
        s, t = r["solver"], r["timings_s"]
        rows.append(
            (
                r["mesh"][:28],
                str(r["faces"]),
                r["units"],
                str(r["candidates"]),
                str(r["viewpoints"]),
                s["status"],
                _f(s["objective"], "g"),
                _f(s["bound"], "g"),
                _f(s["gap"], ".3f"),
                _f(100 * r["coverage"]["area"], ".2f"),
                _f(100 * r["coverage"]["max_area"], ".2f"),
                _f(100 * r["resolution"]["met_area"], ".2f"),
                _f(100 * r["resolution"]["max_met_area"], ".2f"),
                str(r["uncoverable"]["faces"]),
                _f(r["rays"]["cast_per_s"] / 1e6, ".1f"),
                *(_f(t[k], ".2f") for k in STAGES),
                _f(r["wall_s"], ".1f"),
                _f(r["peak_rss_mib"], ".0f"),
            )
        )
    width = [max(len(row[i]) for row in rows if len(row) == len(head)) for i in range(len(head))]
    out = []
    for row in rows:
        if len(row) != len(head):  # failure: mesh, faces, units, then the message
            out.append("  ".join([row[0].ljust(width[0]), row[1].rjust(width[1]), *row[2:]]))
        else:
            rest = (c.rjust(w) for c, w in zip(row[1:], width[1:], strict=True))
            cells = [row[0].ljust(width[0]), *rest]
            out.append("  ".join(cells))
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("meshes", nargs="*", type=Path, metavar="MESH", help="default: shared meshes")
    ap.add_argument("--units", choices=["mm", "cm", "m", "in"], help="override the units of all")
    ap.add_argument("--candidates", type=int, default=500, help="candidates to generate")
    ap.add_argument("--solver", choices=["milp", "greedy"], default="milp")
    ap.add_argument("--time-limit", type=float, default=60.0, help="solver time limit, s")
    ap.add_argument("--resolution", type=float, default=0.18, help="target resolution, mm")
    ap.add_argument("--threads", type=int, default=None, help="vpp --threads (default: vpp's)")
    ap.add_argument("--timeout", type=float, default=None, help="kill a run after this many s")
    ap.add_argument("--out", type=Path, default=None, help="folder for the plan documents")
    args = ap.parse_args(argv)

    meshes: list[Path] = args.meshes
    if not meshes:
        if not SHARED_MESHES.is_dir():
            print(f"bench/plan.py: {SHARED_MESHES} is absent; nothing to run", file=sys.stderr)
            return 0
        meshes = default_meshes()
    out_dir = args.out or Path(tempfile.mkdtemp(prefix="vpp-bench-plan-"))
    out_dir.mkdir(parents=True, exist_ok=True)
    print(f"bench/plan.py: plan documents in {out_dir}", file=sys.stderr)

    lines = []
    for mesh in meshes:
        units = args.units or manifest_units(mesh.resolve().parent).get(mesh.name, "mm")
        line = bench_mesh(mesh, units, args, out_dir)
        print(json.dumps(line), flush=True)
        lines.append(line)
    print("\n" + table(lines), file=sys.stderr, flush=True)
    return 1 if any("error" in r for r in lines) else 0


if __name__ == "__main__":
    raise SystemExit(main())
