"""Experiment files (raico/pipeline/experiments/expfile.py, ``raico exp run`` / ``raico exp show``): variants over seeds as
ordinary cached stage runs, one runs table, summaries over seeds; bad input refused before anything runs."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from raico.pipeline.errors import BadInput
from raico.pipeline.experiments import expfile

ARM = '''
name = "alpha-arm"
description = "R-AICO's alpha against iLQG"
stages = ["plan", "execute"]
seeds = "range(2)"
[base]
plant = "arm5"
task = "reach"
iterations = 4
[grid]
alpha = [0.5, 5.0]
[[point]]
label = "ilqg"
solver = "ilqg"
'''


def write(tmp_path: Path, text: str, name: str = "exp.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_variants_are_the_grid_times_the_zip_plus_the_points(tmp_path):
    exp = expfile.load(write(tmp_path, '''
stages = ["plan"]
seeds = [3, 5]
[base]
plant = "arm5"
task = "reach"
[grid]
alpha = [1.0, 10.0]
[zip]
gamma = [1.0, 0.5]
iterations = [5, 9]
[[point]]
label = "ilqg"
solver = "ilqg"
'''), ["seeds=range(3)"])
    assert exp.seeds == (0, 1, 2) and exp.name == "exp"
    labels = [v.label for v in exp.variants]
    assert labels == ["alpha=1.0, gamma=1.0, iterations=5", "alpha=1.0, gamma=0.5, iterations=9",
                      "alpha=10.0, gamma=1.0, iterations=5", "alpha=10.0, gamma=0.5, iterations=9", "ilqg"]
    assert len(exp.runs) == 15
    ilqg = exp.variants[-1]
    assert ilqg.options["plan"] == {"plant": "arm5", "task": "reach", "solver": "ilqg"}
    assert ilqg.swept["alpha"] == 0.0                      # what the run uses: iLQG has no alpha
    cfg = expfile.first_config(exp, exp.runs[0])
    assert (cfg.alpha, cfg.gamma, cfg.iterations, cfg.seed) == (1.0, 1.0, 5, 0)
    expfile.validate(exp)


def test_overrides_parse_values():
    assert expfile.parse_override("alpha=0.1,1,10") == ("alpha", [0.1, 1, 10])
    assert expfile.parse_override("solver=ilqg,raico") == ("solver", ["ilqg", "raico"])
    assert expfile.parse_override("iterations=range(2, 4)") == ("iterations", [2, 3])
    assert expfile.parse_override("relinearize=true") == ("relinearize", [True])
    with pytest.raises(BadInput, match="expected KEY=VALUE"):
        expfile.parse_override("alpha")


@pytest.mark.parametrize("text,needle", [
    ('colour = "red"\n[base]\nplant = "arm5"\ntask = "reach"', "unknown key 'colour': valid keys are name"),
    ('[base]\nplant = "arm5"\ntask = "reach"\nalpah = 1', "unknown option 'alpah': valid are alpha,"),
    ('[base]\nplant = "arm5"\ntask = "reach"\n[grid]\nalpha = [-1.0]', "--alpha must be >= 0.0"),
    ('[base]\nplant = "arm5"\ntask = "reach"\n[grid]\niterations = ["many"]', "iterations"),
    ('[base]\nplant = "arm5"\ntask = "reach"\n[grid]\nalpha = []', "[grid] alpha must be a non-empty list"),
    ('[base]\nplant = "arm5"\ntask = "reach"\n[zip]\nalpha = [1.0]\ngamma = [1.0, 2.0]', "equal lengths"),
    ('seeds = [1, 1]\n[base]\nplant = "arm5"\ntask = "reach"', "a seed is listed twice"),
    ('seeds = "many"\n[base]\nplant = "arm5"\ntask = "reach"', "neither a list of integers nor range"),
    ('stages = ["execute"]\n[base]\nplant = "arm5"', "stages ['execute'] is not one of"),
    ('[base]\nplant = "arm5"\ntask = "reach"\n[execute]\nx0_noise = 0.1', "[execute] options, but execute"),
    ('[base]\nplant = "arm5"\ntask = "reach"\n[[point]]\nsolver = "ilqg"', "needs a unique label"),
    ('[base]\nplant = "arm5"\ntask = "reach"\n[grid]\n"execute.x0_noise" = [0.1]', "not a later stage"),
    ('[base]\nplant = "arm5"\ntask = "reach"\nseed = 3', "set the seeds with seeds = [...]"),
    ('[base\nplant = "arm5"', "not valid TOML"),
])
def test_bad_files_are_one_line_and_run_nothing(raico, tmp_path, text, needle):
    f = write(tmp_path, text)
    res = raico("exp", "run", f, "--artifacts", tmp_path / "arts")
    assert res.exit_code == 2, res.output
    assert res.stderr.count("\n") == 1 and res.stderr.startswith("raico: error: ") and needle in res.stderr, res.stderr
    assert not (tmp_path / "arts" / "plan").exists()


def test_run_twice_computes_nothing_and_a_new_value_computes_only_its_runs(raico, tmp_path):
    f = write(tmp_path, ARM)
    arts = tmp_path / "arts"
    dry = raico("exp", "run", f, "--dry-run", "--json", "--artifacts", arts)
    assert dry.exit_code == 0 and json.loads(dry.stdout.splitlines()[-1]) == {
        "experiment": "alpha-arm", "variants": 3, "seeds": 2, "runs": 6, "cached": 0, "to_compute": 6}
    assert not (arts / "plan").exists()
    first = raico("exp", "run", f, "--jobs", 1, "--json", "--artifacts", arts)
    assert first.exit_code == 0, first.output
    assert json.loads(first.stdout.splitlines()[-1])["cached"] == 0
    plans = sorted(p.name for p in (arts / "plan").iterdir())
    assert len(plans) == 6 and len(list((arts / "execute").iterdir())) == 6
    again = raico("exp", "run", f, "--json", "--artifacts", arts)
    assert json.loads(again.stdout.splitlines()[-1])["cached"] == 6
    assert sorted(p.name for p in (arts / "plan").iterdir()) == plans
    more = raico("exp", "run", f, "-S", "alpha=0.5,5.0,50.0", "--jobs", 1, "--json", "--artifacts", arts)
    line = json.loads(more.stdout.splitlines()[-1])
    assert (line["runs"], line["cached"]) == (8, 6) and len(list((arts / "plan").iterdir())) == 8
    # each run is the same cached entry a plain `raico plan` with those options makes
    cli = raico("plan", "--plant", "arm5", "--task", "reach", "--iterations", 4, "--alpha", 50.0, "--seed", 1,
                 "--no-record", "--json", "--artifacts", arts)
    assert json.loads(cli.stdout.splitlines()[-1])["cached"]
    table = pd.read_csv(arts / "exp" / "alpha-arm" / "runs.csv")
    assert len(table) == 8 and set(table["seed"]) == {0, 1}
    assert {"variant", "alpha", "solver", "plan.key", "plan.final_cost", "plan.cost.min", "execute.key",
            "execute.rmse_planned_executed", "plan.code_version", "status", "failed"} <= set(table.columns)
    row = table[(table["alpha"] == 50.0) & (table["seed"] == 1)].iloc[0]
    meta = json.loads((arts / "plan" / row["plan.key"] / "meta.json").read_text())
    assert row["plan.final_cost"] == pytest.approx(meta["metrics"]["final_cost"], rel=1e-9)
    assert row["plan.cost.min"] <= row["plan.cost.first"]
    show = raico("exp", "show", "alpha-arm", "--format", "json", "--artifacts", arts)
    groups = json.loads(show.stdout)
    assert [g["variant"] for g in groups] == ["alpha=0.5", "alpha=5.0", "alpha=50.0", "ilqg"]
    sel = table[table["variant"] == "alpha=5.0"]["plan.final_cost"].to_numpy()
    assert groups[1]["plan.final_cost"] == pytest.approx(np.median(sel)) and groups[1]["n"] == 2
    text = raico("exp", "show", f, "--where", "solver == 'raico' and alpha < 10", "--sort", "plan.final_cost",
                  "--artifacts", arts).stdout
    assert "ilqg" not in text and "alpha=50.0" not in text and "plan.final_cost (IQR)" in text


def test_set_adds_a_grid_value_and_the_table_keeps_the_others(raico, tmp_path):
    """``-S alpha=3`` adds 3 to the file's alpha axis (as the README says): the runs table keeps the file's
    variants (cached) beside the new one's runs; a key that is no grid axis becomes one."""
    f = write(tmp_path, ARM.replace('stages = ["plan", "execute"]', 'stages = ["plan"]'))
    arts = tmp_path / "arts"
    assert raico("exp", "run", f, "--jobs", 1, "--artifacts", arts).exit_code == 0
    res = raico("exp", "run", f, "-S", "alpha=3", "--jobs", 1, "--json", "--artifacts", arts)
    assert res.exit_code == 0, res.output
    line = json.loads(res.stdout.splitlines()[-1])
    assert (line["variants"], line["runs"], line["cached"]) == (4, 8, 6)
    table = pd.read_csv(arts / "exp" / "alpha-arm" / "runs.csv")
    assert sorted(set(table["variant"])) == ["alpha=0.5", "alpha=3", "alpha=5.0", "ilqg"] and len(table) == 8
    exp = expfile.load(f, ["iterations=2,3"])
    assert exp.grid == {"alpha": [0.5, 5.0], "iterations": [2, 3]}


