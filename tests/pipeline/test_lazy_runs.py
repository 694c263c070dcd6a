"""Many runs (``raico.pipeline.engine.executors.stream``, ``expfile.run``): a grid generated as it is consumed,
runs batched into tasks (one failing run reports itself, its batch's others finish), resumed experiments
recompute nothing finished, the runs table written as runs finish, a worker's code version checked.

Module level imports stay light: pool workers import this module for its job functions."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

PENDULUM = '''
name = "{name}"
stages = ["plan"]
seeds = "range({seeds})"
[base]
plant = "pendulum"
task = "swing-up"
dynamics = "analytic"
solver = "raico"
iterations = 2
q0_std = 0.05
[grid]
{grid}
'''


def pendulum(tmp_path: Path, grid: str, seeds: int = 2, name: str = "pend") -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(PENDULUM.format(name=name, seeds=seeds, grid=grid))
    return path


# ----------------------------------------------------------------------------- job functions (run in workers)
def _square_or_fail(x: int) -> int:
    if x == 5:
        raise ZeroDivisionError("run 5 divides by zero")
    return x * x


class Stop(Exception):
    """Raised by a progress callback: the experiment stops there."""


# ----------------------------------------------------------------------------- tests
def test_a_lazy_grid_starts_its_first_run_before_the_grid_is_enumerated(tmp_path, monkeypatch):
    """10^5 points (two axes): checked axis value by axis value, counted without enumerating, and the first
    run finishes when a handful of runs have been generated."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.executors import make_executor
    from raico.pipeline.experiments import expfile

    alphas = ", ".join(str(0.1 + i / 1000) for i in range(1000))
    stds = ", ".join(str(0.01 + i / 10000) for i in range(100))
    exp = expfile.load(pendulum(tmp_path, f"alpha = [{alphas}]\nq0_std = [{stds}]", seeds=1))
    expfile.validate(exp)
    assert expfile.run_count(exp) == 100_000 and expfile.variant_count(exp) == 100_000
    assert len(list(expfile.checked_variants(exp))) == 1 + 1000 + 100 - 2   # the first combination once
    generated = []
    runs = expfile.iter_runs

    def counted(e):
        for r in runs(e):
            generated.append(r)
            yield r

    monkeypatch.setattr(expfile, "iter_runs", counted)

    def first(p: expfile.Progress) -> None:
        raise Stop(len(generated), p.done, p.total)

    with pytest.raises(Stop) as stop:
        expfile.run(Cache(tmp_path / "arts"), exp, make_executor("serial", 1), progress=first)
    n_generated, done, total = stop.value.args
    assert (done, total) == (1, 100_000) and n_generated <= 2
    assert "variants" not in exp.__dict__   # the list of every variant was never made


def test_a_failing_run_in_a_batch_reports_itself_and_the_others_finish():
    """Ten runs in tasks of four on two worker processes: run 5 raises; it is reported with its error
    (the exception's kind and text), and every other run of its task and of the others has its value."""
    from raico.pipeline.engine.executors import Item, make_executor, stream

    with make_executor("process", 2) as pool:
        done = list(stream(pool, (Item(_square_or_fail, i, tag=i) for i in range(10)), batch=4))
    by = {d.item.tag: d for d in done}
    assert sorted(by) == list(range(10))
    assert by[5].error == "ZeroDivisionError: run 5 divides by zero" and by[5].value is None
    assert all(by[i].error is None and by[i].value == i * i for i in range(10) if i != 5)


