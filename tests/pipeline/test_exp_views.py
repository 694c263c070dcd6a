"""Views of an experiment's runs: ``raico plot`` (raico/pipeline/experiments/plots.py) and ``raico compare`` (raico/pipeline/experiments/compare.py),
on one small experiment (the arm's reach, 3 iterations, R-AICO at two alphas and iLQG, 4 seeds)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from raico.pipeline.engine.cache import Cache
from raico.pipeline.experiments import expfile, plots
from raico.pipeline.interface.cli import app

runner = CliRunner()

SMALL = '''
name = "small"
stages = ["plan"]
seeds = "range(4)"
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


@pytest.fixture(scope="module")
def arts(raico, tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("views")
    f = root / "small.toml"
    f.write_text(SMALL)
    res = raico("exp", "run", f, "--executor", "serial", "--artifacts", root / "arts")
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


def test_line_plot_draws_the_median_and_quartiles_over_seeds(raico, arts, tmp_path):
    out = tmp_path / "line.png"
    res = raico("plot", "small", "--x", "alpha", "--out", out, "--artifacts", arts)
    assert res.exit_code == 0, res.output
    assert png_size(out) == (900, 600)
    assert "plot small: line of plan.final_cost against alpha, 12 runs in 2 groups" in res.stderr
    df, swept = expfile.read_table(Cache(arts), "small")
    drawn = plots.line_plot(df, swept, "alpha", "plan.final_cost", tmp_path / "again.png", "small", Cache(arts))
    t = table(arts)
    raico = t[t["solver"] == "raico"]
    line = drawn.series["solver=raico"]
    assert line["x"] == [0.5, 5.0] and line["n"] == [4, 4]
    for xv, med, lo, hi in zip(line["x"], line["median"], line["q25"], line["q75"]):
        v = raico[raico["alpha"] == xv]["plan.final_cost"].to_numpy()
        assert med == pytest.approx(np.median(v)) and (lo, hi) == pytest.approx(tuple(np.percentile(v, [25, 75])))
    base = drawn.series["solver=ilqg"]       # one x value, and alpha unused: a dashed baseline across the plot
    assert base["x"] is None and base["median"] == pytest.approx([np.median(t[t["solver"] == "ilqg"]["plan.final_cost"])])
    assert not any(KEY.search(label) for label in drawn.series)


def test_cost_curves_per_group_and_boxes(raico, arts, tmp_path):
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
    res = raico("plot", "small", "--kind", "box", "--metric", "plan.cost.min", "--where", "seed < 2",
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
    (("--kind", "violin"), "--kind violin: choose one of line, curve, wall, box"),
    (("--kind", "curve", "--ylim", "1"), "--ylim 1: give two numbers LO,HI"),
    (("--kind", "curve", "--ylim", "5,1"), "--ylim 5,1: LO < HI, both finite"),
    (("--kind", "curve", "--ylim", "0,10"), "--ylim 0,10: a log axis needs LO > 0"),
    ((), "--kind line needs --x OPTION: one of the swept options alpha, solver"),
    (("--kind", "box", "--x", "alpha"), "--x goes with --kind line"),
    (("--kind", "box", "--where", "colour == 'red'"), "--where 'colour == 'red'': UndefinedVariableError"),
    (("--kind", "box", "--where", "seed > 10"), "--where 'seed > 10' keeps no run"),
    (("--kind", "box", "--group", "colour"), "--group colour: no such column"),
    (("--kind", "box", "--yscale", "cubic"), "--yscale cubic: choose auto, linear or log"),
    (("--kind", "box", "--out", "plot.pdf"), "--out plot.pdf: a .png file"),
])
def test_plot_refuses_bad_input_in_one_line(raico, arts, args, needle):
    res = raico("plot", "small", *args, "--artifacts", arts)
    assert res.exit_code == 2, res.output
    assert res.stderr.count("\n") == 1 and res.stderr.startswith("raico: error: ") and needle in res.stderr, res.stderr


def test_plot_kinds_ylim_categories_and_units(raico, arts, tmp_path):
    """--ylim says what it leaves out; --kind wall draws cost against wall time; a categorical x draws points."""
    t = table(arts)
    res = raico("plot", "small", "--kind", "curve", "--ylim", "1,100", "--out", tmp_path / "c.png", "--artifacts", arts)
    assert res.exit_code == 0, res.output
    costs = np.concatenate([np.load(arts / "plan" / k / "plan.npz")["costs"] for k in t["plan.key"]])
    above = int((costs > 100).sum())
    assert above and f"(clipped: {above} values above 100 (up to {costs.max():.3g}; beyond --ylim))" in res.stderr
    res = raico("plot", "small", "--kind", "wall", "--out", tmp_path / "w.png", "--artifacts", arts)
    assert res.exit_code == 0, res.output
    assert "plot small: wall of cost against wall time, 12 runs in 3 groups" in res.stderr
    assert png_size(tmp_path / "w.png") == (900, 600) and "clipped" not in res.stderr
    cache = Cache(arts)
    df, swept = expfile.read_table(cache, "small")
    wall = plots.wall_plot(df, swept, tmp_path / "w2.png", "small", cache)
    line = wall.series["alpha=5, solver=raico"]
    assert np.all(np.diff(line["x"]) > 0) and np.nanmin(line["median"]) == pytest.approx(
        np.median([np.load(arts / "plan" / k / "plan.npz")["costs"][-1]
                   for k in t[t["variant"] == "alpha=5.0"]["plan.key"]]))
    res = raico("plot", "small", "--x", "solver", "--out", tmp_path / "s.png", "--artifacts", arts)
    assert res.exit_code == 0, res.output
    cat = plots.line_plot(df, swept, "solver", "plan.final_cost", tmp_path / "s2.png", "small", cache)
    assert {s["drawn"] for s in cat.series.values()} == {"points"}
    num = plots.line_plot(df, swept, "alpha", "plan.final_cost", tmp_path / "a.png", "small", cache)
    assert num.series["solver=raico"]["drawn"] == "line"
    assert plots.axis_label("plan.final_cost") == "plan.final_cost (cost, no unit)"
    assert plots.axis_label("plan.wall_time_s") == "plan.wall_time_s (s)"
    assert plots.axis_label("execute.rmse_planned_executed") == "execute.rmse_planned_executed (rad)"
    assert plots.axis_label("plan.iterations") == "plan.iterations (count)"


def test_cost_axis_leaves_out_exploding_values_and_says_so(tmp_path):
    """Synthetic plans: one run's early iterates explode to 1e250 (as FDDP's infeasible ones can); the axis spans
    the others, a run that starts high (1e8) stays in view, and the figure and the plot say what was left out."""
    cache = Cache(tmp_path)
    rows = []
    curves = {"a": [1e3, 1e2, 1e1, 1.0], "b": [2e3, 2e2, 2e1, 2.0], "c": [1e250, 3e3, np.inf, 3e2],
              "d": [1e8, 1e4, 1e2, 1.5]}
    for i, (k, c) in enumerate(curves.items()):
        key = f"{i:016x}"
        (tmp_path / "plan" / key).mkdir(parents=True)
        np.savez(tmp_path / "plan" / key / "plan.npz", costs=np.array(c), elapsed=0.01 * np.arange(1, 5))
        rows.append({"plan.key": key, "seed": i, "variant": "v", "solver": "fddp" if k == "c" else "raico"})
    df = pd.DataFrame(rows)
    drawn = plots.curve_plot(df, ["solver"], tmp_path / "c.png", "synthetic", cache)
    lo, hi = drawn.limits
    assert 1e8 < hi < 1e12 and lo < 1.0
    assert drawn.clipped.startswith("clipped: 1 value above") and "up to 1e+250; exploding" in drawn.clipped
    assert "1 not finite" in drawn.clipped
    clip = plots.clip_range(np.array([1e8, 1e6, 1e3, 10, 1, 0.5, 0.3]), log=True, first=np.array([1e8]))
    assert clip.above == 0 and clip.text() == ""   # where runs start is never exploding
    wall = plots.wall_plot(df, ["solver"], tmp_path / "w.png", "synthetic", cache)
    assert wall.limits[1] < 1e12 and "up to 1e+250" in wall.clipped


def test_plot_of_an_experiment_that_has_not_run(raico, tmp_path):
    res = raico("plot", "nothing", "--kind", "box", "--artifacts", tmp_path)
    assert res.exit_code == 2 and "no runs table of experiment 'nothing'" in res.stderr


def _chunks(path: Path) -> list:
    from rerun.chunk import RrdReader

    return RrdReader(path).stream().to_chunks()


def test_compare_writes_one_recording_with_a_path_per_run(raico, arts, tmp_path):
    import json

    from rerun.chunk import RrdReader

    from raico.pipeline.experiments.compare import label_path

    out = tmp_path / "c.rrd"
    res = raico("compare", "--exp", "small", "--where", "seed == 1", "--out", out, "--json", "--artifacts", arts)
    assert res.exit_code == 0, res.output
    runs = json.loads(res.stdout)["runs"]
    t = table(arts)
    one = t[t["seed"] == 1]
    assert runs == {"alpha=0.5, solver=raico": f"plan/{one['plan.key'].iloc[0]}",
                    "alpha=5, solver=raico": f"plan/{one['plan.key'].iloc[1]}",
                    "solver=ilqg": f"plan/{one['plan.key'].iloc[2]}"}
    chunks = _chunks(out)
    entities = {c.entity_path for c in chunks}
    joints = ("base_yaw", "shoulder_pitch", "elbow_pitch", "forearm_roll", "wrist_pitch")
    for label, ref in runs.items():
        base = "/" + label_path(label)
        assert {f"{base}/joints/{j}" for j in joints} | {f"{base}/cost", f"{base}/world/paths/ee"} <= entities
        assert any(e.startswith(f"{base}/world/robot/") for e in entities)
        # the run's own numbers: its planned elbow angle on sim_time, its cost per iteration (log10)
        plan = np.load(arts / "plan" / ref.split("/")[1] / "plan.npz")
        angle = next(c for c in chunks if c.entity_path == f"{base}/joints/elbow_pitch" and not c.is_static)
        assert "sim_time" in angle.timeline_names
        values = np.ravel(angle.to_record_batch().column("Scalars:scalars").to_pylist())
        assert values == pytest.approx(plan["X"][:, 2])
        cost = next(c for c in chunks if c.entity_path == f"{base}/cost" and not c.is_static)
        assert np.ravel(cost.to_record_batch().column("Scalars:scalars").to_pylist()) == \
            pytest.approx(np.log10(plan["costs"]))
        names = next(c for c in chunks if c.entity_path == f"{base}/joints/elbow_pitch" and c.is_static)
        assert names.to_record_batch().column("SeriesLines:names").to_pylist() == [[label]]
    assert not any(KEY.search(e) for e in entities)   # paths named by options, never keys
    reader = RrdReader(out)
    views = {}
    for c in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch = c.to_record_batch()
        if "ViewBlueprint:display_name" in batch.schema.names:
            views[batch.column("ViewBlueprint:display_name").to_pylist()[0][0]] = \
                batch.column("ViewBlueprint:class_identifier").to_pylist()[0][0]
    assert {label: views.get(label) for label in runs} == {label: "3D" for label in runs}
    assert views["elbow_pitch (rad)"] == "TimeSeries" and "log10 cost per iteration (iteration timeline)" in views


def test_compare_by_keys_and_its_bad_input(raico, arts, tmp_path):
    import json

    t = table(arts)
    a, b = t[(t["variant"] == "alpha=0.5") & (t["seed"] == 0)]["plan.key"].iloc[0], \
        t[(t["variant"] == "alpha=0.5") & (t["seed"] == 2)]["plan.key"].iloc[0]
    res = raico("compare", a[:6], f"plan/{b}", a, "--out", tmp_path / "k.rrd", "--json", "--artifacts", arts)
    assert res.exit_code == 0, res.output
    # the same variant at two seeds: the seed is what differs (a key given twice is one run)
    assert json.loads(res.stdout)["runs"] == {"seed=0": f"plan/{a}", "seed=2": f"plan/{b}"}
    assert (tmp_path / "k.rrd").stat().st_size > 0
    # --open starts the viewer on the file; with no display it says so (the recording is written first)
    (tmp_path / "k.rrd").unlink()
    res = runner.invoke(app, ["compare", a, b, "--open", "--out", str(tmp_path / "k.rrd"), "--artifacts", str(arts)],
                        env={"DISPLAY": None, "WAYLAND_DISPLAY": None, "WAYLAND_SOCKET": None})
    assert res.exit_code == 1 and "cannot open the Rerun viewer: no display" in res.stderr
    assert (tmp_path / "k.rrd").stat().st_size > 0
    for args, needle, code in (
            (("--exp", "small"), "12 runs of 'small' match: raico compare shows at most 9", 2),
            (("--exp", "small", "--where", "sed == 0"), "--where 'sed == 0': UndefinedVariableError", 2),
            (("--exp", "small", "--where", "seed == 9"), "no plan run of 'small' matches --where 'seed == 9'", 2),
            (("--exp", "small", "--stage", "execute"), "the table of 'small' has no execute runs", 2),
            (("--where", "seed == 0"), "--where and --stage go with --exp NAME", 2),
            ((), "give the runs to compare", 2),
            ((a, "--out", "c.png"), "--out c.png: a .rrd file", 2),
            (tuple(f"{i:04x}" for i in range(10)), "10 runs: raico compare shows at most 9", 2),
            (("deadbeef",), "no artifact with key 'deadbeef'", 3)):
        res = raico("compare", *args, "--artifacts", arts)
        assert res.exit_code == code, (args, res.output)
        assert res.stderr.count("\n") == 1 and needle in res.stderr, res.stderr


@pytest.mark.parametrize("args,needle", [
    (("exp", "diff", "small", "deadbeef", "0123abcd"), "no run with key 'deadbeef' in the table"),
    (("exp", "diff", "small", "alpha=0.5", "nope"), "no variant 'nope' in the table: variants are 'alpha=0.5'"),
    (("exp", "diff", "small", "alpha=0.5", "iLQG", "--metric", "plan.nothing"), "no column 'plan.nothing'"),
    (("exp", "show", "small", "--where", "colour == 'red'"), "--where 'colour == 'red'': UndefinedVariableError"),
    (("exp", "show", "small", "--where", "alpha >"), "--where 'alpha >': SyntaxError"),
    (("plot", "small", "--x", "colour"), "--x colour: no such option in the table"),
    (("plot", "small", "--kind", "curve", "--where", "colour == 'red'"), "UndefinedVariableError"),
    (("compare", "--exp", "small", "--where", "seed < 4"), "12 runs of 'small' match: raico compare shows at most 9"),
    (("compare", "--exp", "small", "--where", "colour == 'red'"), "UndefinedVariableError"),
])
def test_bad_input_to_the_views_is_one_line_and_exit_2(raico, arts, args, needle):
    res = raico(*args, "--artifacts", arts)
    assert res.exit_code == 2, res.output
    assert res.stderr.count("\n") == 1 and res.stderr.startswith("raico: error: ") and needle in res.stderr, res.stderr
    assert not res.stdout


@pytest.fixture(scope="module")
def ur5_plans(raico, tmp_path_factory) -> tuple[Path, list[str]]:
    """The README's UR5 example (a robot from a model file) planned by R-AICO and iLQG, 2 iterations each."""
    import json

    pytest.importorskip("example_robot_data")
    arts = tmp_path_factory.mktemp("ur5")
    problem = Path(__file__).resolve().parents[2] / "raico" / "problems" / "examples" / "ur5_reach.toml"
    keys = []
    for solver in ("raico", "ilqg"):
        res = raico("plan", "--problem", problem, "--solver", solver, "--iterations", 2, "--no-record", "--json",
                     "--artifacts", arts)
        assert res.exit_code == 0, res.output
        keys.append(json.loads(res.stdout)["key"])
    return arts, keys


