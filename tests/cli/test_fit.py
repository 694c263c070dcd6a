"""End-to-end tests of the fit stage through the CLI: babble -> fit -> learned dynamics, the
batch-N schedule (incremental update vs re-optimization), execute data, the recording, bad input."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader
from typer.testing import CliRunner

from raico.pipeline.interface.cli import app
from raico.plants.gp import GPModel
from raico.stages.fit.gp_fit import refit_fixed

runner = CliRunner()
FAST = ("--restarts", 0)  # one optimizer start keeps the test short


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def run_json(*args) -> dict:
    res = invoke(*args)
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout.strip().splitlines()[-1])


def babble(root: Path, episodes: int, duration: float, seed: int) -> dict:
    return run_json("babble", "--plant", "pendulum", "--episodes", episodes, "--duration", duration, "--seed", seed,
                    "--no-record", "--json", "--artifacts", root)


def model_of(line: dict) -> GPModel:
    return GPModel.from_arrays(np.load(Path(line["path"]) / "model.npz"))


def fit_doc(line: dict) -> dict:
    return json.loads((Path(line["path"]) / "fit.json").read_text())


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A pendulum babble (2 episodes of 0.5 s: 502 samples, 402 for training) and its fit."""
    root = tmp_path_factory.mktemp("fit")
    data = babble(root, 2, 0.5, 0)
    fit = run_json("fit", "--data", data["key"], *FAST, "--json", "--artifacts", root)
    return root, data, fit


def test_fit_heldout_error_recording_and_cache(base):
    root, data, fit = base
    m = fit["metrics"]
    assert fit["stage"] == "fit" and not fit["cached"] and fit["status"] == "ok"
    assert m["optimized"] is True and m["n_points"] == 402 and m["n_heldout"] == 100 and m["n_dropped"] == 0
    # held-out RMSE measured 0.031 rad/s^2 against a held-out std of 3.9 (nrmse 0.008)
    doc = fit_doc(fit)
    held = np.load(Path(fit["path"]) / "heldout.npz")
    assert m["heldout_rmse"]["theta"] < 0.05 * held["Y"].std()
    assert doc["heldout_nrmse"]["theta"] < 0.05 and doc["data_keys"] == [f"babble/{data['key']}"]
    assert doc["n_train_at_optimization"] == 402 and set(doc["hyperparameters"]["theta"]) == {"length_scales", "sf2",
                                                                                             "sn2"}
    rrd = Path(fit["recording"])
    rerun = Path(sys.executable).with_name("rerun")
    assert subprocess.run([str(rerun), "rrd", "verify", str(rrd)], capture_output=True).returncode == 0
    chunks = RrdReader(rrd).stream().to_chunks()
    for series in ("mean", "upper", "lower", "measured"):
        rows = sum(c.num_rows for c in chunks if c.entity_path == f"/fit/theta/{series}"
                   and "sim_time" in c.timeline_names)
        assert rows == m["n_heldout"], series
    again = run_json("fit", "--data", data["key"], *FAST, "--json", "--artifacts", root)
    assert again["cached"] and again["key"] == fit["key"]


@pytest.mark.numerics
def test_learned_model_of_the_fit_predicts_babbled_accelerations(base):
    from raico.plants.dynamics_registry import make_dynamics
    from raico.plants.robots import shared_robot

    _, data, fit = base
    dyn = make_dynamics("learned", shared_robot("pendulum"), 0.002, dict(np.load(Path(fit["path"]) / "model.npz")))
    d = np.load(Path(data["path"]) / "data.npz")
    q, v, u, a = (d[k][:, :200:5].reshape(-1, 1) for k in ("q", "qdot", "u", "qddot"))  # training points
    pred = np.array([dyn.qddot(q[i], v[i], u[i]) for i in range(len(q))])
    assert np.max(np.abs(pred - a)) < 1e-3 * np.abs(a).max()  # measured 1.3e-4


