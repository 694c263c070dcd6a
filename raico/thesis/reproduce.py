"""``raico reproduce``: experiments -> per-figure folders -> ``artifacts/report/README.md``."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Generator
from pathlib import Path

from raico.pipeline.engine.atomic import write_file_atomic
from raico.pipeline.engine.cache import Cache
from raico.pipeline.engine.executors import Executor, ProcessExecutor, Scheduler, SerialExecutor, make_executor
from raico.pipeline.engine.ui import Board, Reporter
from raico.pipeline.lifecycle import Interrupted
from raico.thesis.figures import EXPERIMENTS, LEARN_EXPERIMENTS, experiment_flow, learn_flow
from raico.thesis.report import SMOKE, folder_name, markdown_claims, write_experiment_report, write_learn_report

ALL_IDS = [*EXPERIMENTS, *LEARN_EXPERIMENTS]


QUICK_REPORT = "report-quick"   # the smoke test's report folder (--quick), beside the real one


def report_dir(cache: Cache, quick: bool) -> Path:
    return cache.root / (QUICK_REPORT if quick else "report")


# Longest work first (wall times of `make reproduce`): the learning loops are long sequential chains, so they
# start first, then the plan figures, largest first, the Nao figures with their long stabilizer executions before
# the arm's many short plans (which fill the gaps at the end). A figure's executions (ready when its plans are
# done) go ahead of the plans of figures after it. Ids not listed come last, in the order given.
WORK_ORDER = ("fig4.3", "fig4.1/4.2", "fig3.2c", "fig3.2d", "fig3.4", "fig3.4-inside", "fig3.4-support", "fig3.4-single",
              "fig3.3", "fig3.2b", "fig3.2a")


def work_order(ids: list[str]) -> list[str]:
    """``ids`` (each once) in the order their work is scheduled."""
    ids = list(dict.fromkeys(ids))
    return sorted(ids, key=lambda f: (WORK_ORDER.index(f) if f in WORK_ORDER else len(WORK_ORDER), ids.index(f)))


def reproduce(cache: Cache, ids: list[str], quick: bool = False, jobs: int = 2, record: bool = True,
              reporter: Reporter | None = None, executor: str | Executor = "process",
              address: str | None = None) -> Generator[dict, None, None]:
    """Run the experiments ``ids`` on one executor (``raico.pipeline.engine.executors``: ``serial``, ``process``
    with ``jobs`` workers, or ``ray``; or an :class:`Executor`), all figures at once, longest work
    first; write each figure's report as soon as its runs are done (yielding its summary), then
    (re)write the report README.

    An interrupt (:class:`~raico.pipeline.lifecycle.Interrupted`) stops at once and learns how many runs
    of this call had finished (each is cached, so the next call starts from there)."""
    reporter = reporter or Reporter(quiet=True)
    root = report_dir(cache, quick)
    ex = executor if isinstance(executor, Executor) else make_executor(executor, jobs, address)
    fresh = cache.is_empty()  # the speed target (REPRODUCE_TARGET_S) is for a call from an empty cache
    t0, cpu0, done = time.perf_counter(), os.times(), []
    with ex, reporter.board() as board, Scheduler(ex, _progress(board), cache.cleanup_stale) as sched:
        try:
            for rank, fid in enumerate(work_order(ids)):
                flow = (learn_flow(cache, LEARN_EXPERIMENTS[fid], quick, record) if fid in LEARN_EXPERIMENTS
                        else experiment_flow(cache, EXPERIMENTS[fid], quick, record))
                sched.add(fid, flow, priority=rank)
            for fid, result in sched.run():
                board.remove(fid)
                done.append(_figure_done(cache, fid, result, quick, reporter, sched.started(fid)))
                yield done[-1]
        except Interrupted as e:
            e.finished, e.scheduled, e.note = sched.finished, None, None
            raise
    write_readme(root, reporter)  # (renders the screenshots; written again below with the call's time, cheaply)
    # the executor is closed here: its worker processes have been waited for, so os.times counts their CPU
    local = isinstance(ex, (SerialExecutor, ProcessExecutor))
    cpu1 = os.times()
    if _record_call(root, done, time.perf_counter() - t0, cpu_seconds(cpu0, cpu1) if local else None,
                    cpu_seconds(cpu0, cpu1, children=False), jobs, fresh and not quick and len(done) == len(ALL_IDS)):
        write_readme(root, reporter)
    reporter.say(f"raico: report: {root / 'README.md'}")   # the last line: where to read the results


CALL = "this call"  # timings.json's entry of the whole reproduce call (the figures' entries are keyed by id)
# the target: `make reproduce` (every figure) from an empty cache in at most 10 minutes on the 2-core machine
REPRODUCE_TARGET_S = 600.0


def cpu_seconds(before: os.times_result, after: os.times_result, children: bool = True) -> float:
    """User plus system CPU seconds between two ``os.times()`` of this process and (``children``) its
    waited-for child processes."""
    keys = ("user", "system") + (("children_user", "children_system") if children else ())
    return sum(getattr(after, k) - getattr(before, k) for k in keys)


def _record_call(root: Path, done: list[dict], wall: float, cpu: float | None, main_cpu: float, jobs: int,
                 complete: bool = False) -> bool:
    """The whole call's wall time and CPU (this process and its workers, ``None`` for a remote executor;
    ``main_cpu``: this process alone: scheduling, figures, reports) into ``timings.json`` under
    :data:`CALL` (True), unless every run was cached (then the call that computed them stays: False).
    ``complete``: every figure, from an empty cache (what :data:`REPRODUCE_TARGET_S` is for)."""
    runs, cached = sum(d["runs"] for d in done), sum(d["cached_runs"] for d in done)
    path = root / TIMINGS
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        doc = {}
    if not done or (cached == runs and CALL in doc):
        return False
    doc[CALL] = {"figures": len(done), "runs": runs, "cached_runs": cached, "wall_time_s": round(wall, 1),
                 "cpu_time_s": None if cpu is None else round(cpu, 1), "main_cpu_time_s": round(main_cpu, 1),
                 "jobs": jobs, "from_empty_cache": bool(complete),
                 "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                 "load_average_1min": round(os.getloadavg()[0], 2)}
    root.mkdir(parents=True, exist_ok=True)
    write_file_atomic(path, json.dumps(doc, indent=2) + "\n")
    return True


def _progress(board: Board):
    """Scheduler events -> the board: a bar per figure, or one line per finished run."""

    def show(ev) -> None:
        line = None
        if ev.label is not None:
            line = f"raico: {ev.flow} {ev.kind} {ev.done}/{ev.total} done ({ev.label}, {ev.seconds:.1f} s)"
        board.update(ev.flow, f"{ev.flow} ({ev.total} {ev.kind} runs)", ev.done, ev.total, line)

    return show


def _figure_done(cache: Cache, fid: str, result: dict, quick: bool, reporter: Reporter, t0: float) -> dict:
    """Write the figure's report (unless it is cached), its timing and its line; its summary."""
    root = report_dir(cache, quick)
    out = root / folder_name(fid)
    if fid in LEARN_EXPERIMENTS:
        lexp = LEARN_EXPERIMENTS[fid]
        n = sum(1 if quick else s.seeds for s in lexp.settings if s.quick or not quick)
        cached = sum(x["outcome"].cached for x in result["learns"])
        doc = cached_report(out, _report_key(fid, result)) or write_learn_report(cache, lexp, result, out)
    else:
        exp = EXPERIMENTS[fid]
        n = exp.run_count(quick)
        cached = sum(p["outcome"].cached for p in (*result["plans"], *result.get("integrators", [])))
        doc = cached_report(out, _report_key(fid, result)) or write_experiment_report(cache, exp, result, out)
    _stamp_report(out, _report_key(fid, result))
    elapsed = time.perf_counter() - t0
    _record_timing(root, fid, n, cached, elapsed)
    verdicts = ", ".join(f"{r['claim']}: {r['verdict']}" for r in doc["claims"])
    if quick:
        verdicts = f"({SMOKE}) {verdicts}"
    reporter.say(f"{fid}: {n} runs ({cached} cached) in {elapsed:.1f} s -> {out}; {verdicts}")
    return {"stage": "reproduce", "figure": fid, "path": str(out), "runs": n, "cached_runs": cached,
            "wall_time_s": elapsed, "claims": doc["claims"]}


