"""Model learning while planning (thesis §4): ``raico learn``, a composite stage.

The loop is a sequence of cached stage runs (the steps, see ``raico/stages/base.py``): babble once
(and a fixed held-out babbling), then per episode ``fit`` (the GP, per the hyperparameter schedule,
from the previous fit), ``plan`` (R-AICO on the GP model with the uncertainty term, warm-started
from the last plan) and ``execute`` (the plan's controller on the Drake plant in Drake's Simulator,
never on the GP); the executed data feed the next fit. Every step goes through the cache, so a
killed ``learn`` resumes where it stopped: finished episodes are cache hits. The loop's own
artifact (``learn/<key>/episodes.json``: the per-episode numbers and the keys of their runs) is
keyed like any stage's, by its config and its code version, which includes its steps'. Its
recording (the ``episode`` timeline) is made from that file by ``raico.pipeline.recordings.learn``.

Any robot: ``--problem FILE`` replaces ``--plant`` and ``--task``; the problem file's robot babbles
(``raico.stages.babble``: PD around random trajectories with the model file's gravity compensation and
per-joint random torques), the plans are the problem's with ``--dynamics learned`` and the
executions run on ``[robot.true]``'s robot where the file states one. ``--residual`` fits the GP
to what the model file misses (``raico.stages.fit``) and plans with model + GP. ``--controller mpc`` executes
every episode under receding-horizon control on the episode's model (:meth:`LearnConfig.execute_config`).

An episode whose execution gives no data (its plan diverged, or was not finite and so not executed) is
followed by a random episode (babbling with its own seed, ``RECOVERY_SEED``) whose data join the next fit
and whose seconds count as executed: without it the next fit, plan and divergence would be the same.

A parameter goes one way: the CLI fills :class:`LearnConfig`, which derives each step's config
(:meth:`LearnConfig.plan_config`, :meth:`LearnConfig.fit_config`, ...); the plan config carries
``alpha`` and the uncertainty term's ``sigma_*`` to the plan stage, which normalizes and checks them
(once, ``PlanConfig.normalized`` and the solver's options) and builds the cost from them.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from raico.planning.tasks import get_task
from raico.plants.robots import PLANTS
from raico.stages.base import Artifact, Progress, Stage, StageConfig, StageOutput, Steps
from raico.stages.registry import DESCRIPTIONS

EPISODES_FILE = "episodes.json"
MAX_EPISODES = 100
BABBLE_DT = 0.1  # s between babbling samples
BABBLE_KNOT_S = 0.25  # s between the random knots of the babbling spline (a 1 s reach's pace)


def babble_knots(points: int) -> int:
    """Random knots of a babbling episode of ``points`` samples: one every ``BABBLE_KNOT_S`` s, at
    most one per three samples (the pendulum's 15 samples: 5 knots in 1.4 s; the arms' 200: 66 in
    19.9 s; 8 knots in 9.9 s moved the arm too slowly for the torques a reach needs)."""
    duration = (points - 1) * BABBLE_DT
    return max(1, min(points // 3, int(round(duration / BABBLE_KNOT_S))))


@dataclass(frozen=True)
class LearnConfig(StageConfig):
    """Parameters of ``raico learn`` (defaults stated here only)."""

    HELP = {"plant": "pendulum, cartpole, arm5, biorob or nao.", "task": "Task of the plant (see raico plan --help).",
            "episodes": "Planning-and-execution episodes after babbling.",
            "sigma_star": "Desired model uncertainty sigma* (GP predictive variance, see --sigma-units) or none.",
            "sigma_units": "Units of the uncertainty term's variance: raw ((rad/s^2)^2, thesis eq. 4.3) or "
                           "standardized (over the training outputs' variance).",
            "sigma_weight": "Weight w of the uncertainty term, C_sigma = w I.",
            "schedule": "Hyperparameter schedule: every (re-optimize each episode) or batch-N (N >= 100 new points).",
            "alpha": "R-AICO regularization alpha (0: plain AICO).",
            "alpha_schedule": "R-AICO's alpha schedule: fixed, adaptive or robust (empty: the plan stage's default, "
                              "robust for a problem file, fixed for a built-in plant).",
            "bounds": "hard or none: the robot's joint ranges and effort limits kept by the planner (empty: the plan "
                      "stage's default, hard for a problem file).",
            "babble_points": "Motor-babbling samples (q, qdot, qddot, u) of the initial model (0: the plant's "
                             "default, 15 for the pendulum as in the thesis, 200 for the arms).",
            "iterations": "Planner iterations per episode.", "max_points": "Cap on the GP's training set.",
            "restarts": "Seeded random restarts of the hyperparameter optimizer at the first fit (on the babbling).",
            "refit_restarts": "Random restarts at the later fits (each starts at the previous fit's hyperparameters).",
            "stride": "Use every stride-th executed step as data (0: the plant's default, 5 for the pendulum, 20 for "
                      "the arms).",
            "q0_std": "Std of q0 around the default posture on a revolute joint (rad).",
            "q0_std_prismatic": "Std of q0 around the default posture on a prismatic joint (m).",
            "warm_from": "Start of each episode's plan: trajectory (the last planned trajectory, thesis 4.5), "
                         "controls (the last plan's controls rolled out on the new model) or none (x0 held, "
                         "thesis 4.4).",
            "gp": "GP of every fit: exact, sparse (FITC with --inducing points) or auto (exact up to 1000 training "
                  "points, sparse above, said on stderr; see raico fit --help); default: exact for a built-in plant, "
                  "auto for --problem.",
            "inducing": "Inducing points of --gp sparse (at most --babble-points: the first fit has only the babbling).",
            "problem": "A problem file (TOML) in place of --plant and --task: its robot (a model file; the executed "
                       "robot [robot.true]'s where stated) and task.",
            "residual": "Fit the GP to the difference between the executed accelerations and the planning model's "
                        "(the model file's, or the plant's analytic model) and plan with model + GP.",
            "babble_amplitude": "Spread of the babbling's random knots around the start posture on a revolute "
                                "joint (rad).",
            "babble_amplitude_prismatic": "Spread of the babbling's random knots on a prismatic joint (m).",
            "controller": "Controller of the episodes' executions: pd (the plan's own feedback controller) or mpc "
                          "(receding-horizon control on the episode's model, the model file plus the residual GP with "
                          "the uncertainty term, refit between episodes; raico execute --controller mpc).",
            "period": "--controller mpc: control period (s); default the planning step.",
            "horizon": "--controller mpc: horizon in planning steps (default min(T, 50)).",
            "iterations_per_tick": "--controller mpc: solver iterations per control period.",
            "mpc_solver": "--controller mpc: the solver of each period (one that runs on the learned model).",
            "final_target": "--controller mpc: a term at the problem's last step in the window, receding or fixed "
                            "(raico execute --final-target; default: the execute stage's).",
            "online_every": "--controller mpc with --gp sparse: the episode's model updated from its executed steps "
                            "every K planning steps within the execution (raico execute --online-every); 0: none.",
            "push": "A scripted push in every episode's execution, FRAME:NEWTONS:START:DURATION (raico execute "
                    "--push); repeatable."}

    plant: str = ""
    task: str = ""
    problem: str | None = None  # a problem file's path; normalized: its canonical content (JSON)
    residual: bool = False
    babble_amplitude: float = 1.0  # rad, a revolute joint's
    babble_amplitude_prismatic: float = 0.1  # m, a prismatic joint's
    episodes: int = 10
    sigma_star: str = "none"
    sigma_weight: float = 1e-2
    sigma_units: str = "raw"
    schedule: str = "every"
    alpha: float = 0.0
    alpha_schedule: str = ""  # "": the plan stage's default
    bounds: str = ""  # "": the plan stage's default
    babble_points: int = 0  # 0: the robot's default (Robot.learn_defaults)
    iterations: int = 20
    max_points: int = 2000
    restarts: int = 1
    refit_restarts: int = 0
    stride: int = 0  # 0: the robot's default
    q0_std: float = 0.0  # rad
    q0_std_prismatic: float = 0.0  # m
    warm_from: str = "trajectory"
    seed: int = 0
    gp: str = ""  # "": exact for a built-in plant, auto for a problem file's robot
    inducing: int = 200
    controller: str = "pd"  # the episodes' executions: "pd" (the plan's controller) or "mpc"
    period: float | None = None  # s, --controller mpc (None: the planning step)
    horizon: int | None = None  # planning steps, --controller mpc (None: the execute stage's default)
    iterations_per_tick: int = 1  # --controller mpc
    mpc_solver: str = "raico"  # --controller mpc (raico.planning.mpc.OWN_MODEL)
    final_target: str | None = None  # --controller mpc: "receding" or "fixed" (None: the execute stage's default)
    online_every: int = 0  # --controller mpc, --gp sparse: the online update's interval (planning steps; 0: none)
    push: tuple[str, ...] = ()  # scripted pushes of every episode's execution

    def __post_init__(self) -> None:
        object.__setattr__(self, "push", tuple(self.push or ()))   # the CLI gives None for no --push

    def normalized(self) -> LearnConfig:
        """The config with the robot's defaults in place of 0 (its spec's ``learn``): one key per meaning
        (the runner normalizes every config before it keys it)."""
        from dataclasses import replace

        cfg = self
        if self.problem is not None:
            try:
                pf = self.problem_file()
            except ValueError:
                return self  # validate() says what is wrong
            cfg = replace(self, problem=pf.canonical(), plant=pf.plant or pf.robot_label, task=pf.name)
        d = _robot_defaults(cfg)
        return replace(cfg, babble_points=cfg.babble_points or d["babble_points"], stride=cfg.stride or d["stride"],
                       gp=cfg.gp or ("exact" if cfg.problem is None else "auto"))

    def problem_file(self):
        """The problem file of ``--problem`` (a path, or the canonical content once normalized)."""
        import json

        from raico.planning.problem_file import ProblemFile, read_problem

        text = str(self.problem)
        return ProblemFile(json.loads(text)) if text.lstrip().startswith("{") else read_problem(text)

    def achieved(self) -> dict | None:
        """The task's own criterion of an execution achieved (its problem file's ``[achieved]``), or None."""
        if self.problem is not None:
            return self.problem_file().achieved
        return get_task(self.plant, self.task).achieved

    def robots(self):
        """``(planning robot, executed robot)``: the built-in plant twice, or the problem file's model
        and its ``[robot.true]`` robot (the model again where none is stated)."""
        from raico.plants.robots import shared_robot

        if self.problem is None:
            robot = shared_robot(self.plant)
            return robot, robot
        from raico.stages.plan.stage import robot_and_task, true_robot

        pf = self.problem_file()
        robot, _ = robot_and_task(self.plan_config(model="x", warm_start=None))
        return robot, true_robot(pf) or robot

    def validate(self) -> None:
        """The loop's own values; what goes to the plan stage unchanged (seed, ``alpha``, ``q0_std``, the
        ``sigma_*`` of the uncertainty term) is checked once, by the plan config (and the solver's
        options) it makes."""
        if self.problem is not None:
            pf = self.problem_file()
            if (self.plant, self.task) not in (("", ""), (pf.plant or pf.robot_label, pf.name)):
                raise ValueError("give --plant and --task, or --problem FILE, not both")
        else:
            if self.plant not in PLANTS:
                raise ValueError(f"unknown plant '{self.plant}': choose one of {', '.join(PLANTS)}"
                                 + ("" if self.plant else " (or --problem FILE)"))
            get_task(self.plant, self.task)
        if self.babble_points == 0 or self.stride == 0 or not self.gp:
            return self.normalized().validate()
        if self.warm_from not in WARM_FROM:
            raise ValueError(f"unknown warm-from '{self.warm_from}': choose one of {', '.join(WARM_FROM)}")
        checks = [(1 <= self.episodes <= MAX_EPISODES, f"episodes must be in [1, {MAX_EPISODES}]"),
                  (2 <= self.babble_points <= 100_000, "babble-points must be 0 (the plant's default) or in "
                                                        "[2, 100000]"),
                  (1 <= self.iterations <= 1000, "iterations must be in [1, 1000]"),
                  (0 <= self.babble_amplitude <= 3.2, "babble-amplitude must be in [0, 3.2] rad"),
                  (0 <= self.babble_amplitude_prismatic <= 2.0, "babble-amplitude-prismatic must be in [0, 2] m"),
                  (10 <= self.max_points <= 5000, "max-points must be in [10, 5000]"),
                  (0 <= self.restarts <= 20, "restarts must be in [0, 20]"),
                  (0 <= self.refit_restarts <= 20, "refit-restarts must be in [0, 20]"),
                  (1 <= self.stride <= 1000, "stride must be 0 (the plant's default) or in [1, 1000]"),
                  (self.gp in ("exact", "sparse", "auto"), f"gp must be exact, sparse or auto, got '{self.gp}'"),
                  (self.inducing >= 1, f"inducing must be >= 1, got {self.inducing}"),
                  (self.gp != "sparse" or self.inducing <= self.max_points,
                   f"inducing ({self.inducing}) exceeds max-points ({self.max_points})"),
                  (self.gp != "sparse" or self.inducing <= self.babble_points,
                   f"inducing ({self.inducing}) exceeds babble-points ({self.babble_points}), the first fit's "
                   "training points: give fewer inducing points or more babbling")]
        for ok, msg in checks:
            if not ok:
                raise ValueError(msg)
        parse_schedule(self.schedule)
        self._validate_controller()
        self.plan_config(model="x", warm_start=None).validate()
        self.babble_config().validate()

    def _validate_controller(self) -> None:
        """The episodes' controller: its options as ``raico execute`` checks them, and with ``mpc`` a solver
        that runs on the learned model and a fixed-base robot."""
        from raico.planning.mpc import OWN_MODEL

        if self.controller not in ("pd", "mpc"):
            raise ValueError(f"controller must be pd or mpc, got '{self.controller}'")
        d = LearnConfig.__dataclass_fields__
        if self.controller == "pd":
            given = [n for n in ("period", "horizon", "iterations_per_tick", "mpc_solver", "final_target",
                                 "online_every") if getattr(self, n) != d[n].default]
            if given:
                raise ValueError(f"--{given[0].replace('_', '-')} is an option of --controller mpc")
        elif self.mpc_solver not in OWN_MODEL:
            raise ValueError(f"--mpc-solver {self.mpc_solver} cannot control with the learned model (its window is "
                             f"the model file's); use one of {', '.join(OWN_MODEL)}")
        elif self._robot_spec() is not None and self._robot_spec().execution == "floating":
            raise ValueError("--controller mpc is for fixed-base robots; a floating robot's controllers are pd and wbc")
        else:
            self._check_window()
        self.execute_config("plan/x").validate()

    def _check_window(self) -> None:
        """``--period`` and ``--horizon`` against the task's steps, as the execute stage checks them (before any
        episode runs): the period a divisor of the planning step and at least the robot's simulation step, the
        horizon at most the task's ``T``."""
        if self.problem is not None:
            pf = self.problem_file()
            T, dt = pf.T, pf.dt
        else:
            task = get_task(self.plant, self.task)
            T, dt = task.T, task.dt
        spec = self._robot_spec()
        step = spec.time_step if spec is not None else 0.0
        if self.horizon is not None and self.horizon > T:
            raise ValueError(f"--horizon {self.horizon} is longer than the problem's {T} steps")
        if self.period is not None and self.period > 0:   # not positive: the execute stage's check says so
            every = dt / self.period
            if self.period < step - 1e-12:
                raise ValueError(f"--period {self.period:g} s is shorter than the simulation step {step:g} s")
            if self.period > dt + 1e-12 or abs(every - round(every)) > 1e-9:
                raise ValueError(f"--period {self.period:g} s must divide the planning step {dt:g} s")

    def _robot_spec(self):
        """The robot's spec (its facts), read without loading the robot."""
        from raico.plants.model_file import RobotSpec
        from raico.plants.robots import PLANTS, builtin_spec

        if self.problem is not None:
            pf = self.problem_file()
            return builtin_spec(pf.plant) if pf.plant is not None else RobotSpec.from_dict(pf.doc["robot"])
        return builtin_spec(self.plant) if self.plant in PLANTS else None

    def execute_config(self, plan: str):
        """The execute stage's config of an episode's plan ``plan`` (a plan ref): the plan's controller, or
        receding-horizon control with the episode's model; the pushes."""
        from raico.stages.execute.config import ExecuteConfig

        mpc: dict[str, Any] = {}
        if self.controller == "mpc":
            mpc = {"controller": "mpc", "period": self.period, "horizon": self.horizon,
                   "iterations_per_tick": self.iterations_per_tick, "solver": self.mpc_solver,
                   "final_target": self.final_target, "online_every": self.online_every}
        return ExecuteConfig(plan=plan, seed=self.seed, push=self.push, **mpc)

    @property
    def solver(self) -> str:
        """R-AICO for a nonzero ``alpha`` (a negative one is refused by the solver's options), else AICO."""
        return "aico" if self.alpha == 0 else "raico"

    def plan_config(self, model: str, warm_start: str | None, seed: int | None = None):
        """The plan stage's config of an episode (``warm_from`` none: no warm start)."""
        from raico.stages.plan.stage import PlanConfig

        if self.warm_from == "none":
            warm_start = None

        where: dict[str, Any] = {"problem": self.problem} if self.problem is not None else {"plant": self.plant, "task": self.task}
        return PlanConfig(**where, dynamics="learned", solver=self.solver,
                          alpha=self.alpha, alpha_schedule=self.alpha_schedule, bounds=self.bounds,
                          iterations=self.iterations,
                          seed=self.seed if seed is None else seed, q0_std=self.q0_std,
                          q0_std_prismatic=self.q0_std_prismatic, model=model,
                          warm_start=warm_start, sigma_star=self.sigma_star, sigma_weight=self.sigma_weight,
                          sigma_units=self.sigma_units,
                          warm_from="trajectory" if self.warm_from == "none" else self.warm_from)

    def fit_config(self, data: tuple[str, ...], prior: str | None):
        """The fit stage's config of an episode on the data keys ``data`` (after ``prior``, a fit key)."""
        from raico.stages.fit.stage import FitConfig

        return FitConfig(data=data, prior=prior, schedule=self.schedule,
                         restarts=self.restarts if prior is None else self.refit_restarts, seed=self.seed,
                         max_points=self.max_points, stride=self.stride, holdout=0.0, gp=self.gp,
                         inducing=self.inducing, residual=self.residual)

    def babble_config(self):
        """Babbling that yields ``babble_points`` samples (thesis: 15 for the pendulum): one episode
        of ``BABBLE_DT`` s per sample, so few samples still cover a spread of states and torques."""
        from raico.stages.babble import BabbleConfig

        where: dict[str, Any] = {"problem": self.problem} if self.problem is not None else {"plant": self.plant}
        return BabbleConfig(**where, episodes=1, seed=self.seed, duration=(self.babble_points - 1) * BABBLE_DT,
                            dt=BABBLE_DT, knots=babble_knots(self.babble_points),
                            substeps=int(round(BABBLE_DT / 1e-3)), amplitude=self.babble_amplitude,
                            amplitude_prismatic=self.babble_amplitude_prismatic)


    def heldout_babble_config(self):
        """A fixed held-out set: babbling as :meth:`babble_config` with another seed (``HELDOUT_SEED``
        added), never trained on; every episode's GP is scored on it."""
        from dataclasses import replace

        return replace(self.babble_config(), seed=(self.seed + HELDOUT_SEED) % 2**32)

    def recovery_babble_config(self, episode: int):
        """The random episode that replaces episode ``episode``'s execution when it gave no data (its plan
        diverged or was not finite): babbling as :meth:`babble_config` with its own seed (``RECOVERY_SEED``)."""
        from dataclasses import replace

        return replace(self.babble_config(), seed=(self.seed + RECOVERY_SEED + episode) % 2**32)


