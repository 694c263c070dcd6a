"""The ``raico`` command line: thin Typer wrappers over the stages.

Every stage command accepts the shared options ``--artifacts DIR`` (env
``RAICO_ARTIFACTS``), ``--seed``, ``--no-record``, ``--quiet`` and ``--json``; with
``--json`` it prints one JSON line ``{"stage", "key", "path", "cached", "status",
"metrics"}`` on stdout. Bad input prints one line ``raico: error: ...`` on stderr and exits
non-zero, and nothing half-written is left behind.
"""

# ruff: noqa: E402  (the signal handlers below are installed before the slow imports)
from __future__ import annotations

import os
import signal
import sys

# The raico command quiets Rerun's Rust-side log lines (e.g. its file writer's own coloured errors,
# which the command reports as one line instead); a RUST_LOG the user set wins. Here, in the
# command's module, not in the library modules: importing pipeline.recordings.rerun_io or the stages leaves
# RUST_LOG to the user. Set before Rerun loads (it reads RUST_LOG when it is imported).
os.environ.setdefault("RUST_LOG", "off")


def _exit_at_once(signum: int, frame) -> None:
    """SIGINT/SIGTERM while the modules load: nothing is written yet and no child runs."""
    os.write(2, f"raico: error: interrupted by {signal.Signals(signum).name}\n".encode())
    os._exit(128 + signum)


if os.path.basename(sys.argv[0]) == "raico" or __name__ == "__main__":
    if "multiprocessing.spawn" in sys.modules:  # a pool worker of the CLI re-importing its main module
        from pipeline.lifecycle import die_with_parent

        die_with_parent(os.environ.get("RAICO_PARENT_PID"))
    else:  # the CLI itself: Ctrl-C during the imports is one line, too (main() installs the real handlers)
        for _sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(_sig, _exit_at_once)

import dataclasses
import functools
import inspect
import json
import typing
from pathlib import Path
from typing import Annotated, Any

import typer
from typer.core import TyperGroup

from pipeline.errors import BadInput, MissingArtifact, RaicoError, StorageError, check_folder, os_error_text
from pipeline.lifecycle import Interrupted, install_signal_handlers, interrupt_in, stop_resource_tracker

if typing.TYPE_CHECKING:
    from pipeline.engine.cache import Cache
    from pipeline.engine.runner import Outcome
    from pipeline.engine.ui import Reporter


class _LazyStageGroup(TyperGroup):
    """The ``raico`` group with the stage commands built on first use: ``raico --help`` lists them from
    the registry's names and one-line descriptions, so help, ``--version`` and usage errors start without
    importing a stage (Drake, crocoddyl, scipy); ``raico plan ...`` imports the plan stage only."""

    def parse_args(self, ctx, args: list[str]) -> list[str]:
        if not args and self.no_args_is_help and not ctx.resilient_parsing:  # plain `raico`: the help, exit 0
            typer.echo(ctx.get_help())
            ctx.exit(0)
        return super().parse_args(ctx, args)

    def list_commands(self, ctx) -> list[str]:
        from stages.registry import stage_names

        return [*stage_names(), *(c for c in super().list_commands(ctx) if c not in stage_names())]

    def get_command(self, ctx, name: str):
        from stages.registry import stage_names

        if name in stage_names() and name not in self.commands:
            self.commands[name] = _stage_click_command(name)
        return _with_docs(super().get_command(ctx, name), name)

    def format_commands(self, ctx, formatter) -> None:
        from stages.registry import DESCRIPTIONS

        names = self.list_commands(ctx)
        limit = formatter.width - 6 - max(map(len, names))   # as click's own listing
        rows = []
        for name in names:
            cmd = self.commands.get(name)
            text = _short(DESCRIPTIONS[name], limit) if name in DESCRIPTIONS else cmd.get_short_help_str(limit)
            rows.append((name, text))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