REPORT_STAMP = "report_key.txt"
TIMINGS = "timings.json"


def _record_timing(root: Path, fid: str, runs: int, cached: int, elapsed: float) -> None:
    """Wall time of this call's work on a figure (``timings.json``; the report shows it): from its first
    run handed to a worker to its report written (figures run at the same time share the workers). A
    call that found every run cached leaves the entry of the call that computed them."""
    path = root / TIMINGS
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        doc = {}
    if runs and cached == runs and fid in doc:  # served from the cache: keep the call that computed it
        return
    doc[fid] = {"runs": runs, "cached_runs": cached, "wall_time_s": round(elapsed, 2),
                "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "load_average_1min": round(os.getloadavg()[0], 2)}
    rank = {f: i for i, f in enumerate(ALL_IDS)}  # the report's order, whatever order figures finish in
    doc = dict(sorted(doc.items(), key=lambda kv: rank.get(kv[0], len(rank))))
    root.mkdir(parents=True, exist_ok=True)
    write_file_atomic(path, json.dumps(doc, indent=2) + "\n")


def _report_key(fid: str, result: dict) -> str:
    """What a figure's report is made from: the report code, the figure's experiment file (its labels,
    claims and notes) and every run's key (input-addressed, like a stage: the same runs, file and code
    give the same report)."""
    import hashlib

    from raico.pipeline.engine.keys import source_version

    keys = sorted(o.key for o in _outcomes(result))
    code = source_version("report", "raico.thesis.report", "raico.thesis.reproduce", "raico.thesis.figures", "raico.thesis.claims",
                          "raico.thesis.panels", "raico.stages.evaluate")
    exp = EXPERIMENTS.get(fid) or LEARN_EXPERIMENTS.get(fid)
    text = Path(exp.source).read_bytes() if exp is not None and exp.source else b""
    return hashlib.sha256(json.dumps([fid, code, keys, hashlib.sha256(text).hexdigest()]).encode()).hexdigest()[:16]


def _outcomes(result: dict) -> list:
    return ([p["outcome"] for p in result.get("plans", [])] + list(result.get("executions", []))
            + [x["outcome"] for x in result.get("learns", [])]
            + [o for p in result.get("integrators", []) for o in (p["outcome"], p["integration"])])


def cached_report(out: Path, key: str) -> dict | None:
    """The figure's ``claims.json`` if it was written from the same runs and code, else None."""
    try:
        if (out / REPORT_STAMP).read_text().strip() != key or not (out / "figure.png").is_file():
            return None
        return _read_claims(out / "claims.json")
    except (OSError, ValueError):
        return None


def _stamp_report(out: Path, key: str) -> None:
    write_file_atomic(out / REPORT_STAMP, key + "\n")


def _read_claims(path: Path) -> dict:
    """A figure's ``claims.json``; ``ValueError`` saying what is wrong if it is damaged."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f"unreadable ({e})") from None
    except ValueError as e:
        raise ValueError(f"not valid JSON ({e})") from None
    if not (isinstance(doc, dict) and isinstance(doc.get("figure"), str) and isinstance(doc.get("claims"), list)
            and all(isinstance(r, dict) for r in doc["claims"])):
        raise ValueError("not a claims document")
    return doc


def write_readme(root: Path, reporter: Reporter | None = None) -> None:
    """The report: every figure written so far, its claims table, deviations and recordings. A
    damaged figure report is left out with a warning (running that figure again rebuilds it)."""
    from raico.planning.tasks import TASK_NOTES
    from raico.thesis.report import (
        FIGURE_CAPTION,
        INTEGRATOR_TEXT,
        identical_results_remarks,
        markdown_integrators,
        not_holding_section,
        processor_section,
        standing_section,
    )

    reporter = reporter or Reporter(quiet=True)
    docs = []
    for fid in ALL_IDS:
        f = root / folder_name(fid) / "claims.json"
        if f.exists():
            try:
                docs.append(_read_claims(f))
            except ValueError as e:
                reporter.say(f"raico: warning: {f} is damaged ({e}); left out of the report README; "
                             f"`raico reproduce --figure {fid}` rebuilds it")
    rows = [r for d in docs for r in d["claims"]]
    quick = root.name == QUICK_REPORT
    smoke = (["**A smoke test** (`--quick`: 2 seeds and a few iterations per figure): it checks that every "
              "figure runs end to end. Its verdicts are not meaningful at this size; `make reproduce` gives the "
              "real ones.", ""] if quick else [])
    md = ["# raico reproduction report" + (": smoke test (--quick)" if quick else ""), "", *smoke,
          "Thesis: M. Mindt, *Probabilistic Inference for Movement Planning in Humanoids* (TU Darmstadt 2014).",
          "Every number below is measured by this run; verdicts follow the stated criteria.", "",
          "## Claims", "", markdown_claims(rows, smoke=quick), "",
          *([] if quick else not_holding_section(rows)), *processor_section(docs), "## Figures", "", FIGURE_CAPTION, ""]
    md += standing_section(docs, root)
    remarks = identical_results_remarks(docs)
    for d in docs:
        folder = folder_name(d["figure"])
        md += [f"### {d['figure']}: {d['description']}", "", f"![{d['figure']}]({folder}/figure.png)", ""]
        md += [line for r in remarks.get(d["figure"], []) for line in (r, "")]
        if (root / folder / "motion.png").exists():
            md += [f"![{d['figure']} motion]({folder}/motion.png)", ""]
        md += [f"- {line}" for line in d.get("findings") or []] + ([""] if d.get("findings") else [])
        if d.get("integrators"):
            md += [f"**Pseudo-dynamics integrators (appendix C).** {INTEGRATOR_TEXT}", "",
                   markdown_integrators(d["integrators"]), ""]
        md += [f"Details, run table and recordings: [{folder}/claims.md]({folder}/claims.md)", ""]
    try:
        timings = json.loads((root / TIMINGS).read_text())
    except (OSError, ValueError):
        timings = {}
    call = timings.pop(CALL, None)
    if call:
        md += ["## The latest call that ran anything", "", call_line(call), ""]
    if timings:
        md += ["## Wall time per figure (latest call that ran it)", "",
               "| figure | runs | of them cached | wall time (s) | load average (1 min) | when (UTC) |",
               "|---|---|---|---|---|---|"]
        md += [f"| {f} | {t['runs']} | {t['cached_runs']} | {t['wall_time_s']} | {t['load_average_1min']} | "
               f"{t['when']} |" for f, t in timings.items()]
        md += [""]
    shots = _screenshots(root, reporter.say)
    if shots:
        md += ["## Recordings as the Rerun viewer opens them", "",
               "Rendered headless by the native viewer (`raico/pipeline/recordings/screenshots.py`); open any run's "
               "`recording.rrd` with `raico show KEY --open`.", ""]
        md += [line for caption, png in shots for line in (f"![{caption}]({png.relative_to(root)})", "",
                                                            f"*{caption}*", "")]
    md += crocoddyl_problems_section(root)
    md += ["## Errors and inconsistencies in the thesis", "",
           "Where the thesis contradicts itself or its physics; raico follows the reading given.", "",
           "| where | what the thesis says | what raico does |", "|---|---|---|"]
    md += [f"| {where} | {what} | {done} |" for where, what, done in THESIS_ERRORS]
    md += ["", "## Deviations and choices", "", "| item | choice |", "|---|---|"]
    notes = {k: v for e in LEARN_EXPERIMENTS.values() for k, v in e.notes}
    md += [f"| {k} | {v} |" for k, v in {**DEVIATIONS, **TASK_NOTES, **notes}.items()]
    root.mkdir(parents=True, exist_ok=True)
    write_file_atomic(root / "README.md", "\n".join(md) + "\n")


def crocoddyl_problems_section(root: Path) -> list[str]:
    """The report's page on crocoddyl's own problems written as problem files (``make bench``
    measures them: ``bench/crocoddyl_problems.md`` beside the report), copied into the report with
    a pointer; nothing where the bench has not run."""
    page = root.parent / "bench" / "crocoddyl_problems.md"
    if not page.is_file():
        return []
    root.mkdir(parents=True, exist_ok=True)
    write_file_atomic(root / "crocoddyl_problems.md", page.read_text())
    return ["## crocoddyl's own problems, as problem files", "",
            "crocoddyl's Kinova reach, its Talos arm reach and the single-support phases of its humanoid taichi, "
            "written as raico problem files (`raico/problems/crocoddyl/`), solved by R-AICO, AICO, iLQG and crocoddyl's "
            "FDDP and executed in Drake; measured by the latest `make bench`, not by this call: "
            "[crocoddyl_problems.md](crocoddyl_problems.md).", ""]


def call_line(call: dict) -> str:
    """One sentence on a whole reproduce call (``timings.json``'s :data:`CALL` entry)."""
    cpu = (f", {call['cpu_time_s']} s of CPU (this process and its workers; {call['main_cpu_time_s']} s of it in "
           "this process: scheduling, figures, reports)" if call.get("cpu_time_s") is not None
           else " (CPU not counted: remote workers)")
    figures = f"{call['figures']} figure{'s' if call['figures'] != 1 else ''}"
    jobs = f"{call['jobs']} job{'s' if call['jobs'] != 1 else ''}"
    line = (f"{figures}, {call['runs']} runs ({call['cached_runs']} cached) with {jobs}: "
            f"{call['wall_time_s']} s wall (the report README and its screenshots included){cpu}; "
            f"finished {call['when']}, load average (1 min) {call['load_average_1min']}.")
    if call.get("from_empty_cache"):
        over = call["wall_time_s"] - REPRODUCE_TARGET_S
        verdict = (f"met ({-over:.0f} s to spare)" if over <= 0
                   else f"missed by {over:.0f} s ({over / REPRODUCE_TARGET_S:.0%})")
        line += (f" Every figure from an empty cache, against the target of at most {REPRODUCE_TARGET_S:.0f} s "
                 f"on the 2-core machine: {verdict}.")
    return line


def _screenshots(root: Path, say=None) -> list:
    """The report's screenshots (one plan recording per plant of the cache ``root`` belongs to, one
    learn recording per learning plant), rendered once per entry and reused; none where no renderer is
    available (said to ``say``)."""
    from raico.pipeline.recordings.screenshots import report_screenshots

    return report_screenshots(Cache(root.parent), root / "screenshots", say)


THESIS_ERRORS = (
    ("Eq. (4.1)", "the GP mean's gradient with a factor -2 (appendix E derives it without)",
     "the gradient without the factor, tested against finite differences"),
    ("Appendix D.1", "the forward mean s_t = S_t (a + A S^-1 s)^-1, with an inverse",
     "s_t = S_t (a + A S^-1 s), without it"),
    ("§3.3", "r_t = J^T C (f(q0) - x*): no J q0 term, the sign flipped",
     "r = J^T C (x* - phi(q0) + J q0)"),
    ("§4.1", "the pendulum's gravity term written with q = 0 upright, while the text starts at the stable "
     "equilibrium", "q = 0 hanging down"),
    ("§4.4", "a 300 ms horizon in which the pendulum plans several swings: not possible under +-10 N m",
     "a 2 s horizon (deviations below)"),
    ("§4.3", "one Jacobian of state and control together", "the state part into R, r, the control part into H, h; "
     "cross terms dropped"),
    ("§4.4 against the Fig. 4.2 caption", "§4.4: the algorithm explores too much \"for σ* = 1 and σ* = 0.1\"; the "
     "caption: \"σ* = 1 and σ* = 0.2\"; 0.1 is none of the values §4.4 evaluated ({0, 0.2, 1})",
     "a typo of §4.4: the claim quotes the caption (σ* = 0.2)"),
    ("Fig. 4.3 caption", "names two panels (C): the computation time and the end-effector trajectory",
     "the trajectory is (D), as §4.5 says"),
)

DEVIATIONS = {
    "integrator": "Drake 1.51 has no RK4 scheme: babbling and execution use Drake's runge_kutta5 at a fixed step "
                  "(the open-loop integration check of appendix C: runge_kutta3, exact for held accelerations)",
    "analytic discretization": "semi-implicit Euler at the planning step (equals the thesis's backward-Euler "
                               "pseudo-dynamics when controls are accelerations)",
    "analytic derivatives": "exact: AutoDiffXd of Drake's inverse dynamics, d qdd/d(q,v) = -M^-1 dID/d(q,v) "
                            "(the thesis used finite differences; the ablation 'AICO, finite differences' uses them)",
    "reflected inertia": "5e-3 kg m^2 per geared joint of arm5, biorob and Nao (keeps light links well posed)",
    "Nao stance": "left sole welded to the world; default posture leans the torso over the left leg",
    "Nao start posture": "q0 ~ N(0, 0.05^2) about that leaning posture, not about the zero posture (the thesis's "
                         "zero-mean Gaussian): the Nao's zero posture (legs straight, arms forward) puts its CoG "
                         "between the feet rather than over the welded stance sole; kept as before (the "
                         "free-standing executions build standing start states), with the thesis's spread of 0.05 rad",
    "arm5 start posture": "q0 ~ N(0, 0.05^2) about q = 0, which is the thesis's initial pose x2 = (1, 0, 0) m",
    "reference optimum": "only the claims beyond the thesis judge a final cost against the lowest median final cost any "
                         "solver run on all of the figure's initial states reaches (on fig3.2c/d crocoddyl FDDP and the "
                         "adaptive R-AICO at 100 iterations included); the thesis's claims compare the thesis's own "
                         "solvers at the figure's budget",
    "convergence criteria": "'flat': the median run's cost changes by at most 1 % per iteration over its last 5 "
                            "iterations; 'a low cost': within 1.5x the best of the thesis's solvers on the figure and "
                            "the via-points met (largest via-point error <= 1 cm, median over the runs); 'no low-cost "
                            "solution': a run diverged, above 2x that best, or the via-points missed; 'decay "
                            "exponentially fast': a rho^k + b fitted to the figure's whole budget, b never crossed by "
                            "the curve, with rho <= 0.8 and R^2 >= 0.95, per alpha",
    "figures": "the thesis's solvers' cost panels show the mean and standard deviation over the initial states, as "
               "the thesis's figures do (the band's lower edge not below the lowest run), with the median dashed; "
               "the panels beyond the thesis and against wall time show the median and interquartile range; a "
               "diverged run leaves the statistics from its divergence on and is drawn thin up to its last iterate",
    "ablations of §3.4-3.5": "AICO with the thesis's finite-difference linearizations (fig3.2c/d) and with a "
                             "learning rate of 0.5 on the belief update or on the controller (Algorithm 1 lines 13 "
                             "and 18; fig3.2b/c) run as ablations",
    "pseudo-dynamics integrators (appendix C)": "Euler, backward Euler (the default) and Heun pseudo-dynamics "
                                                "(dynamics pseudo-euler, pseudo, pseudo-heun) with R-AICO a=1 and plain "
                                                "AICO on fig3.2a's first 5 initial states (not in --quick); the thesis "
                                                "does not say what it compared them against: raico takes Drake's "
                                                "integration of the planned accelerations held per step, open loop "
                                                "(computed torque on the continuous arm, runge_kutta3 at 1 ms), which "
                                                "Heun's model matches exactly; 'no significant difference': costs "
                                                "within 10 %, via-point error medians of Drake's trajectories within "
                                                "1 mm",
    "Nao coupled hip": "25 planning joints, RHipYawPitch = LHipYawPitch in the 26-joint tree",
    "Nao execution": "computed torque on all 26 joints; Drake saturates actuation at the effort limits",
    "theta (AICO repeat rule)": "0.1 (state units), at most 3 repeats per step",
    "iterations": "40 (arm pseudo), 25 (arm analytic, Nao); beyond the thesis: crocoddyl FDDP and the adaptive "
                  "R-AICO 100 (fig3.2c/d), the FDDP ablations on the first 3 initial states; --quick: 2 seeds, "
                  "4-12 iterations",
    "GP hyperparameters": "type-II maximum likelihood by L-BFGS-B with the analytic gradient (sklearn's kernel and "
                          "bounds, own likelihood: the same values, about half the cost); in a learning loop the "
                          "first fit adds seeded random restarts, every later fit starts at the previous one's "
                          "hyperparameters, then the configured refit restarts (fig4.1/4.2: 1, fig4.3: 0)",
}
