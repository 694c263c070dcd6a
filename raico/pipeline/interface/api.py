"""raico from Python: the CLI's stages as functions returning the same artifacts.

Every function runs through the same cache as the CLI (``artifacts``, default ``./artifacts`` or
``$RAICO_ARTIFACTS``), so a run made here is a cache hit for ``raico plan ...`` and the other way
round. Keyword arguments are the stage's config fields (``raico <stage> --help`` lists them, with
``-`` for ``_``); a bad value raises ``ValueError`` with the CLI's message.

    from raico.pipeline.interface import api
    p = api.plan(plant="arm5", task="reach", dynamics="analytic", iterations=25)
    e = api.execute(plan=p.key)
    X = api.arrays(e, "rollout.npz")["X"]            # executed states (T+1, n_x)
    l = api.learn(plant="biorob", task="reach", episodes=20, alpha=2.0)
    api.show_png(p.key, "plan.png", time=0.5)         # the recording as the viewer opens it, headless
    df = api.exp_run("experiments/arm_alpha.toml")    # an experiment file: its runs table (a DataFrame)
    api.exp_show("arm-alpha")                         # grouped over seeds, as `raico exp show`
    api.plot("arm-alpha", kind="curve")               # a Plot: .path, .series, .clipped
    api.compare(exp="arm-alpha", where="seed == 0")   # {"recording": Path, "runs": {label: STAGE/KEY}}

Each returns a :class:`raico.pipeline.engine.runner.Outcome` (``key``, ``path``, ``status``, ``metrics``,
``recording``: the ``.rrd`` to open in the Rerun viewer, or in a notebook with ``rerun-notebook``).
Progress and outcome go to stderr as from the CLI (a bar on a terminal, one line per stage run or
learning episode otherwise); ``quiet=True`` silences them. A keyword the stage does not have is a
``TypeError`` that lists the valid ones.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from raico.pipeline.engine.cache import Cache
from raico.pipeline.engine.runner import Outcome

__all__ = ["arrays", "babble", "compare", "evaluate", "execute", "exp_run", "exp_show", "fit", "learn", "plan", "plot",
           "run", "show_png"]


def _cache(artifacts: str | Path | None) -> Cache:
    return Cache(Path(artifacts if artifacts is not None else os.environ.get("RAICO_ARTIFACTS", "artifacts")))


def run(stage: str, artifacts: str | Path | None = None, record: bool = True, quiet: bool = False,
        **config: Any) -> Outcome:
    """Run (or look up) one stage (``babble``, ``fit``, ``plan``, ``execute``, ``evaluate``, ``learn``) with
    the config fields ``config``; the result is cached as by the CLI."""
    import dataclasses

    from raico.pipeline.engine import runner
    from raico.pipeline.engine.ui import Reporter
    from raico.stages.registry import get_stage

    spec = get_stage(stage)
    fields = [f for f in dataclasses.fields(spec.config_cls)]
    names = [f.name for f in fields]
    unknown = [k for k in config if k not in names]
    missing = [f.name for f in fields if f.default is dataclasses.MISSING and f.name not in config]
    if unknown or missing:
        what = (f"unknown keyword {', '.join(map(repr, unknown))}" if unknown
                else f"missing keyword {', '.join(map(repr, missing))}")
        raise TypeError(f"{stage}(): {what}; its keywords are {', '.join(names)} (and artifacts, record, quiet)")
    cfg = spec.config_cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in config.items()})
    cfg.validate()
    reporter = Reporter(quiet)
    for name, why in (cfg.ignored() if hasattr(cfg, "ignored") else {}).items():
        reporter.say(f"raico: note: {name}={getattr(cfg, name)!r} is ignored: it is {why} (not part of the cache key)")
    outcome = runner.run(_cache(artifacts), spec, cfg, record=record, reporter=reporter)
    reporter.say(runner.outcome_line(outcome))
    return outcome


def babble(artifacts: str | Path | None = None, record: bool = True, quiet: bool = False,
           **config: Any) -> Outcome:
    """Motor babbling in Drake (``raico babble``)."""
    return run("babble", artifacts, record, quiet, **config)


def fit(artifacts: str | Path | None = None, record: bool = True, quiet: bool = False,
        **config: Any) -> Outcome:
    """A GP dynamics model (``raico fit``; ``data`` a list of babble/execute keys)."""
    return run("fit", artifacts, record, quiet, **config)


def plan(artifacts: str | Path | None = None, record: bool = True, quiet: bool = False,
         **config: Any) -> Outcome:
    """A plan with AICO, R-AICO, iLQG or crocoddyl FDDP (``raico plan``)."""
    return run("plan", artifacts, record, quiet, **config)


def execute(artifacts: str | Path | None = None, record: bool = True, quiet: bool = False,
            **config: Any) -> Outcome:
    """A plan executed in Drake's Simulator (``raico execute``; ``plan`` a plan key)."""
    return run("execute", artifacts, record, quiet, **config)


def evaluate(artifacts: str | Path | None = None, record: bool = True, quiet: bool = False,
             **config: Any) -> Outcome:
    """One run's evaluation (``raico evaluate``)."""
    return run("evaluate", artifacts, record, quiet, **config)


def learn(artifacts: str | Path | None = None, record: bool = True, quiet: bool = False,
          **config: Any) -> Outcome:
    """The learning loop (``raico learn``): babble, then fit, plan and execute per episode."""
    return run("learn", artifacts, record, quiet, **config)


