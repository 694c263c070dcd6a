"""``raico exp``: experiment files run (``exp run``), shown (``exp show``) and compared (``exp diff``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from raico.pipeline.errors import BadInput
from raico.pipeline.interface.cli.common import (
    Address,
    Artifacts,
    ExecutorName,
    Json,
    Quiet,
    executor_of,
    handles_errors,
    open_cache,
)

exp_app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                      rich_markup_mode=None,
                      help="Experiments written as files: variants over seeds, run through the cache, one runs table.")


@exp_app.command("run")
@handles_errors
def exp_run(
    file: Annotated[Path, typer.Argument(help="The experiment file (TOML; see raico/pipeline/experiments/expfile.py).")],
    set_: Annotated[list[str] | None, typer.Option("--set", "-S", help="Add values to a grid axis of the file "
                                                   "(KEY=A,B or KEY=range(N)); one value of another option sets "
                                                   "[base]'s for every variant (a point that sets it keeps its own, "
                                                   "as the run says); several make a new axis; seeds=range(N) sets "
                                                   "the seeds.")] = None,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Say what would run (variants, runs, cached, to "
                                          "compute); run nothing.")] = False,
    jobs: Annotated[int, typer.Option("--jobs", "-j", help="Parallel workers: processes, or the CPUs of a local "
                                      "Ray instance.")] = 2,
    executor: ExecutorName = "process",
    address: Address = None,
    record: Annotated[bool, typer.Option("--record", help="Write each run's recording (off by default: "
                                         "`raico show KEY --open` writes one from the cache).")] = False,
    artifacts: Artifacts = None, quiet: Quiet = False, json_: Json = False,
):
    """Run an experiment file: every variant at every seed, each an ordinary cached stage run (a rerun
    computes only what is missing; runs in flight in another call are waited for, not run twice). The grid
    is generated as it runs; runs shorter than a second go to the workers in batches. The runs table
    artifacts/exp/NAME/runs.parquet (with runs.csv and runs.json) is written as runs finish. Exit 1 if a
    run raised an error (its row says why), after the others ran; a diverged solver is a result."""
    from raico.pipeline.engine.ui import Reporter
    from raico.pipeline.experiments import expfile

    pool = executor_of(executor, jobs, address)   # its workers start at the first run that is not cached
    exp = expfile.load(file, set_ or [])
    expfile.validate(exp)
    cache = open_cache(artifacts)
    reporter = Reporter(quiet)
    for line in exp.notes:   # what the -S overrides reach, and what they do not
        reporter.say(f"exp {exp.name}: {line}")
    same = expfile.identical_seeds(exp)   # seeds that cannot differ: said before the runs
    if same:
        reporter.say(same)

    def summary_of(cached: int) -> dict:
        runs = expfile.run_count(exp)
        return {"experiment": exp.name, "variants": expfile.variant_count(exp), "seeds": len(exp.seeds), "runs": runs,
                "cached": cached, "to_compute": runs - cached}

    if dry_run:
        plan = expfile.dry_run(cache, exp)
        summary = summary_of(len(plan.runs) - plan.to_compute)
        for v in exp.variants:
            typer.echo(f"{v.label}: {len(exp.seeds)} seeds")
        reporter.say(f"exp {exp.name}: {summary['variants']} variants x {summary['seeds']} seeds = "
                     f"{summary['runs']} runs, {summary['cached']} cached, {summary['to_compute']} to compute")
        if json_:
            typer.echo(json.dumps(summary))
        return
    rows = expfile.run_reported(cache, exp, pool, record, reporter)
    summary = summary_of(sum(all(r.get(f"{s}.cached") is True for s in exp.stages) for r in rows))
    errors = [r for r in rows if r["status"] == "error"]     # a stage raised: the run has no result
    failed = [r for r in rows if r["failed"]]                 # ... or a solver diverged, the robot fell
    out = expfile.table_dir(cache, exp.name)
    if json_:
        typer.echo(json.dumps({**summary, "failed": len(failed), "errors": len(errors),
                               "table": str(out / expfile.TABLE)}))
    if errors:
        raise typer.Exit(1)


@exp_app.command("show")
@handles_errors
def exp_show(
    experiment: Annotated[str, typer.Argument(help="An experiment's name or its file.")],
    where: Annotated[str | None, typer.Option("--where", help="Keep rows matching a condition on the table's "
                                              "columns, e.g. \"alpha > 1 and solver == 'raico'\" (use "
                                              "backticks around names with dots).")] = None,
    sort: Annotated[str | None, typer.Option("--sort", help="Sort by this column.")] = None,
    metric: Annotated[list[str] | None, typer.Option("--metric", "-m", help="Metric columns to show "
                                                     "(repeatable; default: a few headline metrics).")] = None,
    stat: Annotated[str, typer.Option("--stat", help="median (with the interquartile range) or mean (with a 95 %% "
                                      "t-interval), over seeds.")] = "median",
    no_group: Annotated[bool, typer.Option("--no-group", help="One row per run instead of per variant.")] = False,
    only_changed: Annotated[bool, typer.Option("--only-changed", help="Leave out option columns that do not "
                                               "vary.")] = False,
    fmt: Annotated[str, typer.Option("--format", help="table, md, csv or json.")] = "table",
    artifacts: Artifacts = None,
):
    """Show an experiment's runs table grouped over seeds: per variant n, failures k/n and each metric's
    median and interquartile range (or mean and 95 % interval)."""
    from raico.pipeline.experiments import expfile

    if fmt not in ("table", "md", "csv", "json"):
        raise BadInput(f"--format {fmt}: choose one of table, md, csv, json")
    if stat not in ("median", "mean"):
        raise BadInput(f"--stat {stat}: choose median or mean")
    cache = open_cache(artifacts)
    df, swept = expfile.read_table(cache, experiment)
    if metric:
        missing = [m for m in metric if m not in df.columns]
        if missing:
            raise BadInput(f"--metric {missing[0]}: no such column; metrics: "
                           + ", ".join(c for c in df.columns if c.count(".") >= 1))
    out = expfile.summarize(df, swept, metric, stat, not no_group, where, sort, only_changed)
    typer.echo(expfile.render(out, fmt))


@exp_app.command("diff")
@handles_errors
def exp_diff(
    experiment: Annotated[str, typer.Argument(help="An experiment's name or its file.")],
    a: Annotated[str, typer.Argument(help="A variant's label (as exp show lists it), or a run's cache key (or a "
                                     "prefix of it, at least 4 characters; plan/KEY also works).")],
    b: Annotated[str, typer.Argument(help="Another variant's label, or another run's key: B - A is reported.")],
    metric: Annotated[str, typer.Option("--metric", "-m", help="The column compared (two variants).")]
    = "plan.final_cost",
    fmt: Annotated[str, typer.Option("--format", help="table or json.")] = "table",
    artifacts: Artifacts = None,
):
    """Two variants of an experiment, paired by seed: per-seed differences of a metric, their median, the
    mean's 95 % t-interval and a Wilcoxon signed-rank test (below 6 seeds: not enough seeds, no test).
    Two runs (cache keys): every metric side by side with B - A, and the options that differ."""
    from raico.pipeline.experiments import expfile

    if fmt not in ("table", "json"):
        raise BadInput(f"--format {fmt}: choose table or json")
    cache = open_cache(artifacts)
    df, swept = expfile.read_table(cache, experiment)
    labels = set(df["variant"])
    if a in labels and b in labels:
        typer.echo(expfile.render_paired(expfile.paired(df, a, b, metric), fmt))
        return
    runs = [expfile.find_run(df, x) if x not in labels else None for x in (a, b)]
    if any(x in labels for x in (a, b)) and any(r is not None for r in runs):
        raise BadInput("give two variants (paired by seed) or two runs' keys, not one of each")
    if runs[0] is None and runs[1] is None and not any(expfile.KEY_RE.match(x.split("/")[-1].lower()) for x in (a, b)):
        expfile.paired(df, a, b, metric)   # neither a variant nor a key: the variants' error, with their labels
    typer.echo(expfile.render_run_diff(expfile.run_diff(df, swept, a, b, cache), fmt))
