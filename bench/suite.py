"""The solver suite on ``make bench``'s page: ``python -m bench.suite [--artifacts DIR] [--jobs N]``.

Runs ``raico/problems/suite/suite.toml`` as ``raico bench suite`` does (:mod:`raico.pipeline.experiments.suite`: every solver on
every problem, each an ordinary cached plan in ``DIR`` executed in Drake, one run at a time in this process for the
cleanest times) and writes ``DIR/bench/suite.json``, ``suite.md`` (the page; its tables go into
docs/benchmarks.md through ``scripts/readme_numbers.py``), ``suite_profiles.png`` and ``suite_iterations.png``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def run(artifacts: Path, file: Path | None = None, jobs: int = 1) -> dict:
    """The suite's document (see :func:`raico.pipeline.experiments.suite.bench`)."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.executors import make_executor
    from raico.pipeline.experiments import suite

    s = suite.load(file)

    def say(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    def progress(p) -> None:  # an experiment's Progress (raico.pipeline.experiments.expfile)
        if p.label:
            print(p.line(s.name), flush=True)

    doc = suite.bench(Cache(Path(artifacts)), s, make_executor("process", jobs), say, Path(artifacts) / "bench",
                      progress)
    print(f"wrote {', '.join(doc['outputs'])}", flush=True)
    return doc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--artifacts", default="artifacts")
    ap.add_argument("--file", default=None, help="the suite's list file (default raico/problems/suite/suite.toml)")
    ap.add_argument("--jobs", type=int, default=1)
    args = ap.parse_args()
    run(Path(args.artifacts), args.file, args.jobs)


if __name__ == "__main__":
    main()
