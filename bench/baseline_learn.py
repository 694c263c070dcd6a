"""A baseline that is not raico: PETS-style CEM-MPC over a bootstrap ensemble of scikit-learn MLPs
(``bench/baseline_pets.py``) on raico's cart-pole in PILCO's setting and on the UR5 with its unmodelled 5 kg.

Executed on the same Drake plants raico's loop executes on (the robot's own model file and execution facts:
the cart-pole as a 1 ms discrete plant that keeps the cart on its rail; the UR5 with ``[robot.true]``'s
payload), the action held over each control step. The cart-pole: control every 0.1 s, 4 s episodes, one
random episode first (a uniform random force in +-10 N per step), then per episode the ensemble fit on all
transitions and 40 steps of CEM-MPC; the measure is PILCO's and ``bench/cartpole_pilco.py``'s: executed
seconds (the random episode's included) until the first episode that ends upright, judged by the same
function as raico's loop (``raico.stages.learn.own_criterion`` on the problem file's ``[achieved]``). The
cost is PILCO's (loss_cp.m): ``1 - exp(-d^2 / (2 0.25^2))``, ``d`` the pole tip's distance to the upright
tip over the rail's centre. The UR5: the reach of ``raico/problems/examples/ur5_payload_5kg.toml`` (the
tool 0.15 m forward, 0.1 m down in 1 s), torques on top of the model file's gravity compensation (as
raico's babbling), one random episode first; success: the tool within 1 cm of the target at the end.

    python -m bench.baseline_learn [--seeds 10] [--episodes 10] [--only cartpole|payload] [--render]
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from bench.baseline_pets import Controller, Ensemble, Task, transitions
from bench.learning_common import load_text, parser

ROOT = Path(__file__).resolve().parents[1]
PAYLOAD = ROOT / "raico" / "problems" / "examples" / "ur5_payload_5kg.toml"
CARTPOLE = ROOT / "raico" / "problems" / "cartpole_swing-up.toml"
PILCO_S = 17.5      # s, PILCO's executed seconds to the cart-pole swing-up (bench/cartpole_pilco.py)
REACH = 0.01        # m: the payload arm's goal (bench/payload.py)
SETTINGS = {   # chosen after the trials the docs page states
    "cartpole": {"members": 5, "hidden": [64, 64], "horizon": 20, "population": 400, "elites": 40, "iterations": 5},
    "payload": {"members": 5, "hidden": [64, 64], "horizon": 10, "population": 300, "elites": 30, "iterations": 4,
                "control_dt": 0.05},
}


class DrakeEpisodes:
    """Episodes on a robot's Drake plant as raico executes it (its execution facts: discrete or continuous,
    its step): a motor command held over each control step, added to ``bias(q)`` (a gravity compensation)."""

    def __init__(self, spec, dt: float, bias=None):
        from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator

        from raico.plants.model_file import load_model

        discrete = spec.execution == "discrete"
        self.robot = load_model(spec, None, spec.time_step if discrete else 0.0)
        self.sim = Simulator(self.robot.builder.Build())
        if not discrete:
            integ = ResetIntegratorFromFlags(self.sim, "runge_kutta5", spec.time_step)
            integ.set_fixed_step_mode(True)
        self.ctx = self.robot.plant.GetMyMutableContextFromRoot(self.sim.get_mutable_context())
        self.port = self.robot.plant.get_actuation_input_port()
        self.dt, self.bias = dt, bias
        self.effort = self.robot.effort[self.robot.actuated]

    def run(self, q0: np.ndarray, policy, steps: int) -> tuple[np.ndarray, np.ndarray]:
        """``(X (steps + 1, 2 n_q), U (steps, n_act))`` from rest at ``q0`` under ``policy(x) -> u`` (clipped to the
        efforts); the rows after a non-finite state or a failed step stay NaN."""
        r, n = self.robot, self.robot.n_q
        self.sim.get_mutable_context().SetTime(0.0)
        r.plant.SetPositions(self.ctx, r.to_plant_q(q0))
        r.plant.SetVelocities(self.ctx, np.zeros(r.plant.num_velocities()))
        self.sim.Initialize()
        X, U = np.full((steps + 1, 2 * n), np.nan), np.full((steps, len(self.effort)), np.nan)
        X[0] = np.concatenate([q0, np.zeros(n)])
        for k in range(steps):
            U[k] = np.clip(policy(X[k]), -self.effort, self.effort)
            tau = r.S @ U[k] + (0.0 if self.bias is None else self.bias(X[k, :n]))
            self.port.FixValue(self.ctx, r.actuation(r.P @ tau))
            try:
                self.sim.AdvanceTo((k + 1) * self.dt)
            except RuntimeError:
                break
            xp = r.plant.GetPositionsAndVelocities(self.ctx)
            if not np.all(np.isfinite(xp)):
                break
            n_p = r.plant.num_positions()
            X[k + 1] = np.concatenate([r.from_plant_q(xp[:n_p]), r.from_plant_q(xp[n_p:])])
        return X, U


# ----------------------------------------------------------------------------- the cart-pole
def episode_controller(task: Task, settings: dict, seed: int, Zs: list, Ys: list) -> tuple[Controller, float]:
    """The episode's CEM controller on an ensemble fit to every transition so far (``Zs``, ``Ys``: the
    episodes' inputs and state changes), and the fit's wall time (s)."""
    t0 = time.perf_counter()
    model = Ensemble(settings["members"], tuple(settings["hidden"]), seed=seed).fit(np.concatenate(Zs),
                                                                                    np.concatenate(Ys))
    t_fit = time.perf_counter() - t0
    return Controller(task, model, settings["horizon"], settings["population"], settings["elites"],
                      settings["iterations"], seed=seed), t_fit


def cartpole_task() -> tuple[Task, dict]:
    """The learner's view of the swing-up: features ``[x, sin th, cos th, xdot, thdot]``, PILCO's saturating
    cost on the tip's distance to upright, the motor's +-10 N, 0.1 s steps, 40 per episode; and the criterion."""
    from raico.planning.problem_file import read_problem

    pf = read_problem(CARTPOLE)
    ell = 0.5   # m, the pole's length (PILCO's l)

    def features(X):
        return np.concatenate([X[..., :1], np.sin(X[..., 1:2]), np.cos(X[..., 1:2]), X[..., 2:]], axis=-1)

    def cost(X, U):
        d2 = (X[..., 0] + ell * np.sin(X[..., 1])) ** 2 + (ell + ell * np.cos(X[..., 1])) ** 2
        return 1.0 - np.exp(-d2 / (2 * 0.25 ** 2))

    return Task(features, cost, np.array([-10.0]), np.array([10.0]), pf.dt, pf.T), dict(pf.achieved)


def run_cartpole(seed: int, episodes: int, settings: dict) -> dict:
    """One seed: a random episode, then ``episodes`` ensemble fits and CEM-MPC episodes, stopping at the first
    upright one; per episode the end's angle error, speed, transitions and wall times."""
    from raico.plants.robots import builtin_spec
    from raico.stages.learn import own_criterion

    task, crit = cartpole_task()
    env = DrakeEpisodes(builtin_spec("cartpole"), task.dt)
    rng = np.random.default_rng(seed)
    q0 = np.zeros(2)
    X, U = env.run(q0, lambda x: rng.uniform(task.lower, task.upper), task.steps)
    Zs, Ys = [], []
    Z, Y = transitions(X, U, task.features)
    Zs.append(Z), Ys.append(Y)
    seconds, rows = task.steps * task.dt, []
    first = None
    for ep in range(1, episodes + 1):
        ctrl, t_fit = episode_controller(task, settings, seed * 1000 + ep, Zs, Ys)
        t0 = time.perf_counter()
        X, U = env.run(q0, ctrl.act, task.steps)
        t_run = time.perf_counter() - t0
        seconds += task.steps * task.dt
        Z, Y = transitions(X, U, task.features)
        Zs.append(Z), Ys.append(Y)
        end = X[-1]
        verdict = own_criterion(crit, float(end[1]), "ok" if np.all(np.isfinite(X)) else "diverged", float(end[3]))
        rows.append({"error": verdict["error"], "speed": verdict["speed"], "achieved": verdict["achieved"],
                     "points": ctrl.model.n_points, "fit_s": t_fit, "run_s": t_run, "cart_max": float(np.nanmax(np.abs(X[:, 0])))})
        print(f"cartpole seed {seed} ep {ep}: err {verdict['error']:.3f} speed {verdict['speed']:.2f} "
              f"fit {t_fit:.1f}s run {t_run:.1f}s", flush=True)
        if verdict["achieved"]:
            first = ep
            break
    return {"seed": seed, "seconds": seconds if first else float("inf"), "first_episode": first, "episodes": rows}