def test_a_failing_run_is_a_row_and_the_others_go_on(raico, tmp_path):
    f = write(tmp_path, ARM.replace('[[point]]\nlabel = "ilqg"\nsolver = "ilqg"\n', "")
              .replace("alpha = [0.5, 5.0]", "alpha = [0.5]") + '[execute]\ncontroller = "pd"\n')
    arts = tmp_path / "arts"
    res = raico("exp", "run", f, "-S", "execute.controller=pd,wbc", "--jobs", 1, "--artifacts", arts)
    assert res.exit_code == 1
    assert "error: alpha=0.5, execute.controller=wbc seed 0: execute: --controller wbc is for plans" in res.stderr
    assert "4 runs (0 cached; 2 failed, of them 2 with an error)" in res.stderr
    table = pd.read_csv(arts / "exp" / "alpha-arm" / "runs.csv")
    ok, bad = table[table["execute.controller"] == "pd"], table[table["execute.controller"] == "wbc"]
    assert len(ok) == len(bad) == 2 and (ok["status"] == "ok").all() and (bad["status"] == "error").all()
    assert bad["plan.key"].notna().all() and bad["execute.key"].isna().all()
    show = json.loads(raico("exp", "show", "alpha-arm", "--format", "json", "--artifacts", arts).stdout)
    assert {g["execute.controller"]: g["failed"] for g in show} == {"pd": "0/2", "wbc": "2/2"}