# The documentation page each command's --help ends with (docs/PAGE; `make docs` builds the site from docs/).
DOCS_PAGES = {"": "index.md", "babble": "learning.md", "fit": "learning.md", "plan": "planning.md",
              "execute": "execution.md", "evaluate": "stages.md", "learn": "learning.md", "reproduce": "results.md",
              "exp": "experiment-files.md", "exp run": "experiment-files.md", "exp show": "experiment-files.md",
              "exp diff": "experiment-files.md", "bench": "benchmarks.md", "bench suite": "benchmarks.md",
              "plot": "experiment-files.md", "compare": "experiment-files.md", "ls": "cache.md", "show": "stages.md"}


def docs_line(command: str) -> str:
    """The last line of ``raico COMMAND --help``: the page that documents it."""
    return f"Docs: docs/{DOCS_PAGES[command]}"


def _with_docs(cmd, path: str):
    """``cmd`` (and its subcommands) with the docs line as the epilog of its help."""
    if cmd is not None and path in DOCS_PAGES:
        cmd.epilog = docs_line(path)
        for name, sub in getattr(cmd, "commands", {}).items():
            _with_docs(sub, f"{path} {name}")
    return cmd


def _short(text: str, limit: int = 70) -> str:
    """Click's short help: the first sentence, cut at ``limit`` characters."""
    first = text.split(". ")[0].split("; ")[0]
    return first if len(first) <= limit else first[: limit - 3].rsplit(" ", 1)[0] + "..."


app = typer.Typer(cls=_LazyStageGroup, add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  rich_markup_mode=None, epilog=docs_line(""),
                  help="raico: probabilistic movement planning (AICO, R-AICO, iLQG) on Drake "
                       "plants, with cached stages and Rerun recordings.")

Artifacts = Annotated[str | None, typer.Option(
    "--artifacts", envvar="RAICO_ARTIFACTS", help="Cache folder (default ./artifacts).")]
NoRecord = Annotated[bool, typer.Option("--no-record", help="Skip the .rrd recording and MCAP.")]
Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="No progress or messages on stderr.")]
Json = Annotated[bool, typer.Option("--json", help="Print one JSON line with the outcome.")]
# where the runs of a command that runs many execute (exp run, bench suite, reproduce): one set of options
ExecutorName = Annotated[str, typer.Option("--executor", help="Where the runs execute: serial (this process), "
                                           "process (one pool of --jobs worker processes; --jobs 1 runs here) or "
                                           "ray (a local Ray instance with --jobs CPUs, or the cluster at "
                                           "--address).")]
Address = Annotated[str | None, typer.Option("--address", help="Ray cluster to run on (HOST:PORT of its head, "
                                             "or auto); goes with --executor ray. A head started with a token "
                                             "needs RAY_AUTH_MODE=token and its token here, as `ray start`.")]


def executor_of(name: str, jobs: int, address: str | None):
    """The executor of ``--executor``, ``--jobs`` and ``--address`` (:class:`BadInput` on a bad value, before
    any work; nothing starts until the first run that is not cached)."""
    from pipeline.engine.executors import make_executor

    if not 1 <= jobs <= 64:
        raise BadInput("--jobs must be in [1, 64]")
    return make_executor(name, jobs, address)