# ----------------------------------------------------------------------------- the payload arm
class ChainPosition:
    """The position of a frame's origin on a serial chain of revolute joints, vectorized over configurations:
    the product of exponentials from Drake's joint axes and origins at ``q = 0`` (world), each joint turning
    the point about its axis, the last joint first (Rodrigues)."""

    def __init__(self, robot, frame: str):
        plant, ctx = robot.plant, robot.plant.CreateDefaultContext()
        plant.SetPositions(ctx, np.zeros(plant.num_positions()))
        self.axes, self.origins = [], []
        for name in robot.joint_names:
            j = plant.GetJointByName(name)
            X = j.frame_on_child().CalcPoseInWorld(ctx)
            self.axes.append(X.rotation().matrix() @ np.asarray(j.revolute_axis(), float))
            self.origins.append(X.translation())
        self.p0 = plant.GetFrameByName(frame).CalcPoseInWorld(ctx).translation()

    def __call__(self, Q: np.ndarray) -> np.ndarray:
        """``(..., 3)`` positions (m, world) at configurations ``Q (..., n_q)`` (rad)."""
        p = np.broadcast_to(self.p0, (*Q.shape[:-1], 3)).copy()
        for i in reversed(range(len(self.axes))):
            w, r = self.axes[i], self.origins[i]
            v = p - r
            c, s = np.cos(Q[..., i])[..., None], np.sin(Q[..., i])[..., None]
            p = r + v * c + np.cross(w, v) * s + w * (v @ w)[..., None] * (1 - c)
        return p


