"""Fixtures shared by the tests. The folders mirror the packages (``plants/``, ``planning/``, ``stages/``,
``pipeline/``, ``thesis/``, ``bench/``); ``cli/`` holds the end-to-end tests of the ``raico`` command
line; the layout, install, README and tolerance checks sit at the top. Long runs are marked ``slow``
(``make test-fast`` leaves them out)."""

from pathlib import Path

import pytest

import raico.plants.threads  # noqa: F401  (one BLAS thread: set before numpy loads)

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def repo() -> Path:
    """The repository's root folder."""
    return REPO


@pytest.fixture(scope="session")
def raico():
    """``raico(*args)``: the ``raico`` command line run in this process through Typer's CliRunner, each
    argument turned to text; returns click's ``Result`` (``exit_code``, ``stdout``, ``stderr``)."""
    from typer.testing import CliRunner

    from raico.pipeline.interface.cli import app

    runner = CliRunner()

    def invoke(*args, **kwargs):
        return runner.invoke(app, [str(a) for a in args], **kwargs)

    return invoke


@pytest.fixture(scope="session")
def crocoddyl_baseline():
    """The crocoddyl adapter (:mod:`raico.planning.crocoddyl`), or the test skipped with the reason it is not
    installed."""
    from raico.planning import crocoddyl as cm

    if not cm.AVAILABLE:
        pytest.skip(f"crocoddyl baseline: {cm.UNAVAILABLE_REASON}")
    return cm