def version_text() -> str:
    """``raico VERSION`` (the installed package's version)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"raico {version('raico')}"
    except PackageNotFoundError:  # a source tree that was not installed
        return "raico (not installed)"


def _print_version(value: bool) -> None:
    if value:
        typer.echo(version_text())
        raise typer.Exit(0)


@app.callback()
def _global(version: Annotated[bool, typer.Option("--version", callback=_print_version, is_eager=True,
                                                  help="Print raico's version and exit.")] = False) -> None:
    """raico: probabilistic movement planning (AICO, R-AICO, iLQG) on Drake plants, with cached stages and
    Rerun recordings."""
SHARED_HELP = {"seed": "Random seed."}


def fail(message: str, code: int = 2) -> None:
    """One clear line on stderr, non-zero exit."""
    typer.echo(f"raico: error: {' '.join(str(message).split())}", err=True)
    raise typer.Exit(code)


def handles_errors(fn):
    """Turn bad input and faults into one stderr line and an exit code."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except RaicoError as e:
            fail(str(e), e.exit_code)
        except Interrupted as e:
            fail(e.message(), e.exit_code)
        except OSError as e:  # the file system said no: the path and the cause
            fail(os_error_text(e), StorageError.exit_code)
        except MemoryError:
            fail("out of memory (the run was too large for this machine); nothing was cached", 1)
        except (ValueError, KeyError) as e:
            fail(str(e).strip("'\""), 2)
        except KeyboardInterrupt:
            fail("interrupted by SIGINT; the interrupted run left no partial artifact", 130)
        except Exception as e:  # a signal inside an import: the interrupt, not the import's error
            signal_ = interrupt_in(e)
            if signal_ is None:
                raise
            fail(signal_.message(), signal_.exit_code)

    return wrapper


def report(outcome: Outcome, as_json: bool, reporter: Reporter) -> None:
    """Say whether the stage ran (and why) or was cached; print the JSON line if asked."""
    from pipeline.engine import runner

    note = (outcome.metrics.get("balance") or {}).get("note") if isinstance(outcome.metrics, dict) else None
    if outcome.cached and note:  # a plan's moved via-points (stages.plan.balance): said again on a cache hit
        print(note, file=sys.stderr, flush=True)
    reporter.say(runner.outcome_line(outcome))
    if as_json:
        typer.echo(json.dumps(outcome.json_line(), default=float, allow_nan=False))


def _option(name: str, hint: Any, default: Any, help_text: str) -> inspect.Parameter:
    """A Typer option parameter for config field ``name`` (``--kebab-name``)."""
    origin = typing.get_origin(hint)
    if origin is tuple:  # repeatable input: --data A --data B
        hint, default = list[str] | None, None
    required = default is inspect.Parameter.empty
    opt = typer.Option(f"--{name.replace('_', '-')}", help=help_text, show_default=not required)
    if hint is bool:
        opt = typer.Option(f"--{name.replace('_', '-')}/--no-{name.replace('_', '-')}", help=help_text)
    return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default,
                             annotation=Annotated[hint, opt])


def config_command(name: str, cls: type, description: str, action, target: typer.Typer | None = None) -> None:
    """Register ``raico NAME``: one option per field of the config class ``cls`` (defaults and help
    from the class), plus the shared ``--artifacts``, ``--no-record``, ``--quiet`` and ``--json``.
    ``action(cache, config, record, reporter) -> Outcome`` does the work."""
    hints = typing.get_type_hints(cls)
    helps = {**SHARED_HELP, **getattr(cls, "HELP", {})}
    params = []
    unset = set()   # fields whose default "" means "the task's" (left out); a typed "" is refused
    for f in dataclasses.fields(cls):
        default = inspect.Parameter.empty if f.default is dataclasses.MISSING else f.default
        hint = hints[f.name]
        if default == "" and hint is str:
            unset.add(f.name)
            hint, default = str | None, None
        params.append(_option(f.name, hint, default, helps.get(f.name, "")))
    shared = {"artifacts": (Artifacts, None), "no_record": (NoRecord, False), "quiet": (Quiet, False),
              "json_": (Json, False)}
    params += [inspect.Parameter(k, inspect.Parameter.KEYWORD_ONLY, default=d, annotation=a)
               for k, (a, d) in shared.items()]

    def command(**kw):
        from pipeline.engine.ui import Reporter

        artifacts, no_record, quiet, as_json = (kw.pop(k) for k in ("artifacts", "no_record", "quiet", "json_"))
        for k in unset:
            if kw[k] is None:
                del kw[k]
            elif not kw[k].strip():
                raise BadInput(f"--{k.replace('_', '-')}: an empty value (leave the option out for its default)")
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in kw.items()}
        try:
            cfg = cls(**values)
            cfg.validate()
        except (TypeError, ValueError) as e:
            raise BadInput(str(e)) from None
        reporter = Reporter(quiet)
        for field_name, why in (cfg.ignored() if hasattr(cfg, "ignored") else {}).items():
            reporter.say(f"raico: note: --{field_name.replace('_', '-')} {getattr(cfg, field_name)} is ignored: "
                         f"it is {why} (not part of the cache key)")
        cache = open_cache(artifacts)
        cache.notify = reporter.say  # repairs it makes on its own (a damaged recording written again)
        outcome = action(cache, cfg, not no_record, reporter)
        report(outcome, as_json, reporter)

    typing.cast(Any, command).__signature__ = inspect.Signature(params)   # what Typer reads the options from
    command.__annotations__ = {p.name: p.annotation for p in params}
    command.__name__ = name
    command.__doc__ = description
    (target or app).command(name, help=description)(handles_errors(command))