def test_show_refuses_what_it_cannot_read(raico, tmp_path):
    arts = tmp_path / "arts"
    res = raico("exp", "show", "nothing", "--artifacts", arts)
    assert res.exit_code == 2 and "`raico exp run FILE` makes it" in res.stderr
    df = pd.DataFrame({"variant": ["a"], "seed": [0], "status": ["ok"], "failed": [False], "x": [1.0]})
    with pytest.raises(BadInput, match="--where 'x >>> 2'"):
        expfile.summarize(df, [], ["x"], where="x >>> 2")
    with pytest.raises(BadInput, match="--where 'y > 2'.*columns: variant, seed"):
        expfile.summarize(df, [], ["x"], where="y > 2")
    with pytest.raises(BadInput, match="--sort z: no such column"):
        expfile.summarize(df, [], ["x"], sort="z")


def test_summaries_over_seeds_on_known_numbers():
    x = np.array([1.0, 2.0, 4.0, 10.0])
    df = pd.DataFrame({"variant": ["a"] * 4 + ["b"] * 2, "alpha": [1.0] * 4 + [2.0] * 2, "seed": [0, 1, 2, 3, 0, 1],
                       "status": ["ok", "ok", "diverged", "ok", "ok", "error"],
                       "failed": [False, False, True, False, False, True],
                       "m": [*x, 5.0, math.nan]})
    med = expfile.summarize(df, ["alpha"], ["m"]).set_index("variant")
    assert med.loc["a", "m"] == 3.0 and med.loc["a", "m IQR"] == pytest.approx(np.subtract(*np.percentile(x, [75, 25])))
    assert med.loc["a", "failed"] == "1/4" and med.loc["b", "failed"] == "1/2" and med.loc["b", "n"] == 2
    mean = expfile.summarize(df, ["alpha"], ["m"], stat="mean").set_index("variant")
    half = stats.t.ppf(0.975, 3) * x.std(ddof=1) / 2.0
    assert mean.loc["a", "m"] == pytest.approx(4.25) and mean.loc["a", "m ±95%"] == pytest.approx(half)
    assert mean.loc["b", "m ±95%"] is None or math.isnan(mean.loc["b", "m ±95%"])   # one value: no interval
    flat = expfile.summarize(df, ["alpha"], ["m"], group=False)
    assert len(flat) == 6 and list(flat.columns[:2]) == ["variant", "alpha"]
    assert "alpha" not in expfile.summarize(df[df.alpha == 1.0], ["alpha"], ["m"], only_changed=True).columns
    table = expfile.render(med.reset_index(), "table")
    assert "m (IQR)" in table.splitlines()[0] and "3 (3.75)" in table


