"""The plan stage: plant + task + dynamics model + solver -> trajectory and feedback controller.

``STAGE`` runs ``plan(PlanConfig) -> PlanOutput`` and stores ``plan.npz`` and ``problem.json``
(the objective as data, see ``raico.planning.objective``). The initial state is ``x0 = (q0, 0)`` with
``q0 = default posture + N(0, q0_std^2)`` drawn with ``seed`` (thesis: 10 initial states with
std 0.05). Arrays follow the solver contract of ``raico.planning.problem``.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from raico.planning.achieved import task_errors, task_verdict
from raico.planning.costs import SIGMA_UNITS, Uncertainty, via_point_errors
from raico.planning.objective import Objective, build_terms, objective_from_description, uncertainty  # noqa: F401
from raico.planning.problem import Bounds, Problem, Result
from raico.planning.problem_file import INTEGRATORS, ProblemFile, read_problem
from raico.planning.solvers import SOLVERS, SolverSpec, get_solver, make_options, solve, takers
from raico.planning.solvers import flags as solver_flags
from raico.planning.tasks import TASKS, TaskSpec, get_task, task_from_problem
from raico.plants.dynamics import ActuatedDynamics, PseudoDynamics, SubstepDynamics
from raico.plants.dynamics_registry import make_dynamics
from raico.plants.robots import PLANTS, Chain, Robot, kinematic_chain, shared_robot
from raico.stages.base import Artifact, Progress, Stage, StageConfig, StageOutput
from raico.stages.plan.balance import BALANCE_MODES, MARGIN, NO_BALANCE_MARGIN, apply_balance, cog_margins
from raico.stages.registry import DESCRIPTIONS

DYNAMICS = ("pseudo", "analytic", "analytic-fd", "learned", "pseudo-euler", "pseudo-heun")
PLAN_FILE = "plan.npz"
PROBLEM_FILE = "problem.json"


Q0_STD = 0.05  # rad, the thesis's spread of the initial states
INTEGRATOR_DYNAMICS = tuple(n for m in INTEGRATORS.values() for n in m.values())
WARM_FROM = ("trajectory", "controls")
STARTS = ("held", "rollout", "quasi-static")
BOUNDS = ("hard", "none")
# every registered solver's plan-stage options (its options class's FLAGS): PlanConfig's solver fields
FLAGS = solver_flags()
SolverFields = dataclasses.make_dataclass(
    "SolverFields", [(f.name, f.type, dataclasses.field(default=f.default)) for f in FLAGS.values()], frozen=True)


def _solver_names(specs) -> str:  # noqa: ANN001
    """``"R-AICO's (--solver raico)"``, ``"AICO's and R-AICO's (--solver aico, raico)"``."""
    return (" and ".join(f"{s.label}'s" for s in specs)
            + f" (--solver {', '.join(s.name for s in specs)})")


@dataclass(frozen=True)
class PlanProblem:
    """The plan stage's problem, its solver and the stage's own options: ``PlanConfig`` without the
    solvers' options (those come from the solvers' ``FLAGS``, ``SolverFields``)."""

    plant: str = ""
    task: str = ""
    problem: str | None = None  # a problem file's path; normalized: its canonical content (JSON)
    dynamics: str = ""  # "": the task's or the problem file's
    solver: str = "raico"
    iterations: int = 50
    seed: int = 0
    q0_std: float | None = None  # rad; None: 0.05 for the built-in tasks, 0 for a problem file
    q0_std_prismatic: float = 0.0  # m, a prismatic joint's q0 std (no built-in plant has one)
    x0_nudge: float = 0.0  # rad added to every joint of q0 after it is drawn (a perturbation test)
    model: str | None = None
    warm_start: str | None = None
    sigma_star: str = "none"  # a number, or "none": no uncertainty term
    sigma_weight: float = 1e-2
    sigma_units: str = "raw"  # the uncertainty term's variance: "raw" (thesis eq. 4.3) or "standardized"
    warm_from: str = "trajectory"  # with warm_start: "trajectory" (thesis 4.5) or "controls" (rollout)
    start: str = "held"  # without a warm start: "held" (x0 at every step, thesis), "rollout" or "quasi-static"
    bounds: str = ""  # "hard" (joint ranges, effort limits kept by the solver) or "none"; "": hard for a problem file
    balance: str = "none"  # a robot on its soles: "none", "support" (double support) or "single" (left foot), raico.stages.plan.balance
    balance_margin: float = MARGIN  # m, with balance: the CoG ground projection this far inside every edge


@dataclass(frozen=True)
class PlanConfig(SolverFields, PlanProblem, StageConfig):  # type: ignore[misc, valid-type]
    """Declared parameters of the plan stage: the problem, ``solver`` and the solvers' options
    (``SolverFields``: the fields, defaults and help of every solver's ``FLAGS``, one per name).

    ``model``: the fit artifact whose GP the ``learned`` dynamics use (an input, so its key,
    not the reference typed, is part of the cache key).
    """

    INPUTS = ("model", "warm_start")
    INPUT_STAGES = {"model": "fit", "warm_start": "plan"}
    HELP = {"plant": "pendulum, cartpole, arm5, biorob or nao (or --problem FILE).",
            "problem": "A problem file (TOML): robot (a built-in plant or a URDF/SDF/MJCF model file), horizon, "
                       "dynamics and named cost terms; replaces --plant and --task.",
            "task": "Task of the plant: " + "; ".join(f"{p}: {t}" for p, t in sorted(TASKS)) + ".",
            "dynamics": "Default: the task's or the problem file's. pseudo (controls = accelerations, backward Euler), analytic (Drake, torques), analytic-fd "
                        "(the same, linearized by finite differences), learned (GP of --model), or pseudo-euler / "
                        "pseudo-heun (appendix C's other pseudo-dynamics).",
            "solver": "One of " + ", ".join(f"{n} ({s.label})" for n, s in SOLVERS.items())
                      + " (crocoddyl's FDDP and its ablations where crocoddyl is installed).",
            "iterations": "Maximum solver iterations.",
            **{f.name: f.help for f in FLAGS.values()},
            "q0_std": "Std of q0 around the default posture on a revolute joint (rad); default 0.05 for the built-in "
                      "tasks (the thesis's), 0 for a problem file (its start posture exactly).",
            "q0_std_prismatic": "Std of q0 around the default posture on a prismatic joint (m).",
            "x0_nudge": "Added to every joint of q0 (rad) after it is drawn: a perturbation test of the start (1e-9: "
                        "does a run's result change far more than its start, a chaotic run?).",
            "model": "Key of a fit artifact (the GP of --dynamics learned).",
            "warm_start": "Key of an earlier plan that starts this one (see --warm-from).",
            "warm_from": "With --warm-start: trajectory (linearize first at the earlier plan's states and "
                         "controls; thesis 4.5: 'initialized with the last planned trajectory'; "
                         + ", ".join(n for n, s in SOLVERS.items() if "trajectory" in s.caps.warm_from)
                         + ") or controls (its controls rolled out on this model: the others always).",
            "sigma_star": "Desired model uncertainty sigma* (GP predictive variance, see --sigma-units), "
                          "or none (no uncertainty term); learned dynamics only.",
            "sigma_units": "Units of the uncertainty term's variance: raw ((rad/s^2)^2, thesis eq. 4.3) or "
                           "standardized (over the training outputs' variance).",
            "sigma_weight": "Weight w of the uncertainty term, C_sigma = w I.",
            "start": "The first trajectory: held (x0 at every step, the thesis; the solver's own start where it has "
                     "one: iLQG rolls zero controls out), rollout (the zero-control rollout: "
                     + ", ".join(n for n, s in SOLVERS.items() if "rollout" in s.caps.starts)
                     + "; crocoddyl FDDP's rollout start is its solver fddp-rollout) or quasi-static (every solver: "
                     "the torques that hold x0 at rest, g(q0), rolled out: crocoddyl's examples' start; zero "
                     "accelerations for pseudo-dynamics).",
            "bounds": "hard (the model's joint ranges and, for torque controls, effort limits, kept by "
                      + ", ".join(n for n, s in SOLVERS.items() if s.caps.hard_bounds)
                      + " (controls clipped in the rollout, ranges by an augmented Lagrangian) and as a control box by "
                      + ", ".join(n for n, s in SOLVERS.items() if s.caps.control_box and not s.caps.hard_bounds)
                      + "; a plan that cannot stay inside has status out-of-bounds) or none (only the soft limit terms "
                      "the task has). Default: hard for --problem FILE, none for --plant/--task (the thesis's).",
            "balance": f"A robot that stands on its soles (its model states feet and a sole outline, e.g. nao): none "
                       f"(the task as stated), support (CoG ground projection kept {MARGIN * 100:g} cm "
                       "(--balance-margin) inside both "
                       "soles' support polygon at every step, right sole held) or single (balance on the left foot: "
                       "CoG inside the left sole, right sole released and lifted >= 2 cm from T/3). CoG via-points "
                       "outside the polygon are reported on stderr and planned at the nearest feasible point.",
            "balance_margin": "With --balance: the CoG's least distance (m) inside every support-polygon edge."}

    def validate(self) -> None:
        if self.problem is not None:
            pf = self.problem_file()
            if pf.plant is None and self.balance != "none":
                raise ValueError("--balance needs a built-in plant (the support polygon is the Nao's)")
            if self.dynamics not in ("", *INTEGRATOR_DYNAMICS, "analytic-fd", "learned"):
                raise ValueError(f"unknown dynamics '{self.dynamics}': choose one of {', '.join(DYNAMICS)}")
            check_problem(self)
        else:
            if not self.plant or not self.task:
                raise ValueError(f"give --plant and --task, or --problem FILE (missing: "
                                 f"{'--plant' if not self.plant else '--task'})")
            if self.plant not in PLANTS:
                raise ValueError(f"unknown plant '{self.plant}': choose one of {', '.join(PLANTS)}")
            get_task(self.plant, self.task)
        if self.dynamics not in ("", *DYNAMICS):
            raise ValueError(f"unknown dynamics '{self.dynamics}': choose one of {', '.join(DYNAMICS)}")
        if (self.dynamics == "learned") != (self.model is not None):
            raise ValueError("--model KEY goes with --dynamics learned, and only with it")
        if self.solver not in SOLVERS:
            raise ValueError(f"unknown solver '{self.solver}': choose one of {', '.join(SOLVERS)}")
        if not 1 <= self.iterations <= 10000:
            raise ValueError("iterations must be in [1, 10000]")
        if not 0 <= self.seed < 2**32:
            raise ValueError("seed must be in [0, 2^32 - 1]")
        if not abs(self.x0_nudge) <= 1e-3:
            raise ValueError(f"x0-nudge must be at most 1e-3 rad in size (a perturbation), got {self.x0_nudge}")
        if self.q0_std is not None and not 0 <= self.q0_std <= 1.0:
            raise ValueError("q0-std must be in [0, 1] rad")
        if not 0 <= self.q0_std_prismatic <= 0.5:
            raise ValueError("q0-std-prismatic must be in [0, 0.5] m")
        if self.sigma is not None and self.dynamics != "learned":
            raise ValueError("--sigma-star needs --dynamics learned (the GP's variance)")
        if self.sigma is not None and not 0 <= self.sigma <= 100:
            raise ValueError("sigma-star must be in [0, 100] or none")
        if not (np.isfinite(self.sigma_weight) and 0 <= self.sigma_weight <= 1e8):
            raise ValueError("sigma-weight must be in [0, 1e8]")
        if self.sigma_units not in SIGMA_UNITS:
            raise ValueError(f"unknown sigma-units '{self.sigma_units}': choose one of {', '.join(SIGMA_UNITS)}")
        if self.start not in STARTS:
            raise ValueError(f"unknown start '{self.start}': choose one of {', '.join(STARTS)}")
        if self.bounds not in ("", *BOUNDS):
            raise ValueError(f"unknown bounds '{self.bounds}': choose one of {', '.join(BOUNDS)}")
        if self.warm_from not in WARM_FROM:
            raise ValueError(f"unknown warm-from '{self.warm_from}': choose one of {', '.join(WARM_FROM)}")
        if self.balance not in BALANCE_MODES:
            raise ValueError(f"unknown balance '{self.balance}': choose one of {', '.join(BALANCE_MODES)}")
        if self.balance != "none" and not self._has_soles():
            raise ValueError(f"--balance {self.balance} needs a robot that stands on its soles (--plant nao): "
                             f"{self.robot_name() or 'this robot'} has none")
        if not (isinstance(self.balance_margin, (int, float)) and 0 <= self.balance_margin <= 0.04):
            raise ValueError(f"balance-margin must be in [0, 0.04] m, got {self.balance_margin}")
        try:
            make_options(self.solver, self.solver_options())
        except ValueError as e:   # the solver's option names, said as the options the user typed
            text = str(e).replace("option iterations ", "--iterations ")
            for f in self.spec().flags:
                text = text.replace(f"option {f.option or f.name} ", f"--{f.name.replace('_', '-')} ")
            raise ValueError(text) from None

    def ignored(self) -> dict[str, str]:
        """Options given (not at their default) that this solver or set-up does not use: option name ->
        why. They are dropped from the cache key (:meth:`normalized`); the CLI says so on stderr."""
        d, out = PlanConfig.defaults(), {}

        def note(names, why):
            out.update({n: why for n in names if getattr(self, n) != d[n]})

        spec = self.spec()
        for name, used in self._flags_used().items():
            if used is None:
                note((name,), f"{_solver_names(takers(name))}, not {self.solver}'s")
            elif not used:
                note((name,), FLAGS[name].only[2])
        if self.start not in spec.caps.starts:
            note(("start",), f"{_solver_names([s for s in SOLVERS.values() if self.start in s.caps.starts])}, "
                             f"not {self.solver}'s")
        if self.warm_start is None or len(spec.caps.warm_from) < 2:
            chooses = [s for s in SOLVERS.values() if len(s.caps.warm_from) > 1]
            note(("warm_from",), f"for {_solver_names(chooses)} with --warm-start")
        if self.sigma is None:
            note(("sigma_weight", "sigma_units"), "for --sigma-star")
        if self.balance == "none":
            note(("balance_margin",), "for --balance support or single")
        return out

    @property
    def sigma(self) -> float | None:
        """sigma* as a number, or None for "none"."""
        text = str(self.sigma_star).strip().lower()
        if text == "none":
            return None
        try:
            return float(text)
        except ValueError:
            raise ValueError(f"sigma-star must be a number or none, got '{self.sigma_star}'") from None

    def problem_file(self) -> ProblemFile:
        """The problem file of ``--problem`` (a path, or the canonical content once normalized)."""
        text = str(self.problem)
        if text.lstrip().startswith("{"):
            return ProblemFile(json.loads(text))
        return read_problem(text)

    def _has_soles(self) -> bool:
        """The robot states its soles and their outline (a support polygon to balance in)."""
        robot, _ = robot_and_task(self)
        return robot.support_polygon is not None and len(robot.feet) > 0

    def robot_name(self) -> str:
        """The built-in plant's name ("" for a model file's robot)."""
        if self.problem is None:
            return self.plant
        return self.problem_file().plant or ""

    def normalized(self) -> PlanConfig:
        """One spelling per meaning (cache key): a problem file as its canonical content, the
        dynamics as the task states them unless given, the solver's options in force (those it leaves
        unused at one value), sigma* as a canonical number or "none", its weight only with it."""
        if self.solver not in SOLVERS:
            return self  # validate() says what is wrong
        d = asdict(self)
        if self.problem is not None:
            try:
                pf = self.problem_file()
            except ValueError:
                return self  # validate() says what is wrong
            d.update(problem=pf.canonical(), plant=pf.plant or pf.robot_label, task=pf.name)
            if not self.dynamics:
                d["dynamics"] = pf.dynamics
            if self.q0_std is None:
                d["q0_std"] = 0.0
        else:
            if not self.dynamics:
                try:
                    d["dynamics"] = get_task(self.plant, self.task).dynamics
                except ValueError:
                    return self
            if self.q0_std is None:
                d["q0_std"] = Q0_STD
        sigma = self.sigma
        d["sigma_star"] = "none" if sigma is None else repr(sigma)
        if sigma is None:
            d["sigma_weight"] = 0.0
            d["sigma_units"] = "raw"
        # the solver's options as in force (a default resolved), the ones it leaves unused at one value
        d.update({name: self.flag_value(name) if used else FLAGS[name].unused
                  for name, used in self._flags_used().items()})
        caps = self.spec().caps
        if self.warm_start is None or self.warm_from not in caps.warm_from:
            d["warm_from"] = "controls"  # nothing to start from, or a solver that only rolls the controls out
        if self.warm_start is not None or self.start not in caps.starts:
            d["start"] = "held"  # a warm start decides the first trajectory; other solvers have their own
        if self.balance == "none":
            d["balance_margin"] = NO_BALANCE_MARGIN  # no balance term: its margin means nothing
        d["bounds"] = self.hard_bounds()
        return PlanConfig(**d)

    def hard_bounds(self) -> str:
        """``hard`` or ``none``: the one given, else hard for a problem file, none for a built-in plant and task."""
        if self.bounds:
            return self.bounds
        return "hard" if self.problem is not None else "none"

    def spec(self) -> SolverSpec:
        """The solver's registered spec (``ValueError`` for an unknown name)."""
        return get_solver(self.solver)

    def flag_value(self, name: str) -> Any:
        """The value in force of solver flag ``name``: the one given, or the default it resolves to (R-AICO's
        alpha schedule: robust for a problem file, the thesis's fixed one for a built-in plant and task)."""
        f = FLAGS[name]
        value = getattr(self, name)
        return f.resolve(value, self.problem is not None) if f.resolve is not None else value

    def _flags_used(self) -> dict[str, bool | None]:
        """Every solver flag: None where this solver does not take it, False where its other options leave it
        unused (``Flag.only``), True where it is used."""
        taken = {f.name for f in self.spec().flags}
        out: dict[str, bool | None] = {}
        for name, f in FLAGS.items():
            if name not in taken:
                out[name] = None
            elif f.only is not None:
                other = self.flag_value(f.only[0]) if f.only[0] in taken else FLAGS[f.only[0]].unused
                out[name] = other in f.only[1]
            else:
                out[name] = True
        return out

    def solver_options(self) -> dict:
        """The options of the solver these fields set (its ``options()`` applies its own defaults)."""
        opts: dict[str, Any] = {"iterations": self.iterations}
        for f in self.spec().flags:
            value = self.flag_value(f.name)
            if f.to_option is not None:
                value = f.to_option(value)
            if value is not None:
                opts[f.option or f.name] = value
        return opts


