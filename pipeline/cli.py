"""The ``raico`` command line: thin Typer wrappers over the stages (SPEC §9).

Every stage command accepts the shared options ``--artifacts DIR`` (env
``RAICO_ARTIFACTS``), ``--seed``, ``--no-record``, ``--quiet`` and ``--json``; with
``--json`` it prints one JSON line ``{"stage", "key", "path", "cached", "status",
"metrics"}`` on stdout. Bad input prints one line ``raico: error: ...`` on stderr and exits
non-zero (SPEC §12).
"""

from __future__ import annotations

import functools
import json
import sys
from pathlib import Path
from typing import Annotated

import typer
from typer._click import exceptions as click_exceptions  # typer 0.29 vendors click

from pipeline import stage_io
from pipeline.cache import Cache
from pipeline.errors import BadInput, RaicoError
from pipeline.runner import Outcome, artifacts_root, finite_json
from pipeline.ui import Reporter

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  rich_markup_mode=None,
                  help="raico: probabilistic movement planning (AICO, R-AICO, iLQG) on Drake "
                       "plants, with cached stages and Rerun recordings.")

Artifacts = Annotated[Path | None, typer.Option(
    "--artifacts", envvar="RAICO_ARTIFACTS", help="Cache folder (default ./artifacts).")]
Seed = Annotated[int, typer.Option("--seed", help="Random seed.")]
NoRecord = Annotated[bool, typer.Option("--no-record", help="Skip the .rrd recording and MCAP.")]
Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="No progress or messages on stderr.")]
Json = Annotated[bool, typer.Option("--json", help="Print one JSON line with the outcome.")]


def fail(message: str, code: int = 2) -> None:
    """One clear line on stderr, non-zero exit."""
    typer.echo(f"raico: error: {' '.join(str(message).split())}", err=True)
    raise typer.Exit(code)