def show_png(ref: str, png: str | Path, time: float | None = None, artifacts: str | Path | None = None) -> Path:
    """A cached run's recording (``ref``: ``KEY``, a key prefix or ``STAGE/KEY``) rendered headless as the
    Rerun viewer opens it, saved as ``png`` (1920 x 1080), the time cursor at ``time`` s of ``sim_time``
    if given (``raico show KEY --png PNG --time T``). The recording is written from the entry's data if
    missing. Raises :class:`raico.pipeline.errors.RaicoError` with one line naming what is missing where it
    cannot render (no Vulkan driver, no ``rerun`` executable), ``ValueError`` for a run without one."""
    from raico.pipeline.engine import runner
    from raico.pipeline.recordings.screenshots import render_png

    cache = _cache(artifacts)
    entry = runner.find_entry(cache, ref)
    rec = runner.ensure_recording(cache, entry)
    if rec is None:
        raise ValueError(f"{ref} is {runner.with_article(entry.stage)} artifact, which has no recording")
    return render_png(rec, png, time)


def exp_run(file: str | Path, overrides: list[str] | None = None, artifacts: str | Path | None = None,
            jobs: int = 2, executor: str = "process", record: bool = False, quiet: bool = False,
            address: str | None = None):
    """Run an experiment file (``raico exp run FILE -S ...``): every variant at every seed through the cache
    (cached runs are looked up, not run again). Returns its runs table, a pandas ``DataFrame`` (one row per
    run; a run that raised has ``status`` "error" and its reason in ``error``, as in ``runs.csv``).
    ``overrides``: the ``-S`` ones (``["alpha=3", "seeds=range(5)"]``); ``executor``, ``jobs`` and ``address``
    (a Ray cluster's ``HOST:PORT``) as the command's options. Bad input raises
    :class:`raico.pipeline.errors.BadInput` with the command's message."""
    from raico.pipeline.engine.executors import make_executor
    from raico.pipeline.engine.ui import Reporter
    from raico.pipeline.errors import BadInput
    from raico.pipeline.experiments import expfile

    exp = expfile.load(file, list(overrides or []))
    expfile.validate(exp)
    if not 1 <= jobs <= 64:
        raise BadInput("jobs must be in [1, 64]")
    cache = _cache(artifacts)
    reporter = Reporter(quiet)
    for line in exp.notes:   # what the overrides reach, and what they do not
        reporter.say(f"exp {exp.name}: {line}")
    expfile.run_reported(cache, exp, make_executor(executor, jobs, address), record, reporter)
    return expfile.read_table(cache, exp.name)[0]


def exp_show(experiment: str | Path, where: str | None = None, metrics: list[str] | None = None,
             stat: str = "median", group: bool = True, sort: str | None = None, only_changed: bool = False,
             artifacts: str | Path | None = None):
    """An experiment's runs table (its name or file) as ``raico exp show`` shows it, a pandas ``DataFrame``:
    per variant n, failures k/n and each metric's median and IQR (``stat="mean"``: mean and 95 %
    half-width) over seeds; ``group=False`` one row per run."""
    from raico.pipeline.errors import BadInput
    from raico.pipeline.experiments import expfile

    if stat not in ("median", "mean"):
        raise BadInput(f"--stat {stat}: choose median or mean")
    df, swept = expfile.read_table(_cache(artifacts), str(experiment))
    missing = [m for m in metrics or [] if m not in df.columns]
    if missing:
        raise BadInput(f"--metric {missing[0]}: no such column; metrics: "
                       + ", ".join(c for c in df.columns if c.count(".") >= 1))
    return expfile.summarize(df, swept, list(metrics) if metrics else None, stat, group, where, sort, only_changed)


def plot(experiment: str | Path, kind: str = "line", x: str | None = None, metric: str = "plan.final_cost",
         group: list[str] | None = None, where: str | None = None, yscale: str = "auto",
         ylim: tuple[float, float] | None = None, out: str | Path | None = None,
         artifacts: str | Path | None = None, quiet: bool = True):
    """``raico plot``: a figure of an experiment's runs table (``kind`` line, curve, wall or box) written as a
    PNG (default ``artifacts/exp/NAME/KIND-METRIC.png``). Returns the :class:`raico.pipeline.experiments.plots.Plot`: its
    ``path``, the numbers behind each legend entry (``series``) and what the value axis left out
    (``clipped``); ``quiet=False`` prints the command's line."""
    from raico.pipeline.engine.ui import Reporter
    from raico.pipeline.experiments.plots import plot_experiment

    drawn = plot_experiment(_cache(artifacts), str(experiment), kind, x, metric, group, where, yscale, ylim, out)
    Reporter(quiet).say(drawn.line)
    return drawn


def compare(keys: list[str] | None = None, exp: str | Path | None = None, where: str | None = None,
            stage: str | None = None, out: str | Path | None = None, artifacts: str | Path | None = None) -> dict:
    """``raico compare``: up to nine runs (``keys``, or those of experiment ``exp`` that ``where`` keeps) in one
    Rerun recording. Returns ``{"recording": Path, "runs": {label: "STAGE/KEY"}}`` (the labels: the options
    that differ between the runs)."""
    from raico.pipeline.experiments.compare import compare as compare_runs

    path, runs = compare_runs(_cache(artifacts), list(keys or []), None if exp is None else str(exp), where, stage,
                              None if out is None else Path(out))
    return {"recording": path, "runs": {r.label: r.ref for r in runs}}


def arrays(outcome: Outcome, name: str) -> dict[str, np.ndarray]:
    """The arrays of an outcome's data file (``plan.npz``, ``rollout.npz``, ``data.npz``, ``model.npz``)."""
    with np.load(Path(outcome.path) / name, allow_pickle=False) as f:
        return {k: f[k] for k in f.files}