def stage_command(name: str, target: typer.Typer | None = None) -> None:
    """``raico NAME`` for a registered stage: its config's fields, run through the cache."""
    from pipeline.engine import runner
    from stages.registry import get_stage

    stage = get_stage(name)
    config_command(name, stage.config_cls, stage.description,
                   lambda cache, cfg, record, reporter: runner.run(cache, stage, cfg, record=record,
                                                                  reporter=reporter), target)


def _stage_click_command(name: str):
    """The click command of stage ``name`` (built when the group first needs it)."""
    one = typer.Typer(add_completion=False, pretty_exceptions_enable=False, rich_markup_mode=None)
    stage_command(name, one)
    return typer.main.get_command(one)


def open_cache(artifacts: str | Path | None) -> Cache:
    """The cache at ``--artifacts`` (or ``$RAICO_ARTIFACTS``, or ``./artifacts``).

    An empty path, one that is a file or lies below a file is refused before any work; other
    OS errors (read-only, unwritable, full disk) are reported where they happen."""
    from pipeline.engine.cache import Cache
    from pipeline.engine.runner import artifacts_root
    if artifacts is not None and not str(artifacts).strip():
        raise BadInput("--artifacts: an empty path")
    root = artifacts_root(artifacts)
    if not str(root).strip():
        raise BadInput("--artifacts: an empty path")
    check_folder(root, "artifacts folder")
    return Cache(root)


COMMANDS_GROUP = "raico.commands"


def register_commands(group: typer.Typer) -> None:
    """The commands other packages add to raico: every entry point of the group ``raico.commands``
    (pyproject.toml's ``[project.entry-points."raico.commands"]``) is ``register(app)`` and is called
    here, in name order, so its commands are listed at this place (the thesis's ``reproduce``). The
    tool's layers name no such package: the package names itself in its entry point."""
    from importlib.metadata import entry_points

    for ep in sorted(entry_points(group=COMMANDS_GROUP), key=lambda e: e.name):
        ep.load()(group)


register_commands(app)


exp_app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                      rich_markup_mode=None,
                      help="Experiments written as files: variants over seeds, run through the cache, one runs table.")
app.add_typer(exp_app, name="exp")


@exp_app.command("run")
@handles_errors
def exp_run(
    file: Annotated[Path, typer.Argument(help="The experiment file (TOML; see pipeline/experiments/expfile.py).")],
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
    from pipeline.engine.ui import Reporter
    from pipeline.experiments import expfile

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
    from pipeline.experiments import expfile

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
    from pipeline.experiments import expfile

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


bench_app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                        rich_markup_mode=None, help="Benchmarks: the solver suite judged by performance profiles.")
app.add_typer(bench_app, name="bench")