def test_the_table_takes_non_finite_metrics(tmp_path):
    """A diverged run's inf cost is null in runs.json (strict JSON) and empty in runs.csv."""
    from raico.pipeline.engine.cache import Cache

    exp = expfile.load(write(tmp_path, '[base]\nplant = "arm5"\ntask = "reach"\n'))
    row = {"experiment": exp.name, "variant": "base", "seed": 0, "plan.final_cost": math.inf, "status": "diverged",
           "failed": True}
    out = expfile.write_table(Cache(tmp_path / "arts"), exp, [row])
    assert json.loads((out / "runs.json").read_text())["rows"][0]["plan.final_cost"] is None
    assert pd.read_csv(out / "runs.csv")["plan.final_cost"].iloc[0] in ("inf", math.inf)


def test_two_variants_paired_by_seed_on_known_numbers():
    df = pd.DataFrame({"variant": ["a"] * 7 + ["b"] * 7, "seed": list(range(7)) * 2,
                       "m": [10.0, 10, 10, 10, 10, 10, 10, 11, 12, 13, 14, 15, 16, math.nan]})
    r = expfile.paired(df, "a", "b", "m")
    assert r.seeds == [0, 1, 2, 3, 4, 5] and r.differences == [1, 2, 3, 4, 5, 6]    # seed 6: b has no value
    assert r.median == 3.5 and r.p_value == pytest.approx(0.03125)                  # exact: 2 / 2^6
    half = stats.t.ppf(0.975, 5) * np.std([1, 2, 3, 4, 5, 6], ddof=1) / math.sqrt(6)
    assert r.interval == pytest.approx((3.5 - half, 3.5 + half))
    few = expfile.paired(df[df.seed < 3], "a", "b", "m")
    assert few.p_value is None and "not enough seeds for a signed-rank test (at least 6)" in few.note
    assert expfile.paired(df, "a", "a", "m").p_value == 1.0
    with pytest.raises(BadInput, match="no variant 'c' in the table: variants are 'a', 'b'"):
        expfile.paired(df, "a", "c", "m")
    with pytest.raises(BadInput, match="no column 'z'"):
        expfile.paired(df, "a", "b", "z")
    text = expfile.render_paired(r)
    assert text.startswith("m: b - a, paired by seed (6 seeds paired)") and "signed-rank p 0.0312" in text