def payload_problem():
    """``(planning spec, true spec, q0, the reach target (m, world), tool frame)`` of the payload problem."""
    from raico.planning.problem_file import read_problem
    from raico.plants.model_file import shared_model

    pf = read_problem(PAYLOAD)
    spec, true = pf.robot_spec(), pf.true_spec()
    model = shared_model(spec)
    q0 = np.asarray(model.default_q, float).copy()
    reach = pf.doc["costs"]["terms"]["reach"]
    fk = ChainPosition(model, reach["frame"])
    target = fk(q0) + np.asarray(reach["target"], float)   # relative = "start"
    return pf, spec, true, model, q0, target, fk


def payload_task(fk, target: np.ndarray, effort: np.ndarray, dt: float, steps: int) -> Task:
    """The learner's view of the reach: features ``[q, qdot]``, the tool's distance to the target (m) at every
    step, torques within a quarter of each motor's effort on top of the model file's gravity compensation."""
    n = len(effort)

    def cost(X, U):
        return np.linalg.norm(fk(X[..., :n]) - target, axis=-1)

    return Task(lambda X: X, cost, -0.25 * effort, 0.25 * effort, dt, steps)


def run_payload(seed: int, episodes: int, settings: dict) -> dict:
    """One seed on the UR5 with 5 kg: a random episode, then per episode the ensemble fit on all transitions and
    a CEM-MPC episode; stops at the first that ends with the tool within 1 cm of the target."""
    pf, spec, true, model, q0, target, fk = payload_problem()
    ctx = model.plant.CreateDefaultContext()

    def gravity(q):   # the model file's gravity compensation (it does not know the payload)
        model.plant.SetPositions(ctx, model.to_plant_q(q))
        return model.P.T @ -model.plant.CalcGravityGeneralizedForces(ctx)

    dt = float(settings["control_dt"])
    steps = int(round(pf.T * pf.dt / dt))
    env = DrakeEpisodes(true, dt, bias=gravity)
    task = payload_task(fk, target, env.effort, dt, steps)
    rng = np.random.default_rng(seed)
    X, U = env.run(q0, lambda x: rng.uniform(task.lower, task.upper), steps)
    Zs, Ys = [], []
    Z, Y = transitions(X, U, task.features)
    Zs.append(Z), Ys.append(Y)
    seconds, rows, first = steps * dt, [], None
    for ep in range(1, episodes + 1):
        ctrl, t_fit = episode_controller(task, settings, seed * 1000 + ep, Zs, Ys)
        t0 = time.perf_counter()
        X, U = env.run(q0, ctrl.act, steps)
        t_run = time.perf_counter() - t0
        seconds += steps * dt
        Z, Y = transitions(X, U, task.features)
        Zs.append(Z), Ys.append(Y)
        dist = float(np.linalg.norm(fk(X[-1, :len(q0)]) - target)) if np.all(np.isfinite(X[-1])) else float("inf")
        rows.append({"distance_m": dist, "achieved": dist <= REACH, "points": ctrl.model.n_points, "fit_s": t_fit,
                     "run_s": t_run})
        print(f"payload seed {seed} ep {ep}: {100 * dist:.2f} cm fit {t_fit:.1f}s run {t_run:.1f}s", flush=True)
        if dist <= REACH:
            first = ep
            break
    return {"seed": seed, "seconds": seconds if first else float("inf"), "first_episode": first, "episodes": rows}


