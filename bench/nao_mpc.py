"""The pushed Nao: the plan with the whole-body stabilizer against MPC above the stabilizer, stood per seed.

``python -m bench.nao_mpc [--artifacts DIR] [--seeds N]`` runs ``experiments/nao_push_mpc.toml`` and its ceiling
``experiments/nao_push_ceiling.toml`` (the stabilizer holding the standing posture, pushed alike; runs cached in
``DIR/bench/nao_mpc``) and writes ``DIR/bench/nao_mpc.json``, ``nao_mpc.md`` (the counts, the
per-seed statuses, the MPC's tick times) and ``nao_mpc.png`` (the CoG's lateral path of every run).

The experiment fixes the push (7 N at the torso along world +y from 1.8 s for 0.1 s) and the seeds (the
start postures); a run stood when the execution's ``stood`` metric holds (no fall: torso drop or tilt, a
sole lifted). Target (issue: MPC in the loop): the MPC stands in at least 9 of 10 seeds where the plan with
the stabilizer falls in more. Tick times are wall times on a shared machine (the load in the page).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = ROOT / "experiments" / "nao_push_mpc.toml"
CEILING = ROOT / "experiments" / "nao_push_ceiling.toml"
LEAD = ROOT / "experiments" / "nao_push_lead.toml"   # held-out seeds: the window ten steps ahead
TARGET_STOOD = 9
SEEN_AT = (1.75, 1.9, 2.0)   # s: before the push, at its end, 0.2 s on (the second CoG via-point)


def run_experiment(cache, seeds: int | None, path: Path = EXPERIMENT) -> tuple[Any, list[dict]]:
    """The experiment's runs (cached ones read back), one process: ``(experiment, rows)``."""
    from raico.pipeline.engine.executors import SerialExecutor
    from raico.pipeline.experiments import expfile

    exp = expfile.load(path, [f"seeds=range({seeds})"] if seeds else [])
    rows = expfile.run(cache, exp, SerialExecutor())
    return exp, list(rows)


def per_seed(rows: list[dict]) -> dict[str, dict[int, dict]]:
    """variant -> seed -> the run's status, stood, failure time (s), its reason, MPC tick median / p99 (s),
    and the path of its execution."""
    out: dict[str, dict[int, dict]] = {}
    for r in rows:
        e = {k.removeprefix("execute."): v for k, v in r.items() if k.startswith("execute.")}
        get = e.get
        out.setdefault(r["variant"], {})[int(r["seed"])] = {
            "status": get("status"), "stood": bool(get("stood")), "failure_time": get("failure_time"),
            "reason": get("reason"), "median_tick_s": get("mpc_median_tick_s"), "p99_tick_s": get("mpc_p99_tick_s"),
            "over_period": get("mpc_over_period"), "key": get("key")}
    return out


