"""The PETS-style baseline (bench/baseline_pets.py, bench/baseline_learn.py): CEM against the exact optimum of a
linear-quadratic problem, the MPC's rollout through a model, the ensemble's forward pass against scikit-learn's,
its data count per episode, the chain kinematics against Drake and the page."""

import numpy as np
import pytest

from bench import baseline_learn, baseline_pets
from tests.tolerance import REL, bound

DT, R, H = 0.1, 0.01, 8
A = np.array([[1.0, DT], [0.0, 1.0]])       # a double integrator: position, velocity; the input accelerates
B = np.array([[0.0], [DT]])
X0 = np.array([1.0, 0.0])
WQ = np.array([1.0, 0.1])                    # state cost per step: p^2 + 0.1 v^2, plus R u^2


def lq_optimum() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The exact optimum ``U*`` of ``sum_h x_{h+1}' diag(WQ) x_{h+1} + R u_h^2`` from ``X0`` (a least-squares
    solve of the stacked rollout ``X = F + G U``), with ``F`` and ``G``."""
    G, F = np.zeros((2 * H, H)), np.zeros(2 * H)
    for h in range(H):
        F[2 * h:2 * h + 2] = np.linalg.matrix_power(A, h + 1) @ X0
        for j in range(h + 1):
            G[2 * h:2 * h + 2, j] = (np.linalg.matrix_power(A, h - j) @ B)[:, 0]
    W = np.tile(WQ, H)
    return np.linalg.solve(G.T @ (W[:, None] * G) + R * np.eye(H), -G.T @ (W * F)), F, G


class Linear:
    """A stand-in for the ensemble: every member predicts the linear system's state change exactly."""

    members = 3

    def predict_all(self, Z):
        return Z[..., :2] @ (A - np.eye(2)).T + Z[..., 2:] @ B.T


def lq_task() -> baseline_pets.Task:
    return baseline_pets.Task(lambda X: X, lambda X, U: X[..., 0] ** 2 + WQ[1] * X[..., 1] ** 2 + R * U[..., 0] ** 2,
                              np.array([-20.0]), np.array([20.0]), DT, 10)


@pytest.mark.numerics
def test_cem_finds_the_lq_optimum_within_its_own_spread():
    U_star, F, G = lq_optimum()
    W = np.tile(WQ, H)

    def cost(U):
        X = F + U @ G.T
        return (W * X ** 2).sum(-1) + R * (U ** 2).sum(-1)

    mean, std = baseline_pets.cem(cost, np.zeros(H), np.full(H, 10.0), np.full(H, -20.0), np.full(H, 20.0),
                                  np.random.default_rng(0), population=500, elites=50, iterations=40)
    assert std.max() < 1e-5 * np.abs(U_star).max()              # the sampling distribution has collapsed ...
    assert np.abs(mean - U_star).max() <= 2 * std.max()          # ... onto the optimum, within its spread


@pytest.mark.numerics
def test_mpc_first_action_is_the_lq_optimum_through_the_model():
    U_star, _, _ = lq_optimum()
    ctrl = baseline_pets.Controller(lq_task(), Linear(), horizon=H, population=500, elites=50, iterations=40, seed=0)
    first = ctrl.mean.copy()
    u = ctrl.act(X0)
    assert np.allclose(first, 0.0) and ctrl.mean.shape == (H, 1)
    assert abs(u[0] - U_star[0]) <= 1e-5 * abs(U_star[0])


def synthetic(seed: int, K: int = 40):
    rng = np.random.default_rng(seed)
    X = np.cumsum(rng.normal(size=(K + 1, 4)) * 0.1, axis=0)
    U = rng.uniform(-10, 10, size=(K, 1))
    return X, U


def test_transitions_give_one_row_per_action_until_the_state_is_lost():
    X, U = synthetic(0)
    Z, Y = baseline_pets.transitions(X, U, lambda X: X)
    assert Z.shape == (40, 5) and Y.shape == (40, 4)
    assert np.array_equal(Y, X[1:] - X[:-1]) and np.array_equal(Z[:, 4:], U)
    X[31:] = np.nan                                               # a run that diverged after 30 steps
    Z, Y = baseline_pets.transitions(X, U, lambda X: X)
    assert len(Z) == 30


