"""The thesis's command, ``raico reproduce``, added to the ``raico`` command line.

The command line (:mod:`raico.pipeline.interface.cli`) knows nothing of the thesis: it calls every
``register(app)`` of the entry-point group ``raico.commands``, and pyproject.toml names
:func:`register` there (``reproduce = "raico.thesis.cli:register"``).
"""

# no ``from __future__ import annotations``: Typer reads the options from the annotations, which name
# the shared options imported inside register()
import json
from typing import Annotated

import typer


def register(app: typer.Typer) -> None:
    """Add ``reproduce`` to the ``raico`` group ``app`` (called while :mod:`raico.pipeline.interface.cli` loads;
    the shared options and helpers it uses are defined by then)."""
    from raico.pipeline.errors import BadInput
    from raico.pipeline.interface.cli.common import (
        Address,
        Artifacts,
        ExecutorName,
        Json,
        NoRecord,
        Quiet,
        executor_of,
        handles_errors,
        open_cache,
    )

    @app.command()
    @handles_errors
    def reproduce(
        figure: Annotated[list[str] | None, typer.Option("--figure", help="Experiment id (repeatable): fig3.2a, fig3.2b, fig3.2c, fig3.2d, fig3.3, fig3.4, "
                                      "fig3.4-inside, fig3.4-support, fig3.4-single, fig4.1/4.2, fig4.3.")] = None,
        all_: Annotated[bool, typer.Option("--all", help="Every experiment: the thesis's figures and raico's own.")] = False,
        quick: Annotated[bool, typer.Option("--quick", help="2 seeds and few iterations (minutes).")] = False,
        jobs: Annotated[int, typer.Option("--jobs", "-j", help="Parallel workers: processes, or the CPUs of a local "
                                          "Ray instance.")] = 2,
        executor: ExecutorName = "process",
        address: Address = None,
        thesis_setups: Annotated[bool, typer.Option("--thesis-setups", help="Also run the thesis's set-ups beside "
                                                    "raico's (the Nao's reach from the zero posture, its balancing with "
                                                    "eq. 3.7's cost, the pendulum with x0 held), each judged in rows of "
                                                    "its own; about 1.5 min more on 2 cores.")] = False,
        artifacts: Artifacts = None, no_record: NoRecord = False, quiet: Quiet = False, json_: Json = False,
    ):
        """Run experiments over their initial states in parallel (cached per run), then write the
        figure PNG and claims table of each, and the report artifacts/report/README.md.

        All requested figures share the workers (longest work first); each figure's report is written as
        soon as its runs are done. Progress: a bar per figure on a terminal, else one line per finished run."""
        import contextlib

        from raico.pipeline.engine.runner import finite_json
        from raico.pipeline.engine.ui import Reporter
        from raico.thesis import reproduce as repro

        if thesis_setups:
            from raico.thesis.figures import include_thesis_setups

            include_thesis_setups()
        ids = list(repro.ALL_IDS) if all_ else list(figure or [])
        if not ids:
            raise BadInput(f"give --figure ID or --all; experiments: {', '.join(repro.ALL_IDS)}")
        unknown = [i for i in ids if i not in repro.ALL_IDS]
        if unknown:
            raise BadInput(f"unknown experiment '{unknown[0]}': choose one of {', '.join(repro.ALL_IDS)}")
        pool = executor_of(executor, jobs, address)  # checks the name, the address and that Ray is there
        reporter = Reporter(quiet)
        cache = open_cache(artifacts)
        cache.notify = reporter.say  # damaged entries and recordings found on the way
        with contextlib.closing(repro.reproduce(cache, ids, quick=quick, jobs=jobs, record=not no_record,
                                                reporter=reporter, executor=pool)) as docs:  # closed: workers stopped
            for doc in docs:
                if json_:
                    typer.echo(json.dumps(finite_json(doc), default=float, allow_nan=False))
