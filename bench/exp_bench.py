"""Experiment files at scale: ``make bench`` rows for the runs table and its views.

- building the runs table of a 1000-run experiment: a row per run from its entry (``meta.json``, the
  plan's cost per iteration from ``plan.npz``), then ``runs.csv`` and ``runs.json``
  (``raico.pipeline.experiments.expfile.table_row`` and ``write_table``, what ``raico exp run`` does after its runs);
- ``raico exp show`` of that experiment, the whole command (Python's start included), warm: it reads
  the runs table only;
- ``raico exp run FILE --dry-run`` of each thesis file (raico/thesis/experiments/), the whole command: what
  would run and how much of it is cached, in the bench's cache.

The 1000 runs are synthetic entries (a plan's ``meta.json`` with a real plan's metrics, a ``plan.npz``
with 25 costs and a 1001-step trajectory) in a temporary cache, made once per process: the table's
code reads them as it reads real ones (it does not check their hashes), and 1000 real plans would
take minutes of both cores.

    .venv/bin/python -m bench.exp_bench
"""

from __future__ import annotations

import atexit
import functools
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RUNS = 1000
GRID = {"alpha": [0.1, 0.3, 1.0, 3.0, 10.0], "alpha_schedule": ["fixed", "adaptive"]}
SEEDS = RUNS // 10   # 10 variants x 100 seeds
EXPERIMENT = f'''name = "bench-1000"
description = "synthetic: 10 R-AICO variants x {SEEDS} seeds"
stages = ["plan"]
seeds = "range({SEEDS})"
[base]
plant = "arm5"
task = "reach-roll"
dynamics = "analytic"
iterations = 25
[grid]
alpha = {GRID["alpha"]}
alpha_schedule = {json.dumps(GRID["alpha_schedule"])}
'''


def _raico() -> str:
    return str(Path(sys.executable).with_name("raico"))


def _metrics(rng: np.random.Generator) -> dict:
    cost = float(rng.uniform(300, 1000))
    return {"cost_ratio": cost / 3.4e5, "final_cost": cost, "first_iteration_cost": cost * 10,
            "initial_cost": 3.4e5, "iterations": 25, "message": "reached 25 iterations", "status": "max-iterations",
            "via_point_errors": {"roll@1000": 3e-4, "roll@500": 3e-4, "via_x1@500": float(rng.uniform(0.01, 0.1)),
                                 "via_x2@1000": 0.01}, "wall_time_s": float(rng.uniform(0.4, 1.2))}


@functools.cache
def synthetic() -> tuple[Path, object, list]:
    """A temporary cache with the 1000 runs' entries and the experiment file: ``(root, experiment, results)``
    where ``results`` are the runs' outcomes as ``raico exp run`` collects them."""
    from raico.pipeline.experiments import expfile

    root = Path(tempfile.mkdtemp(prefix="raico-bench-exp-"))
    atexit.register(shutil.rmtree, root, True)   # 1000 entries, about 100 MB: gone with the process
    f = root / "bench.toml"
    f.write_text(EXPERIMENT)
    exp = expfile.load(f)
    rng = np.random.default_rng(0)
    results = []
    for i, run in enumerate(exp.runs):
        key = f"{i:016x}"
        folder = root / "arts" / "plan" / key
        folder.mkdir(parents=True)
        metrics = _metrics(rng)
        cfg = {**run.variant.options["plan"], "seed": run.seed}
        (folder / "meta.json").write_text(json.dumps({"config": cfg, "metrics": metrics, "status": "max-iterations",
                                                      "timings": {"compute_s": metrics["wall_time_s"]},
                                                      "code_version": "plan+bench"}))
        costs = np.geomspace(metrics["final_cost"] * 10, metrics["final_cost"], 25)
        with open(folder / "plan.npz", "wb") as fh:
            np.savez(fh, costs=costs, X=rng.standard_normal((1001, 10)), U=rng.standard_normal((1000, 5)))
        results.append({"plan": {"stage": "plan", "key": key, "path": str(folder), "cached": True,
                                 "status": "max-iterations", "metrics": metrics, "recording": None, "reason": ""}})
    return root, exp, results


def build_table() -> float:
    """Seconds to build and write the runs table of the 1000 runs."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.experiments import expfile

    root, exp, results = synthetic()
    cache = Cache(root / "arts")
    t0 = time.perf_counter()
    rows = [expfile.table_row(cache, exp, r, res) for r, res in zip(exp.runs, results)]
    expfile.write_table(cache, exp, rows)
    return time.perf_counter() - t0


def bench_exp_table(reps: int) -> list[float]:
    return [build_table() for _ in range(reps)]


def bench_exp_show(reps: int) -> list[float]:
    """Wall time (s) of ``raico exp show bench-1000`` (grouped, the default metrics), after one warm-up."""
    root, _, _ = synthetic()
    if not (root / "arts" / "exp" / "bench-1000" / "runs.json").exists():
        build_table()
    cmd = [_raico(), "exp", "show", "bench-1000", "--artifacts", str(root / "arts")]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)   # warm: the page cache holds the table
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        times.append(time.perf_counter() - t0)
    return times


def thesis_dry_runs(reps: int, artifacts: str | Path = "artifacts") -> dict[str, list[float]]:
    """Per thesis file, the wall times (s) of ``raico exp run FILE --dry-run`` in the cache ``artifacts``."""
    from raico.thesis.figures import THESIS_DIR, THESIS_FILES

    out = {}
    for name in THESIS_FILES:
        cmd = [_raico(), "exp", "run", str(THESIS_DIR / f"{name}.toml"), "--dry-run", "--quiet", "--artifacts",
               str(artifacts)]
        out[name] = []
        for _ in range(reps):
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
            out[name].append(time.perf_counter() - t0)
    return out


def bench_thesis_dry_run(reps: int, artifacts: str | Path = "artifacts") -> list[float]:
    """The samples of the slowest thesis file's dry run (each file's median printed)."""
    per_file = thesis_dry_runs(reps, artifacts)
    medians = {k: statistics.median(v) for k, v in per_file.items()}
    print("  dry runs (median s): " + ", ".join(f"{k} {v:.2f}" for k, v in medians.items()), flush=True)
    return per_file[max(medians, key=medians.get)]


if __name__ == "__main__":
    for name, fn, args in (("runs table of 1000 runs", bench_exp_table, (3,)),
                           ("raico exp show, 1000 runs", bench_exp_show, (5,)),
                           ("slowest thesis dry run", bench_thesis_dry_run, (3,))):
        s = fn(*args)
        print(f"{name}: median {statistics.median(s):.3f} s ({', '.join(f'{x:.3f}' for x in s)})")
