"""The ``raico`` command line: thin Typer wrappers over the stages, one module per verb group.

- :mod:`~raico.pipeline.interface.cli.common`: the shared options, error handling, the cache, the docs line;
- :mod:`~raico.pipeline.interface.cli.stages`: babble, fit, plan, execute, evaluate and learn, generated
  from the stages' configs (built on first use);
- :mod:`~raico.pipeline.interface.cli.exp`: ``exp run``, ``exp show``, ``exp diff``;
- :mod:`~raico.pipeline.interface.cli.bench`: ``bench suite``;
- :mod:`~raico.pipeline.interface.cli.views`: ``ls``, ``show``, ``plot``, ``compare``;
- here: the ``raico`` group :data:`app`, the commands other packages add (``raico reproduce``) and
  :func:`main`, the console entry point.

Bad input prints one line ``raico: error: ...`` on stderr and exits non-zero, and nothing
half-written is left behind.
"""

# ruff: noqa: E402  (the signal handlers below are installed before the slow imports)
from __future__ import annotations

import os
import signal
import sys

# The raico command quiets Rerun's Rust-side log lines (e.g. its file writer's own coloured errors,
# which the command reports as one line instead); a RUST_LOG the user set wins. Here, in the
# command's module, not in the library modules: importing raico.pipeline.recordings.rerun_io or the stages leaves
# RUST_LOG to the user. Set before Rerun loads (it reads RUST_LOG when it is imported).
os.environ.setdefault("RUST_LOG", "off")


def _exit_at_once(signum: int, frame) -> None:
    """SIGINT/SIGTERM while the modules load: nothing is written yet and no child runs."""
    os.write(2, f"raico: error: interrupted by {signal.Signals(signum).name}\n".encode())
    os._exit(128 + signum)


# the command itself: the `raico` script, or `python -m raico.pipeline.interface.cli` (argv[0] is "-m" while the
# package is imported, before its __main__ runs)
if os.path.basename(sys.argv[0]) == "raico" or sys.argv[0] == "-m":
    if "multiprocessing.spawn" in sys.modules:  # a pool worker of the CLI re-importing its main module
        from raico.pipeline.lifecycle import die_with_parent

        die_with_parent(os.environ.get("RAICO_PARENT_PID"))
    else:  # the CLI itself: Ctrl-C during the imports is one line, too (main() installs the real handlers)
        for _sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(_sig, _exit_at_once)

from typing import Annotated

import typer

from raico.pipeline.interface.cli import bench, exp, views
from raico.pipeline.interface.cli.common import docs_line, version_text
from raico.pipeline.interface.cli.stages import LazyStageGroup
from raico.pipeline.lifecycle import Interrupted, install_signal_handlers, stop_resource_tracker

app = typer.Typer(cls=LazyStageGroup, add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  rich_markup_mode=None, epilog=docs_line(""),
                  help="raico: probabilistic movement planning (AICO, R-AICO, iLQG) on Drake "
                       "plants, with cached stages and Rerun recordings.")


def _print_version(value: bool) -> None:
    if value:
        typer.echo(version_text())
        raise typer.Exit(0)


@app.callback()
def _global(version: Annotated[bool, typer.Option("--version", callback=_print_version, is_eager=True,
                                                  help="Print raico's version and exit.")] = False) -> None:
    """raico: probabilistic movement planning (AICO, R-AICO, iLQG) on Drake plants, with cached stages and
    Rerun recordings."""


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
views.register(app)
app.add_typer(exp.exp_app, name="exp")
app.add_typer(bench.bench_app, name="bench")


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
