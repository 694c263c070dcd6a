"""The thesis from Python: ``raico reproduce`` as a function (beside :mod:`raico.pipeline.interface.api`).

    from raico.thesis import api
    rows = api.reproduce(["fig3.2a"], quick=True)     # one summary per figure
"""

from __future__ import annotations

from pathlib import Path

from raico.pipeline.engine.cache import Cache
from raico.pipeline.engine.runner import artifacts_root
from raico.pipeline.engine.ui import Reporter

__all__ = ["reproduce"]


def reproduce(figures: list[str], artifacts: str | Path | None = None, quick: bool = False, jobs: int = 2,
              record: bool = True, executor: str = "process", quiet: bool = False) -> list[dict]:
    """The named experiments (``raico reproduce --figure ...``): one summary per figure (its runs,
    claims and report folder), the report README written as by the CLI."""
    from raico.thesis.figures import EXPERIMENTS, LEARN_EXPERIMENTS
    from raico.thesis.reproduce import reproduce as run_all

    unknown = [f for f in figures if f not in EXPERIMENTS and f not in LEARN_EXPERIMENTS]
    if not figures or unknown:
        raise ValueError(f"unknown experiment '{(unknown or [''])[0]}': choose one of "
                         f"{', '.join([*EXPERIMENTS, *LEARN_EXPERIMENTS])}")
    return list(run_all(Cache(artifacts_root(artifacts)), list(dict.fromkeys(figures)), quick=quick, jobs=jobs, record=record,
                        executor=executor, reporter=Reporter(quiet)))