def test_an_interrupted_experiment_resumed_recomputes_nothing_finished(tmp_path, monkeypatch):
    """Interrupted after 3 of 8 runs (SIGINT, as Ctrl-C): the rows so far are readable (written as runs
    finish); the second call finds those 3 cached, computes the other 5 only, and its table equals the
    table of the same experiment run in one go elsewhere, value by value."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.executors import make_executor
    from raico.pipeline.experiments import expfile
    from raico.pipeline.lifecycle import Interrupted

    monkeypatch.setattr(expfile.TableWriter, "FLUSH_ROWS", 1)
    exp = expfile.load(pendulum(tmp_path, "alpha = [0.5, 1.0, 2.0, 4.0]"))
    cache = Cache(tmp_path / "arts")
    seen = []

    def interrupt_at_3(p: expfile.Progress) -> None:
        seen.append(len(expfile.read_table(cache, exp.name)[0]))
        if p.done == 3:
            raise Interrupted(signal.SIGINT)

    with pytest.raises(Interrupted) as stop:
        expfile.run(cache, exp, make_executor("serial", 1), progress=interrupt_at_3)
    assert (stop.value.finished, stop.value.scheduled) == (3, 8) and seen == [1, 2, 3]
    finished = {(r["variant"], r["seed"]) for r in expfile.read_table(cache, exp.name)[0].to_dict("records")}
    rows = expfile.run(cache, exp, make_executor("serial", 1))
    cached = {(r["variant"], r["seed"]) for r in rows if r["plan.cached"]}
    assert cached == finished and len(rows) == 8
    fresh = expfile.run(Cache(tmp_path / "fresh"), exp, make_executor("serial", 1))
    columns = ("variant", "alpha", "seed", "plan.key", "plan.final_cost", "plan.cost.min", "status")
    assert [[r[c] for c in columns] for r in rows] == [[r[c] for c in columns] for r in fresh]
    assert not (expfile.table_dir(cache, exp.name) / expfile.PARTS).exists()   # the whole table replaced them


def test_a_node_running_other_code_is_named_in_one_line():
    from raico.pipeline.engine.executors import VersionMismatch, check_version

    check_version(("head", "raico+abc"), ("head", "raico+abc"))
    with pytest.raises(VersionMismatch) as e:
        check_version(("10.0.0.7 (Ray node 1234abcd)", "raico+def"), ("head", "raico+abc"))
    assert str(e.value).startswith("node 10.0.0.7 (Ray node 1234abcd) runs code version raico+def, this head "
                                   "raico+abc") and "\n" not in str(e.value)


@pytest.mark.parametrize("args,needle", [
    (["--executor", "dask"], "unknown executor 'dask': choose one of serial, process, ray"),
    (["--address", "127.0.0.1:6379"], "--address goes with --executor ray"),
    (["--executor", "ray", "--address", "nohost"], "--address nohost: give HOST:PORT of the Ray head"),
    (["--jobs", "0"], "--jobs must be in [1, 64]"),
])
@pytest.mark.parametrize("command", [["exp", "run", "FILE"], ["bench", "suite"], ["reproduce", "--all"]])
def test_every_command_of_many_runs_refuses_bad_executor_values_in_one_line(raico, tmp_path, command, args, needle):
    f = pendulum(tmp_path, "alpha = [1.0]")
    res = raico(*[str(f) if a == "FILE" else a for a in command], *args, "--artifacts", tmp_path / "arts")
    assert res.exit_code == 2 and res.stderr.strip() == f"raico: error: {needle}" if "nohost" not in needle else \
        res.exit_code == 2 and needle in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "arts" / "plan").exists()


def test_the_signed_rank_p_value_is_scipy_s():
    """exp diff's p-value without importing scipy.stats (exact counts over 2^n sign patterns) equals
    scipy.stats.wilcoxon's to rounding (sums of n pmf terms: n eps); ties and zeros go to scipy."""
    import numpy as np
    from scipy import stats

    from raico.pipeline.experiments.expfile import signed_rank_p

    rng = np.random.default_rng(3)
    for n in (1, 2, 6, 10, 25, 50, 51):
        d = rng.normal(0.3, 1.0, n)
        assert signed_rank_p(d) == pytest.approx(stats.wilcoxon(d).pvalue, rel=1e-9)
    tied = np.array([1.0, -1.0, 2.0, 3.0, -4.0, 5.0, 0.0, 6.0])
    assert signed_rank_p(tied) == pytest.approx(stats.wilcoxon(tied).pvalue, rel=1e-9)


def test_a_second_call_on_the_same_file_adds_what_is_missing_and_shares_the_runs_in_flight(tmp_path):
    """Two `raico exp run` at once on one artifacts folder, the second with one more alpha: every run is
    computed once in all (a run the other call is computing is waited for through its key's lock, then
    read), and the second's table has every run of its grid."""
    import json
    import subprocess
    import sys
    import time

    import pandas as pd

    f = pendulum(tmp_path, "alpha = [0.5, 1.0, 2.0, 4.0]", seeds=2)
    f.write_text(f.read_text().replace("iterations = 2", "iterations = 10"))
    arts = tmp_path / "arts"
    raico = [str(Path(sys.executable).parent / "raico"), "exp", "run", str(f), "--executor", "serial", "--json",
             "--quiet", "--artifacts", str(arts)]
    first = subprocess.Popen(raico, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (arts / "plan").is_dir() and time.monotonic() < deadline:   # the first call has started its runs
        time.sleep(0.02)
    second = subprocess.run([*raico, "-S", "alpha=8.0"], capture_output=True, text=True, timeout=120)
    out_first, err_first = first.communicate(timeout=120)
    assert first.returncode == 0 and second.returncode == 0, (err_first, second.stderr)
    one, two = (json.loads(out.splitlines()[-1]) for out in (out_first, second.stdout))
    entries = [p for p in (arts / "plan").iterdir() if not p.name.startswith(".")]
    assert len(entries) == 10 and (one["runs"], two["runs"]) == (8, 10)
    assert one["to_compute"] + two["to_compute"] == 10   # no run computed by both
    table = pd.read_parquet(arts / "exp" / "pend" / "runs.parquet")   # whichever call finished last wrote it
    assert len(table) == 10 and set(table["alpha"]) == {0.5, 1.0, 2.0, 4.0, 8.0}