@bench_app.command("suite")
@handles_errors
def bench_suite(
    file: Annotated[Path | None, typer.Argument(help="The suite's list file (default problems/suite/suite.toml; "
                                                "see pipeline/experiments/suite.py).")] = None,
    problem: Annotated[list[str] | None, typer.Option("--problem", "-p", help="Run only this problem (its label; "
                                                      "repeatable).")] = None,
    solver: Annotated[list[str] | None, typer.Option("--solver", "-s", help="Run only this solver (its label; "
                                                     "repeatable).")] = None,
    jobs: Annotated[int, typer.Option("--jobs", "-j", help="Parallel workers (1: one run at a time in this process, "
                                      "the cleanest times).")] = 1,
    executor: ExecutorName = "process",
    address: Address = None,
    out: Annotated[Path | None, typer.Option("--out", help="Folder of the page, its JSON and the profiles' PNG "
                                             "(default ARTIFACTS/bench).")] = None,
    artifacts: Artifacts = None, quiet: Quiet = False, json_: Json = False,
):
    """Every solver of the suite on every problem (each an ordinary cached plan; `raico exp show suite`),
    then per problem final cost, status, iterations, wall time, time to within 1 % of the best cost and
    limit violations, and Dolan-More performance profiles (table and PNG). With --problem/--solver the page
    and the runs table hold those cells only. A missing problem, a budget of 0 or a solver that cannot
    express a problem is one line and the suite goes on; exit 1 after it if a problem entry could not run."""
    from pipeline.engine.ui import Reporter
    from pipeline.experiments import suite as suite_mod

    pool = executor_of(executor, jobs, address)
    s = suite_mod.load(file)
    for flag, chosen, have in (("--problem", problem, [p.label for p in s.problems]),
                               ("--solver", solver, [x.label for x in s.solvers])):
        missing = [c for c in chosen or [] if c not in have]
        if missing:
            raise BadInput(f"{flag} {missing[0]}: not in the suite; choose from {', '.join(have)}")
    if problem:
        s.problems = [p for p in s.problems if p.label in problem]
    if solver:
        s.solvers = [x for x in s.solvers if x.label in solver]
    reporter = Reporter(quiet)
    cache = open_cache(artifacts)

    def say(line: str) -> None:   # the suite's bad-input lines: said even with --quiet
        typer.echo(line, err=True)

    with reporter.board() as board:
        def progress(p) -> None:
            board.update(s.name, f"suite {s.name}", p.done, p.total,
                         p.line(s.name).replace("exp ", "suite ", 1) if p.label else None)

        doc = suite_mod.bench(cache, s, pool, say, out or cache.root / "bench", progress)
    reporter.say(f"suite {s.name}: {len(s.problems)} problems x {len(s.solvers)} solvers -> {doc['outputs'][1]}")
    if json_:
        from pipeline.engine.runner import finite_json

        typer.echo(json.dumps(finite_json({k: doc[k] for k in ("suite", "profiles", "records", "outputs")}),
                              default=float, allow_nan=False))
    elif not quiet:
        typer.echo(suite_mod.markdown(doc).split("## Every run")[0].rstrip())
    bad = [p.label for p in s.problems if p.reason]
    if bad:   # the list file named what cannot run (said above, one line each): not a clean result
        say(f"suite: {len(bad)} problem entr{'y' if len(bad) == 1 else 'ies'} could not run ({', '.join(bad)}): exit 1")
        raise typer.Exit(1)