# ----------------------------------------------------------------------------- the page
RUNNERS = {"cartpole": run_cartpole, "payload": run_payload}


def median_s(rows: list[dict]) -> float:
    return float(np.median([r["seconds"] for r in rows])) if rows else float("nan")


def join(spec: str, values) -> str:
    return " ".join(format(v, spec) for v in values)


def fmt_s(v: float) -> str:
    return "not reached" if not np.isfinite(v) else f"{v:g} s"


def cartpole_row(doc: dict) -> str:
    """The baseline's row of the cart-pole table (``bench/cartpole_pilco.py``'s columns)."""
    rows = doc["cartpole"]["rows"]
    sec = np.array([r["seconds"] for r in rows], float)
    return (f"| PETS-style baseline (CEM-MPC over a bootstrap ensemble of scikit-learn MLPs; not raico) | cart-pole "
            f"swing-up | {fmt_s(median_s(rows))} ({int(np.isfinite(sec).sum())}/{len(rows)} seeds reached it within "
            f"{doc['cartpole']['episodes']} episodes) | {int((sec <= 8.0).sum())}/{len(rows)} |")


def payload_row(doc: dict) -> str:
    """The baseline's row of ``bench/payload.py``'s summary table (its 12 columns; the GP's and planner's ``-``)."""
    rows = doc["payload"]["rows"]
    firsts = [r["first_episode"] for r in rows if r["first_episode"] is not None]
    hit = sum(f <= 2 for f in firsts)
    k = min(len(r["episodes"]) for r in rows)
    med = " / ".join(f"{100 * np.median([r['episodes'][i]['distance_m'] for r in rows]):.3g}" for i in range(min(k, 3)))
    wall = [x["fit_s"] + x["run_s"] for r in rows for x in r["episodes"]]
    first = f"{np.median(firsts):g}" if firsts else f"none in {doc['payload']['episodes']}"
    return (f"| PETS-style baseline, not raico (CEM-MPC over a bootstrap ensemble of scikit-learn MLPs, from scratch, "
            f"{doc['payload']['settings']['control_dt']:g} s control; `bench/baseline_learn.py`) | {hit} of {len(rows)} | "
            f"{first} | {med} | - | - | {sum(x['achieved'] for r in rows for x in r['episodes'])} of "
            f"{sum(len(r['episodes']) for r in rows)} (reach only) | - | - | {np.median(wall):.1f} / {max(wall):.1f} "
            f"(fit + episode) | - | - |")


def load_doc(artifacts) -> dict | None:
    """``baseline_learn.json`` of an artifacts folder (``None`` where the baseline has not run there)."""
    path = Path(artifacts) / "bench" / "baseline_learn.json"
    return json.loads(path.read_text()) if path.exists() else None


