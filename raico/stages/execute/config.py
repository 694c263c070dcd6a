"""The execute stage's parameters (:class:`ExecuteConfig`) and its result (:class:`ExecuteOutput`)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from raico.planning.mpc import WARM_STARTABLE
from raico.planning.solvers import get_solver
from raico.plants.robots import Robot, robot_for
from raico.stages.base import StageConfig
from raico.stages.plan.stage import PROBLEM_FILE

STARTS = ("plan", "standing")  # a floating robot's start state (docs/execution.md)
CONTROLLERS = ("pd", "wbc", "mpc")  # pd, wbc (floating), mpc (fixed: re-planning; floating: above the stabilizer)
MPC_SOLVERS = WARM_STARTABLE  # the solvers with a shift warm start (their spec's caps.mpc, raico.planning.mpc)
MPC_HORIZON = 50  # planning steps: --controller mpc's default horizon (at most the problem's T)
FINAL_TARGETS = ("receding", "fixed")  # --final-target: a term at the problem's last step in the MPC's window
WINDOW_TARGETS = ("start", "plan")  # --window-target: what the window's posture and velocity terms hold
ARM_FINAL_TARGET = "receding"  # --final-target's default for a fixed-base arm (a floating robot's: fixed)


@dataclass(frozen=True)
class ExecuteConfig(StageConfig):
    """Declared parameters of the execute stage; ``plan`` is its input (a plan artifact)."""

    INPUTS = ("plan",)
    INPUT_STAGES = {"plan": "plan"}
    HELP = {"plan": "Key (or prefix) of a plan artifact.", "x0_noise": "Std of initial joint-angle noise (rad).",
            "process_noise": "Std of torque noise per planning step and joint (N m).",
            "clip_torques": "Clip the logged torques at the effort limits (arms, pendulum).",
            "open_loop": "Integration check (arms, pendulum; appendix C): the plan's controls U applied open loop (no "
                         "feedback, no noise) to Drake's continuous plant (no joint limits), runge_kutta3 at a fixed "
                         "step of at most 1 ms; how far Drake's integration of the planned controls is from the plan.",
            "start": "Nao start state: plan (the plan's x0 on the ground, tipped onto its lowest sole corners) or "
                     "standing (projected to double support by inverse kinematics); default: standing with "
                     "--controller wbc, plan with the joint PD.",
            "controller": "Nao controller: pd (joint PD + inverse-dynamics feed-forward) or wbc (the whole-body "
                          "stabilizer, a task-space inverse-dynamics QP with contact); arms: mpc (receding-horizon "
                          "control re-planning every --period from the measured state, raico.planning.mpc; a floating robot: the "
                          "window's reference handed to the whole-body stabilizer).",
            "period": "--controller mpc: control period (s); default the planning step; a divisor of it, at least "
                      "the simulation step.",
            "horizon": f"--controller mpc: horizon in planning steps (default min(T, {MPC_HORIZON})).",
            "iterations_per_tick": "--controller mpc: solver iterations per control period.",
            "solver": "--controller mpc: the solver of each period: " + ", ".join(MPC_SOLVERS) + ".",
            "rti": "--controller mpc: the preparation / feedback split (real-time iteration): the control from the "
                   "controller prepared for the model's prediction, the next period's solve after it (solvers that "
                   "split: raico, aico; a fixed-base robot; the period the planning step).",
            "final_target": "--controller mpc: a term at the problem's last step in the window: receding (the "
                            "window's last step costs it while the problem's end lies beyond the window) or fixed "
                            "(only once the problem's end is inside the window); default: receding for a fixed-base "
                            "arm, fixed above a floating robot's stabilizer (docs/mpc.md).",
            "window_posture": "--controller mpc on a floating robot: the weight (1/rad^2) of a term on the joint "
                              "positions' distance from the standing start at every step of the window (not of the "
                              "plan): what the problem leaves free held instead of carried on; default 0 (none; "
                              "docs/mpc.md).",
            "online_every": "--controller mpc on a learned model with a sparse GP (fixed inducing points): its "
                            "posterior updated from the executed steps every K planning steps within the run "
                            "(raico.planning.mpc.OnlineResidual; no refit of hyperparameters); default 0 (none).",
            "window_damping": "--controller mpc on a floating robot: the weight (s^2/rad^2) of a term on the joint "
                              "velocities at every step of the window (not of the plan); default 0 (none).",
            "window_target": "--controller mpc on a floating robot: what --window-posture and --window-damping hold: "
                             "start (the standing start at rest, default) or plan (the plan's joint positions and "
                             "velocities at each window step's absolute time, moving with the window).",
            "window_lead": "--controller mpc on a floating robot: the stabilizer's joint and CoG reference at the "
                           "tick's step from the window's state that many steps ahead (0, default: the window's "
                           "first state, the measured one; docs/mpc.md).",
            "push": "Any controller: a scripted push FRAME:NEWTONS:START:DURATION "
                    "(a force at the frame's origin on its body, NEWTONS along the world x axis or FX,FY,FZ; START "
                    "and DURATION in s); repeatable."}

    plan: str  # key, key prefix or plan/KEY of the plan to execute (required)
    x0_noise: float = 0.0  # rad, std of noise on the initial joint angles
    process_noise: float = 0.0  # N m, std of torque noise per planning step
    seed: int = 0
    clip_torques: bool = True
    open_loop: bool = False  # the integration check of appendix C (see HELP)
    start: str | None = None  # floating: "plan" or "standing" (STARTS); None: standing with the stabilizer, else plan
    controller: str = "pd"  # floating: "pd" or "wbc"; fixed-base: "pd" (the plan's controller) or "mpc" (CONTROLLERS)
    period: float | None = None  # s, --controller mpc: control period (None: the planning step)
    horizon: int | None = None  # planning steps, --controller mpc (None: min(T, MPC_HORIZON))
    iterations_per_tick: int = 1  # --controller mpc
    solver: str = "raico"  # --controller mpc (MPC_SOLVERS)
    rti: bool = False  # --controller mpc: the preparation / feedback split (MPC(..., split=True))
    final_target: str | None = None  # --controller mpc: FINAL_TARGETS (None: the controller's default, see HELP)
    window_posture: float = 0.0  # --controller mpc, floating robot: the window's posture term's weight (1/rad^2)
    window_damping: float = 0.0  # --controller mpc, floating robot: the window's joint-velocity term's weight
    window_target: str = "start"  # --controller mpc, floating robot: WINDOW_TARGETS
    window_lead: int = 0  # --controller mpc, floating robot: the stabilizer follows the window from this state on
    push: tuple[str, ...] = ()  # scripted pushes FRAME:NEWTONS:START:DURATION
    online_every: int = 0  # --controller mpc, learned sparse model: update it every K planning steps (0: never)

    def __post_init__(self) -> None:
        object.__setattr__(self, "push", tuple(self.push or ()))   # the CLI gives None for no --push

    def normalized(self) -> ExecuteConfig:
        """The start state spelled out: the standing start with the stabilizer (which needs both soles on the
        ground), the plan's start with the joint PD (the thesis rows); with MPC left open (a floating robot's
        MPC, above the stabilizer, starts standing; a fixed one's has no start to choose)."""
        if self.start is not None or self.controller == "mpc":
            return self
        return dataclasses.replace(self, start="standing" if self.controller == "wbc" else "plan")

    def check_inputs(self, inputs: dict) -> None:
        """The options of a robot executed on its soles refused for another robot's plan, and the other way
        round (they would change the key, not the run)."""
        plan = inputs["plan"]
        if self.controller == "mpc":
            T = int(plan.document(PROBLEM_FILE)["T"])
            if self.horizon is not None and self.horizon > T:
                raise ValueError(f"--horizon {self.horizon} is longer than the problem's {T} steps")
        if robot_for(plan.document(PROBLEM_FILE)).floating:
            if self.rti:
                raise ValueError("--rti: the preparation / feedback split runs on a fixed-base robot's MPC")
            return
        for name in ("window_posture", "window_damping", "window_target", "window_lead"):
            if getattr(self, name) != ExecuteConfig.__dataclass_fields__[name].default:
                raise ValueError(f"--{name.replace('_', '-')} is for a floating robot's MPC (above its stabilizer)")
        plant = plan.config.get("plant")
        if self.controller not in ("pd", "mpc"):
            raise ValueError(f"--controller {self.controller} is for plans of a floating robot; this plan is of "
                             f"{plant} (its executions use the computed-torque controller)")
        if self.start not in (None, "plan"):
            raise ValueError(f"--start {self.start} is for plans of a floating robot; this plan is of {plant}")

    def mpc_horizon(self, T: int | None) -> int:
        """The MPC's horizon in planning steps for a problem of ``T`` steps."""
        if self.horizon is not None:
            return self.horizon
        return MPC_HORIZON if T is None else min(T, MPC_HORIZON)

    def receding_end(self, default: str) -> bool:
        """Whether a term at the problem's last step follows the window's receding end (``--final-target``, or
        the controller's ``default``, one of :data:`FINAL_TARGETS`)."""
        return (self.final_target or default) == "receding"

    def pushes(self) -> list[tuple[str, np.ndarray, float, float]]:
        """The scripted pushes ``(frame, force (3,) N in world, start s, duration s)``."""
        out = []
        for spec in self.push:
            parts = spec.rsplit(":", 3)
            try:
                if len(parts) != 4 or not parts[0]:
                    raise ValueError
                f = np.array([float(v) for v in parts[1].split(",")])
                force = np.array([f[0], 0.0, 0.0]) if f.size == 1 else f
                start, duration = float(parts[2]), float(parts[3])
                if force.size != 3 or not np.all(np.isfinite(force)) or not (start >= 0 and duration > 0):
                    raise ValueError
            except ValueError:
                raise ValueError(f"--push {spec!r}: expected FRAME:NEWTONS:START:DURATION (NEWTONS one number along "
                                 "world x or FX,FY,FZ; START >= 0 and DURATION > 0 in s)") from None
            out.append((parts[0], force, start, duration))
        return out

    def _validate_mpc(self) -> None:
        d = ExecuteConfig.__dataclass_fields__
        if self.controller != "mpc":
            given = [n for n in ("period", "horizon", "iterations_per_tick", "solver", "rti",
                                 "final_target", "window_posture", "window_damping", "window_target",
                                 "window_lead", "online_every")
                     if getattr(self, n) != d[n].default]
            if given:
                raise ValueError(f"--{given[0].replace('_', '-')} is an option of --controller mpc")
            return
        if self.solver not in MPC_SOLVERS:
            raise ValueError(f"--solver {self.solver} cannot warm-start a receding horizon; use one of "
                             f"{', '.join(MPC_SOLVERS)}")
        if self.rti and not get_solver(self.solver).caps.split:
            raise ValueError(f"--rti: solver {self.solver} has no preparation / feedback split")
        if self.period is not None and not (math.isfinite(self.period) and self.period > 0):
            raise ValueError(f"--period must be a positive number of seconds, got {self.period}")
        if self.horizon is not None and self.horizon < 1:
            raise ValueError(f"--horizon must be at least 1 planning step, got {self.horizon}")
        if self.iterations_per_tick < 1:
            raise ValueError(f"--iterations-per-tick must be at least 1, got {self.iterations_per_tick}")
        if self.online_every < 0:
            raise ValueError(f"--online-every must be 0 (none) or a number of planning steps, got {self.online_every}")
        if self.final_target not in (None, *FINAL_TARGETS):
            raise ValueError(f"--final-target must be one of {', '.join(FINAL_TARGETS)}, got {self.final_target!r}")
        for name in ("window_posture", "window_damping"):
            w = getattr(self, name)
            if not (math.isfinite(w) and w >= 0):
                raise ValueError(f"--{name.replace('_', '-')} must be a finite weight >= 0, got {w}")
        if self.window_lead < 0:
            raise ValueError(f"--window-lead must be 0 or a number of planning steps, got {self.window_lead}")
        if self.window_target not in WINDOW_TARGETS:
            raise ValueError(f"--window-target must be one of {', '.join(WINDOW_TARGETS)}, got {self.window_target!r}")
        if self.open_loop:
            raise ValueError("--open-loop holds the plan's controls; --controller mpc re-plans: choose one")

    def validate(self) -> None:
        self._validate_mpc()
        self.pushes()
        if self.start is not None and self.start not in STARTS:
            raise ValueError(f"start must be one of {', '.join(STARTS)} (got {self.start!r})")
        if self.controller not in CONTROLLERS:
            raise ValueError(f"controller must be one of {', '.join(CONTROLLERS)} (got {self.controller!r})")
        if not 0 <= self.x0_noise <= 1.0:
            raise ValueError("x0-noise must be in [0, 1] rad")
        if not 0 <= self.process_noise <= 100.0:
            raise ValueError("process-noise must be in [0, 100] N m")
        if self.plan is None:
            raise ValueError("execute needs --plan KEY")
        if not 0 <= self.seed < 2**32:
            raise ValueError("seed must be in [0, 2^32 - 1]")
        if self.open_loop and (self.x0_noise > 0 or self.process_noise > 0):
            raise ValueError("--open-loop integrates the plan's own controls: no x0-noise or process-noise")