@dataclass
class PlanOutput:
    config: PlanConfig
    task: TaskSpec
    robot: Robot
    problem: Problem
    result: Result
    q0: np.ndarray
    description: dict

    @property
    def times(self) -> np.ndarray:
        """``(T+1,)`` s."""
        return np.arange(self.problem.T + 1) * self.task.dt

    def via_point_errors(self, X: np.ndarray | None = None) -> dict[str, float]:
        """Task error (m or rad) at each via-point time of ``X`` (default: the plan)."""
        return via_point_errors(self.problem, self.result.X if X is None else X)

    def arrays(self) -> dict[str, np.ndarray]:
        """``plan.npz``: the plan (``X``, ``U``, controller ``o``, ``O``), its history per iteration
        (``costs``, wall times, ``step``, ``mu``, ``accepted``, AICO's relinearization ``repeats``) and every iteration's trajectory decimated in time,
        ``X_iterations (iterations + 1, K, n_x)`` float32 (a display copy; row 0 the initial
        trajectory, NaN rows for iterations that diverged) at the steps ``t_iterations (K,)``
        (``raico.planning.problem.iterate_steps``)."""
        r = self.result
        iterates = {} if r.X_iterations is None else {"X_iterations": r.X_iterations,
                                                       "t_iterations": r.t_iterations}
        U, o, O = joint_controls(self.problem, r.U, r.o, r.O)
        return {"X": r.X, "U": U, "o": o, "O": O, "costs": r.costs, "q0": self.q0,
                "times": self.times, "wall_time": np.array([h.time_s for h in r.history]),
                "elapsed": np.array([h.elapsed_s for h in r.history]),
                "step": np.array([h.step for h in r.history]), "mu": np.array([h.mu for h in r.history]),
                "accepted": np.array([h.accepted for h in r.history], bool),
                "repeats": np.array([h.repeats for h in r.history], np.int64),
                "beliefs": r.beliefs if r.beliefs is not None else np.zeros((0,)),
                "joint_names": np.array(self.robot.joint_names), **iterates}

    def metrics(self) -> dict:
        """``initial_cost``: iteration 0, the initial trajectory (``x_t = x0``, ``u = 0``) rolled out;
        ``first_iteration_cost``: after the first update; ``cost_ratio = final / initial``."""
        r = self.result
        costs = r.costs
        first = float(costs[0]) if costs.size else float("nan")
        init = float(r.initial_cost)
        out = {"initial_cost": init, "first_iteration_cost": first,
               "final_cost": float(r.cost), "cost_ratio": float(r.cost / init) if init else None,
               "iterations": int(r.iterations), "status": str(r.status),
               "wall_time_s": float(sum(h.time_s for h in r.history)),
               "via_point_errors": self.via_point_errors(), "task": task_verdict(task_errors(self.problem, r.X)),
               "message": r.message}
        if "balance" in self.description:  # only with --balance: other plans' metrics as before
            out["balance"] = self.balance_metrics()
        caps = self.config.spec().caps
        if caps.sweeps and r.history:
            # the relinearization repeats per iteration set AICO's time per iteration (small steps repeat more)
            out["repeats_per_iteration"] = float(np.median([h.repeats for h in r.history]))
        if caps.schedules and self.config.solver_options().get("schedule", "fixed") != "fixed" and r.history:
            # the trials the schedule rejected: each an iteration that kept the previous iterate
            out["rejected_trials"] = int(sum(not h.accepted for h in r.history))
        return out

    def balance_metrics(self) -> dict:
        """The balance objective's report (``raico.stages.plan.balance``) and the planned CoG's smallest
        static margin ``cog_min_margin`` (m, over steps 1..T) against its support polygon."""
        b = dict(self.description["balance"])
        margins = cog_margins(self.robot, self.result.X[1:], np.array(b["polygon"]))
        b["cog_min_margin"] = float(np.nanmin(margins)) if np.isfinite(margins).any() else float("nan")
        return b