@pytest.mark.numerics
def test_ensemble_counts_its_data_and_its_forward_pass_is_sklearns():
    Zs, Ys = [], []
    for episode in range(3):                                      # the random episode and two more: 40 each
        X, U = synthetic(episode)
        Z, Y = baseline_pets.transitions(X, U, lambda X: X)
        Zs.append(Z), Ys.append(Y)
        model = baseline_pets.Ensemble(members=3, hidden=(16, 16), seed=0, max_iter=50).fit(
            np.concatenate(Zs), np.concatenate(Ys))
        assert model.n_points == 40 * (episode + 1)
    Zq = synthetic(9)[0][:, :4]
    Zq = np.concatenate([Zq, np.ones((len(Zq), 1))], axis=1)
    ours = model.predict_all(Zq)
    for b, net in enumerate(model.nets):
        theirs = net.predict((Zq - model.z_mu) / model.z_sd) * model.y_sd + model.y_mu
        assert np.abs(ours[b] - theirs).max() <= bound(3 * 16) * np.abs(theirs).max()


@pytest.mark.numerics
def test_chain_position_is_drakes_forward_kinematics():
    _, _, _, model, q0, target, fk = baseline_learn.payload_problem()
    ctx = model.plant.CreateDefaultContext()
    frame = model.plant.GetFrameByName("tool0")
    rng = np.random.default_rng(0)
    Q = q0 + rng.normal(size=(5, q0.size))
    P = fk(Q)
    for q, p in zip(Q, P):
        model.plant.SetPositions(ctx, model.to_plant_q(q))
        ref = frame.CalcPoseInWorld(ctx).translation()
        assert np.abs(p - ref).max() <= REL * max(1.0, np.abs(ref).max())
    assert np.linalg.norm(target - fk(q0)) == pytest.approx(np.hypot(0.15, 0.1), rel=REL)


@pytest.mark.slow
def test_cartpole_loop_fits_forty_transitions_per_episode():
    tiny = {"members": 2, "hidden": [8], "horizon": 2, "population": 10, "elites": 2, "iterations": 1}
    out = baseline_learn.run_cartpole(0, 2, tiny)
    assert out["episodes"]
    for k, ep in enumerate(out["episodes"], start=1):             # the random episode's 40, then 40 per episode
        assert ep["points"] == 40 * k
    assert (out["seconds"] == 4.0 * (out["first_episode"] + 1)) if out["first_episode"] else out["seconds"] == np.inf


def test_page_names_the_baseline_and_counts_seeds():
    ep = {"error": 0.05, "speed": 0.2, "achieved": True, "points": 40, "fit_s": 1.0, "run_s": 10.0, "cart_max": 0.5}
    rows = [{"seed": 0, "seconds": 8.0, "first_episode": 1, "episodes": [ep]},
            {"seed": 1, "seconds": float("inf"), "first_episode": None, "episodes": [dict(ep, achieved=False)]}]
    pl = [{"seed": 0, "seconds": float("inf"), "first_episode": None,
           "episodes": [{"distance_m": 0.2, "achieved": False, "points": 20, "fit_s": 1.0, "run_s": 3.0}]}]
    doc = {"load": "1.00 1.00 1.00", "cartpole": {"settings": {}, "episodes": 1, "rows": rows},
           "payload": {"settings": {}, "episodes": 1, "rows": pl}}
    text = baseline_learn.page(doc)
    assert "| PETS-style baseline" in text and "(1/2 seeds reached it within 1 episodes) | 1/2 |" in text
    assert "| 0 | 20.0 | 20 | 4 |" in text


def test_cartpole_and_payload_tables_take_the_baselines_row():
    from bench import cartpole_pilco, payload
    from tests.bench.test_bench_payload import doc as payload_doc

    ep = {"error": 0.05, "speed": 0.2, "achieved": True, "points": 40, "fit_s": 1.0, "run_s": 10.0, "cart_max": 0.5}
    base = {"load": "1 1 1", "cartpole": {"settings": {}, "episodes": 3,
                                         "rows": [{"seed": 0, "seconds": 12.0, "first_episode": 2, "episodes": [ep]}]},
            "payload": {"settings": {"control_dt": 0.05}, "episodes": 2, "rows": [{"seed": 0, "seconds": float("inf"),
                        "first_episode": None, "episodes": [{"distance_m": 0.2, "achieved": False, "points": 20,
                                                             "fit_s": 1.0, "run_s": 3.0}]}]}}
    raico = [{"seed": 0, "seconds": 8.0, "first_episode": 1, "task_error": [0.05], "episode_s": [3.0]}]
    text = cartpole_pilco.page(raico, "1 1 1", None, base)
    assert "| PETS-style baseline" in text and "| 12 s (1/1 seeds reached it within 3 episodes) | 0/1 |" in text
    assert "PETS-style" not in cartpole_pilco.page(raico, "1 1 1")
    row = next(line for line in payload.page({**payload_doc(), "baseline": base}).splitlines()
               if line.startswith("| PETS-style"))
    assert row.count("|") == 13 and "| 0 of 1 | none in 2 | 20 |" in row