def handles_errors(fn):
    """Turn bad input and faults into one stderr line and an exit code (SPEC §12)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except RaicoError as e:
            fail(str(e), e.exit_code)
        except (ValueError, KeyError) as e:
            fail(str(e).strip("'\""), 2)
        except KeyboardInterrupt:
            fail("interrupted; nothing was cached for the interrupted run", 130)

    return wrapper


def report(outcome: Outcome, as_json: bool, reporter: Reporter) -> None:
    """Say whether the stage ran (and why) or was cached; print the JSON line if asked."""
    what = "cached" if outcome.cached else f"ran ({outcome.reason})"
    reporter.say(f"{outcome.stage} {outcome.key}: {what} -> {outcome.path} [{outcome.status}]")
    if as_json:
        typer.echo(json.dumps(outcome.json_line(), default=float, allow_nan=False))


@app.command()
@handles_errors
def babble(
    plant: Annotated[str, typer.Option(help="pendulum, arm5, biorob or nao.")],
    episodes: Annotated[int, typer.Option(help="Number of babbling episodes.")] = 5,
    duration: Annotated[float, typer.Option(help="Seconds per episode.")] = 1.0,
    dt: Annotated[float, typer.Option(help="Sample period (s).")] = 0.002,
    amplitude: Annotated[float, typer.Option(help="Spread of the random knots (rad).")] = 0.6,
    seed: Seed = 0, artifacts: Artifacts = None, no_record: NoRecord = False,
    quiet: Quiet = False, json_: Json = False,
):
    """Motor babbling: random desired trajectories tracked by a PD controller in Drake."""
    from stages.babble import BabbleConfig

    cfg = BabbleConfig(plant=plant, episodes=episodes, seed=seed, duration=duration, dt=dt,
                       amplitude=amplitude)
    _validate(cfg)
    reporter = Reporter(quiet)
    cache = Cache(artifacts_root(artifacts))
    outcome = stage_io.run_babble(cache, cfg, record=not no_record, reporter=reporter)
    report(outcome, json_, reporter)


@app.command()
@handles_errors
def plan(
    plant: Annotated[str, typer.Option(help="pendulum, arm5, biorob or nao.")],
    task: Annotated[str, typer.Option(help="reach, reach-roll (arm5), balance (nao), swing-up, ...")],
    dynamics: Annotated[str, typer.Option(help="pseudo or analytic.")] = "pseudo",
    solver: Annotated[str, typer.Option(help="aico, raico or ilqg.")] = "raico",
    alpha: Annotated[float, typer.Option(help="R-AICO regularization alpha (raico only).")] = 1.0,
    gamma: Annotated[float, typer.Option(help="alpha^[n] = alpha^[n-1] gamma (raico only).")] = 1.0,
    iterations: Annotated[int, typer.Option(help="Maximum solver iterations.")] = 50,
    q0_std: Annotated[float, typer.Option("--q0-std", help="Std of q0 around the default posture (rad).")] = 0.05,
    relinearize: Annotated[bool, typer.Option(help="AICO: relinearize inside the sweeps (theta rule).")] = True,
    seed: Seed = 0, artifacts: Artifacts = None, no_record: NoRecord = False,
    quiet: Quiet = False, json_: Json = False,
):
    """Plan a movement with AICO, R-AICO or iLQG; the artifact holds the feedback controller."""
    from stages.plan.stage import PlanConfig

    cfg = PlanConfig(plant=plant, task=task, dynamics=dynamics, solver=solver, alpha=alpha,
                     gamma=gamma, iterations=iterations, seed=seed, q0_std=q0_std, relinearize=relinearize)
    _validate(cfg)
    reporter = Reporter(quiet)
    outcome = stage_io.run_plan(Cache(artifacts_root(artifacts)), cfg, record=not no_record,
                                reporter=reporter)
    report(outcome, json_, reporter)


@app.command()
@handles_errors
def execute(
    plan: Annotated[str, typer.Option("--plan", help="Key (or prefix) of a plan artifact.")],
    x0_noise: Annotated[float, typer.Option("--x0-noise", help="Std of initial joint-angle noise (rad).")] = 0.0,
    process_noise: Annotated[float, typer.Option("--process-noise", help="Std of torque noise per step (N m).")] = 0.0,
    seed: Seed = 0, artifacts: Artifacts = None, no_record: NoRecord = False,
    quiet: Quiet = False, json_: Json = False,
):
    """Run a plan's feedback controller in closed loop with the Drake plant (Drake's Simulator)."""
    from stages.execute import ExecuteConfig

    cfg = ExecuteConfig(x0_noise=x0_noise, process_noise=process_noise, seed=seed)
    _validate(cfg)
    reporter = Reporter(quiet)
    outcome = stage_io.run_execute(Cache(artifacts_root(artifacts)), plan, cfg,
                                   record=not no_record, reporter=reporter)
    report(outcome, json_, reporter)


@app.command()
@handles_errors
def evaluate(
    plan: Annotated[str, typer.Option("--plan", help="Key (or prefix) of a plan artifact.")],
    rollout: Annotated[str | None, typer.Option("--rollout", help="Key of an execute artifact of that plan.")] = None,
    artifacts: Artifacts = None, quiet: Quiet = False, json_: Json = False,
):
    """Evaluate one run: final cost, via-point errors, iterations, wall time, planned-vs-executed RMSE."""
    reporter = Reporter(quiet)
    outcome = stage_io.run_evaluate(Cache(artifacts_root(artifacts)), plan, rollout, reporter=reporter)
    report(outcome, json_, reporter)


@app.command()
@handles_errors
def reproduce(
    figure: Annotated[list[str] | None, typer.Option("--figure", help="Experiment id (repeatable), e.g. fig3.2c.")] = None,
    all_: Annotated[bool, typer.Option("--all", help="Every experiment of SPEC 10 that is implemented.")] = False,
    quick: Annotated[bool, typer.Option("--quick", help="2 seeds and few iterations (minutes).")] = False,
    jobs: Annotated[int, typer.Option("--jobs", "-j", help="Parallel worker processes.")] = 2,
    artifacts: Artifacts = None, no_record: NoRecord = False, quiet: Quiet = False, json_: Json = False,
):
    """Run experiments over their initial states in parallel (cached per run), then write the
    figure PNG and claims table of each, and the report artifacts/report/README.md."""
    from pipeline import reproduce as repro
    from pipeline.experiments import EXPERIMENTS

    ids = list(EXPERIMENTS) if all_ else list(figure or [])
    if not ids:
        raise BadInput(f"give --figure ID or --all; experiments: {', '.join(EXPERIMENTS)}")
    unknown = [i for i in ids if i not in EXPERIMENTS]
    if unknown:
        raise BadInput(f"unknown experiment '{unknown[0]}': choose one of {', '.join(EXPERIMENTS)}")
    if not 1 <= jobs <= 64:
        raise BadInput("jobs must be in [1, 64]")
    reporter = Reporter(quiet)
    cache = Cache(artifacts_root(artifacts))
    for doc in repro.reproduce(cache, ids, quick=quick, jobs=jobs, record=not no_record, reporter=reporter):
        if json_:
            typer.echo(json.dumps(finite_json(doc), default=float, allow_nan=False))


@app.command("ls")
@handles_errors
def ls(
    stage: Annotated[str | None, typer.Argument(help="Only this stage.")] = None,
    artifacts: Artifacts = None,
    all_: Annotated[bool, typer.Option("--all", help="Also list invalid entries.")] = False,
    json_: Json = False,
):
    """List cached artifacts (valid ones; --all also shows invalid or partial entries)."""
    cache = Cache(artifacts_root(artifacts))
    rows = [r for r in cache.list(stage) if r.valid or all_]
    for r in rows:
        if json_:
            typer.echo(json.dumps({"stage": r.stage, "key": r.key, "path": str(r.path),
                                   "valid": r.valid, "reason": r.reason, "created": r.created,
                                   "size": r.size}))
        else:
            flag = "" if r.valid else f"  INVALID: {r.reason}"
            typer.echo(f"{r.stage:10s} {r.key}  {r.created or '-':20s} {r.size / 1e6:8.2f} MB  "
                       f"{r.path}{flag}")


@app.command()
@handles_errors
def show(
    ref: Annotated[str, typer.Argument(help="STAGE/KEY or KEY of a cached artifact.")],
    artifacts: Artifacts = None,
    open_: Annotated[bool, typer.Option("--open", help="Open the recording in the Rerun viewer.")] = False,
):
    """Print an artifact's meta.json and recording path, or open its recording in Rerun."""
    cache = Cache(artifacts_root(artifacts))
    entry = stage_io.find_entry(cache, ref)
    rrd = entry.path / "recording.rrd"
    if open_:
        import subprocess

        if not rrd.exists():
            raise BadInput(f"{ref} has no recording")
        subprocess.run([str(Path(sys.executable).with_name("rerun")), str(rrd)], check=False)
        return
    typer.echo(json.dumps({"path": str(entry.path), "recording": str(rrd) if rrd.exists() else None,
                           **{k: entry.meta.get(k) for k in ("stage", "key", "config", "inputs",
                                                             "status", "metrics", "timings")}},
                          indent=2, default=str))


def _validate(cfg) -> None:
    try:
        cfg.validate()
    except ValueError as e:
        raise BadInput(str(e)) from None


def main() -> None:
    """Console entry point: usage errors become one line on stderr, too."""
    try:
        code = app(standalone_mode=False)
    except click_exceptions.UsageError as e:
        typer.echo(f"raico: error: {' '.join(e.format_message().split())}", err=True)
        sys.exit(2)
    except (typer.Abort, KeyboardInterrupt):
        typer.echo("raico: error: interrupted", err=True)
        sys.exit(130)
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    main()