@app.command("plot")
@handles_errors
def plot(
    experiment: Annotated[str, typer.Argument(help="An experiment's name or its file.")],
    kind: Annotated[str, typer.Option("--kind", help="line: a metric against --x with bands over seeds (points "
                                      "and error bars on a categorical option); curve: cost per iteration per "
                                      "group (log axis); wall: cost against wall time per group; box: a box and "
                                      "the runs per group.")] = "line",
    x: Annotated[str | None, typer.Option("--x", help="The swept option on the x axis (--kind line).")] = None,
    metric: Annotated[str, typer.Option("--metric", "-m", help="The runs table's column plotted (line, box).")]
    = "plan.final_cost",
    group: Annotated[list[str] | None, typer.Option("--group", help="Group the runs by these options (repeatable; "
                                                    "default: every swept option that varies, but --x).")] = None,
    where: Annotated[str | None, typer.Option("--where", help="Keep rows matching a condition, as in exp show.")]
    = None,
    yscale: Annotated[str, typer.Option("--yscale", help="auto (log when the values span two decades; curve: "
                                        "log), linear or log.")] = "auto",
    ylim: Annotated[str | None, typer.Option("--ylim", help="LO,HI: the value axis's range (default: the data's; "
                                             "curve and wall: the finite values that do not explode).")] = None,
    out: Annotated[Path | None, typer.Option("--out", "-o", help="The PNG to write (default: artifacts/exp/NAME/"
                                             "KIND-METRIC.png).")] = None,
    artifacts: Artifacts = None, quiet: Quiet = False,
):
    """Plot an experiment's runs table: a metric against a swept option (median line, interquartile band over
    seeds), the cost per iteration per group, or a box per group. Legends name the options that differ."""
    from pipeline.engine.ui import Reporter
    from pipeline.experiments import plots

    if out is not None and out.suffix.lower() != ".png":
        raise BadInput(f"--out {out}: a .png file")
    cache = open_cache(artifacts)
    drawn = plots.plot_experiment(cache, experiment, kind, x, metric, group, where, yscale, ylim, out)
    Reporter(quiet).say(drawn.line)


@app.command("compare")
@handles_errors
def compare(
    keys: Annotated[list[str] | None, typer.Argument(help="Runs to compare: plan or execute keys, key prefixes or "
                                                     "STAGE/KEY (at most 9).")] = None,
    exp: Annotated[str | None, typer.Option("--exp", help="Compare runs of this experiment (its name or file) "
                                            "instead: those --where keeps.")] = None,
    where: Annotated[str | None, typer.Option("--where", help="With --exp: the runs to compare, a condition on "
                                              "the runs table as in exp show, e.g. \"seed == 0\".")] = None,
    stage: Annotated[str | None, typer.Option("--stage", help="With --exp: plan or execute (default: the "
                                              "experiment's first stage).")] = None,
    out: Annotated[Path | None, typer.Option("--out", "-o", help="The recording to write (default: "
                                             "artifacts/compare/HASH.rrd).")] = None,
    open_: Annotated[bool, typer.Option("--open", help="Open the recording in the Rerun viewer.")] = False,
    artifacts: Artifacts = None, quiet: Quiet = False, json_: Json = False,
):
    """Put up to 9 runs into one Rerun recording on one timeline, each under its own entity path named by
    the options that differ, with a generated layout: a 3D view per run beside overlaid joint angles (and
    each run's log10 cost per iteration on the iteration timeline)."""
    from pipeline.engine.ui import Reporter
    from pipeline.experiments import compare as cmp

    if out is not None and out.suffix != ".rrd":
        raise BadInput(f"--out {out}: a .rrd file")
    cache = open_cache(artifacts)
    path, runs = cmp.compare(cache, list(keys or []), exp, where, stage, out)
    reporter = Reporter(quiet)
    reporter.say(f"compare: {len(runs)} runs -> {path}")
    for r in runs:
        reporter.say(f"  {r.label}: {r.ref}")
    if json_:
        typer.echo(json.dumps({"recording": str(path), "runs": {r.label: r.ref for r in runs}}))
    if open_:
        open_viewer(str(path))


def describe_entry(cache: Cache, info) -> dict:
    """What a listing shows of an entry: plant, task, solver (or dynamics), status and headline
    metric. An execution or evaluation takes plant, task and solver from its plan."""
    meta = info.meta or {}
    cfg = dict(meta.get("config") or {})
    for ref in meta.get("inputs") or []:
        if "plant" in cfg or not ref.startswith("plan/"):
            continue
        try:
            cfg = {**json.loads((cache.root / ref / "meta.json").read_text()).get("config", {}), **cfg}
        except (OSError, ValueError):
            pass
    m = meta.get("metrics") or {}
    headline = {"plan": ("final_cost", m.get("final_cost")), "evaluate": ("final_cost", m.get("final_cost")),
                "execute": ("rmse", m.get("rmse_planned_executed")),
                "fit": ("heldout_rmse", m.get("heldout_rmse_overall")),
                "babble": ("samples", m.get("samples")),
                "learn": ("gp_error_last", (m.get("gp_error") or [None])[-1])}.get(info.stage, ("", None))
    return {"plant": cfg.get("plant"), "task": cfg.get("task"),
            "solver": cfg.get("solver") or cfg.get("schedule"), "dynamics": cfg.get("dynamics"),
            "status": meta.get("status"), "metric": headline[0], "value": headline[1]}