def test_exp_diff_from_the_command_line(raico, tmp_path):
    f = write(tmp_path, ARM.replace('seeds = "range(2)"', 'seeds = [0, 1]'))
    arts = tmp_path / "arts"
    assert raico("exp", "run", f, "-S", "alpha=0.5", "--jobs", 1, "--artifacts", arts).exit_code == 0
    res = raico("exp", "diff", "alpha-arm", "alpha=0.5", "ilqg", "--format", "json", "--artifacts", arts)
    doc = json.loads(res.stdout)
    table = pd.read_csv(arts / "exp" / "alpha-arm" / "runs.csv").set_index(["variant", "seed"])
    want = [table.loc[("ilqg", s), "plan.final_cost"] - table.loc[("alpha=0.5", s), "plan.final_cost"] for s in (0, 1)]
    assert doc["seeds"] == [0, 1] and doc["differences"] == pytest.approx(want) and doc["p_value"] is None
    bad = raico("exp", "diff", "alpha-arm", "alpha=0.5", "nope", "--artifacts", arts)
    assert bad.exit_code == 2 and "no variant 'nope'" in bad.stderr
    # two single runs: their keys (or prefixes); the options from the entries' configs
    ka, kb = table.loc[("alpha=0.5", 1), "plan.key"], table.loc[("ilqg", 1), "plan.key"]
    res = raico("exp", "diff", "alpha-arm", ka[:6], f"plan/{kb}", "--format", "json", "--artifacts", arts)
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["a"]["keys"]["plan"] == ka and doc["b"]["keys"]["execute"] == table.loc[("ilqg", 1), "execute.key"]
    assert {o["option"]: (o["a"], o["b"]) for o in doc["options"]} == {"alpha": (0.5, 0.0), "solver": ("raico", "ilqg")}
    assert {o["option"]: o["unused_by"] for o in doc["options"]} == {"alpha": ["b"], "solver": []}   # iLQG has no alpha
    cost = next(m for m in doc["metrics"] if m["metric"] == "plan.final_cost")
    assert cost["b_minus_a"] == pytest.approx(table.loc[("ilqg", 1), "plan.final_cost"]
                                              - table.loc[("alpha=0.5", 1), "plan.final_cost"])
    text = raico("exp", "diff", "alpha-arm", ka, kb, "--artifacts", arts).stdout
    assert text.startswith(f"A: plan {ka}, execute ") and "options that differ:" in text
    assert any(line.split()[:3] == ["alpha", "0.5", "0"] and line.endswith("0 (not used)") for line in text.splitlines())
    for args, needle in (((ka, "deadbeef"), "no run with key 'deadbeef'"),
                         ((ka, "ilqg"), "two variants (paired by seed) or two runs' keys, not one of each")):
        bad = raico("exp", "diff", "alpha-arm", *args, "--artifacts", arts)
        assert bad.exit_code == 2 and bad.stderr.count("\n") == 1 and needle in bad.stderr, bad.stderr


def test_two_single_runs_side_by_side_on_known_numbers():
    df = pd.DataFrame({"experiment": ["e"] * 3, "variant": ["a", "a", "b"], "alpha": [1.0, 1.0, 0.0],
                       "solver": ["raico", "raico", "ilqg"], "seed": [0, 1, 0],
                       "plan.key": ["aaaa111100000000", "aaaa222200000000", "bbbb111100000000"],
                       "plan.status": ["converged", "converged", "diverged"], "plan.final_cost": [10.0, 12.0, 25.5],
                       "plan.cached": [True, True, True], "failed": [False, False, True]})
    r = expfile.run_diff(df, ["alpha", "solver"], "aaaa1", "plan/bbbb")
    assert r.a["keys"] == {"plan": "aaaa111100000000"} and (r.b["variant"], r.b["seed"]) == ("b", 0)
    assert r.options == [("alpha", 1.0, 0.0), ("solver", "raico", "ilqg")]     # the seed is the same: not listed
    metrics = {m: (x, y, d) for m, x, y, d in r.metrics}
    assert metrics["plan.final_cost"] == (10.0, 25.5, 15.5) and metrics["plan.status"][2] is None
    assert "plan.cached" not in metrics and "plan.key" not in metrics
    same_variant = expfile.run_diff(df, ["alpha", "solver"], "aaaa1", "aaaa2")
    assert same_variant.options == [("seed", 0, 1)]
    text = expfile.render_run_diff(r)
    assert text.splitlines()[0] == "A: plan aaaa111100000000 (a, seed 0)" and "options that differ:" in text
    assert any(line.split()[:4] == ["plan.final_cost", "10", "25.5", "15.5"] for line in text.splitlines())
    with pytest.raises(BadInput, match="key prefix 'aaaa' names 2 runs"):
        expfile.run_diff(df, [], "aaaa", "bbbb")
    with pytest.raises(BadInput, match="no run with key 'cccc'"):
        expfile.run_diff(df, [], "aaaa1", "cccc")


