"""The thesis's experiments as files (raico/thesis/experiments/*.toml, read by raico.pipeline.experiments.expfile for raico reproduce and
raico exp run alike): every run keeps the cache key it had when the experiments were Python definitions
(tests/thesis_reference.py, a frozen copy of them), with and without --quick, plans, executions, noise sweeps,
open-loop integrations and learning loops; the claims are the ones the definitions named."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from raico.pipeline.engine.cache import Cache
from raico.pipeline.engine.keys import code_version, stage_key
from raico.pipeline.engine.runner import Outcome
from raico.pipeline.errors import BadInput
from raico.pipeline.experiments import expfile
from raico.pipeline.interface.cli import app
from raico.stages.registry import get_stage
from raico.thesis import figures as files
from tests import thesis_reference as python

FIGURES = list(python.EXPERIMENTS)
LEARNING = list(python.LEARN_EXPERIMENTS)


def key_of(stage: str, cfg) -> str:
    """The cache key of a run of ``cfg`` (as raico.pipeline.engine.runner computes it; its input references are whole
    ``STAGE/KEY``s, so no cache is needed to resolve them)."""
    cfg = cfg.normalized() if hasattr(cfg, "normalized") else cfg
    inputs = []
    for name in cfg.INPUTS:
        value = getattr(cfg, name)
        inputs += list(value) if isinstance(value, tuple) else [] if value is None else [value]
    return stage_key(stage, code_version(get_stage(stage)), cfg.key_dict(), inputs)


def runs_of(flow) -> list[tuple[str, str, bool, str]]:
    """Every job of a figure's flow, ``(stage, key, recorded, label)`` in order, the flow fed the keys as
    its runs' outcomes (so the executions see their plans' keys)."""
    out = []
    try:
        batch = next(flow)
        while True:
            outcomes = []
            for job in batch.jobs:
                _, stage, cfg, record = job.arg
                key = key_of(stage, cfg)
                out.append((stage, key, record, job.label))
                outcomes.append(Outcome(stage=stage, key=key, path="", cached=True, status="ok"))
            batch = flow.send(outcomes)
    except StopIteration:
        return out


def test_every_figure_is_a_file_and_the_same_experiment(tmp_path):
    assert list(files.EXPERIMENTS) == FIGURES and list(files.LEARN_EXPERIMENTS) == LEARNING
    for fid in FIGURES:
        assert files.EXPERIMENTS[fid] == python.EXPERIMENTS[fid], fid
        assert Path(files.EXPERIMENTS[fid].source).parent == files.THESIS_DIR
    for fid in LEARNING:
        assert files.LEARN_EXPERIMENTS[fid] == python.LEARN_EXPERIMENTS[fid], fid
    assert files.NOISE_SWEEPS == python.NOISE_SWEEPS and files.REFERENCE == python.REFERENCE
    # the claims are Python functions, named from the files
    from raico.thesis import claims

    named = {c for e in (*files.EXPERIMENTS.values(), *files.LEARN_EXPERIMENTS.values()) for c in e.claims}
    assert named and all(callable(claims.CLAIMS[c]) for c in named)


@pytest.mark.parametrize("quick", [False, True])
@pytest.mark.parametrize("fid", FIGURES)
def test_every_run_keeps_its_cache_key(tmp_path, fid, quick):
    cache = Cache(tmp_path)
    new = runs_of(files.experiment_flow(cache, files.EXPERIMENTS[fid], quick))
    old = runs_of(python.experiment_flow(cache, python.EXPERIMENTS[fid], quick))
    assert len(new) == len(old) > 0
    assert new == old
    assert sum(stage == "plan" for stage, *_ in new) == files.EXPERIMENTS[fid].run_count(quick)
    # raico exp run of the same file makes the same plans (the integrator comparison's too, not in --quick)
    fexp = expfile.load(files.EXPERIMENTS[fid].source, quick=quick)
    expfile.validate(fexp)
    assert sorted(key_of("plan", expfile.first_config(fexp, r)) for r in fexp.runs) == \
        sorted(key for stage, key, *_ in new if stage == "plan")


@pytest.mark.parametrize("quick", [False, True])
@pytest.mark.parametrize("fid", LEARNING)
def test_every_learning_loop_keeps_its_cache_key(tmp_path, fid, quick):
    cache = Cache(tmp_path)
    new = runs_of(files.learn_flow(cache, files.LEARN_EXPERIMENTS[fid], quick))
    old = runs_of(python.learn_flow(cache, python.LEARN_EXPERIMENTS[fid], quick))
    assert len(new) == len(old) > 0 and new == old


def test_the_thesis_files_run_as_any_experiment(tmp_path):
    res = CliRunner().invoke(app, ["exp", "run", str(files.THESIS_DIR / "fig3.2c.toml"), "--dry-run", "--json",
                                   "--artifacts", str(tmp_path)])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout.splitlines()[-1])
    assert (doc["runs"], doc["cached"]) == (files.EXPERIMENTS["fig3.2c"].run_count(False), 0)
    assert doc["variants"] == len(files.EXPERIMENTS["fig3.2c"].variants)


@pytest.mark.parametrize("change,needle", [
    (('label = "R-AICO a=10"', 'label = "R-AICO ten"'), "point 'R-AICO ten': the figures and claims call these "
                                                         "options 'R-AICO a=10'"),
    (('noise_sweep = "R-AICO a=1"', 'noise_sweep = "R-AICO a=1"\ncolour = "red"'), "[reproduce] colour: valid keys"),
    (('execute = ["R-AICO a=1"]', 'execute = ["R-AICO a=2"]'), "[reproduce] execute: no point 'R-AICO a=2'"),
    (('q0_std = 0.05', 'q0_std = 0.05\nsigma_weight = 1.0'), "[base] sigma_weight: a figure's base options are"),
    (('seeds = "range(10)"', 'seeds = "range(2, 10)"'), "seeds: the seeds of a figure are range(N)"),
    (('"executed_reaches",', '"executed_reaches",\n    "executed_flies",'), "claim 'executed_flies': no such claim"),
])
def test_a_figure_file_that_does_not_make_a_figure_is_one_line(tmp_path, change, needle):
    text = (files.THESIS_DIR / "fig3.4.toml").read_text()
    assert change[0] in text
    bad = tmp_path / "fig.toml"
    bad.write_text(text.replace(change[0], change[1], 1))
    with pytest.raises(BadInput) as e:
        files.load_figure(bad)
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_the_thesis_setups_run_only_when_asked(monkeypatch):
    """The thesis's set-ups beside raico's (points that need "thesis-setups") are left out of `raico reproduce` unless
    --thesis-setups (the environment's RAICO_THESIS_SETUPS) asks for them; then each figure has them, under the
    labels its claims judge in rows of their own."""
    from raico.thesis.figures import load_figure

    monkeypatch.delenv(expfile.THESIS_SETUPS, raising=False)
    expfile.available.cache_clear()
    try:
        plain = {f: [v.label for v in load_figure(files.THESIS_DIR / f"{f}.toml").variants] for f in ("fig3.3", "fig3.4")}
        learn = [s.label for s in load_figure(files.THESIS_DIR / "fig4.1-4.2.toml").settings]
        assert not any("zero posture" in x or "thesis's cost" in x for v in plain.values() for x in v)
        assert not any(x.endswith("x0 held") for x in learn)
        monkeypatch.setenv(expfile.THESIS_SETUPS, "1")
        expfile.available.cache_clear()
        fig33 = [v.label for v in load_figure(files.THESIS_DIR / "fig3.3.toml").variants]
        fig34 = [v for v in load_figure(files.THESIS_DIR / "fig3.4.toml").variants if v.task == "balance-thesis"]
        learn = [s.label for s in load_figure(files.THESIS_DIR / "fig4.1-4.2.toml").settings]
        assert [x for x in fig33 if x.endswith("zero posture")] == ["iLQG, zero posture", "AICO, zero posture",
                                                                    "R-AICO a=1, zero posture"]
        assert len(fig34) == 4 and sum(x.endswith(", x0 held") for x in learn) == 4
    finally:
        monkeypatch.delenv(expfile.THESIS_SETUPS, raising=False)
        expfile.available.cache_clear()
