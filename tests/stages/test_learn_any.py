"""The learning half on a model file's robot: babbling, the true robot apart from the model, the
residual GP and its derivatives, fit / plan / learn through the CLI on small settings."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tests.tolerance import assert_close

DATA = Path(__file__).resolve().parents[1] / "data"
PROBLEM = DATA / "arm2_payload.toml"


def last_json(res) -> dict:
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout.strip().splitlines()[-1])


def without_true(tmp_path) -> Path:
    """The test problem without its [robot.true] table: the executed robot is the file's."""
    text = PROBLEM.read_text()
    start, end = text.index("[robot.true]"), text.index("[horizon]")
    p = tmp_path / "arm2_model.toml"
    p.write_text(text[:start] + text[end:])
    (tmp_path / "arm2.urdf").write_text((DATA / "arm2.urdf").read_text())
    return p


def robots():
    from raico.planning.problem_file import read_problem
    from raico.plants.model_file import shared_model

    pf = read_problem(PROBLEM)
    return shared_model(pf.robot_spec()), shared_model(pf.true_spec())


@pytest.mark.numerics
def test_true_robot_differs_from_the_model_by_what_the_file_states():
    from raico.plants.dynamics_registry import make_dynamics

    model, true = robots()
    assert model.joint_names == true.joint_names and model.name != true.name
    assert any("0.3 kg payload at 'tip'" in line for line in true.load_report)
    q, v, u = np.array([0.3, 0.5]), np.array([0.4, -0.2]), np.array([1.0, 0.5])
    a_model = make_dynamics("analytic", model, 0.01).qddot(q, v, u)
    a_true = make_dynamics("analytic", true, 0.01).qddot(q, v, u)
    # the generalized forces differ by the payload's and the extra link mass's gravity and the friction
    assert np.linalg.norm(a_true - a_model) > 0.1 * np.linalg.norm(a_model)
    # the true robot's model is Drake's own (the compiled route agrees with AutoDiffXd's evaluation)
    from raico.plants.dynamics import AnalyticDynamics

    np.testing.assert_allclose(AnalyticDynamics(true, 0.01).qddot(q, v, u), a_true, rtol=1e-9,
                               atol=1e-9 * np.abs(a_true).max())


