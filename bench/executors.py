"""Many short runs on one executor: the overhead of ``raico exp run`` at scale, a resume, the views' time.

Three measurements over one experiment of N pendulum plans (R-AICO, a few iterations each, ~0.05-0.2 s;
the grid is alpha x 10 seeds), each in a cache of its own under ``--artifacts`` (default
``artifacts/bench/executors``):

- **overhead**: all N runs on a local Ray instance of ``--cpus`` CPUs through ``expfile.run`` (the grid
  generated as it is consumed, cached runs looked up first, short runs batched into ~1 s tasks). The
  wall time (from the first submit; the instance's start is reported apart) against the sum of the runs'
  own times (in their workers) divided by the CPUs; the driving process's resident memory at a quarter,
  half and the end of the runs (it does not grow with the grid);
- **resume**: ``raico exp run --executor ray`` in a process of its own, SIGKILLed once half the runs
  are in the cache, then run again: the runs the second call computes, and how many of them had
  finished before the kill (0: none recomputed);
- **views**: ``raico exp show`` and ``raico exp diff`` of two variants over the N-run table, the whole
  command (Python's start and imports included) and its work alone (read the table, summarize, render).

The page is ``artifacts/bench/executors.md`` (+ ``.json``).

    python -m bench.executors [--runs 10000] [--cpus 2] [--iterations 4]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SEEDS = 10
EXPERIMENT = '''
name = "many"
description = "pendulum swing-up plans, R-AICO, a grid of alphas over seeds"
stages = ["plan"]
seeds = "range({seeds})"
[base]
plant = "pendulum"
task = "swing-up"
dynamics = "analytic"
solver = "raico"
iterations = {iterations}
q0_std = 0.05
[grid]
alpha = [{alphas}]
'''


def experiment_file(folder: Path, runs: int, iterations: int) -> Path:
    """The experiment of ``runs`` runs (rounded up to a multiple of the seeds)."""
    n = max(1, -(-runs // SEEDS))
    alphas = ", ".join(f"{0.5 + i * 0.001:.3f}" for i in range(n))
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "many.toml"
    path.write_text(EXPERIMENT.format(seeds=SEEDS, iterations=iterations, alphas=alphas))
    return path


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def overhead(arts: Path, file: Path, cpus: int) -> dict:
    """All runs on a local Ray instance of ``cpus`` CPUs: wall against the runs' own seconds / CPUs."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.executors import make_executor
    from raico.pipeline.experiments import expfile

    exp = expfile.load(file)
    total = expfile.run_count(exp)
    pool = make_executor("ray", cpus)
    t = time.perf_counter()
    slots = pool.slots   # connects: the local instance starts here
    startup = time.perf_counter() - t
    memory: dict[str, float] = {}
    last: list = []

    def progress(p) -> None:
        last[:] = [p]
        if p.done == max(1, total // 4):
            memory["quarter"] = rss_mb()
        if p.done == max(1, total // 2):
            memory["half"] = rss_mb()

    t0, cpu0 = time.perf_counter(), time.process_time()
    rows = expfile.run(Cache(arts), exp, pool, progress=progress)
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    memory["end"] = rss_mb()
    p = last[0]
    ideal = p.run_s / slots
    return {"runs": len(rows), "computed": p.done - p.cached, "failed": p.failed, "cpus": slots,
            "ray_start_s": startup, "wall_s": wall, "run_s_sum": p.run_s, "mean_run_s": p.run_s / max(1, p.done - p.cached),
            "ideal_s": ideal, "overhead": wall / ideal - 1 if ideal else None, "driver_cpu_s": cpu,
            "rss_mb_quarter": memory.get("quarter"), "rss_mb_half": memory.get("half"), "rss_mb_end": memory["end"]}


def raico(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([str(Path(sys.executable).parent / "raico"), *args], capture_output=True, text=True, **kw)


def resume(arts: Path, file: Path, cpus: int) -> dict:
    """``raico exp run`` SIGKILLed at half the runs, then again: what the second call computes."""
    from raico.pipeline.experiments import expfile

    total = expfile.run_count(expfile.load(file))
    plans = arts / "plan"

    def entries() -> set[str]:
        return {p.name for p in plans.iterdir() if not p.name.startswith(".")} if plans.is_dir() else set()

    cmd = [str(Path(sys.executable).parent / "raico"), "exp", "run", str(file), "--executor", "ray", "--jobs",
           str(cpus), "--artifacts", str(arts), "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    while proc.poll() is None and len(entries()) < total // 2:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)   # the driver and its reaper's watch: the local Ray instance goes too
    proc.wait()
    time.sleep(1.0)
    before = entries()
    t0 = time.perf_counter()
    again = raico("exp", "run", str(file), "--executor", "ray", "--jobs", str(cpus), "--artifacts", str(arts),
                  "--json", "--quiet")
    wall = time.perf_counter() - t0
    summary = json.loads(again.stdout.splitlines()[-1])
    df, _ = expfile.read_table(_cache(arts), "many")
    computed = set(df.loc[~df["plan.cached"].astype(bool), "plan.key"])
    return {"runs": total, "finished_before": len(before), "second_cached": summary["cached"],
            "second_computed": len(computed), "recomputed_finished": len(computed & before), "second_wall_s": wall}


def _children_cpu() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _cache(arts: Path):
    from raico.pipeline.engine.cache import Cache

    return Cache(arts)


def views(arts: Path) -> dict:
    """``exp show`` and ``exp diff`` of two variants: the command's wall time, and its work alone."""
    from raico.pipeline.experiments import expfile

    cache = _cache(arts)
    t = time.perf_counter()
    df, swept = expfile.read_table(cache, "many")
    expfile.render(expfile.summarize(df, swept), "table")
    show_work = time.perf_counter() - t
    a, b = list(dict.fromkeys(df["variant"]))[:2]
    t = time.perf_counter()
    df, swept = expfile.read_table(cache, "many")
    expfile.render_paired(expfile.paired(df, a, b, "plan.final_cost"))
    diff_work = time.perf_counter() - t
    out = {"rows": len(df), "variants": int(df["variant"].nunique()), "show_work_s": show_work, "diff_work_s": diff_work}
    for name, args in (("show", ["exp", "show", "many"]), ("diff", ["exp", "diff", "many", a, b])):
        cpu = _children_cpu()
        t = time.perf_counter()
        res = raico(*args, "--artifacts", str(arts))
        out[f"{name}_command_s"] = time.perf_counter() - t
        out[f"{name}_command_cpu_s"] = _children_cpu() - cpu   # its CPU time: what a loaded machine does not stretch
        assert res.returncode == 0, res.stderr
    t = time.perf_counter()
    raico("--version")
    out["raico_start_s"] = time.perf_counter() - t   # the command line's own start, for scale
    return out


def page(doc: dict) -> str:
    o, r, v = doc["overhead"], doc["resume"], doc["views"]
    load = doc["load"]
    pct = "-" if o["overhead"] is None else f"{100 * o['overhead']:.1f} %"
    return "\n".join([
        f"**Many short runs on a local Ray instance of {o['cpus']} CPUs**: `python -m bench.executors --runs {doc['settings']['runs']}` (pendulum swing-up, R-AICO, "
        f"{doc['settings']['iterations']} iterations per plan); the machine's load average at the start: "
        f"{load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f} (1, 5, 15 min; {doc['cpu_count']} CPUs).",
        "",
        "| measure | value |",
        "|---|---|",
        f"| runs computed | {o['computed']} ({o['failed']} failed) |",
        f"| mean run time (in its worker) | {o['mean_run_s']:.3f} s |",
        f"| sum of run times / CPUs | {o['ideal_s']:.1f} s |",
        f"| wall time (from the first submit) | {o['wall_s']:.1f} s |",
        f"| overhead: wall / (sum / CPUs) - 1 | {pct} |",
        f"| the driving process's CPU time (lookups, submits, the table) | {o['driver_cpu_s']:.1f} s |",
        f"| the Ray instance's start (apart) | {o['ray_start_s']:.1f} s |",
        f"| driver's resident memory at 1/4, 1/2 and the end of the runs | "
        f"{o['rss_mb_quarter'] or float('nan'):.0f} MB, {o.get('rss_mb_half') or float('nan'):.0f} MB, "
        f"{o['rss_mb_end']:.0f} MB |",
        f"| resume: finished before the kill at 50 % | {r['finished_before']} of {r['runs']} |",
        f"| resume: computed by the second call | {r['second_computed']} ({r['second_cached']} cached) |",
        f"| resume: finished runs computed again | {r['recomputed_finished']} |",
        f"| `raico exp show` over {v['rows']} runs ({v['variants']} variants): command (its CPU time) / its work | "
        f"{v['show_command_s']:.2f} s ({v['show_command_cpu_s']:.2f} s) / {v['show_work_s']:.3f} s |",
        f"| `raico exp diff` of two variants: command (its CPU time) / its work | {v['diff_command_s']:.2f} s "
        f"({v['diff_command_cpu_s']:.2f} s) / {v['diff_work_s']:.3f} s |",
        f"| `raico --version` (the command line's start, for scale) | {v['raico_start_s']:.2f} s |",
        "",
    ])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10_000, help="runs of the experiment (a multiple of 10 seeds)")
    ap.add_argument("--cpus", type=int, default=2, help="CPUs of the local Ray instance")
    ap.add_argument("--iterations", type=int, default=4, help="iterations of each plan")
    ap.add_argument("--artifacts", default=str(ROOT / "artifacts"))
    args = ap.parse_args()
    out = Path(args.artifacts) / "bench"
    work = out / "executors"
    shutil.rmtree(work, ignore_errors=True)   # every measurement from an empty cache
    file = experiment_file(work, args.runs, args.iterations)
    doc = {"settings": vars(args), "load": os.getloadavg(), "cpu_count": os.cpu_count()}
    doc["overhead"] = overhead(work / "overhead", file, args.cpus)
    print(json.dumps(doc["overhead"]), flush=True)
    doc["resume"] = resume(work / "resume", file, args.cpus)
    print(json.dumps(doc["resume"]), flush=True)
    doc["views"] = views(work / "overhead")
    print(json.dumps(doc["views"]), flush=True)
    (out / "executors.json").write_text(json.dumps(doc, indent=1))
    (out / "executors.md").write_text(page(doc))
    print(page(doc))


if __name__ == "__main__":
    main()