def test_a_quick_profile_point_seeds_needs_and_claims(tmp_path, monkeypatch):
    text = '''
seeds = "range(4)"
claims = ["raico_converges", {name = "raico_reaches_fddp", needs = "crocoddyl"}]
[base]
plant = "arm5"
task = "reach"
iterations = 30
[quick]
seeds = "range(2)"
iterations = 3
points = ["a", "ablation"]
[[point]]
label = "a"
solver = "raico"
iterations = 50
quick = {iterations = 5}
[[point]]
label = "ablation"
solver = "aico"
seeds = [1, 3]
[[point]]
label = "not quick"
solver = "ilqg"
[[point]]
label = "fddp"
solver = "fddp"
needs = "crocoddyl"
'''
    f = write(tmp_path, text)
    full, quick = expfile.load(f), expfile.load(f, quick=True)
    assert [(v.label, v.options["plan"]["iterations"]) for v in full.variants] == [
        ("a", 50), ("ablation", 30), ("not quick", 30), ("fddp", 30)]
    assert [(r.variant.label, r.seed) for r in full.runs if r.variant.label == "ablation"] == [("ablation", 1),
                                                                                                ("ablation", 3)]
    assert len(full.runs) == 4 + 2 + 4 + 4 and full.claims == ("raico_converges", "raico_reaches_fddp")
    assert [(v.label, v.options["plan"]["iterations"]) for v in quick.variants] == [("a", 5), ("ablation", 3)]
    assert [(r.variant.label, r.seed) for r in quick.runs] == [("a", 0), ("a", 1), ("ablation", 1)]
    expfile.validate(quick)
    monkeypatch.setattr(expfile, "available", lambda need: False)   # crocoddyl not installed: left out
    without = expfile.load(f)
    assert [v.label for v in without.variants] == ["a", "ablation", "not quick"] and without.left_out == ("fddp",)
    assert without.claims == ("raico_converges",)
    monkeypatch.undo()
    for old, new, needle in (('seeds = [1, 3]', 'seeds = [1, 7]', "point 'ablation': seed 7 is not among"),
                             ('needs = "crocoddyl"', 'needs = "gpu"', "needs = 'gpu': one of crocoddyl"),
                             ('points = ["a", "ablation"]', 'points = ["b"]', "[quick] points: no point 'b'"),
                             ('claims = ["raico_converges",', 'claims = [3,', "claim 3 is neither a name")):
        with pytest.raises(BadInput, match=re.escape(needle)):
            expfile.load(write(tmp_path, text.replace(old, new), "bad.toml"))


def test_seeds_that_cannot_differ_are_said_in_the_dry_run_and_the_run(raico, tmp_path):
    """A problem file's q0_std defaults to 0: its seeds are identical runs, said in one line; with a spread,
    or execution noise, nothing is said."""
    problem = Path(__file__).resolve().parents[2] / "raico" / "problems" / "arm5_reach.toml"
    f = write(tmp_path, f'''
stages = ["plan"]
seeds = "range(2)"
[base]
problem = "{problem}"
iterations = 2
''')
    arts = tmp_path / "arts"
    dry = raico("exp", "run", f, "--dry-run", "--artifacts", arts)
    assert dry.exit_code == 0, dry.output
    notes = [ln for ln in dry.stderr.splitlines() if "q0_std = 0" in ln]
    assert len(notes) == 1 and "identical runs" in notes[0] and "-S q0_std=0.05" in notes[0], dry.stderr
    ran = raico("exp", "run", f, "--executor", "serial", "--artifacts", arts)
    assert ran.exit_code == 0, ran.output
    assert sum("identical runs" in ln for ln in ran.stderr.splitlines()) == 1
    spread = raico("exp", "run", f, "--dry-run", "-S", "q0_std=0.05", "--artifacts", arts)
    assert spread.exit_code == 0 and "identical runs" not in spread.stderr
    exp = expfile.load(write(tmp_path, ARM.replace('task = "reach"', f'problem = "{problem}"')
                             .replace('plant = "arm5"\n', '') + "[execute]\nx0_noise = 0.01\n", "noisy.toml"))
    assert expfile.identical_seeds(exp) is None     # the execution's noise differs by seed
    exp = expfile.load(write(tmp_path, ARM, "builtin.toml"))
    assert expfile.identical_seeds(exp) is None     # a built-in task's q0_std is 0.05


