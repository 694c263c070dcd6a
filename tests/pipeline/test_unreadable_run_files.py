"""A run's files that the runs table and the cost plots read beside the cache's own checks (``plan.npz``'s
costs, ``meta.json``): one that cannot be read leaves its cells empty (NaN, None) and is said in one line
on stderr, naming the file and what is left out; the readable runs are unchanged."""

from __future__ import annotations

import json

import numpy as np

from raico.pipeline.engine.cache import Cache
from raico.pipeline.experiments import expfile
from raico.pipeline.experiments.plots import cost_curves

GOOD, DAMAGED, OLD = "a" * 16, "b" * 16, "c" * 16


def _cache(tmp_path) -> Cache:
    """Three plan entries: one whole (3 costs), one whose ``plan.npz`` and ``meta.json`` are damaged, one
    whose ``plan.npz`` has no ``elapsed``."""
    for key in (GOOD, DAMAGED, OLD):
        (tmp_path / "plan" / key).mkdir(parents=True)
    np.savez(tmp_path / "plan" / GOOD / "plan.npz", costs=np.array([3.0, 2.0, 1.0]), elapsed=np.array([.1, .2, .3]))
    (tmp_path / "plan" / GOOD / "meta.json").write_text(json.dumps({"timings": {"compute_s": 0.5},
                                                                    "code_version": "v1"}))
    (tmp_path / "plan" / DAMAGED / "plan.npz").write_bytes(b"PK\x03\x04 not a zip")
    (tmp_path / "plan" / DAMAGED / "meta.json").write_text('{"timings": ')
    np.savez(tmp_path / "plan" / OLD / "plan.npz", costs=np.array([5.0, 4.0]))
    return Cache(tmp_path)


def test_cost_curves_say_which_plans_they_could_not_read(tmp_path, capsys):
    cache = _cache(tmp_path)
    C = cost_curves(cache, [GOOD, DAMAGED, float("nan"), OLD])
    assert np.array_equal(C[0], [3.0, 2.0, 1.0]) and np.array_equal(C[3], [5.0, 4.0, 4.0])
    assert np.isnan(C[1]).all() and np.isnan(C[2]).all()
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1
    assert err[0].startswith(f"raico: warning: 1 of 4 plans have no readable 'costs' in plan.npz (plan/{DAMAGED}: ")
    assert err[0].endswith("): their curves are left out (NaN)")
    E = cost_curves(cache, [GOOD, OLD], "elapsed")
    assert np.array_equal(E[0], [.1, .2, .3]) and np.isnan(E[1]).all()
    err = capsys.readouterr().err.splitlines()
    assert err == [f"raico: warning: 1 of 2 plans have no readable 'elapsed' in plan.npz (plan/{OLD}: KeyError: "
                   "'elapsed is not a file in the archive'): their curves are left out (NaN)"]
    cost_curves(cache, [GOOD, float("nan")])       # a run without a plan is no file to read: nothing said
    assert capsys.readouterr().err == ""


def test_the_runs_table_row_says_which_files_it_could_not_read(tmp_path, capsys):
    cache = _cache(tmp_path)
    variant = expfile.Variant("R-AICO", {"plan": {}}, {})
    exp = expfile.Experiment("e", "", ("plan",), (0,), {}, {}, {}, [])

    def row(key):
        return expfile.table_row(cache, exp, expfile.Run(variant, 0),
                                 {"plan": {"key": key, "status": "ok", "cached": True, "metrics": {}}})

    good = row(GOOD)
    assert good["plan.cost.first"] == 3.0 and good["plan.cost.iterations_to_1pct"] == 3
    assert good["plan.compute_s"] == 0.5 and good["plan.code_version"] == "v1"
    assert capsys.readouterr().err == ""
    bad = row(DAMAGED)
    assert set(bad) == set(good)   # the same columns, empty
    assert bad["plan.cost.first"] is None and bad["plan.compute_s"] is None and bad["plan.code_version"] is None
    assert bad["status"] == "ok" and bad["plan.key"] == DAMAGED
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2
    assert err[0].startswith(f"raico: warning: runs table: plan/{DAMAGED}/meta.json cannot be read (JSONDecodeError: ")
    assert err[0].endswith("): the row's plan.compute_s and plan.code_version stay empty")
    assert err[1].startswith(f"raico: warning: runs table: plan/{DAMAGED}/plan.npz cannot be read (")
    assert err[1].endswith("): its cost columns stay empty")