@app.command("ls")
@handles_errors
def ls(
    stage: Annotated[str | None, typer.Argument(help="Only this stage (babble, fit, plan, execute, evaluate, learn).")]
    = None,
    artifacts: Artifacts = None,
    plant: Annotated[str | None, typer.Option(help="Only entries of this plant.")] = None,
    task: Annotated[str | None, typer.Option(help="Only entries of this task.")] = None,
    solver: Annotated[str | None, typer.Option(help="Only entries of this solver (aico, raico, ilqg, ...).")] = None,
    status: Annotated[str | None, typer.Option(help="Only entries with this status (ok, converged, diverged, ...).")]
    = None,
    all_: Annotated[bool, typer.Option("--all", help="Also list invalid entries.")] = False,
    verify: Annotated[bool, typer.Option("--verify", help="Deep check: re-hash every file of every entry.")] = False,
    json_: Json = False,
):
    """List cached artifacts with plant, task, solver, status and headline metric, filtered by them
    (valid ones; --all also shows invalid or partial entries).

    A plain listing checks each entry's own record and file sizes; --verify re-hashes every file."""
    from pipeline.engine.runner import finite_json
    from stages.registry import stage_names

    cache = open_cache(artifacts)
    known = stage_names()
    if stage is not None and stage not in known:
        raise BadInput(f"unknown stage '{stage}': choose one of {', '.join(known)}")
    for name, value in (("plant", plant), ("task", task), ("solver", solver), ("status", status)):
        if value is not None and not value.strip():
            raise BadInput(f"--{name}: an empty value")
    if not cache.root.is_dir():
        raise MissingArtifact(f"no artifacts folder {cache.root}")
    wanted = {"plant": plant, "task": task, "solver": solver, "status": status}
    for r in cache.list(stage, deep=verify):
        if not (r.valid or all_):
            continue
        d = describe_entry(cache, r)
        if any(v is not None and d[k] != v for k, v in wanted.items()):
            continue
        if json_:
            typer.echo(json.dumps(finite_json({"stage": r.stage, "key": r.key, "path": str(r.path),
                                               "valid": r.valid, "reason": r.reason, "created": r.created,
                                               "size": r.size, **d})))
        else:
            flag = f"  INVALID: {r.reason}" if not r.valid else "" if r.reason == "cached" else f"  STALE: {r.reason}"
            what = " ".join(str(d[k]) for k in ("plant", "task", "solver", "dynamics") if d[k]) or "-"
            val = d["value"]
            metric = f"{d['metric']}={val:.4g}" if isinstance(val, (int, float)) else "-"
            typer.echo(f"{r.stage:9s} {r.key}  {what:40s} {str(d['status'] or '-'):15s} {metric:24s} "
                       f"{r.created or '-':20s} {r.size / 1e6:8.2f} MB  {r.path}{flag}")