def test_unused_options_and_stage_fields_drop_only_an_old_entry_s_errors(monkeypatch):
    """An entry of another version (a field or value this version refuses) counts as "nothing unused" and an
    unknown stage as "every field"; any other error is not swallowed."""
    from raico.stages import registry

    cfg = {"plant": "arm5", "task": "reach", "solver": "ilqg", "alpha": 0.5}
    assert expfile.unused_in("plan", cfg, ["alpha"], {"alpha": {0.5, 5.0}}) == {"alpha"}   # iLQG's alpha

    def old(name):
        raise TypeError("__init__() got an unexpected keyword argument 'sigma'")

    monkeypatch.setattr(registry, "get_stage", old)
    assert expfile.unused_in("plan", cfg, ["alpha"], {"alpha": {0.5, 5.0}}) == set()

    def broken(name):
        raise RuntimeError("a bug, not an old entry")

    monkeypatch.setattr(registry, "get_stage", broken)
    with pytest.raises(RuntimeError, match="a bug"):
        expfile.unused_in("plan", cfg, ["alpha"], {"alpha": {0.5, 5.0}})
    monkeypatch.setattr(expfile, "entry_meta", lambda cache, stage, key: {"config": {"alpha": 2.0, "plan": "k"}})
    with pytest.raises(RuntimeError, match="a bug"):
        expfile.step_configs(None, {"keys": {"execute": "k"}}, "plan")
    monkeypatch.undo()
    monkeypatch.setattr(expfile, "entry_meta", lambda cache, stage, key: {"config": {"alpha": 2.0, "plan": "k"}})
    assert expfile.step_configs(None, {"keys": {"dance": "k"}}, "plan") == {"dance.alpha": 2.0, "dance.plan": "k"}
    assert expfile.step_configs(None, {"keys": {"execute": "k"}}, "plan") == {"execute.alpha": 2.0}


def test_a_model_file_s_load_report_is_said_once_per_experiment(raico, tmp_path):
    pytest.importorskip("example_robot_data")
    problem = Path(__file__).resolve().parents[2] / "raico" / "problems" / "examples" / "ur5_reach.toml"
    f = write(tmp_path, f'name = "ur5"\nstages = ["plan"]\nseeds = "range(3)"\n[base]\nproblem = "{problem}"\n'
                        'iterations = 1\nq0_std = 0.01\n')
    res = raico("exp", "run", f, "--executor", "serial", "--artifacts", tmp_path / "arts")
    assert res.exit_code == 0, res.output
    assert "3 runs (0 cached" in res.stderr
    notes = [ln for ln in res.stderr.splitlines() if ln.startswith("raico: note: ur5_robot.urdf: ")]
    assert notes and len(notes) == len(set(notes)), res.stderr   # each line of the load report once, not per run
    # a single plan still says it
    res = raico("plan", "--problem", problem, "--iterations", 1, "--seed", 7, "--no-record", "--artifacts",
                 tmp_path / "arts")
    assert [ln for ln in res.stderr.splitlines() if ln.startswith("raico: note: ur5_robot.urdf: ")] == notes


def test_problem_files_are_read_from_the_experiment_file_s_folder(tmp_path):
    """``problem = ...`` in [base], a point or a grid: a relative path is the experiment file's neighbour."""
    (tmp_path / "sub").mkdir()
    f = write(tmp_path / "sub", 'name = "p"\n[base]\nproblem = "a.toml"\n[grid]\nproblem = ["b.toml", "/abs/c.toml"]\n'
                                '[[point]]\nlabel = "d"\nproblem = "d.toml"\n')
    exp = expfile.load(f)
    here = (tmp_path / "sub").resolve()
    assert exp.base["plan"]["problem"] == str(here / "a.toml")
    assert exp.grid["problem"] == [str(here / "b.toml"), "/abs/c.toml"]
    assert exp.points[0]["problem"] == str(here / "d.toml")
