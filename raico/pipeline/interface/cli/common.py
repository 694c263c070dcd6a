"""What every ``raico`` command shares: the options, the error handling, the cache and the docs line.

A command wrapped in :func:`handles_errors` turns bad input and faults into one line
``raico: error: ...`` on stderr and a non-zero exit (:mod:`raico.pipeline.errors`' codes; an interrupt
128 + its signal), with nothing half-written left behind.
"""

from __future__ import annotations

import functools
import json
import sys
import typing
from pathlib import Path
from typing import Annotated

import typer

from raico.pipeline.errors import BadInput, RaicoError, StorageError, check_folder, os_error_text
from raico.pipeline.lifecycle import Interrupted, interrupt_in

if typing.TYPE_CHECKING:
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import Outcome
    from raico.pipeline.engine.ui import Reporter


# The documentation page each command's --help ends with (docs/PAGE; `make docs` builds the site from docs/).
DOCS_PAGES = {"": "index.md", "babble": "learning.md", "fit": "learning.md", "plan": "planning.md",
              "execute": "execution.md", "evaluate": "stages.md", "learn": "learning.md", "reproduce": "results.md",
              "exp": "experiment-files.md", "exp run": "experiment-files.md", "exp show": "experiment-files.md",
              "exp diff": "experiment-files.md", "bench": "benchmarks.md", "bench suite": "benchmarks.md",
              "plot": "experiment-files.md", "compare": "experiment-files.md", "ls": "cache.md", "show": "stages.md"}


def docs_line(command: str) -> str:
    """The last line of ``raico COMMAND --help``: the page that documents it."""
    return f"Docs: docs/{DOCS_PAGES[command]}"


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
    from raico.pipeline.engine.executors import make_executor

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
    from raico.pipeline.engine import runner

    note = (outcome.metrics.get("balance") or {}).get("note") if isinstance(outcome.metrics, dict) else None
    if outcome.cached and note:  # a plan's moved via-points (raico.stages.plan.balance): said again on a cache hit
        print(note, file=sys.stderr, flush=True)
    reporter.say(runner.outcome_line(outcome))
    if as_json:
        typer.echo(json.dumps(outcome.json_line(), default=float, allow_nan=False))


def open_cache(artifacts: str | Path | None) -> Cache:
    """The cache at ``--artifacts`` (or ``$RAICO_ARTIFACTS``, or ``./artifacts``).

    An empty path, one that is a file or lies below a file is refused before any work; other
    OS errors (read-only, unwritable, full disk) are reported where they happen."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import artifacts_root
    if artifacts is not None and not str(artifacts).strip():
        raise BadInput("--artifacts: an empty path")
    root = artifacts_root(artifacts)
    if not str(root).strip():
        raise BadInput("--artifacts: an empty path")
    check_folder(root, "artifacts folder")
    return Cache(root)