HELDOUT_SEED = 1_000_003  # seed offset of the held-out babbling
RECOVERY_SEED = 2_000_003  # seed offset of the random episodes that replace executions without data
WARM_FROM = ("trajectory", "controls", "none")
# Per-plant defaults of the options whose 0 means "the plant's": the pendulum as in the thesis (§4.1: 15 babbling
# points); a 5-joint arm needs more babbling to plan its first reach (BioRob reach, 8 episodes: with 15
# samples every execution lost tracking; with 100, 7 of 8 seeds reached 5 cm by their third episode, seed 11 never;
# with 200, seeds 0, 1 and 11 reached 2 cm in their first episode).
def _robot_defaults(cfg: LearnConfig) -> dict[str, int]:
    """The robot's learning defaults (``babble_points``, ``stride``: its spec's ``learn``; an arm's where it
    states none), read from its spec without loading the robot."""
    from raico.plants.robots import LEARN_DEFAULTS

    spec = cfg._robot_spec()
    return {**LEARN_DEFAULTS, **dict(spec.learn if spec is not None else ())}


def parse_schedule(schedule: str) -> int | None:
    """``every`` -> None (re-optimize every episode); ``batch-N`` -> N (>= 100)."""
    if schedule == "every":
        return None
    if schedule.startswith("batch-") and schedule[6:].isdigit() and int(schedule[6:]) >= 100:
        return int(schedule[6:])
    raise ValueError(f"schedule must be 'every' or 'batch-N' with N >= 100, got '{schedule}'")