def figure(cache_root: Path, table: dict[str, dict[int, dict]], path: Path, push: tuple[float, float]) -> None:
    """The CoG's lateral position (world y, m) over time of every run, one panel per variant (the pushed ones in
    the first row, the unpushed in the second); green: stood, red: fell (drawn to its fall); the push shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pushed = [lb for lb in table if "no push" not in lb]
    unpushed = [lb for lb in table if "no push" in lb]
    rows = 2 if unpushed and pushed else 1
    cols = max(len(pushed), len(unpushed))
    fig, axes = plt.subplots(rows, cols, figsize=(4.4 * cols, 3.4 * rows), sharex=True, sharey=True, squeeze=False)
    panels = [(axes[0, i], lb) for i, lb in enumerate(pushed or unpushed)]
    panels += [(axes[1, i], lb) for i, lb in enumerate(unpushed)] if rows == 2 else []
    for ax in axes.ravel()[len(panels):] if rows == 1 else [*axes[0, len(pushed):], *axes[1, len(unpushed):]]:
        ax.set_visible(False)
    for ax, label in panels:   # a row per push (the file's order)
        seeds = table[label]
        for _, run in sorted(seeds.items()):
            d = np.load(cache_root / "execute" / run["key"] / "rollout.npz")
            t, y = d["times"], d["cog"][:, 1]
            if not run["stood"] and run["failure_time"] is not None:
                keep = t <= run["failure_time"] + 0.1
                t, y = t[keep], y[keep]
            ax.plot(t, y, color="tab:green" if run["stood"] else "tab:red", lw=1.0, alpha=0.8)
        if "no push" not in label:
            ax.axvspan(push[0], push[0] + push[1], color="0.85", zorder=0, label="push")
            ax.legend(loc="lower left", fontsize=8)
        stood = sum(r["stood"] for r in seeds.values())
        ax.set_title(f"{label.replace(' + stabilizer', '')}:\nstood {stood} of {len(seeds)}", fontsize=9)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    for ax in axes[:, 0]:
        ax.set_ylabel("CoG y, world (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def what_the_model_sees(cache_root: Path, table: dict[str, dict[int, dict]], times: tuple[float, ...]) -> dict:
    """Per variant and time (s), medians over its seeds (runs fallen by then left out; a run that stood
    and lost the plan's track stays): the CoG's forward and
    lateral position in the world, its lateral position on the planning model (the fixed-base Nao, left sole
    at the origin, at the measured joints: what the MPC's problem sees) (m), the largest joint deviation
    from the plan (rad) and the torso's tilt from upright (rad)."""
    from raico.plants.robots import shared_robot
    from raico.stages.execute.wbc import plan_cog

    fixed = shared_robot("nao")
    out: dict = {}
    for label, seeds in table.items():
        rows: dict[float, list] = {t: [] for t in times}
        for run in seeds.values():
            d = np.load(cache_root / "execute" / run["key"] / "rollout.npz")
            dt = float(d["times"][1] - d["times"][0])
            for t in times:
                k = int(round(t / dt))
                if not run["stood"] and run["failure_time"] is not None and t >= run["failure_time"]:
                    continue
                c_model = plan_cog(fixed, d["X"][k:k + 1], dt)[0][0, 1]
                dev = float(np.max(np.abs(d["X"][k, :fixed.n_q] - d["X_plan"][k, :fixed.n_q])))
                tilt = float(np.arccos(np.clip(d["torso_z"][k, 2], -1, 1)))
                rows[t].append((d["cog"][k, 0], d["cog"][k, 1], c_model, dev, tilt))
        out[label] = {t: (np.median(np.array(v), axis=0).tolist(), len(v)) if v else (None, 0) for t, v in rows.items()}
    return out


def fall_diagnosis(cache_root: Path, table: dict[str, dict[int, dict]], push: tuple[float, float],
                   force_y: float) -> dict:
    """Per pushed variant, how its runs went over the left sole's outer edge (the push is along +y): per run
    the time the right sole's normal force first fell below 1 N after the push began (the robot on the left
    sole alone), the least distance (m) from the CoG's ground projection to that sole's outer edge (its
    corners' largest y) between the push's end and the run's end or fall (negative: the CoG passed it), the
    time it first passed it, the fall time; and at the push's start the moment (N m) of the push (``force_y`` N
    at the torso's origin) about that edge against gravity's (the soles' normal forces over the 0.1 s before
    times the CoG's distance to the edge): the push alone tips the robot onto the edge where it is larger.
    Returns variant -> list of per-run dicts."""
    out: dict = {}
    for label, seeds in table.items():
        if "no push" in label:
            continue
        runs = []
        for run in seeds.values():
            d = np.load(cache_root / "execute" / run["key"] / "rollout.npz")
            t, f = d["times"], d["sole_force"]
            edge = np.nanmax(d["corners"][:, 0, :, 1], axis=1)   # (K,) the left sole's outer edge, world y
            gap = edge - d["cog"][:, 1]
            k0 = int(round(push[0] / (t[1] - t[0])))
            lifted = np.flatnonzero(f[k0:, 1] < 1.0)
            end = len(t) if run["stood"] or run["failure_time"] is None else int(round(run["failure_time"] / (t[1] - t[0])))
            after = np.arange(int(round((push[0] + push[1]) / (t[1] - t[0]))), end)
            past = after[gap[after] < 0] if after.size else after
            weight = float(np.nanmedian(f[max(k0 - 10, 1):k0].sum(axis=1)))
            runs.append({"push_moment": force_y * float(d["torso_p"][k0, 2]), "gravity_moment": weight * float(gap[k0]),
                         "stood": run["stood"], "lift": float(t[k0 + lifted[0]]) if lifted.size else None,
                         "least_gap": float(np.nanmin(gap[after])) if after.size else None,
                         "past": float(t[past[0]]) if past.size else None, "fell": run["failure_time"]})
        out[label] = runs
    return out


def exp_force_y(push: str) -> float:
    """The lateral force (N, world y) of a push ``FRAME:NEWTONS:START:DURATION`` (NEWTONS ``FX,FY,FZ``, or one
    number along x: 0 lateral)."""
    f = push.rsplit(":", 3)[1].split(",")
    return float(f[1]) if len(f) == 3 else 0.0


def _median(values: list) -> str:
    v = [x for x in values if x is not None]
    return "-" if not v else f"{np.median(v):.2f}"


def diagnosis_lines(diag: dict) -> list[str]:
    """The table of :func:`fall_diagnosis`: per pushed variant, runs whose right sole lifted and their median
    lift time, runs whose CoG passed the left sole's outer edge and the median time, the median fall time, the
    median least CoG-edge distance after the push of the runs that stood and of those that fell, the moments at
    the push's start."""
    lines = ["", "How the pushed runs went over the left sole's outer edge (medians over the runs counted): the right "
             "sole unloaded (normal force below 1 N after the push began: the robot on the left sole's outer edge), "
             "the CoG's ground projection past that edge, the fall, and the least distance from the CoG to the edge "
             "after the push (negative: past it); at the push's start, the push's moment about that edge (the force "
             "at the torso's height) and gravity's (the weight at the CoG's distance to the edge):", "",
             "| controller | push's moment (N m) | gravity's (N m) | right sole unloaded (runs) | at (s) | "
             "CoG past the edge (runs) | at (s) | fell at (s) | least CoG-edge distance, stood (cm) | "
             "least CoG-edge distance, fell (cm) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for label, runs in diag.items():
        lifted = [r["lift"] for r in runs if r["lift"] is not None]
        past = [r["past"] for r in runs if r["past"] is not None]
        gap_s = [100 * r["least_gap"] for r in runs if r["stood"] and r["least_gap"] is not None]
        gap_f = [100 * r["least_gap"] for r in runs if not r["stood"] and r["least_gap"] is not None]
        lines.append(f"| {label} | {_median([r['push_moment'] for r in runs])} | "
                     f"{_median([r['gravity_moment'] for r in runs])} | {len(lifted)} of {len(runs)} | {_median(lifted)} | {len(past)} | {_median(past)} | "
                     f"{_median([r['fell'] for r in runs if not r['stood']])} | {_median(gap_s)} | {_median(gap_f)} |")
    return lines


def _ms(v) -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{1e3 * v:.1f}"


def markdown(table: dict[str, dict[int, dict]], push: str, load: tuple[float, float], seen: dict | None = None,
             diag: dict | None = None) -> str:
    """The page: the counts, the target's verdict, what the MPC's problem sees (``seen``:
    :func:`what_the_model_sees`), how the pushed runs fell (``diag``: :func:`fall_diagnosis`), the per-seed
    statuses."""
    labels = list(table)
    seeds = sorted(next(iter(table.values())))
    lines = [f"The Nao pushed at the torso (`--push {push}`), seeds {seeds[0]}-{seeds[-1]} (start postures); "
             f"machine: 2 cores, 1-minute load average {load[0]:.2f} at the start, {load[1]:.2f} at the end "
             "(tick times are wall times under that load).", "",
             "| controller | stood | fell | median tick (ms) | p99 tick (ms) | ticks past the 10 ms period |",
             "|---|---|---|---|---|---|"]
    for label in labels:
        runs = table[label]
        stood = sum(r["stood"] for r in runs.values())
        med = [r["median_tick_s"] for r in runs.values() if r["median_tick_s"] is not None]
        p99 = [r["p99_tick_s"] for r in runs.values() if r["p99_tick_s"] is not None]
        over = [r["over_period"] for r in runs.values() if r["over_period"] is not None]
        lines.append(f"| {label} | {stood} | {len(runs) - stood} | {_ms(float(np.median(med)) if med else None)} | "
                     f"{_ms(float(np.median(p99)) if p99 else None)} | "
                     f"{f'{int(np.sum(over))} of {300 * len(over)}' if over else '-'} |")
    mpc = [lb for lb in labels if lb.startswith("MPC") and "no push" not in lb]
    base = [lb for lb in labels if lb.startswith("plan") and "no push" not in lb]
    if mpc and base:
        f_base = sum(not r["stood"] for r in table[base[0]].values())
        lines += ["", f"Target: MPC stands in at least {TARGET_STOOD} of 10 and the plan with the stabilizer falls in "
                  f"more ({base[0]}: fell {f_base}):"]
        for lb in mpc:
            s_mpc = sum(r["stood"] for r in table[lb].values())
            met = s_mpc >= TARGET_STOOD and f_base > len(table[lb]) - s_mpc
            lines.append(f"{'met' if met else 'missed'} by {lb} (stood {s_mpc}, fell {len(table[lb]) - s_mpc});")
        lines[-1] = lines[-1][:-1] + "."
    if seen:
        lines += ["", "Before the push (1.75 s), at its end (1.9 s) and at the second via-point (2.0 s), medians over "
                  "the seeds still standing then: the CoG in the world (x forward, y lateral), its lateral position "
                  "on the planning model at the measured joints (the fixed-base Nao, left sole at the origin: what "
                  "the MPC's problem sees), the largest joint deviation from the plan and the torso's tilt:", "",
                  "| controller | t (s) | runs | CoG x (cm) | CoG y (cm) | CoG y on the model (cm) | "
                  "largest joint deviation (rad) | torso tilt (rad) |", "|---|---|---|---|---|---|---|---|"]
        for label, per_t in seen.items():
            for t, (v, n) in per_t.items():
                if v is None:
                    lines.append(f"| {label} | {t:.2f} | 0 | - | - | - | - | - |")
                    continue
                lines.append(f"| {label} | {t:.2f} | {n} | {100 * v[0]:.2f} | {100 * v[1]:.2f} | {100 * v[2]:.2f} | "
                             f"{v[3]:.2f} | {v[4]:.3f} |")
    if diag:
        lines += diagnosis_lines(diag)
    lines += ["", "| seed | " + " | ".join(labels) + " |", "|---|" + "---|" * len(labels)]
    for s in seeds:
        cells = []
        for label in labels:
            r = table[label].get(s)
            if r is None:
                cells.append("-")
                continue
            ft = f" at {r['failure_time']:.2f} s" if r["failure_time"] is not None and not r["stood"] else ""
            cells.append(f"{'stood' if r['stood'] else 'fell'} ({r['status']}{ft})")
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    lines += ["", "![the pushed Nao's CoG](nao_mpc.png)"]
    return "\n".join(lines) + "\n"


def lead_markdown(table: dict[str, dict[int, dict]], load: tuple[float, float]) -> str:
    """The held-out check of ``experiments/nao_push_lead.toml``: per variant how many seeds stood, the statuses,
    the falls' times, and the MPC's tick."""
    lines = [f"`experiments/nao_push_lead.toml` (seeds {min(min(v) for v in table.values())}-"
             f"{max(max(v) for v in table.values())}, no choice made on them; how its lead was chosen: the file's "
             f"comment). Machine: 2 cores, 1-minute load {load[0]:.1f} at the start, {load[1]:.1f} at the end.", "",
             "| variant | stood | statuses | falls (s) | MPC tick median / p99 (ms) |", "|---|---|---|---|---|"]
    for label, seeds in table.items():
        runs = list(seeds.values())
        statuses = ", ".join(f"{st} {sum(r['status'] == st for r in runs)}" for st in sorted({r["status"] for r in runs}))
        falls = " ".join(f"{r['failure_time']:.2f}" for r in runs if not r["stood"] and r["failure_time"] is not None)
        ticks = [r["median_tick_s"] for r in runs if r["median_tick_s"] is not None]
        p99 = [r["p99_tick_s"] for r in runs if r["p99_tick_s"] is not None]
        tick = f"{_ms(float(np.median(ticks)))} / {_ms(float(np.median(p99)))}" if ticks else "-"
        lines.append(f"| {label} | {sum(r['stood'] for r in runs)} of {len(runs)} | {statuses} | {falls or '-'} | {tick} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--artifacts", default="artifacts")
    ap.add_argument("--seeds", type=int, default=None, help="the first N seeds only (default: the file's)")
    ap.add_argument("--held-out-only", action="store_true", help="only experiments/nao_push_lead.toml's page")
    args = ap.parse_args(argv)
    from raico.pipeline.engine.cache import Cache

    out = Path(args.artifacts) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    start = os.getloadavg()[0]
    cache = Cache(out / "nao_mpc")
    if args.held_out_only:
        return held_out(cache, out)
    exp, rows = run_experiment(cache, args.seeds)
    _, ceiling = run_experiment(cache, args.seeds, CEILING)
    table = per_seed([*rows, *ceiling])
    push = exp.base["execute"]["push"][0]
    _, _, t0, dur = push.rsplit(":", 3)
    figure(cache.root, table, out / "nao_mpc.png", (float(t0), float(dur)))
    (out / "nao_mpc.json").write_text(json.dumps({"push": push, "runs": table}, indent=2, allow_nan=True))
    seen = what_the_model_sees(cache.root, table, SEEN_AT)
    diag = fall_diagnosis(cache.root, table, (float(t0), float(dur)), exp_force_y(push))
    page = markdown(table, push, (start, os.getloadavg()[0]), seen, diag)
    (out / "nao_mpc.md").write_text(page)
    sys.stdout.write(page)
    return held_out(cache, out)


def held_out(cache, out: Path) -> int:
    """Run ``experiments/nao_push_lead.toml`` and write its page ``nao_mpc_lead.md``."""
    start = os.getloadavg()[0]
    _, rows = run_experiment(cache, None, LEAD)
    lead = lead_markdown(per_seed(rows), (start, os.getloadavg()[0]))
    (out / "nao_mpc_lead.md").write_text(lead)
    sys.stdout.write(lead)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