def page(doc: dict) -> str:
    """The baseline's markdown block: its settings, the two tables' rows and the per-seed numbers."""
    lines = ["Baseline: PETS-style model-based RL (Chua et al. 2018) written on scikit-learn "
             "(`bench/baseline_pets.py`), run by `python -m bench.baseline_learn` (load averages at the end of each "
             "task's run below; 2 cores shared with other jobs: wall times are under load).", ""]
    if "cartpole" in doc:
        c = doc["cartpole"]
        lines += [f"Cart-pole (settings {c['settings']}; at most {c['episodes']} episodes after the random one; "
                  f"{len(c['rows'])} seeds; load average {c.get('load', doc['load'])}):", "",
                  "| learner | task | executed seconds to the first upright episode (median) | seeds within 8 s |",
                  "|---|---|---|---|", cartpole_row(doc),
                  f"| PILCO (Deisenroth and Rasmussen, ICML 2011) | cart-pole swing-up | {PILCO_S:g} s | |", "",
                  "raico's loop on the same task: the table above (`bench/cartpole_pilco.py`, which adds this row "
                  "to its table when this run's `baseline_learn.json` is in its artifacts).", "",
                  "| seed | seconds to upright | end error per episode (rad) | end speed per episode (rad/s) | "
                  "largest cart distance from the centre per episode (m; the rail ends at 2) | transitions per fit | "
                  "fit + episode wall (s) |", "|---|---|---|---|---|---|---|"]
        for r in c["rows"]:
            e = r["episodes"]
            lines.append(f"| {r['seed']} | {fmt_s(r['seconds'])} | {join('.3g', [x['error'] for x in e])} | "
                         f"{join('.2g', [x['speed'] for x in e])} | {join('.2f', [x['cart_max'] for x in e])} | "
                         f"{join('d', [x['points'] for x in e])} | "
                         f"{join('.0f', [x['fit_s'] + x['run_s'] for x in e])} |")
        lines.append("")
    if "payload" in doc:
        p = doc["payload"]
        rows = p["rows"]
        sec = np.array([r["seconds"] for r in rows], float)
        within2 = sum(1 for r in rows if r["first_episode"] is not None and r["first_episode"] <= 2)
        lines += [f"UR5 with 5 kg (settings {p['settings']}; at most {p['episodes']} episodes after the 1 s random "
                  f"one; {len(rows)} seeds; load average {p.get('load', doc['load'])}):", "",
                  "| learner | executed seconds to the first episode within 1 cm (median) | seeds within 1 cm "
                  "after at most 2 episodes | best distance per seed (cm) |", "|---|---|---|---|",
                  f"| PETS-style baseline (not raico) | {fmt_s(float(np.median(sec)))} "
                  f"({int(np.isfinite(sec).sum())}/{len(rows)} seeds reached it) | {within2}/{len(rows)} | "
                  f"{join('.1f', [100 * min(x['distance_m'] for x in r['episodes']) for r in rows])} |", "",
                  "| seed | executed distance per episode (cm) | transitions per fit | fit + episode wall (s) |",
                  "|---|---|---|---|"]
        for r in rows:
            e = r["episodes"]
            lines.append(f"| {r['seed']} | {join('.1f', [100 * x['distance_m'] for x in e])} | "
                         f"{join('d', [x['points'] for x in e])} | {join('.0f', [x['fit_s'] + x['run_s'] for x in e])} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = parser(__doc__.splitlines()[0], "baseline_learn.json")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--episodes", type=int, default=0, help="cap after the random episode (0: 10 each)")
    ap.add_argument("--only", choices=sorted(RUNNERS), action="append")
    args = ap.parse_args()
    out = Path(args.artifacts) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    path = out / "baseline_learn.json"
    doc = json.loads(path.read_text()) if path.exists() else {}
    if not args.render:
        for name in args.only or sorted(RUNNERS):
            episodes = args.episodes or {"cartpole": 10, "payload": 10}[name]
            doc[name] = {"settings": SETTINGS[name], "episodes": episodes, "rows": []}
            for seed in range(args.seeds):
                doc[name]["rows"].append(RUNNERS[name](seed, episodes, SETTINGS[name]))
                doc["load"] = doc[name]["load"] = load_text()
                path.write_text(json.dumps(doc, indent=1))   # after every seed: a killed run keeps its seeds
    (out / "baseline_learn.md").write_text(page(doc))
    print(page(doc))


if __name__ == "__main__":
    main()