def test_missing_payload_frame_is_one_line_exit_2(raico, tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text(PROBLEM.read_text().replace('frame = "tip", mass', 'frame = "tipp", mass')
                 .replace('file = "arm2.urdf"', f'file = "{DATA / "arm2.urdf"}"'))
    for cmd in (("plan", "--problem", p), ("babble", "--problem", p)):
        res = raico(*cmd, "--artifacts", tmp_path / "art")
        assert res.exit_code == 2, res.output
        assert res.output.strip().count("\n") == 0 and "payload frame 'tipp' is not in arm2.urdf" in res.output
        assert "tip" in res.output.split("closest")[1]
    assert not (tmp_path / "art" / "plan").exists()


def test_true_table_refused_for_a_built_in_plant_and_bad_values(tmp_path):
    from raico.planning.problem_file import read_problem

    bad = tmp_path / "b.toml"
    base = PROBLEM.read_text().replace('file = "arm2.urdf"', f'file = "{DATA / "arm2.urdf"}"')
    bad.write_text(base.replace("mass_scale = 1.2", "mass_scale = -1"))
    with pytest.raises(ValueError, match="mass_scale must be in"):
        read_problem(bad)
    bad.write_text(base.replace("friction = 0.05", "stiction = 0.05"))
    with pytest.raises(ValueError, match="unknown key 'stiction'"):
        read_problem(bad)


@pytest.mark.numerics
def test_babble_a_problem_files_robot_within_its_ranges_on_the_true_robot(raico, tmp_path):
    line = last_json(raico("babble", "--problem", PROBLEM, "--episodes", 2, "--duration", 2.0, "--dt", 0.01,
                            "--json", "--artifacts", tmp_path))
    data = np.load(Path(line["path"]) / "data.npz")
    model, true = robots()
    q, u = data["q"].reshape(-1, 2), data["u"].reshape(-1, 2)
    assert data["q"].shape == (2, 201, 2)
    # babbling never leaves the joint ranges (the PD's desired trajectory stays 5 % inside them)
    assert np.all(q >= model.lower) and np.all(q <= model.upper)
    assert np.all(np.abs(u) <= model.effort + 1e-9)
    # it moves: the random trajectories and torques spread the joints
    assert np.all(q.std(axis=0) > 0.05)
    # the samples are the true robot's dynamics, not the model file's
    from raico.plants.dynamics_registry import make_dynamics

    X = np.hstack([q, data["qdot"].reshape(-1, 2), u])
    a = data["qddot"].reshape(-1, 2)
    rows = np.arange(0, len(X), 37)
    f_true = make_dynamics("analytic", true, 0.01)
    f_model = make_dynamics("analytic", model, 0.01)
    for k in rows:
        np.testing.assert_allclose(f_true.qddot(X[k, :2], X[k, 2:4], X[k, 4:]), a[k], rtol=1e-6,
                                   atol=1e-6 * np.abs(a).max())
    err_model = max(np.abs(f_model.qddot(X[k, :2], X[k, 2:4], X[k, 4:]) - a[k]).max() for k in rows)
    assert err_model > 0.01 * np.abs(a).max()


@pytest.mark.numerics
def test_residual_gp_on_the_models_own_data_learns_zero(raico, tmp_path):
    p = without_true(tmp_path)
    art = tmp_path / "art"
    babble = last_json(raico("babble", "--problem", p, "--episodes", 1, "--duration", 2.0, "--dt", 0.02, "--substeps", 10,
                              "--json", "--artifacts", art))
    fit = last_json(raico("fit", "--data", babble["key"], "--residual", "--restarts", 0, "--json",
                           "--artifacts", art))
    from raico.plants.gp import GPModel
    from raico.plants.learned import is_residual

    arrays = dict(np.load(Path(fit["path"]) / "model.npz"))
    assert is_residual(arrays)
    gp = GPModel.from_arrays({k: v for k, v in arrays.items() if k != "residual"})
    data = np.load(Path(babble["path"]) / "data.npz")
    X = np.hstack([data["q"][0], data["qdot"][0], data["u"][0]])
    scale = np.abs(data["qddot"]).max()
    # the data are the model's own: the residual is rounding, and so is what the GP learns
    assert np.abs(gp.predict_mean(X)).max() < 1e-6 * scale
    assert fit["metrics"]["heldout_rmse_overall"] < 1e-6 * scale


def residual_dynamics():
    """A ResidualDynamics on the test arm: the model file's dynamics plus a GP of a smooth function."""
    from raico.plants.fast_analytic import make_fast_or_exact
    from raico.plants.gp import GPModel
    from raico.plants.learned import ResidualDynamics

    model, _ = robots()
    rng = np.random.default_rng(0)
    X = np.hstack([0.4 * rng.standard_normal((60, 2)), rng.standard_normal((60, 2)), 2 * rng.standard_normal((60, 2))])
    Y = np.column_stack([np.sin(X[:, 0]) * X[:, 4], np.cos(X[:, 1]) + 0.3 * X[:, 3]])
    gp = GPModel(X, Y, np.full((2, 6), 1.5), np.ones(2), np.full(2, 1e-4))
    return ResidualDynamics(gp, make_fast_or_exact(model, 0.01), 0.01)


@pytest.mark.numerics
def test_residual_dynamics_derivatives_by_finite_differences():
    dyn = residual_dynamics()
    x, u = np.array([0.2, -0.3, 0.5, 0.1]), np.array([0.7, -0.4])
    A, a, B = dyn.linearize(x, u)
    f0 = dyn.step(x, u)
    assert_close(A @ x + a + B @ u, f0)
    h = 1e-6
    A_fd = np.column_stack([(dyn.step(x + h * e, u) - dyn.step(x - h * e, u)) / (2 * h) for e in np.eye(4)])
    B_fd = np.column_stack([(dyn.step(x, u + h * e) - dyn.step(x, u - h * e)) / (2 * h) for e in np.eye(2)])
    np.testing.assert_allclose(A, A_fd, rtol=1e-6, atol=1e-7 * np.abs(A).max())
    np.testing.assert_allclose(B, B_fd, rtol=1e-6, atol=1e-7 * np.abs(B).max())
    # the step is the model's plus the GP mean's acceleration
    base = dyn.base.qddot(x[:2], x[2:], u) + dyn.model.predict_mean(np.concatenate([x, u])[None])[0]
    assert_close(dyn.qddot(x[:2], x[2:], u), base)
    # the batch linearization is the point one at every step
    X = x + 0.1 * np.arange(3)[:, None]
    U = u + 0.2 * np.arange(3)[:, None]
    At, at, Bt = dyn.linearize_trajectory(X, U)
    for t in range(3):
        Ap, ap, Bp = dyn.linearize(X[t], U[t])
        assert_close(At[t], Ap)
        assert_close(Bt[t], Bp)
        np.testing.assert_allclose(at[t], ap, rtol=1e-9, atol=1e-9 * np.abs(ap).max())
    # the variance is the GP's, its gradient by central differences
    var, dvx, dvu = dyn.predict_variance(x[None], u[None])
    fd = np.column_stack([(dyn.predict_variance((x + h * e)[None], u[None])[0][0]
                           - dyn.predict_variance((x - h * e)[None], u[None])[0][0]) / (2 * h) for e in np.eye(4)])
    np.testing.assert_allclose(dvx[0], fd, rtol=1e-5, atol=1e-7 * np.abs(dvx).max())
    if dyn.c_linearizer() is not None:   # compiled (residual_step.c): the same linearization
        Ac, ac, Bc = dyn.substep_kernel(1).linearize(x, u)
        assert_close(Ac, A)
        assert_close(Bc, B)
        assert_close(Ac @ x + ac + Bc @ u, f0)


@pytest.mark.numerics
def test_fit_plan_learned_and_learn_on_a_problem_file(raico, tmp_path):
    """Babble, fit (residual or full GP), plan on the learned model, execute; learn two episodes. The plans
    are R-AICO's with the problem file's robust schedule, which takes no step that raises the cost: a
    result that holds for every rounding (plain AICO on these learned models diverges or not, and ends
    anywhere from 0.3 to 5e6, by which OpenBLAS kernels the processor picks; in the learn loop it
    diverged, its execution too, and no data joined the second fit)."""
    from raico.stages.fit.stage import FAILED

    art = tmp_path / "art"
    babble = last_json(raico("babble", "--problem", PROBLEM, "--episodes", 1, "--duration", 3.0, "--dt", 0.02, "--substeps", 10,
                              "--json", "--artifacts", art))
    for residual in ("--residual", "--no-residual"):
        fit = last_json(raico("fit", "--data", babble["key"], residual, "--restarts", 0, "--json",
                               "--artifacts", art))
        plan = last_json(raico("plan", "--problem", PROBLEM, "--dynamics", "learned", "--model", fit["key"],
                                "--solver", "raico", "--iterations", 5, "--sigma-star", 0, "--sigma-weight", 1e-4,
                                "--json", "--artifacts", art))
        assert plan["status"] != "diverged" and plan["metrics"]["final_cost"] < plan["metrics"]["initial_cost"]
        desc = json.loads((Path(plan["path"]) / "problem.json").read_text())
        assert desc["dynamics"] == "learned" and "robot_true" in desc and desc["robot_true"]["true"]
        ex = last_json(raico("execute", "--plan", plan["key"], "--json", "--artifacts", art))
        assert np.isfinite(ex["metrics"]["via_point_errors"]["reach@50"])
    # a GP of another robot with as many joints is refused (the same arm welded at its tip)
    stand = stand_problem(tmp_path)
    res = raico("plan", "--problem", stand, "--dynamics", "learned", "--model", fit["key"], "--artifacts", art)
    assert res.exit_code == 2 and res.output.strip().count("\n") == 0 and "is a GP of arm2-" in res.output
    res = raico("learn", "--problem", PROBLEM, "--episodes", 2, "--babble-points", 40, "--iterations", 5, "--alpha", 1,
                 "--residual", "--stride", 5, "--restarts", 0, "--json", "--artifacts", art)
    line = last_json(res)
    assert line["metrics"]["episodes"] == 2 and len(line["metrics"]["task_error"]) == 2
    assert all(np.isfinite(e) for e in line["metrics"]["gp_error_heldout"])
    doc = json.loads((Path(line["path"]) / "episodes.json").read_text())
    assert (Path(line["path"]) / "recording.rrd").is_file()
    assert doc["config"]["gp"] == "auto" and doc["config"]["residual"] is True  # a problem file's default GP
    # the first execution ran its plan (R-AICO's, as above) to the end and its data joined the second fit
    first, second = doc["episodes"][:2]
    assert first["plan_status"] != "diverged" and first["execution_status"] not in FAILED, first
    assert first["data_steps"] > 0 and second["n_points"] > first["n_points"], (first, second)
    # the data count per episode: the babbling's samples, then every 5th usable executed step of each episode
    assert first["n_points"] == 40
    assert second["n_points"] == first["n_points"] + math.ceil(first["data_steps"] / 5), (first, second)


@pytest.mark.parametrize("args, needle", [(("--episodes", 0), "episodes must be in [1, 100]"),
                                          (("--plant", "arm5"), "give --plant"),
                                          ])
def test_learn_problem_file_bad_input_is_one_line(raico, tmp_path, args, needle):
    res = raico("learn", "--problem", PROBLEM, *args, "--artifacts", tmp_path)
    assert res.exit_code == 2, res.output
    assert res.output.strip().count("\n") == 0 and needle in res.output
    assert not (tmp_path / "learn").exists()


def stand_problem(tmp_path) -> Path:
    """A robot whose root is free in its file, welded to the world at another frame (as a humanoid at its
    sole): the test arm turned upside down, standing on its tip."""
    urdf = (DATA / "arm2.urdf").read_text()
    urdf = urdf.replace('<link name="world"/>', "").replace(
        '<joint name="weld" type="fixed"><parent link="world"/><child link="base"/></joint>', "")
    (tmp_path / "stand.urdf").write_text(urdf)
    p = tmp_path / "stand.toml"
    p.write_text('name = "stand"\n[robot]\nfile = "stand.urdf"\nweld = "tip"\nstart = { shoulder = 0.2, elbow = -0.3 }\n'
                 '[horizon]\nT = 10\ndt = 0.01\n[dynamics]\nmodel = "analytic"\n'
                 '[costs.hold]\ntype = "posture"\ntarget = "start"\ntimes = "last"\nweight = 1.0\n')
    return p


@pytest.mark.numerics
def test_babble_a_robot_standing_on_a_welded_sole(raico, tmp_path):
    p = stand_problem(tmp_path)
    line = last_json(raico("babble", "--problem", p, "--episodes", 1, "--duration", 1.0, "--dt", 0.01,
                            "--json", "--artifacts", tmp_path / "art"))
    data = np.load(Path(line["path"]) / "data.npz")
    from raico.planning.problem_file import read_problem
    from raico.plants.dynamics_registry import make_dynamics
    from raico.plants.model_file import shared_model

    robot = shared_model(read_problem(p).robot_spec())
    assert any("welded to the world" in note for note in robot.load_report)
    q = data["q"].reshape(-1, 2)
    assert np.all(q >= robot.lower) and np.all(q <= robot.upper) and np.all(q.std(axis=0) > 0.02)
    f = make_dynamics("analytic", robot, 0.01)
    k = 50
    a = f.qddot(q[k], data["qdot"][0, k], data["u"][0, k])
    np.testing.assert_allclose(a, data["qddot"][0, k], rtol=1e-6, atol=1e-6 * np.abs(data["qddot"]).max())


def test_auto_gp_switches_to_the_sparse_gp_and_says_so(capsys):
    from raico.stages.fit.stage import AUTO_EXACT_POINTS, FitConfig, gp_kind

    cfg = FitConfig(data=("x",), gp="auto", max_points=5000, inducing=300)
    assert gp_kind(cfg, AUTO_EXACT_POINTS) == "exact" and capsys.readouterr().err == ""
    assert gp_kind(cfg, AUTO_EXACT_POINTS + 1) == "sparse"
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "too many for the exact GP" in err and "300 inducing points" in err
    # the cap comes first: 3000 points capped at 800 stay exact
    assert gp_kind(FitConfig(data=("x",), gp="auto", max_points=800), 3000) == "exact"
    assert gp_kind(FitConfig(data=("x",), gp="exact", max_points=5000), 4000) == "exact"


def test_an_experiment_file_sweeps_learn_on_a_problem_file(raico, tmp_path):
    (tmp_path / "arm2.urdf").write_text((DATA / "arm2.urdf").read_text())
    (tmp_path / "arm2_payload.toml").write_text(PROBLEM.read_text())
    f = tmp_path / "sweep.toml"
    f.write_text('name = "learn-any"\nstages = ["learn"]\nseeds = [0]\n[base]\nproblem = "arm2_payload.toml"\n'
                 'episodes = 1\nbabble_points = 30\niterations = 3\nstride = 10\nrestarts = 0\n'
                 '[grid]\nresidual = [true, false]\n')
    res = raico("exp", "run", f, "--jobs", 1, "--json", "--artifacts", tmp_path / "arts")
    assert res.exit_code == 0, res.output
    line = json.loads(res.stdout.splitlines()[-1])
    assert line["runs"] == 2
    import pandas as pd

    table = pd.read_csv(tmp_path / "arts" / "exp" / "learn-any" / "runs.csv")
    assert sorted(table["residual"]) == [False, True] and set(table["learn.status"]) == {"ok"}


@pytest.mark.numerics
def test_full_gp_dynamics_of_a_model_files_robot_by_finite_differences():
    """The thesis's model (the GP's mean alone) on a model file's robot: linearization and variance gradient."""
    from raico.plants.dynamics_registry import make_dynamics
    from raico.plants.learned import example_params

    model, _ = robots()
    dyn = make_dynamics("learned", model, 0.01, example_params(model))
    x, u = np.array([0.35, 0.4, 0.2, -0.1]), np.array([0.5, -0.3])
    A, a, B = dyn.linearize(x, u)
    h = 1e-6
    A_fd = np.column_stack([(dyn.step(x + h * e, u) - dyn.step(x - h * e, u)) / (2 * h) for e in np.eye(4)])
    B_fd = np.column_stack([(dyn.step(x, u + h * e) - dyn.step(x, u - h * e)) / (2 * h) for e in np.eye(2)])
    np.testing.assert_allclose(A, A_fd, rtol=1e-6, atol=1e-7 * np.abs(A).max())
    np.testing.assert_allclose(B, B_fd, rtol=1e-6, atol=1e-7 * np.abs(B).max())
    _, dvx, dvu = dyn.predict_variance(x[None], u[None])
    fd = np.column_stack([(dyn.predict_variance(x[None], (u + h * e)[None])[0][0]
                           - dyn.predict_variance(x[None], (u - h * e)[None])[0][0]) / (2 * h) for e in np.eye(2)])
    np.testing.assert_allclose(dvu[0], fd, rtol=1e-5, atol=1e-7 * np.abs(dvu).max())


@pytest.mark.numerics
def test_ur5_payload_example_parses_and_its_true_robot_carries_the_payload():
    """``ur5_payload_5kg.toml``: the model file's UR5 plans, the executed robot carries 5 kg at ``tool0``; at the
    start posture, under the model file's gravity compensation, the model stays at rest and the true robot sags."""
    from raico.planning.problem_file import read_problem
    from raico.plants.dynamics_registry import make_dynamics
    from raico.plants.model_file import example_robot_data, shared_model

    if example_robot_data() is None:
        pytest.skip("example-robot-data is not installed (it comes with the extra raico[baseline])")
    pf = read_problem(Path(__file__).resolve().parents[2] / "raico" / "problems" / "examples" / "ur5_payload_5kg.toml")
    assert pf.substeps == 5
    model, true = shared_model(pf.robot_spec()), shared_model(pf.true_spec())
    assert model.joint_names == true.joint_names and model.name != true.name
    assert any("5 kg payload at 'tool0'" in line for line in true.load_report), true.load_report
    dm, dt = make_dynamics("analytic", model, 0.01), make_dynamics("analytic", true, 0.01)
    q, v = model.default_q.copy(), np.zeros(model.n_q)
    # the torque that holds the model at rest: qddot is affine in u, solve qddot(u) = 0
    a0 = dm.qddot(q, v, np.zeros(model.n_q))
    B = np.column_stack([dm.qddot(q, v, e) - a0 for e in np.eye(model.n_q)])
    g = np.linalg.solve(B, -a0)
    assert np.abs(dm.qddot(q, v, g)).max() < 1e-6 * np.abs(g).max()
    sag = dt.qddot(q, v, g)
    assert np.linalg.norm(sag) > 1.0, sag    # rad/s^2: 5 kg the model's torques do not hold