class Predictor:
    """A fit's model of ``qddot (K, n_q)`` at inputs ``(K, 2 n_q + n_u)``: the GP mean, or for a residual fit
    the planning model's accelerations plus the GP mean (``predict_mean``, as the GP's)."""

    def __init__(self, arrays, robot):
        from raico.plants.gp import GPModel
        from raico.plants.learned import RESIDUAL_KEY, is_residual

        self.gp = GPModel.from_arrays({k: v for k, v in arrays.items() if k != RESIDUAL_KEY})
        self.robot = robot if is_residual(arrays) else None

    def predict_mean(self, XU: np.ndarray) -> np.ndarray:
        mean = self.gp.predict_mean(XU)
        if self.robot is None:
            return mean
        from raico.stages.fit.stage import model_accelerations

        return mean + model_accelerations(self.robot, XU)


def gp_prediction_error(model, X: np.ndarray, tau: np.ndarray, qddot: np.ndarray) -> float:
    """RMSE (rad/s^2) of the GP mean's ``qddot`` against the true ``qddot (K, n_q)`` at the executed
    states ``X (K, n_x)`` and torques ``tau (K, n_q)``; non-finite rows are left out."""
    ok = np.all(np.isfinite(X), axis=1) & np.all(np.isfinite(tau), axis=1) & np.all(np.isfinite(qddot), axis=1)
    if not ok.any():
        return float("inf")
    pred = model.predict_mean(np.hstack([X[ok], tau[ok]]))
    return float(np.sqrt(np.mean((pred - qddot[ok]) ** 2)))