def joint_controls(problem: Problem, U: np.ndarray, o: np.ndarray, O: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A plan's controls as every planning joint's torque (what ``plan.npz`` stores and executions apply):
    an underactuated robot's motor commands ``U (T, n_act)`` and controller ``o (T, n_act)``,
    ``O (T, n_act, n_x)`` times its selection ``S`` (0 on the unactuated joints); others unchanged."""
    dyn = problem.dynamics
    if not isinstance(dyn, ActuatedDynamics):
        return U, o, O
    S = dyn.S
    return U @ S.T, o @ S.T, np.einsum("ij,tjk->tik", S, O)


def motor_controls(problem: Problem, U: np.ndarray) -> np.ndarray:
    """The inverse of :func:`joint_controls` for stored controls ``U (T, n_q)`` (a warm start): the motor
    commands ``(T, n_act)`` of an underactuated robot (the actuated joints' columns), else ``U``."""
    dyn = problem.dynamics
    return U @ dyn.S if isinstance(dyn, ActuatedDynamics) and U.ndim == 2 and U.shape[1] == dyn.S.shape[0] else U


def initial_posture(robot: Robot, q0_std: float, seed: int, q0_std_prismatic: float = 0.0) -> np.ndarray:
    """``q0 = default + N(0, q0_std^2)`` (rad; ``q0_std_prismatic`` m on a prismatic joint), clipped to the
    joint limits (a robot cannot start outside them; the Nao's hands default to their lower limit), widened
    to hold the default posture where a model file's start posture lies outside them."""
    rng = np.random.default_rng(seed)
    lower, upper = np.minimum(robot.lower, robot.default_q), np.maximum(robot.upper, robot.default_q)
    prismatic = np.array([robot.plant.GetJointByName(n).type_name() == "prismatic" for n in robot.joint_names])
    std = np.where(prismatic, q0_std_prismatic, q0_std)
    return np.clip(robot.default_q + std * rng.standard_normal(robot.n_q), lower, upper)


def quasi_static_controls(problem: Problem, q0: np.ndarray) -> np.ndarray:
    """``(T, n_u)``: the controls that hold ``x0 = (q0, 0)`` at rest at every step: the torques
    ``g(q0)`` of the model's inverse dynamics (zero accelerations for pseudo-dynamics)."""
    dyn = problem.dynamics
    if isinstance(dyn, PseudoDynamics):
        return np.zeros((problem.T, problem.n_u))
    inverse = getattr(dyn, "inverse_dynamics", None)
    if inverse is None:
        raise ValueError(f"--start quasi-static needs a model with inverse dynamics, not {type(dyn).__name__}")
    zero = np.zeros_like(q0)
    return np.tile(np.asarray(inverse(q0, zero, zero), float), (problem.T, 1))


def hard_bounds(robot: Robot, kind: str, dt: float | None = None) -> Bounds | None:
    """The robot's joint ranges (rad; the joints with a finite one), its velocity limits (rad/s; the joints with
    a finite one) and its effort limits (N m; unlimited joints ``inf``): on the torque controls, or for
    acceleration controls (with ``dt``; a fixed base) on the torques of the accelerations (the analytic model's
    inverse dynamics), as a problem's hard bounds (``None`` if it has none)."""
    idx = np.flatnonzero(np.isfinite(robot.lower) | np.isfinite(robot.upper))
    eff = np.where((robot.effort > 0) & np.isfinite(robot.effort), robot.effort, np.inf)
    if kind == "torque" and robot.underactuated:  # the controls are the motors' commands
        eff = robot.effort[robot.actuated]
    torque = kind == "torque" and bool(np.any(np.isfinite(eff)))
    vel = robot.velocity if robot.velocity is not None else np.full(robot.n_q, np.inf)
    vidx = np.flatnonzero(np.isfinite(vel))
    # a robot on its soles: the welded model's inverse dynamics are not its motors' torques
    tau = (kind == "acceleration" and dt is not None and not robot.floating and not robot.stands_on_a_link
           and bool(np.any(np.isfinite(eff))))
    if not len(idx) and not torque and not len(vidx) and not tau:
        return None
    return Bounds(u_lower=-eff if torque else None, u_upper=eff if torque else None,
                  q_index=idx if len(idx) else None, q_lower=robot.lower[idx], q_upper=robot.upper[idx],
                  v_index=robot.n_q + vidx if len(vidx) else None, v_lower=-vel[vidx], v_upper=vel[vidx],
                  tau_model=make_dynamics("analytic", robot, dt) if tau else None, tau_limit=eff if tau else None)


def actuated(dyn, robot: Robot, substeps: int = 1):
    """The problem's model of step model ``dyn``: stepped ``substeps`` times per control step
    (:class:`raico.plants.dynamics.SubstepDynamics`) and, for an underactuated robot, with the motors' commands as
    its controls (:class:`raico.plants.dynamics.ActuatedDynamics`); ``dyn`` itself for one step of a fully actuated
    robot. Pseudo-dynamics (every joint's acceleration commanded) take neither: ``ValueError``."""
    if isinstance(dyn, PseudoDynamics) and robot.underactuated:
        off = [n for k, n in enumerate(robot.joint_names) if k not in set(robot.actuated.tolist())]
        raise ValueError(f"{robot.name} has unactuated joints ({', '.join(off)}): pseudo-dynamics command every "
                         "joint's acceleration; use --dynamics analytic or learned")
    if isinstance(dyn, PseudoDynamics) and substeps != 1:
        raise ValueError(f"the problem steps its model {substeps} times per control step: for the analytic and "
                         "learned models only, not pseudo-dynamics")
    if substeps != 1:
        dyn = SubstepDynamics(dyn, substeps)
    return ActuatedDynamics(dyn, robot.S) if robot.underactuated else dyn


def control_kind(dynamics) -> str:
    """``acceleration`` for pseudo-dynamics, ``torque`` for the analytic and learned models."""
    return "acceleration" if isinstance(dynamics, PseudoDynamics) else "torque"


def describe_problem(cfg: PlanConfig, task: TaskSpec, q0: np.ndarray, descriptions: list,
                     model_key: str | None, kind: str) -> dict:
    """The stored problem description (``problem.json``): enough to rebuild the objective."""
    return {"plant": cfg.plant, "task": cfg.task, "dynamics": cfg.dynamics, "model": model_key,
            "control_kind": kind, "dt": task.dt, "T": task.T, "q0": q0.tolist(),
            "x0": np.concatenate([q0, np.zeros_like(q0)]).tolist(), "terms": descriptions}


# plan() says a model file's load report and its own notes (reach, start outside the limits); within
# load_notes_said the caller said the report once, and plan() says each note once ("said": those said so
# far) or, when the caller said those too, none ("said": None)
_LOAD_NOTES: dict[str, Any] = {"say": True, "said": set()}


def load_notes(robot: Robot) -> list[str]:
    """The lines saying what loading ``robot``'s model file changed (none for a built-in plant)."""
    if robot.builtin:
        return []
    return [f"raico: note: {Path(robot.spec.file).name}: {line}" for line in robot.load_report]


class load_notes_said:  # noqa: N801 - used as a context manager, as contextlib's
    """Within it, plan() does not say the model file's load report (the caller, an experiment or a learning
    loop, said it once) and says each of its own notes (:func:`plan_notes`) once, or (``plan_notes`` False:
    the caller said them too) not at all."""

    def __init__(self, plan_notes: bool = True):
        self.plan_notes = plan_notes

    def __enter__(self):
        self.before = dict(_LOAD_NOTES)
        _LOAD_NOTES.update(say=False, said=set() if self.plan_notes else None)
        return self

    def __exit__(self, *exc):
        _LOAD_NOTES.update(self.before)
        return False


def plan_notes(cfg: PlanConfig, robot: Robot, problem: Problem) -> list[str]:
    """What the plan stage says before planning: targets beyond the reach (:func:`reach_notes`), a start
    outside the joint limits (:func:`start_limit_notes`)."""
    return reach_notes(robot, problem) + start_limit_notes(cfg, robot, problem) + start_collision_notes(problem)


def start_collision_notes(problem: Problem) -> list[str]:
    """One line per collision term whose pairs are closer than its margin at the start posture (below 0:
    in collision), saying it is planned anyway (a hard term: its stiff penalty, or the constraint, pushes
    the pairs apart from the first step the dynamics allow)."""
    from raico.planning.costs import Collision
    from raico.plants.scene import ROBOT_PREFIX

    out = []
    q0 = problem.x0[:len(problem.x0) // 2]
    for term in problem.state_terms:
        if not isinstance(term, Collision) or term.weight == 0:
            continue
        d = term.taskmap.value(q0)
        k = int(np.argmin(d)) if d.size else -1
        if k < 0 or d[k] >= term.margin:
            continue
        a, b = (n.removeprefix(ROBOT_PREFIX) for n in term.taskmap.pairs[k])
        what = "in collision" if d[k] < 0 else "inside the margin"
        out.append(f"raico: note: the start is {what} of '{term.name}': {a} | {b} at {1e3 * d[k]:.3g} mm "
                   f"(margin {1e3 * term.margin:.3g} mm, {int(np.sum(d < term.margin))} pairs below it): "
                   f"planned anyway ({'hard' if term.hard else 'soft'})")
    return out


def _say_plan_notes(lines: list[str]) -> None:
    """Print ``lines`` on stderr, each once within :class:`load_notes_said` (none there if the caller said them)."""
    said = _LOAD_NOTES["said"]
    for line in lines:
        if _LOAD_NOTES["say"] or (said is not None and line not in said):
            print(line, file=sys.stderr, flush=True)
            if said is not None:
                said.add(line)


def robot_and_task(cfg: PlanConfig) -> tuple[Robot, TaskSpec]:
    """The robot and the task of ``cfg``: a built-in plant's shipped task, or a problem file's."""
    if cfg.problem is None:
        task = get_task(cfg.plant, cfg.task)
        return task.robot(shared_robot(cfg.plant)), task
    pf = cfg.problem_file()
    if pf.plant is not None:
        task = task_from_problem(pf)
        return task.robot(shared_robot(pf.plant)), task
    from raico.plants.model_file import ModelError, shared_model

    try:
        robot = shared_model(pf.robot_spec())
    except ModelError as e:
        raise ValueError(str(e)) from None
    return robot, task_from_problem(pf)


def check_problem(cfg: PlanConfig) -> None:
    """A problem file's robot loads and its terms build at the start posture (``ValueError``
    otherwise): bad frames, joints and shapes are refused before anything runs."""
    robot, task = robot_and_task(cfg)
    task.build(robot, robot.default_q.copy(), task.T)
    true_robot(cfg.problem_file())


def true_robot(pf: ProblemFile) -> Robot | None:
    """The robot a problem's babbling and executions run on when ``[robot.true]`` states one (its
    own shared model), else None (``ValueError`` for a frame it names that is not in the file)."""
    spec = pf.true_spec()
    if spec is None:
        return None
    from raico.plants.model_file import ModelError, shared_model

    try:
        return shared_model(spec)
    except ModelError as e:
        raise ValueError(str(e)) from None


def check_model_robot(model: Artifact, robot: Robot) -> None:
    """A fit's GP is of this robot (its data's plant, or the model file's robot by name: file and spec),
    else ``ValueError``: a model of another robot with as many joints would plan silently wrong. A fit
    whose ``fit.json`` cannot be read or names no plant is refused as well (``ValueError``, one line):
    the fit stage always writes it, so such a fit is damaged, and its robot cannot be checked."""
    try:
        doc = model.document("fit.json")
    except (OSError, ValueError) as e:   # missing, unreadable, not UTF-8, not JSON
        why = (str(e).strip().splitlines() or [""])[0]
        raise ValueError(f"--model {model.key}: its fit.json cannot be read ({type(e).__name__}: {why}), so the "
                         "robot its GP was fit on cannot be checked: fit it again") from None
    fitted = doc.get("plant") if isinstance(doc, dict) else None
    if not isinstance(fitted, str):
        raise ValueError(f"--model {model.key}: its fit.json names no plant, so the robot its GP was fit on "
                         "cannot be checked: fit it again")
    if fitted != robot.name:
        raise ValueError(f"--model {model.key} is a GP of {fitted}, this problem's robot is {robot.name}: "
                         "fit it on data of this robot")


def build_problem(cfg: PlanConfig, model: Artifact | None = None, q0: np.ndarray | None = None
                  ) -> tuple[Robot, TaskSpec, Problem, np.ndarray, dict]:
    """Robot, task, problem, ``q0`` and the problem's description for ``cfg`` (normalized here: the
    task's dynamics and spread of ``q0`` where ``cfg`` leaves them to it); ``q0``: another start posture
    (the terms relative to the start then relative to it)."""
    cfg = cfg.normalized()
    robot, task = robot_and_task(cfg)
    if q0 is None:
        q0 = initial_posture(robot, Q0_STD if cfg.q0_std is None else cfg.q0_std, cfg.seed,
                             cfg.q0_std_prismatic) + cfg.x0_nudge
    params = model.arrays("model.npz") if model is not None else None
    if model is not None:
        check_model_robot(model, robot)
    dyn = actuated(make_dynamics(cfg.dynamics, robot, task.dt / task.substeps, params), robot, task.substeps)
    kind = control_kind(dyn)
    terms = task.build(robot, q0, task.T)
    terms, balance = apply_balance(robot, q0, task.T, terms, cfg.balance, float(cfg.balance_margin))
    objective = build_terms(robot, terms, task.T, kind)
    descriptions, joint = objective.descriptions, list(objective.joint_terms)
    if cfg.sigma is not None:  # the uncertainty term from the config's values (its description only stored)
        joint.append(Uncertainty(dyn, cfg.sigma, cfg.sigma_weight, task.T, units=cfg.sigma_units))
        descriptions = [*descriptions, uncertainty(cfg.sigma, cfg.sigma_weight, units=cfg.sigma_units)]
    x0 = np.concatenate([q0, np.zeros(robot.n_q)])
    problem = Problem(dyn, x0, task.T, objective.state_terms, objective.control_terms, joint,
                      hard_bounds(robot, kind, task.dt / task.substeps) if cfg.hard_bounds() == "hard" else None)
    desc = describe_problem(cfg, task, q0, descriptions, model.ref if model else None, kind)
    if not robot.builtin:  # a model file's robot: execute, evaluate and the recordings rebuild it
        desc.update(plant=robot.name, robot=robot.spec.to_dict(), load_report=list(robot.load_report))
        true_spec = cfg.problem_file().true_spec()
        if true_spec is not None:  # the robot that executes the plan: the file's with [robot.true]'s changes
            desc["robot_true"] = true_spec.to_dict()
    if balance is not None:
        desc["balance"] = balance.to_dict()
    return robot, task, problem, q0, desc


# relative to the chain's length: the bound and the target's distance are sums of a few link vectors, rounded
# to a few eps each; a target this close to the bound is at it
REACH_SLACK = 1e-9


def _directions(chain: Chain, target: np.ndarray, axes: np.ndarray) -> list[np.ndarray]:
    """Unit directions (3,) to compare the target with the reach along: toward it, along and against each
    joint's axis, and toward it normal to each axis (a lift's target too high, an arm's too far out),
    within the coordinates ``axes`` the term sets."""
    delta = np.zeros(3)
    delta[axes] = target - chain.base[axes]
    out = [delta]
    for _, axis in chain.joints:
        out += [axis, -axis, delta - (delta @ axis) * axis]
    mask = np.zeros(3)
    mask[axes] = 1.0
    units = []
    for e in out:
        e = e * mask
        n = float(np.linalg.norm(e))
        if n > 1e-9 * max(1.0, float(np.linalg.norm(delta))):
            units.append(e / n)
    return units


def reach_notes(robot: Robot, problem: Problem) -> list[str]:
    """One line per position target (a via-point on a frame's points) that lies farther from the robot's
    base along some direction than the point can get along it (:meth:`raico.plants.robots.Chain.reach_along`, a
    bound from the chain's links: toward the target, along and against the joints' axes, toward it normal
    to them). A target that passes may still be out of reach; one that fails is. Only the target's
    coordinates the term sets (its ``axes``) count."""
    from raico.planning.costs import ViaPoint
    from raico.plants.taskmaps import FramePoints

    out = []
    for term in problem.state_terms:
        tm = getattr(term, "taskmap", None)
        if not isinstance(term, ViaPoint) or not isinstance(tm, FramePoints) or term.weight == 0:
            continue
        k = len(tm.points)
        axes = tm.rows[:len(tm.rows) // k] % 3
        targets = term.target.reshape(k, len(axes))
        worst = None
        for j in range(k):
            chain = kinematic_chain(robot, tm.frame.name(), tm.points[j])
            if chain is None:
                break
            delta = np.zeros(3)
            delta[axes] = targets[j] - chain.base[axes]
            slack = REACH_SLACK * chain.reach()   # a target at the bound, as rounded, is within it
            for e in _directions(chain, targets[j], axes):
                far, reach = float(e @ delta), chain.reach_along(e)
                if far - reach > slack and (worst is None or far - reach > worst[0] - worst[1]):
                    worst = (far, reach, j, chain.base, e)
        if worst is not None:
            far, reach, j, base, e = worst
            out.append(f"raico: note: the target of '{term.name}' ({tm.frame.name()} at "
                       f"{np.round(targets[j], 4).tolist()} m) lies {far:.3g} m from the robot's base at "
                       f"{np.round(base, 4).tolist()} m along {np.round(e, 3).tolist()}, beyond its reach of "
                       f"{reach:.3g} m along it (the most its links and prismatic travel can add): planning anyway")
    return out


def start_limit_notes(cfg: PlanConfig, robot: Robot, problem: Problem) -> list[str]:
    """One line where the start ``x0`` lies outside the model's joint ranges, saying what the bounds in
    force make of it: hard bounds (a problem file's default) bring those joints back as fast as their velocity
    limits allow (:meth:`raico.planning.problem.Bounds.position_box`; else status out-of-bounds); without them only a
    ``joint_limit`` term pulls them in, and without one planning knows no limits."""
    q0 = problem.x0[:robot.n_q]
    outside = np.flatnonzero((q0 < robot.lower) | (q0 > robot.upper))
    if not len(outside):
        return []
    which = ", ".join(f"{robot.joint_names[i]} ({q0[i]:.4g}, range {robot.lower[i]:.4g} to {robot.upper[i]:.4g})"
                      for i in outside[:4]) + (f" and {len(outside) - 4} more" if len(outside) > 4 else "")
    head = f"raico: note: the start is outside the joint limits on {which}"
    bounds = problem.bounds
    held = bounds is not None and bounds.has_positions and bool(np.isin(outside, bounds.q_index).any())
    if held:
        return [f"{head}: the hard bounds (--bounds hard{', the default for a problem file' if cfg.problem else ''})"
                " bring them back as fast as their velocity limits allow (inside from step 1 where a joint has "
                "none), or the plan ends out-of-bounds; --bounds none plans without them"]
    pf = cfg.problem_file() if cfg.problem is not None else None
    soft = pf is not None and any(t.get("type") == "joint_limit" for t in pf.doc["costs"]["terms"].values())
    return [f"{head}: planning keeps no hard bounds (--bounds none); "
            + ("the joint_limit term pulls them in" if soft else "no joint_limit term either: it plans as if "
               "there were no limits") + "; an execution starts clipped to them"]


def plan(cfg: PlanConfig, model: Artifact | None = None, progress: Progress | None = None,
         warm_start: Artifact | None = None) -> PlanOutput:
    """Plan; a diverging solver is a result (status ``diverged``), not an exception.

    ``cfg``: a valid config (the runner validates and normalizes it before the stage runs; the solver
    checks its options again, as the planning library checks every caller's). ``warm_start``: an
    earlier plan of the same horizon: its controls are the initial guess, and with
    ``warm_from = "trajectory"`` (AICO/R-AICO) its states are the first linearization point."""
    robot, task, problem, q0, desc = build_problem(cfg, model)
    for line in desc.get("load_report", []) if _LOAD_NOTES["say"] else []:  # what loading the model file changed
        print(f"raico: note: {Path(desc['robot']['file']).name}: {line}", file=sys.stderr, flush=True)
    _say_plan_notes(plan_notes(cfg, robot, problem))
    if "balance" in desc:  # say it before planning, never silently
        if desc["balance"]["note"]:
            print(desc["balance"]["note"], file=sys.stderr, flush=True)
    init = {}
    caps = cfg.spec().caps
    if cfg.start == "rollout" and warm_start is None and "rollout" in caps.starts:
        init["U_init"] = np.zeros((problem.T, problem.n_u))  # the first trajectory: the zero-control rollout
    if cfg.start == "quasi-static" and warm_start is None:
        init["U_init"] = quasi_static_controls(problem, q0)
    if warm_start is not None:
        U0 = motor_controls(problem, np.asarray(warm_start.arrays(PLAN_FILE)["U"], float))
        if U0.shape != (problem.T, problem.n_u) or not np.all(np.isfinite(U0)):
            raise ValueError(f"warm start {warm_start.key}: its controls do not fit this problem "
                             f"(shape {U0.shape}, expected {(problem.T, problem.n_u)}, finite)")
        init["U_init"] = U0
        if cfg.warm_from == "trajectory" and "trajectory" in caps.warm_from:
            X0 = warm_start.arrays(PLAN_FILE)["X"]
            if X0.shape != (problem.T + 1, problem.n_x) or not np.all(np.isfinite(X0)):
                raise ValueError(f"warm start {warm_start.key}: its states do not fit this problem")
            init["X_init"] = np.array(X0, dtype=float)
    callback = None
    if progress is not None:
        def callback(rec, *_):  # noqa: ANN001
            progress(rec.iteration, cfg.iterations)
    result = solve(problem, cfg.solver, cfg.solver_options(), callback=callback, **init)
    return PlanOutput(cfg, task, robot, problem, result, q0, desc)


def run(cfg: PlanConfig, inputs: dict | None = None, progress: Progress | None = None) -> StageOutput:
    """The plan stage: ``plan.npz`` (trajectory, controller, history) and ``problem.json``; ``cfg``
    normalized and validated by the runner."""
    inputs = inputs or {}
    out = plan(cfg, inputs.get("model"), progress, inputs.get("warm_start"))
    return StageOutput(status=str(out.result.status), metrics=out.metrics(), arrays={PLAN_FILE: out.arrays()},
                       documents={PROBLEM_FILE: out.description}, payload=out)


STAGE = Stage(name="plan", config_cls=PlanConfig, run=run, sources=("raico.plants", "raico.planning", "raico.stages.plan", "raico.stages.base", "raico.stages.evaluate.metrics",
                                                        "files:problems/*.toml"),
              data_files=(PLAN_FILE, PROBLEM_FILE),
              description=DESCRIPTIONS["plan"],
              progress_total=lambda cfg: cfg.iterations)
