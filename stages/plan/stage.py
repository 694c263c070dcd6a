"""The plan stage: plant + task + dynamics model + solver -> trajectory and feedback controller.

``run(PlanConfig) -> PlanOutput``. The initial state is ``x0 = (q0, 0)`` with
``q0 = default posture + N(0, q0_std^2)`` drawn with ``seed`` (thesis: 10 initial states with
std 0.05). Arrays follow the solver contract of ``stages.plan.problem``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from plants.dynamics import make_dynamics
from plants.robots import PLANTS, Robot, shared_robot
from stages.plan.costs import ViaPoint
from stages.plan.problem import Problem, Result
from stages.plan.solvers import SOLVERS, make_options, solve
from stages.plan.tasks import TaskSpec, get_task

CODE_VERSION = "plan-2"
DYNAMICS = ("pseudo", "analytic")


@dataclass(frozen=True)
class PlanConfig:
    """Declared parameters of the plan stage (all part of its cache key)."""

    plant: str
    task: str
    dynamics: str = "pseudo"
    solver: str = "raico"
    alpha: float = 1.0  # R-AICO only
    gamma: float = 1.0  # R-AICO only
    iterations: int = 50
    seed: int = 0
    q0_std: float = 0.05  # rad
    relinearize: bool = True  # AICO/R-AICO: relinearize inside the sweeps (theta rule); False: theta = inf

    def validate(self) -> None:
        if self.plant not in PLANTS:
            raise ValueError(f"unknown plant '{self.plant}': choose one of {', '.join(PLANTS)}")
        get_task(self.plant, self.task)
        if self.dynamics not in DYNAMICS:
            raise ValueError(f"unknown dynamics '{self.dynamics}': choose one of {', '.join(DYNAMICS)}")
        if self.solver not in SOLVERS:
            raise ValueError(f"unknown solver '{self.solver}': choose one of {', '.join(SOLVERS)}")
        if not 1 <= self.iterations <= 10000:
            raise ValueError("iterations must be in [1, 10000]")
        if not 0 <= self.q0_std <= 1.0:
            raise ValueError("q0-std must be in [0, 1] rad")
        make_options(self.solver, self.solver_options())

    def normalized(self) -> PlanConfig:
        """alpha/gamma only mean something for R-AICO: fix them for the others (cache key)."""
        if self.solver == "raico":
            return self
        relinearize = self.relinearize if self.solver == "aico" else True  # iLQG has no sweeps
        return PlanConfig(**{**asdict(self), "alpha": 0.0, "gamma": 1.0, "relinearize": relinearize})

    def solver_options(self) -> dict:
        if self.solver == "ilqg":
            return {"iterations": self.iterations}
        opts = {"iterations": self.iterations}
        if not self.relinearize:
            opts["theta"] = float("inf")
        if self.solver == "raico":
            opts.update(alpha=self.alpha, gamma=self.gamma)
        return opts

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> PlanConfig:
        """From a stored config (``meta.json``); keys it does not declare are ignored."""
        return cls(**{k: d[k] for k in cls.__dataclass_fields__ if k in d})


@dataclass
class PlanOutput:
    config: PlanConfig
    task: TaskSpec
    robot: Robot
    problem: Problem
    result: Result
    q0: np.ndarray

    @property
    def times(self) -> np.ndarray:
        """``(T+1,)`` s."""
        return np.arange(self.problem.T + 1) * self.task.dt

    def via_point_errors(self, X: np.ndarray | None = None) -> dict[str, float]:
        """Task error (m or rad) at each via-point time of ``X`` (default: the plan)."""
        return via_point_errors(self.problem, self.result.X if X is None else X)

    def arrays(self) -> dict[str, np.ndarray]:
        r = self.result
        return {"X": r.X, "U": r.U, "o": r.o, "O": r.O, "costs": r.costs, "q0": self.q0,
                "times": self.times, "wall_time": np.array([h.time_s for h in r.history]),
                "step": np.array([h.step for h in r.history]), "mu": np.array([h.mu for h in r.history]),
                "beliefs": r.beliefs if r.beliefs is not None else np.zeros((0,)),
                "joint_names": np.array(self.robot.joint_names)}

    def metrics(self) -> dict:
        """``initial_cost``: iteration 0, the initial trajectory (``x_t = x0``, ``u = 0``) rolled out;
        ``first_iteration_cost``: after the first update; ``cost_ratio = final / initial``."""
        r = self.result
        costs = r.costs
        first = float(costs[0]) if costs.size else float("nan")
        init = float(r.initial_cost)
        return {"initial_cost": init, "first_iteration_cost": first,
                "final_cost": float(r.cost), "cost_ratio": float(r.cost / init) if init else None,
                "iterations": int(r.iterations), "status": r.status,
                "wall_time_s": float(sum(h.time_s for h in r.history)),
                "via_point_errors": self.via_point_errors(), "message": r.message}


def via_point_errors(problem: Problem, X: np.ndarray) -> dict[str, float]:
    """``{"<term>@<t>": error}``: Euclidean task error over the dimensions that count.

    Dimensions count whose precision is at least 1% of the largest (balance: the lateral
    axis only). Terms held at every step (the Nao's right sole) report their largest error.
    """
    n_q = problem.n_x // 2
    out: dict[str, float] = {}
    for term in problem.state_terms:
        if not isinstance(term, ViaPoint):
            continue
        w = np.diag(term.C)
        keep = w >= 0.01 * w.max()
        idx = np.flatnonzero(term.active(np.arange(problem.T + 1)))
        if not np.all(np.isfinite(X[idx])):
            errs = np.full(idx.size, np.inf)
        else:
            phi, _ = term.taskmap.values_and_jacobians(X[idx, :n_q])
            errs = np.linalg.norm((term.target - phi)[:, keep], axis=1)
        if idx.size > 3:
            out[f"{term.name}@max"] = float(errs.max())
        else:
            out.update({f"{term.name}@{t}": float(e) for t, e in zip(idx, errs)})
    return out


def initial_posture(robot: Robot, q0_std: float, seed: int) -> np.ndarray:
    """``q0 = default + N(0, q0_std^2)`` (rad)."""
    rng = np.random.default_rng(seed)
    return robot.default_q + q0_std * rng.standard_normal(robot.n_q)


def build_problem(cfg: PlanConfig) -> tuple[Robot, TaskSpec, Problem, np.ndarray]:
    robot = shared_robot(cfg.plant)
    task = get_task(cfg.plant, cfg.task)
    q0 = initial_posture(robot, cfg.q0_std, cfg.seed)
    state_terms, control_terms = task.build(robot, q0, cfg.dynamics)
    dyn = make_dynamics(cfg.dynamics, robot, task.dt)
    x0 = np.concatenate([q0, np.zeros(robot.n_q)])
    return robot, task, Problem(dyn, x0, task.T, state_terms, control_terms), q0


def run(cfg: PlanConfig, progress: Callable[[int, int], None] | None = None) -> PlanOutput:
    """Plan; a diverging solver is a result (status ``diverged``), not an exception."""
    cfg.validate()
    robot, task, problem, q0 = build_problem(cfg)
    callback = None
    if progress is not None:
        def callback(rec, *_):  # noqa: ANN001
            progress(rec.iteration, cfg.iterations)
    result = solve(problem, cfg.solver, cfg.solver_options(), callback=callback)
    return PlanOutput(cfg, task, robot, problem, result, q0)