@dataclass
class ExecuteOutput:
    times: np.ndarray  # (T+1,) s
    X: np.ndarray  # (T+1, n_x) executed
    U: np.ndarray  # (T, n_u) commanded planning controls
    tau: np.ndarray  # (T, n_q) applied torques, N m
    X_plan: np.ndarray
    metrics: dict
    effort_at_limit: np.ndarray = None  # (T, n_q) bool
    floating: dict = field(default_factory=dict)  # a floating robot's arrays (docs/execution.md, "Rollout")
    problem: Any = None  # the plan's problem (task terms for recordings)
    robot: Robot | None = None
    mpc: dict = field(default_factory=dict)  # --controller mpc: per-tick records (raico.planning.mpc.TickLog.arrays)

    @property
    def cog(self):
        return self.floating.get("cog")

    @property
    def cog_margin(self):
        return self.floating.get("cog_margin")

    def arrays(self) -> dict[str, np.ndarray]:
        d = {"times": self.times, "X": self.X, "U": self.U, "tau": self.tau, "X_plan": self.X_plan,
             "effort_at_limit": np.asarray(self.effort_at_limit if self.effort_at_limit is not None
                                           else np.zeros((0, self.X.shape[1] // 2)), bool)}
        d.update(self.floating)
        d.update(self.mpc)
        return d


def initial_q(desc: dict, robot: Robot, cfg: ExecuteConfig, rng) -> np.ndarray:
    """The plan's ``q0`` plus ``x0_noise``, clipped to the joint limits (rad): the robot cannot
    start outside its joint range."""
    q0 = np.asarray(desc["q0"], float)
    q = q0 + cfg.x0_noise * rng.standard_normal(q0.size) if cfg.x0_noise > 0 else q0.copy()
    return np.clip(q, robot.lower, robot.upper)
