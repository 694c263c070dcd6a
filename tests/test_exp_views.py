"""Views of an experiment's runs: ``raico plot`` (pipeline/plots.py) and ``raico compare`` (pipeline/compare.py),
on one small experiment (the arm's reach, 3 iterations, R-AICO at two alphas and iLQG, 3 seeds)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from pipeline import expfile, plots
from pipeline.cache import Cache
from pipeline.cli import app

runner = CliRunner()

SMALL = '''
name = "small"
stages = ["plan"]
seeds = "range(3)"
[base]
plant = "arm5"
task = "reach"
iterations = 3
[grid]
alpha = [0.5, 5.0]
[[point]]
label = "iLQG"
solver = "ilqg"
'''
KEY = re.compile(r"[0-9a-f]{16}")


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def arts(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("views")
    f = root / "small.toml"
    f.write_text(SMALL)
    res = invoke("exp", "run", f, "--executor", "serial", "--artifacts", root / "arts")
    assert res.exit_code == 0, res.output
    return root / "arts"


def table(arts: Path) -> pd.DataFrame:
    return pd.read_csv(arts / "exp" / "small" / "runs.csv")


def png_size(path: Path) -> tuple[int, int]:
    from PIL import Image

    with Image.open(path) as im:
        assert im.format == "PNG"
        return im.size


def test_legends_name_the_options_that_differ_and_leave_out_unused_ones(arts):
    df, swept = expfile.read_table(Cache(arts), "small")
    grouped = plots.groups(df, plots.grouping(df, swept, None))
    names = plots.labels(Cache(arts), grouped)
    # iLQG does not use alpha (its normalized config sets it to 0 whatever is given): not in its name
    assert names == ["alpha=0.5, solver=raico", "alpha=5, solver=raico", "solver=ilqg"]
    # without the entries (no cache) the options that differ are all named
    assert plots.labels(None, grouped)[-1] == "alpha=0, solver=ilqg"
    assert plots.labels(None, plots.groups(df, [])) == ["all runs"]


def test_line_plot_draws_the_median_and_quartiles_over_seeds(arts, tmp_path):
    out = tmp_path / "line.png"
    res = invoke("plot", "small", "--x", "alpha", "--out", out, "--artifacts", arts)
    assert res.exit_code == 0, res.output
    assert png_size(out) == (900, 600)
    assert "plot small: line of plan.final_cost against alpha, 9 runs in 2 groups" in res.stderr
    df, swept = expfile.read_table(Cache(arts), "small")
    drawn = plots.line_plot(df, swept, "alpha", "plan.final_cost", tmp_path / "again.png", "small", Cache(arts))
    t = table(arts)
    raico = t[t["solver"] == "raico"]
    line = drawn.series["solver=raico"]
    assert line["x"] == [0.5, 5.0] and line["n"] == [3, 3]
    for xv, med, lo, hi in zip(line["x"], line["median"], line["q25"], line["q75"]):
        v = raico[raico["alpha"] == xv]["plan.final_cost"].to_numpy()
        assert med == pytest.approx(np.median(v)) and (lo, hi) == pytest.approx(tuple(np.percentile(v, [25, 75])))
    base = drawn.series["solver=ilqg"]       # one x value, and alpha unused: a dashed baseline across the plot
    assert base["x"] is None and base["median"] == pytest.approx([np.median(t[t["solver"] == "ilqg"]["plan.final_cost"])])
    assert not any(KEY.search(label) for label in drawn.series)


def test_cost_curves_per_group_and_boxes(arts, tmp_path):
    cache = Cache(arts)
    df, swept = expfile.read_table(cache, "small")
    drawn = plots.curve_plot(df, swept, tmp_path / "curve.png", "small", cache)
    assert png_size(tmp_path / "curve.png")[0] == 900
    t = table(arts)
    keys = t[t["variant"] == "alpha=5.0"]["plan.key"]
    costs = np.array([np.load(arts / "plan" / k / "plan.npz")["costs"] for k in keys])
    curve = drawn.series["alpha=5, solver=raico"]
    assert curve["x"] == [1, 2, 3] and curve["median"] == pytest.approx(np.median(costs, axis=0).tolist())
    assert curve["q75"] == pytest.approx(np.percentile(costs, 75, axis=0).tolist())
    res = invoke("plot", "small", "--kind", "box", "--metric", "plan.cost.min", "--where", "seed < 2",
                 "--artifacts", arts)
    assert res.exit_code == 0, res.output
    out = arts / "exp" / "small" / "box-plan.cost.min.png"
    assert png_size(out)[0] == 900 and "6 runs in 3 groups" in res.stderr
    box = plots.box_plot(df[df["seed"] < 2], swept, "plan.cost.min", tmp_path / "b.png", "small", cache)
    want = t[(t["solver"] == "ilqg") & (t["seed"] < 2)]["plan.cost.min"]
    assert sorted(box.series["solver=ilqg"]["values"]) == pytest.approx(sorted(want))


@pytest.mark.parametrize("args,needle", [
    (("--x", "alfa"), "--x alfa: no such option in the table; swept options: alpha, solver"),
    (("--x", "alpha", "--metric", "plan.nothing"), "--metric plan.nothing: no such column; metrics: plan.initial_cost,"),
    (("--kind", "box", "--metric", "plan.status"), "--metric plan.status: not a number; metrics: plan.initial_cost,"),
    (("--kind", "violin"), "--kind violin: choose one of line, curve, box"),
    ((), "--kind line needs --x OPTION: one of the swept options alpha, solver"),
    (("--kind", "box", "--x", "alpha"), "--x goes with --kind line"),
    (("--kind", "box", "--where", "colour == 'red'"), "--where 'colour == 'red'': UndefinedVariableError"),
    (("--kind", "box", "--where", "seed > 10"), "--where 'seed > 10' keeps no run"),
    (("--kind", "box", "--group", "colour"), "--group colour: no such column"),
    (("--kind", "box", "--yscale", "cubic"), "--yscale cubic: choose auto, linear or log"),
    (("--kind", "box", "--out", "plot.pdf"), "--out plot.pdf: a .png file"),
])
def test_plot_refuses_bad_input_in_one_line(arts, args, needle):
    res = invoke("plot", "small", *args, "--artifacts", arts)
    assert res.exit_code == 2, res.output
    assert res.stderr.count("\n") == 1 and res.stderr.startswith("raico: error: ") and needle in res.stderr, res.stderr


def test_plot_of_an_experiment_that_has_not_run(tmp_path):
    res = invoke("plot", "nothing", "--kind", "box", "--artifacts", tmp_path)
    assert res.exit_code == 2 and "no runs table of experiment 'nothing'" in res.stderr