def test_compare_a_model_file_robot(raico, ur5_plans, tmp_path):
    import json

    from raico.pipeline.experiments.compare import label_path

    arts, keys = ur5_plans
    out = tmp_path / "ur5.rrd"
    res = raico("compare", *keys, "--out", out, "--json", "--artifacts", arts)
    assert res.exit_code == 0, res.output
    runs = json.loads(res.stdout)["runs"]
    assert sorted(runs.values()) == sorted(f"plan/{k}" for k in keys)
    entities = {c.entity_path for c in _chunks(out)}
    for label in runs:
        base = "/" + label_path(label)
        assert {f"{base}/joints/{j}" for j in ("shoulder_pan_joint", "elbow_joint", "wrist_3_joint")} <= entities
        assert any(e.startswith(f"{base}/world/robot/") for e in entities)


def test_show_prints_a_problem_file_as_json(raico, ur5_plans):
    import json

    arts, keys = ur5_plans
    res = raico("show", keys[0], "--artifacts", arts)
    assert res.exit_code == 0, res.output
    problem = json.loads(res.stdout)["config"]["problem"]
    assert problem["name"] == "ur5-reach" and problem["costs"]["terms"]["reach"]["frame"] == "tool0"
    assert '\\"' not in res.stdout   # no JSON text escaped inside a string