@pytest.mark.numerics
def test_batch_schedule_updates_then_reoptimizes(base):
    root, data, fit = base
    prior = model_of(fit)
    small = babble(root, 1, 0.1, 1)  # 51 samples: 41 for training
    upd = run_json("fit", "--data", data["key"], "--data", small["key"], "--prior", fit["key"],
                   "--schedule", "batch-100", *FAST, "--json", "--artifacts", root)
    assert upd["metrics"]["optimized"] is False and upd["metrics"]["mode"] == "incremental"
    model = model_of(upd)
    assert model.N == prior.N + 41 and np.array_equal(model.ell, prior.ell)
    ref = refit_fixed(prior, model.X, model.Y)  # the prior's hyperparameters, factorized from scratch
    Xq = np.load(Path(upd["path"]) / "heldout.npz")["X"]
    (mean, var), (mean_ref, var_ref) = model.predict(Xq), ref.predict(Xq)
    assert np.allclose(mean, mean_ref, rtol=1e-8, atol=1e-8 * np.abs(mean_ref).max())
    # latent variances are sf2 - k*^T K^-1 k*, small differences of O(sf2) numbers: compare on that scale
    assert np.allclose(var, var_ref, rtol=0, atol=1e-8 * prior.sf2[0] * prior.y_std[0] ** 2)
    assert fit_doc(upd)["n_train_at_optimization"] == 402  # still the prior's optimization
    # past the cap: the prior's points and the new ones subsampled, refactorized at the prior's hyperparameters
    capped = run_json("fit", "--data", data["key"], "--data", small["key"], "--prior", fit["key"],
                      "--schedule", "batch-100", "--max-points", 420, *FAST, "--no-record", "--json", "--artifacts", root)
    cm = capped["metrics"]
    assert (cm["mode"], cm["n_points"], cm["n_dropped"], cm["optimized"]) == ("refactorized", 420, 23, False)
    assert np.array_equal(model_of(capped).ell, prior.ell)
    # 69 more training points: 41 + 69 >= 100 added since the last optimization -> re-optimize
    more = babble(root, 1, 0.17, 2)
    opt = run_json("fit", "--data", data["key"], "--data", small["key"], "--data", more["key"],
                   "--prior", upd["key"], "--schedule", "batch-100", *FAST, "--json", "--artifacts", root)
    assert opt["metrics"]["optimized"] is True and opt["metrics"]["points_since_optimization"] == 110
    assert fit_doc(opt)["n_train_at_optimization"] == 512


@pytest.mark.numerics
def test_fit_on_executed_data_labels_by_drake_forward_dynamics(base):
    root, _, _ = base
    plan = run_json("plan", "--plant", "pendulum", "--task", "swing-up", "--dynamics", "analytic", "--solver",
                    "ilqg", "--iterations", 1, "--no-record", "--json", "--artifacts", root)
    ex = run_json("execute", "--plan", plan["key"], "--no-record", "--json", "--artifacts", root)
    fit = run_json("fit", "--data", ex["key"], "--stride", 2, *FAST, "--no-record", "--json", "--artifacts", root)
    held = np.load(Path(fit["path"]) / "heldout.npz")
    X, Y = held["X"], held["Y"][:, 0]
    assert (fit["metrics"]["n_points"], fit["metrics"]["n_heldout"]) == (400, 100)  # 1000 steps, every 2nd
    assert np.allclose(Y, X[:, 2] - X[:, 1] - 9.81 * np.sin(X[:, 0]), atol=1e-6)  # the pendulum's equation
    assert fit["metrics"]["heldout_rmse"]["theta"] < 0.01 * Y.std()


@pytest.mark.parametrize("case", ["batch-50", "sometimes", "empty", "plan-key", "plan-ref"])
def test_bad_input_one_line_nonzero(base, case):
    root, data, _ = base
    if case.startswith("plan"):
        plan = run_json("plan", "--plant", "pendulum", "--task", "swing-up", "--solver", "ilqg", "--iterations", 1,
                        "--no-record", "--json", "--artifacts", root)
        args = ["--data", plan["key"] if case == "plan-key" else f"plan/{plan['key']}"]
    elif case == "empty":
        args = ["--data", ""]
    else:
        args = ["--data", data["key"], "--schedule", case]
    before = sorted((root / "fit").iterdir())
    res = invoke("fit", *args, "--artifacts", root)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.exit_code != 0 and len(lines) == 1 and lines[0].startswith("raico: error:"), res.stderr
    assert sorted((root / "fit").iterdir()) == before

