"""``raico bench``: the solver suite (``bench suite``), judged by performance profiles."""

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

bench_app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                        rich_markup_mode=None, help="Benchmarks: the solver suite judged by performance profiles.")


@bench_app.command("suite")
@handles_errors
def bench_suite(
    file: Annotated[Path | None, typer.Argument(help="The suite's list file (default raico/problems/suite/suite.toml; "
                                                "see raico/pipeline/experiments/suite.py).")] = None,
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
    from raico.pipeline.engine.ui import Reporter
    from raico.pipeline.experiments import suite as suite_mod

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
        from raico.pipeline.engine.runner import finite_json

        typer.echo(json.dumps(finite_json({k: doc[k] for k in ("suite", "profiles", "records", "outputs")}),
                              default=float, allow_nan=False))
    elif not quiet:
        typer.echo(suite_mod.markdown(doc).split("## Every run")[0].rstrip())
    bad = [p.label for p in s.problems if p.reason]
    if bad:   # the list file named what cannot run (said above, one line each): not a clean result
        say(f"suite: {len(bad)} problem entr{'y' if len(bad) == 1 else 'ies'} could not run ({', '.join(bad)}): exit 1")
        raise typer.Exit(1)