def gp_joint_errors(model, X: np.ndarray, tau: np.ndarray, qddot: np.ndarray) -> tuple[list, list]:
    """Per joint: RMSE (rad/s^2) of the GP mean against ``qddot (K, n_q)`` and that RMSE over the
    targets' std (normalized, so light joints with large accelerations do not hide the heavy
    ones); NaN lists without finite rows."""
    ok = np.all(np.isfinite(X), axis=1) & np.all(np.isfinite(tau), axis=1) & np.all(np.isfinite(qddot), axis=1)
    n = qddot.shape[1]
    if not ok.any():
        return [float("nan")] * n, [float("nan")] * n
    err = np.sqrt(np.mean((model.predict_mean(np.hstack([X[ok], tau[ok]])) - qddot[ok]) ** 2, axis=0))
    std = qddot[ok].std(axis=0)
    return err.tolist(), (err / np.maximum(std, 1e-12)).tolist()


def true_accelerations(robot, dt: float, X: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Drake's forward dynamics ``qddot (K, n_q)`` at states ``X (K, n_x)`` under torques ``tau``."""
    from raico.plants.dynamics import SemiImplicitEuler
    from raico.plants.dynamics_registry import make_dynamics

    dyn = cast(SemiImplicitEuler, make_dynamics("analytic", robot, dt))   # an analytic model: it has qddot
    n = robot.n_q
    return np.array([dyn.qddot(x[:n], x[n:], u) for x, u in zip(X, tau)]).reshape(-1, n)


def own_criterion(crit: dict, q_end: float, status: str, v_end: float = 0.0) -> dict:
    """The task's own criterion (a problem file's ``[achieved]``: ``joint`` within ``tol`` rad of ``angle`` at the
    execution's end, the angle wrapped, and its speed ``|v_end|`` within ``velocity_tol`` rad/s where stated) as a
    task verdict (the fields of ``raico.planning.achieved.task_verdict``, with ``speed`` and ``velocity_tol``): judged on
    the final state of a run that neither diverged nor fell (a run that lost tracking of its plan but ends at
    the goal achieved the task; its status says it did not follow the plan). A non-finite end fails."""
    err = float(abs((q_end - crit["angle"] + np.pi) % (2 * np.pi) - np.pi)) if np.isfinite(q_end) else float("inf")
    speed = float(abs(v_end)) if np.isfinite(v_end) else float("inf")
    vtol = crit.get("velocity_tol")
    still = vtol is None or speed <= float(vtol)
    return {"achieved": bool(status not in ("diverged", "fell") and err <= crit["tol"] and still),
            "worst": crit["joint"], "kind": "end angle" if vtol is None else "end angle and speed", "unit": "rad",
            "error": err, "tol": float(crit["tol"]), "status": status, "speed": speed,
            "velocity_tol": None if vtol is None else float(vtol)}


def episode_task(crit: dict | None, q_end: float, metrics: dict, status: str, v_end: float = 0.0) -> dict | None:
    """An episode's executed task verdict: the task's own criterion where it states one (:func:`own_criterion`),
    else execute's judgement of the execution (``raico.stages.evaluate.metrics.executed_task``: every via-point term
    within its tolerance, in its unit, and status ok); None where the task has neither."""
    from raico.stages.evaluate.metrics import executed_task

    if crit is not None:
        return own_criterion(crit, q_end, status, v_end)
    return executed_task(metrics.get("task"), status)


def verdict_error(verdict: dict | None) -> float:
    """The verdict's worst term's error in its unit (NaN without a verdict)."""
    return float("nan") if verdict is None else float(verdict["error"])


def task_words(verdict: dict | None) -> str:
    """An episode's verdict as words for its line (``raico.stages.evaluate.metrics.task_note``)."""
    from raico.stages.evaluate.metrics import task_note

    if verdict is None:
        return "no task term to judge"
    if verdict.get("velocity_tol") is None:
        return task_note(verdict)
    return f"{task_note(verdict)}, end speed {verdict['speed']:.3g} rad/s (tol {verdict['velocity_tol']:g})"


# ----------------------------------------------------------------------------- the loop
def run(cfg: LearnConfig, inputs: dict | None = None, progress: Progress | None = None, *,
        steps: Steps) -> StageOutput:
    """The learn stage: babble, then per episode fit, plan and execute, each a cached step;
    ``episodes.json`` holds every episode's numbers (:func:`episode_measurements`) and the metrics
    their lists (:func:`summary`); a model file's load report is said once, before the loop."""
    from raico.stages.evaluate.metrics import prismatic_joints
    from raico.stages.plan.stage import load_notes, load_notes_said

    t0 = time.perf_counter()
    robot = cfg.robots()
    acc = "rad/s^2 and m/s^2" if prismatic_joints(robot[0]).any() else "rad/s^2"
    for line in load_notes(robot[0]):   # what loading the model file changed: said here once, not per episode
        print(line, file=sys.stderr, flush=True)
    with load_notes_said():
        return _loop(cfg, robot, acc, t0, progress, steps)


def _loop(cfg: LearnConfig, robot, acc: str, t0: float, progress: Progress | None, steps: Steps) -> StageOutput:
    """:func:`run`'s loop (``acc``: the GP error's unit)."""
    babble = steps.run("babble", cfg.babble_config())
    held_out = heldout_set(steps.run("babble", cfg.heldout_babble_config()))
    data, prior, warm = [babble.ref], None, None
    episodes = []
    babble_s = float((cfg.babble_points - 1) * BABBLE_DT)
    for k in range(1, cfg.episodes + 1):
        fit = steps.run("fit", cfg.fit_config(tuple(data), prior))
        plan = steps.run("plan", cfg.plan_config(model=fit.ref, warm_start=warm))
        execution = steps.run("execute", cfg.execute_config(plan.ref))
        m = episode_measurements(cfg, robot, fit, plan, execution, held_out)
        episodes.append({"episode": k, **m})
        steps.say(f"learn episode {k}/{cfg.episodes}: GP error {m['gp_error']:.3g} {acc} "
                  f"(held-out {m['gp_error_heldout']:.3g}), RMSE {m['rmse_planned_executed']:.3g} "
                  f"[execution {execution.status}; {task_words(m['task'])}] "
                  f"({'cached' if plan.cached and fit.cached else 'ran'})")
        if progress:
            progress(k, cfg.episodes)
        data.append(execution.ref)
        if m["data_steps"] == 0:   # nothing usable executed: a random episode instead, so the next fit differs
            rand = steps.run("babble", cfg.recovery_babble_config(k))
            data.append(rand.ref)
            episodes[-1]["random_seconds"] = babble_s
            episodes[-1]["executed_seconds"] += babble_s
            steps.say(f"learn episode {k}: its execution gave no data (plan {plan.status}, execution "
                      f"{execution.status}): a random {babble_s:g} s episode executed instead")
        prior = fit.ref
        if plan.status != "diverged":
            warm = plan.ref
    doc = {"babble": babble.key, "episodes": episodes, "config": cfg.key_dict()}
    return StageOutput(status="ok", metrics={**summary(episodes, time.perf_counter() - t0), "babble_seconds": babble_s},
                       documents={EPISODES_FILE: doc})


def heldout_set(heldout: Artifact) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The held-out babbling's ``X (K, n_x)``, ``tau (K, n_q)``, ``qddot (K, n_q)``."""
    from raico.stages.fit.stage import babble_segments

    _, segs = babble_segments(heldout)
    XU = np.vstack([s.X for s in segs])
    Y = np.vstack([s.Y for s in segs])
    n = Y.shape[1]
    if len(Y) == 0:
        raise ValueError("the held-out babbling holds no finite point")
    return XU[:, :2 * n], XU[:, 2 * n:], Y


def episode_measurements(cfg: LearnConfig, robots, fit: Artifact, plan: Artifact, execution: Artifact,
                         heldout: tuple | None = None) -> dict:
    """One episode's numbers, from its fit, plan and execute artifacts: GP error on the executed
    motion (a true prediction: the episode's data join only the next fit) and on the fixed held-out
    babbling, per joint and normalized; planned-vs-executed RMSE, task error planned and executed,
    whether the task was achieved in execution, how much of the execution may join the data, wall
    times, training points."""
    from raico.stages.fit.stage import usable_steps

    robot, executed = robots if isinstance(robots, tuple) else (robots, robots)
    model = Predictor(fit.arrays("model.npz"), robot)
    roll = execution.arrays("rollout.npz")
    X, tau = roll["X"][:-1], roll["tau"]
    K = min(len(X), len(tau))
    X, tau = X[:K], tau[:K]
    dt = float(roll["times"][1] - roll["times"][0])
    ok = np.all(np.isfinite(X), axis=1)
    qdd = np.full((K, robot.n_q), np.nan)
    if ok.any():
        qdd[ok] = true_accelerations(executed, dt, X[ok], tau[ok])
    em, pm = execution.metrics, plan.metrics
    crit = cfg.achieved()   # the task's own criterion (a joint's end angle, on the Drake plant), or None
    j = robot.joint_names.index(crit["joint"]) if crit is not None else None
    q_end = roll["X"][-1, j] if j is not None else float("nan")
    v_end = roll["X"][-1, robot.n_q + j] if j is not None else float("nan")
    task = episode_task(crit, q_end, em, str(execution.status), v_end)
    planned = pm.get("task")   # the plan stage's verdict of the planned trajectory (its via-point terms)
    per_joint, per_joint_n = gp_joint_errors(model, X, tau, qdd)
    held = {}
    if heldout is not None:
        hj, hn = gp_joint_errors(model, *heldout)
        held = {"gp_error_heldout": gp_prediction_error(model, *heldout), "gp_error_heldout_joint": hj,
                "gp_nrmse_heldout_joint": hn}
    data_steps = usable_steps(execution, dt, K)
    return {"gp_error": gp_prediction_error(model, X, tau, qdd), "gp_error_joint": per_joint,
            "gp_nrmse_joint": per_joint_n, **held,
            "data_steps": int(data_steps), "data_truncated": bool(data_steps < K),
            "rmse_planned_executed": em.get("rmse_planned_executed"),
            "torque_saturation": em.get("torque_saturation"),
            "task": task, "task_error": verdict_error(task), "task_unit": None if task is None else task["unit"],
            "achieved": bool(task is not None and task["achieved"]),
            "execution_status": execution.status, "plan_status": plan.status,
            "planned_task": planned, "planned_task_error": verdict_error(planned),
            "fit_time_s": fit.metrics.get("fit_time_s"), "plan_time_s": pm.get("wall_time_s"),
            "mpc_median_tick_s": em.get("mpc_median_tick_s"),
            "execute_time_s": execution.timings.get("compute_s"),
            "n_points": fit.metrics.get("n_points"), "optimized": fit.metrics.get("optimized"),
            "executed_seconds": float(np.sum(ok) * dt), "random_seconds": 0.0, "final_cost": pm.get("final_cost"),
            "fit": fit.key, "plan": plan.key, "execute": execution.key}


def summary(episodes: list[dict], wall: float) -> dict:
    """The ``--json`` metrics: per-episode lists and the first success."""
    keys = ("gp_error", "gp_error_heldout", "gp_nrmse_joint", "gp_nrmse_heldout_joint", "rmse_planned_executed",
            "task_error", "task_unit", "planned_task_error", "achieved", "fit_time_s", "plan_time_s", "execute_time_s",
            "n_points", "optimized", "execution_status", "executed_seconds", "random_seconds", "data_steps",
            "data_truncated",
            "torque_saturation")
    out: dict[str, Any] = {k: [e.get(k) for e in episodes] for k in keys}
    out["episodes_feeding_data"] = sum(1 for e in episodes if e.get("data_steps", 0) > 0)
    out["episodes_truncated"] = sum(1 for e in episodes if e.get("data_truncated"))
    first = next((e["episode"] for e in episodes if e["achieved"]), None)
    out["first_success_episode"] = first
    out["episodes"] = len(episodes)
    out["wall_time_s"] = wall
    return out


STAGE = Stage(name="learn", config_cls=LearnConfig, run=run, sources=("raico.stages.learn",),
              data_files=(EPISODES_FILE,), step_stages=("babble", "fit", "plan", "execute"),
              progress_total=lambda cfg: cfg.episodes,
              description=DESCRIPTIONS["learn"])
