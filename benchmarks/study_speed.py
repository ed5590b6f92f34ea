#!/usr/bin/env python3
"""Wall and CPU time of ``flexstab study`` (full) and ``flexstab study --quick``, per stage.

Each mode runs as its own ``flexstab study --no-resume`` subprocess into a temporary folder
(``--keep DIR`` keeps the folders).  Per stage the script prints the wall time and the CPU
time that the study recorded in ``<stage>.stage.json`` (``time.process_time`` of the process
that ran the stage plus ``getrusage(RUSAGE_CHILDREN)`` of its worker pools), which process ran it
(``main`` or ``exudyn-k``, the process of the k-th chain of
``flexstab.study.EXUDYN_CHAINS`` with ``--jobs 2``), and for the whole run the wall time and the
CPU time of the study and all its children measured here (``RUSAGE_CHILDREN`` of this script).

The machine's load (``os.getloadavg``) before and after each run is printed beside the times:
on a shared machine the wall times grow with the load, the CPU times much less.  The targets
are for an otherwise idle 2-core machine: full <= 60 s, quick <= 15 s wall.  With
the cores busy all the time the wall time of an idle machine would be the total CPU time over
the number of cores: the script prints that lower bound beside the measured wall time.

Usage::

    python benchmarks/study_speed.py                 # quick, then full
    python benchmarks/study_speed.py --modes quick
    python benchmarks/study_speed.py --jobs 1        # everything in one process
    python benchmarks/study_speed.py --json results/study_speed.json
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from flexstab.study import EXUDYN_CHAINS, STAGES  # noqa: E402  (the study's own stage list and processes)


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_mode(mode: str, out: Path, jobs: int, config: str | None) -> dict:
    """Run one study in a subprocess; return the measured and recorded times."""
    cmd = [sys.executable, "-m", "flexstab.cli", "study", "--out", str(out), "--no-resume", "--jobs", str(jobs)]
    if mode == "quick":
        cmd.append("--quick")
    if config:
        cmd += ["--config", config]
    env = dict(os.environ)
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    env.setdefault("MPLBACKEND", "Agg")
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    load0 = os.getloadavg()
    c0, t0 = _children_cpu(), time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
    load1 = os.getloadavg()
    if proc.returncode != 0:
        sys.stderr.write(proc.stdout + proc.stderr)
    stages = {}
    for name in STAGES:
        rec_path = out / f"{name}.stage.json"
        if rec_path.exists():
            rec = json.loads(rec_path.read_text())
            chain = [i for i, c in enumerate(EXUDYN_CHAINS) if name in c]
            stages[name] = {"wall": rec.get("elapsed"), "cpu": rec.get("cpu"),
                            "process": f"exudyn-{chain[0] + 1}" if (jobs >= 2 and chain) else "main"}
    lanes: dict = {}
    for s in stages.values():
        lanes[s["process"]] = lanes.get(s["process"], 0.0) + (s["cpu"] or 0.0)
    return {"mode": mode, "jobs": jobs, "returncode": proc.returncode, "wall": wall, "cpu": cpu,
            "load_before": list(load0), "load_after": list(load1), "stages": stages,
            "cpu_per_process": lanes,
            "progress_lines": proc.stderr.splitlines()}


def print_mode(r: dict) -> None:
    status = "" if r["returncode"] == 0 else f"  [exit {r['returncode']}]"
    print(f"\n## flexstab study {'--quick ' if r['mode'] == 'quick' else ''}(--jobs {r['jobs']}){status}")
    print(f"load average before {r['load_before'][0]:.2f}, after {r['load_after'][0]:.2f} "
          f"(1-min; {os.cpu_count()} CPUs)")
    print(f"| stage | process | wall (s) | CPU (s) |\n|---|---|---:|---:|")
    for name, s in r["stages"].items():
        print(f"| {name} | {s['process']} | {s['wall']:.1f} | {s['cpu']:.1f} |")
    print(f"| **total** | | **{r['wall']:.1f}** | **{r['cpu']:.1f}** |")
    lanes = r["cpu_per_process"]
    print("stage CPU by process: " + ", ".join(f"{k} {v:.1f} s" for k, v in lanes.items()) + " (each with its "
          f"pools); total CPU / {os.cpu_count()} = {r['cpu'] / (os.cpu_count() or 1):.1f} s: the wall time on an "
          "idle machine with these cores cannot be less")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", default="quick,full", help="comma-separated: quick, full (default both)")
    ap.add_argument("--jobs", type=int, default=2, help="processes of the study (default 2)")
    ap.add_argument("--config", default=None, help="TOML manipulator passed to flexstab study")
    ap.add_argument("--keep", default=None, metavar="DIR", help="write the study folders under DIR and keep them")
    ap.add_argument("--json", default=None, metavar="FILE", help="also write the measurements as JSON")
    args = ap.parse_args(argv)
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    bad = [m for m in modes if m not in ("quick", "full")]
    if bad or not modes:
        ap.error(f"--modes takes quick and/or full, got {args.modes!r}")
    results = []
    with tempfile.TemporaryDirectory(prefix="study_speed_") as tmp:
        base = Path(args.keep) if args.keep else Path(tmp)
        for mode in modes:
            out = base / mode
            out.mkdir(parents=True, exist_ok=True)
            r = run_mode(mode, out, args.jobs, args.config)
            print_mode(r)
            results.append(r)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({"runs": results, "cpus": os.cpu_count()}, indent=2))
    return 0 if all(r["returncode"] == 0 for r in results) else 1


if __name__ == "__main__":
    raise SystemExit(main())