@app.command()
@handles_errors
def show(
    ref: Annotated[str, typer.Argument(help="STAGE/KEY or KEY of a cached artifact.")],
    artifacts: Artifacts = None,
    open_: Annotated[bool, typer.Option("--open", help="Open the recording in the Rerun viewer.")] = False,
    png: Annotated[Path | None, typer.Option("--png", help="Render the recording headless, as the viewer opens "
                                             "it, to this PNG (1920 x 1080; needs a Vulkan driver).")] = None,
    at: Annotated[float | None, typer.Option("--time", help="With --png: the time cursor at T s of sim_time.")]
    = None,
):
    """Print an artifact's meta.json and recording path, open its recording in Rerun, or render it to a PNG."""
    from pipeline.engine import runner
    from pipeline.engine.ui import Reporter
    if open_ and png is not None:
        raise BadInput("give --open or --png, not both")
    if at is not None and png is None:
        raise BadInput("--time goes with --png")
    if png is not None and png.suffix.lower() != ".png":
        raise BadInput(f"--png {png}: a .png file")
    if at is not None and not (at >= 0 and at < float("inf")):
        raise BadInput(f"--time {at}: a time in s, at least 0")
    cache = open_cache(artifacts)
    cache.notify = Reporter().say
    entry = runner.find_entry(cache, ref)
    rrd = entry.path / "recording.rrd"
    if open_ or png is not None:
        rec = runner.ensure_recording(cache, entry)
        if rec is None:
            raise BadInput(f"{ref} is {runner.with_article(entry.stage)} artifact, which has no recording")
        if png is not None:
            from pipeline.recordings.screenshots import render_png

            check_folder(png.parent, "output folder")
            Reporter().say(f"show {entry.stage}/{entry.key}: {render_png(rec, png, at)}")
            return
        open_viewer(rec)
        return
    config = dict(entry.meta.get("config") or {})
    if isinstance(config.get("problem"), str):  # a problem file's content, stored as canonical JSON text
        try:
            config["problem"] = json.loads(config["problem"])
        except ValueError:
            pass
    typer.echo(json.dumps({"path": str(entry.path), "recording": str(rrd) if rrd.exists() else None,
                           **{k: entry.meta.get(k) for k in ("stage", "key", "config", "inputs",
                                                             "status", "metrics", "timings")},
                           "config": config},
                          indent=2, default=str))


def open_viewer(rec: str) -> None:
    """Run the Rerun viewer on ``rec`` until it is closed; an error if it cannot start (no display,
    no viewer binary, the viewer failing), with the viewer's own error line."""
    import subprocess
    import tempfile

    if sys.platform.startswith("linux") and not any(
            os.environ.get(v) for v in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")):
        raise RaicoError(f"cannot open the Rerun viewer: no display (DISPLAY and WAYLAND_DISPLAY are unset); "
                         f"copy the recording and run `rerun {rec}` where there is one")
    exe = Path(sys.executable).with_name("rerun")
    with tempfile.TemporaryFile("w+") as log:
        try:
            res = subprocess.run([str(exe), rec], stdout=subprocess.DEVNULL, stderr=log, check=False)
        except OSError as e:
            raise StorageError(f"cannot start the Rerun viewer: {os_error_text(e, exe)}") from None
        log.seek(0)
        lines = [ln.strip() for ln in log.read().splitlines() if ln.strip()]
    if res.returncode != 0:
        why = next((ln for ln in reversed(lines) if "error" in ln.lower()), lines[-1] if lines else "")
        raise RaicoError(f"the Rerun viewer could not open {rec} (exit {res.returncode}){': ' + why if why else ''}")


def main() -> None:
    """Console entry point: usage errors, faults and SIGINT/SIGTERM become one line on stderr;
    interrupts exit 130 / 143 after the temporary folders are removed and the workers stopped."""
    install_signal_handlers()
    os.environ["RAICO_PARENT_PID"] = str(os.getpid())  # pool workers die with this process
    message = None
    try:
        code = app(standalone_mode=False)
    except typer.TyperException as e:  # typer's public base of its (vendored) click errors: usage errors exit 2
        text = e.format_message() if hasattr(e, "format_message") else str(e)
        message, code = " ".join(text.split()), e.exit_code
    except Interrupted as e:
        message, code = e.message(), e.exit_code
    except (typer.Abort, KeyboardInterrupt):
        message, code = "interrupted by SIGINT", 130
    if message is not None:
        typer.echo(f"raico: error: {message}", err=True)
    stop_resource_tracker()
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    main()
