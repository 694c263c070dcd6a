"""The execute stage: a plan executed on a Drake plant in Drake's Simulator.

Execution models:

- **Nao: the free-standing robot** (``plants.free_nao``): floating base, compliant sole boxes on
  a rigid ground with friction, a discrete plant (2 ms, SAP) that enforces joint position and
  effort limits. The plan (made on the fixed-base model) is tracked joint by joint: Drake's
  PD-controlled actuators (``KP``, ``KD`` of ``plants.free_nao``) around the planned joint
  trajectory (positions linearly interpolated inside a planning step, the step's velocity
  ``v_{k+1}`` of the semi-implicit Euler plan) plus a feed-forward held for the planning step:
  the plan's inverse-dynamics torques on the fixed-base model, ``ID(q_k, v_k, u_k)`` for
  acceleration plans (the planned torques ``u_k`` for torque plans). The total is clamped at
  the effort limits by the plant; the desired positions are clipped to the joint range. The
  robot starts at rest at the plan's ``x0`` joint angles (plus noise, clipped to the joint
  range) with the left sole flat on the ground at the fixed-base model's pose (the world
  frame); when the plan's posture puts the right sole under the ground, the rigid robot is
  first tipped onto its lowest sole corners (``FreeNao.standing_positions``, the tilt is the
  metric ``start_tilt``); a posture that finds no rest within ``MAX_TIP`` cannot stand on flat
  ground and counts as fallen at t = 0. The simulation runs to the end of the horizon (a fallen robot lies
  on the ground).

  Options (the defaults are the behaviour above): ``start="standing"`` projects the start
  posture (the plan's ``x0`` plus noise) to double support with Drake's inverse kinematics
  (``FreeNao.stance_positions``: both soles flat on the ground, the CoG ``STANCE_MARGIN`` inside their
  polygon, the least joint change); the metrics ``start_projection_norm`` and
  ``start_projection_max`` (rad, planning coordinates) give its size, ``start_cog_margin`` (m) its
  CoG margin. The reference tracked is then the plan shifted by that projection (a constant offset),
  so that the plan's held right sole stays flat instead of being pulled back to the uneven feet of
  the plan's start; ``X_plan`` of the rollout is that reference (``X_plan_unshifted`` the plan).
  ``controller="wbc"`` replaces the joint PD and feed-forward by the whole-body stabilizer
  (``stages.wbc``: a task-space inverse-dynamics QP every 2 ms with contact forces, friction cones
  and torque limits; the plant has no PD actuators; process noise is added to its held torques and the sum
  clamped at the effort limits, as the plant clamps the PD's total);
  its corner forces, solve times and failed programs are in the rollout (``wbc_*``) and metrics
  (``wbc_qp_failures``, ``wbc_qp_fallbacks``: programs proxsuite left to Clarabel, ``wbc_qp_relaxed``: programs
  solved again without the joint-limit bounds, ``wbc_qp_median_s``);
  ``U`` holds its torques.
- **arm5, biorob**: the fixed-base arm as a discrete plant (1 ms, SAP: joint position limits
  enforced) driven by the plan's own feedback controller ``u_k = o_k + O_k x_k`` (a LeafSystem,
  zero-order hold per planning step; pseudo-dynamics plans through computed torque evaluated at
  every plant step). Effort limits: Drake clamps the actuation.
- **a model file's robot** executes as the arms do; where its problem states ``[robot.true]`` the plant
  is that robot (payload, mass scale, friction: ``plants.model_file``), the model file only the plan's.
- **pendulum**: the thesis's ideal point mass, continuous plant, the plan's controller as for the
  arms, Drake's ``runge_kutta5`` at a fixed step of at most 1 ms (its +-100 rad joint range is
  no physical limit; its +-10 N m bound is the swing-up task's control limit: saturation is
  reported, ``torque_saturation``, but is no ``limits`` status).
- **open loop** (``--open-loop``, arms and pendulum; appendix C's integration check): the plan's
  controls ``U`` held per planning step without feedback on the continuous plant (no joint
  limits), ``runge_kutta3`` at a fixed step of at most 1 ms (half the cost of ``runge_kutta5``, the
  same trajectory to 1e-15 rad on arm5's plans); pseudo-dynamics plans through computed torque at every
  derivative evaluation, so Drake integrates ``qddot = u`` held over each step (Heun's
  pseudo-dynamics, appendix C.3, is exact for it). ``X`` against ``X_plan`` is then the error of
  the plan's own discretization.

Noise (``--x0-noise`` rad on the initial joint angles, clipped to the joint limits;
``--process-noise`` N m, a torque drawn per planning step and joint actuator) acts on every
model. A plan whose status is ``diverged`` is executed and marked ``diverged`` (never a success;
its data may still serve a model learner); a plan whose trajectory or controller is not finite
is not executed (status ``diverged``, the rollout all NaN). The status of an execution (``ok``, ``limits``,
``tracking-lost``, ``fell``, ``diverged``, ``collided``) follows the stated thresholds of
``stages.evaluate.metrics``.

**A scene** (a plan with collision terms, ``plants.scene``): the executed plant carries the scene's objects and
the robot's own collision geometry with contact (point contact, Coulomb friction ``plants.scene.FRICTION``; the
robot's links do not touch each other in the simulation). The metrics give the executed trajectory's smallest
distance over the terms' pairs at the planning steps (``min_distance`` m, ``min_distance_time`` s,
``min_distance_pair``) and ``contact`` (a distance below 0); a contact before any other failure is the status
``collided``.

Outputs (``rollout.npz``): executed states ``X (T+1, n_x)`` in planning coordinates, the plan's
``X_plan``, applied planning controls ``U (T, n_u)`` (the Nao: the feed-forward's planning
controls), applied torques ``tau (T, n_q)`` (sampled at the end of each step) and
``effort_at_limit (T, n_q)`` (per planning joint: the controller's command, without the process
noise, asks an actuator of it for at least its effort limit); for the Nao also the free plant's positions ``q_free``, the CoG, the
sole corners and the soles' contact forces, every contact point, the controller's command per
actuator without the noise (``torque_asked (T, n_act)`` N m, unclamped), the contact polygon and the
CoG's margin against it, the torso's pose and the planned torso and sole corners.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planning.mpc import WARM_STARTABLE
from planning.objective import objective_from_description
from plants.polygons import convex_hull
from plants.robots import Robot, load_robot_for, robot_for
from stages.base import Artifact, Stage, StageConfig, StageOutput
from stages.evaluate.metrics import (
    cog_via_point_margins,
    execution_metrics,
    padded_polygons,
    plan_beyond_limits,
    point_margins,
    single_support_lift,
    support_polygons,
    task_errors,
    task_verdict,
    via_point_errors,
)
from stages.plan.balance import cog_margins
from stages.plan.stage import PLAN_FILE, PROBLEM_FILE
from stages.registry import DESCRIPTIONS

ROLLOUT_FILE = "rollout.npz"
STARTS = ("plan", "standing")  # the Nao's start state (module docstring)
CONTROLLERS = ("pd", "wbc", "mpc")  # the Nao's controller, or receding-horizon control of an arm (module docstring)
MPC_SOLVERS = WARM_STARTABLE  # the solvers with a shift warm start (their spec's caps.mpc, planning.mpc)
MPC_HORIZON = 50  # planning steps: --controller mpc's default horizon (at most the problem's T)


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
                          "control re-planning every --period from the measured state, planning.mpc).",
            "period": "--controller mpc: control period (s); default the planning step; a divisor of it, at least "
                      "the simulation step.",
            "horizon": f"--controller mpc: horizon in planning steps (default min(T, {MPC_HORIZON})).",
            "iterations_per_tick": "--controller mpc: solver iterations per control period.",
            "solver": "--controller mpc: the solver of each period: " + ", ".join(MPC_SOLVERS) + ".",
            "push": "--controller mpc or the plan's controller (arms): a scripted push FRAME:NEWTONS:START:DURATION "
                    "(a force at the frame's origin on its body, NEWTONS along the world x axis or FX,FY,FZ; START "
                    "and DURATION in s); repeatable."}

    plan: str  # key, key prefix or plan/KEY of the plan to execute (required)
    x0_noise: float = 0.0  # rad, std of noise on the initial joint angles
    process_noise: float = 0.0  # N m, std of torque noise per planning step
    seed: int = 0
    clip_torques: bool = True
    open_loop: bool = False  # the integration check of appendix C (see HELP)
    start: str | None = None  # Nao: "plan" or "standing" (STARTS); None: standing with the stabilizer, else plan
    controller: str = "pd"  # Nao: "pd" or "wbc"; arms: "pd" (the plan's controller) or "mpc" (CONTROLLERS)
    period: float | None = None  # s, --controller mpc: control period (None: the planning step)
    horizon: int | None = None  # planning steps, --controller mpc (None: min(T, MPC_HORIZON))
    iterations_per_tick: int = 1  # --controller mpc
    solver: str = "raico"  # --controller mpc (MPC_SOLVERS)
    push: tuple[str, ...] = ()  # scripted pushes FRAME:NEWTONS:START:DURATION (arms)

    def __post_init__(self) -> None:
        object.__setattr__(self, "push", tuple(self.push or ()))   # the CLI gives None for no --push

    def normalized(self) -> ExecuteConfig:
        """The start state spelled out: the standing start with the stabilizer (which needs both soles on the
        ground), the plan's start with the joint PD (the thesis rows)."""
        if self.start is not None:
            return self
        return dataclasses.replace(self, start="standing" if self.controller == "wbc" else "plan")

    def check_inputs(self, inputs: dict) -> None:
        """The options of a robot executed on its soles (the Nao) refused for another robot's plan (they would
        change the key, not the run)."""
        plan = inputs["plan"]
        if robot_for(plan.document(PROBLEM_FILE)).floating:
            if self.controller == "mpc" or self.push:
                raise ValueError("--controller mpc and --push are for fixed-base robots; the Nao's controllers are "
                                 "pd and wbc")
            return
        plant = plan.config.get("plant")
        if self.controller == "mpc":
            T = int(plan.document(PROBLEM_FILE)["T"])
            if self.horizon is not None and self.horizon > T:
                raise ValueError(f"--horizon {self.horizon} is longer than the problem's {T} steps")
        elif self.controller != "pd":
            raise ValueError(f"--controller {self.controller} is for plans of the Nao; this plan is of {plant} "
                             "(its executions use the computed-torque controller)")
        if self.start not in (None, "plan"):
            raise ValueError(f"--start {self.start} is for plans of the Nao; this plan is of {plant}")

    def mpc_horizon(self, T: int | None) -> int:
        """The MPC's horizon in planning steps for a problem of ``T`` steps."""
        if self.horizon is not None:
            return self.horizon
        return MPC_HORIZON if T is None else min(T, MPC_HORIZON)

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
            given = [n for n in ("period", "horizon", "iterations_per_tick", "solver") if getattr(self, n) != d[n].default]
            if given:
                raise ValueError(f"--{given[0].replace('_', '-')} is an option of --controller mpc")
            return
        if self.solver not in MPC_SOLVERS:
            raise ValueError(f"--solver {self.solver} cannot warm-start a receding horizon; use one of "
                             f"{', '.join(MPC_SOLVERS)}")
        if self.period is not None and not (math.isfinite(self.period) and self.period > 0):
            raise ValueError(f"--period must be a positive number of seconds, got {self.period}")
        if self.horizon is not None and self.horizon < 1:
            raise ValueError(f"--horizon must be at least 1 planning step, got {self.horizon}")
        if self.iterations_per_tick < 1:
            raise ValueError(f"--iterations-per-tick must be at least 1, got {self.iterations_per_tick}")
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
    nao: dict = field(default_factory=dict)  # free-standing Nao arrays (see the module docstring)
    problem: Any = None  # the plan's problem (task terms for recordings)
    robot: Robot | None = None
    mpc: dict = field(default_factory=dict)  # --controller mpc: per-tick records (planning.mpc.TickLog.arrays)

    @property
    def cog(self):
        return self.nao.get("cog")

    @property
    def cog_margin(self):
        return self.nao.get("cog_margin")

    def arrays(self) -> dict[str, np.ndarray]:
        d = {"times": self.times, "X": self.X, "U": self.U, "tau": self.tau, "X_plan": self.X_plan,
             "effort_at_limit": np.asarray(self.effort_at_limit if self.effort_at_limit is not None
                                           else np.zeros((0, self.X.shape[1] // 2)), bool)}
        d.update(self.nao)
        d.update(self.mpc)
        return d


# ----------------------------------------------------------------------------- plan's controller (arms)
def _controller(robot: Robot, plan: dict, pseudo: bool, cfg: ExecuteConfig, dt: float, rng, mpc=None,
                period: float | None = None):
    """LeafSystem: plant state in, held actuation out; logs the commanded controls. With ``mpc``
    (``planning.mpc.MPC``) the control is re-planned every ``period`` s (a divisor of ``dt``) from the measured
    state, the horizon shifted at every planning step, its first control held for the period."""
    from pydrake.multibody.tree import MultibodyForces_
    from pydrake.systems.framework import BasicVector, LeafSystem

    plant, P = robot.plant, robot.P
    n_plant = plant.num_positions()
    Pinv = np.linalg.pinv(P)
    if cfg.open_loop:  # the planned controls themselves, no feedback
        o = np.asarray(plan["U"], float)
        O = np.zeros((*o.shape, 2 * robot.n_q))
    else:
        o, O = plan["o"], plan["O"]
    T = o.shape[0]
    period = dt if period is None else period
    every = int(round(dt / period))   # control periods per planning step
    effort = robot.plant_effort()
    ctx_id = plant.CreateDefaultContext()
    forces = MultibodyForces_[float](plant)
    split = P / np.maximum(P.sum(axis=0), 1.0)  # planning torque shared by coupled joints

    class FeedbackController(LeafSystem):
        """Holds ``u_k = o_k + O_k x_k`` for a planning step (periodic discrete update, ZOH).

        Torque output: analytic plans apply the held torque; pseudo plans hold the planned
        acceleration and evaluate computed torque at every plant step (inner loop), as a
        torque-controlled robot would.
        """

        def __init__(self):
            super().__init__()
            self.log_u: list[np.ndarray] = []
            self.state_port = self.DeclareVectorInputPort("x", 2 * n_plant)
            self.held = self.DeclareDiscreteState(2 * o.shape[1])  # (u, noise)
            # A torque plan's output is a function of the held (u, noise) only: declared so, Drake
            # caches it between updates (one Python call per step instead of one per integrator stage;
            # the same numbers). Computed torque reads the plant state at every evaluation.
            deps = {self.all_sources_ticket()} if pseudo else {self.xd_ticket()}
            self.DeclareVectorOutputPort("tau", BasicVector(plant.num_actuators()), self._torque, deps)
            self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)

        def _update(self, context, discrete_state):
            xp = self.state_port.Eval(context)
            j = int(round(context.get_time() / period))   # control period
            k, first = min(j // every, T - 1), j % every == 0   # planning step; its first period?
            x = np.concatenate([Pinv @ xp[:n_plant], Pinv @ xp[n_plant:]])
            if mpc is not None:
                u = mpc.tick(x, advance=first)[0].copy()
            else:
                u = o[k] + O[k] @ x
            if first:   # the process noise: drawn per planning step
                w = cfg.process_noise * rng.standard_normal(u.size) if cfg.process_noise > 0 else 0 * u
                self.log_u.append(u)
            else:
                w = context.get_discrete_state_vector().CopyToVector()[o.shape[1]:]
            discrete_state.get_mutable_vector().SetFromVector(np.concatenate([u, w]))

        def commanded_torque(self, context) -> np.ndarray:
            """The controller's own generalized forces (plant velocity order, N m) at this instant, without
            the process noise, unclamped: what it asks of the motors."""
            xp = self.state_port.Eval(context)
            u = context.get_discrete_state_vector().CopyToVector()[:o.shape[1]]
            if pseudo:  # computed torque: all tree joints follow P @ u
                plant.SetPositionsAndVelocities(ctx_id, xp)
                plant.CalcForceElementsContribution(ctx_id, forces)
                return plant.CalcInverseDynamics(ctx_id, P @ u, forces)
            return split @ u

        def noise_torque(self, context) -> np.ndarray:
            """The held process noise as generalized forces (plant velocity order, N m)."""
            return split @ context.get_discrete_state_vector().CopyToVector()[o.shape[1]:]

        def plant_torque(self, context, clip: bool = True) -> np.ndarray:
            """Generalized forces (plant velocity order, N m) at this instant: the command plus the noise."""
            tau = self.commanded_torque(context) + self.noise_torque(context)
            return np.clip(tau, -effort, effort) if clip and cfg.clip_torques else tau

        def _torque(self, context, output):
            output.SetFromVector(robot.actuation(self.plant_torque(context)))

    return FeedbackController()


def _pusher(robot: Robot, pushes: list[tuple[str, np.ndarray, float, float]]):
    """LeafSystem: the scripted pushes as ``ExternallyAppliedSpatialForce`` s (each a world-frame force at its
    frame's origin, on the frame's body, during ``[start, start + duration)`` s). Raises ``ValueError`` on a
    frame the simulated robot does not have."""
    from pydrake.common.value import AbstractValue
    from pydrake.multibody.math import SpatialForce
    from pydrake.multibody.plant import ExternallyAppliedSpatialForce
    from pydrake.systems.framework import LeafSystem

    plant = robot.plant
    applied = []
    for frame_name, force, start, duration in pushes:
        if not plant.HasFrameNamed(frame_name):
            raise ValueError(f"--push on frame {frame_name!r}: the robot has no such frame")
        frame = plant.GetFrameByName(frame_name)
        f = ExternallyAppliedSpatialForce()
        f.body_index = frame.body().index()
        f.p_BoBq_B = frame.GetFixedPoseInBodyFrame().translation()
        f.F_Bq_W = SpatialForce(np.zeros(3), np.asarray(force, float))
        applied.append((f, start, start + duration))

    class Pusher(LeafSystem):
        def __init__(self):
            super().__init__()
            self.DeclareAbstractOutputPort("forces", lambda: AbstractValue.Make([ExternallyAppliedSpatialForce()]),
                                           self._calc)

        def _calc(self, context, output):
            t = context.get_time()
            output.set_value([f for f, t0, t1 in applied if t0 <= t < t1])

    return Pusher()


def _mpc_for(cfg: ExecuteConfig, problem, plan: dict, dt: float, sim_step: float):
    """The receding-horizon controller of ``cfg`` on the planning ``problem``, warm-started from the plan, and
    its control period (s). Raises ``ValueError`` on a period shorter than the simulation step or no divisor of
    the planning step, or a horizon longer than the problem."""
    from planning.mpc import MPC

    period = dt if cfg.period is None else float(cfg.period)
    if period < sim_step - 1e-12:
        raise ValueError(f"--period {period:g} s is shorter than the simulation step {sim_step:g} s")
    every = dt / period
    if period > dt + 1e-12 or abs(every - round(every)) > 1e-9:
        raise ValueError(f"--period {period:g} s must divide the planning step {dt:g} s")
    horizon = cfg.mpc_horizon(problem.T)
    if horizon > problem.T:
        raise ValueError(f"--horizon {horizon} is longer than the problem's {problem.T} steps")
    mpc = MPC(problem, horizon, cfg.solver, None,  # the solver's defaults (R-AICO: alpha 1)
              iterations=cfg.iterations_per_tick, budget=period, ticks=problem.T * int(round(every)),
              keep_predictions=True)
    mpc.start_from(np.asarray(plan["X"]), np.asarray(plan["U"]), np.asarray(plan["o"]), np.asarray(plan["O"]))
    return mpc, period


def _mpc_metrics(mpc, period: float) -> dict:
    """The MPC's tick statistics: ticks, median and 99th-percentile solve time (s), ticks past the period."""
    t = mpc.log.solve_time[:mpc.log.n]
    if t.size == 0:
        return {"mpc_ticks": 0}
    return {"mpc_ticks": int(t.size), "mpc_period": period, "mpc_horizon": mpc.H, "mpc_solver": mpc.solver,
            "mpc_median_tick_s": float(np.median(t)), "mpc_p99_tick_s": float(np.percentile(t, 99)),
            "mpc_over_period": int(mpc.log.over_budget[:mpc.log.n].sum()),
            "mpc_iterations": int(mpc.log.iterations[:mpc.log.n].sum()),
            "mpc_max_violation": [float(v) for v in mpc.log.violation[:mpc.log.n].max(axis=0)]}


def _initial_q(desc: dict, robot: Robot, cfg: ExecuteConfig, rng) -> np.ndarray:
    """The plan's ``q0`` plus ``x0_noise``, clipped to the joint limits (rad): the robot cannot
    start outside its joint range."""
    q0 = np.asarray(desc["q0"], float)
    q = q0 + cfg.x0_noise * rng.standard_normal(q0.size) if cfg.x0_noise > 0 else q0.copy()
    return np.clip(q, robot.lower, robot.upper)


def _execute_fixed(cfg: ExecuteConfig, desc: dict, plan: dict, problem, rng, progress, planning=None) -> ExecuteOutput:
    """A fixed-base plant (arms: discrete with limits; pendulum: continuous) with the plan's controller, or
    with receding-horizon control on the ``planning`` problem (``--controller mpc``)."""
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator

    dt, T = float(desc["dt"]), int(desc["T"])
    # the robot's execution model: a discrete plant that enforces its joint limits (the arms, a model file's
    # robot) or a continuous one (the pendulum); the integration check is always continuous
    facts = robot_for(desc, true=True)
    execution, step = facts.execution, facts.time_step  # s: the discrete plant's step, or the integrator's bound
    discrete = execution == "discrete" and not cfg.open_loop
    scene = scene_of(desc)
    robot = load_robot_for(desc, time_step=step if discrete else 0.0, true=True,
                           before_finalize=None if scene is None else _scene_hook(desc, scene))
    if scene is not None:
        _no_self_contact(robot)
    q_start = _initial_q(desc, robot, cfg, rng)
    sim_step = step if discrete else dt / math.ceil(dt / step - 1e-9)
    mpc, period = _mpc_for(cfg, planning, plan, dt, sim_step) if cfg.controller == "mpc" else (None, dt)
    ctrl = robot.builder.AddSystem(_controller(robot, plan, desc["control_kind"] == "acceleration", cfg, dt, rng,
                                               mpc, period))
    robot.builder.Connect(robot.plant.get_state_output_port(), ctrl.get_input_port(0))
    robot.builder.Connect(ctrl.get_output_port(0), robot.plant.get_actuation_input_port())
    if cfg.push:
        pusher = robot.builder.AddSystem(_pusher(robot, cfg.pushes()))
        robot.builder.Connect(pusher.get_output_port(0), robot.plant.get_applied_spatial_force_input_port())
    sim = Simulator(robot.builder.Build())
    if not discrete:
        integ = ResetIntegratorFromFlags(sim, "runge_kutta3" if cfg.open_loop else "runge_kutta5",
                                         dt / math.ceil(dt / step - 1e-9))
        integ.set_fixed_step_mode(True)
    pctx = robot.plant.GetMyMutableContextFromRoot(sim.get_mutable_context())
    robot.plant.SetPositions(pctx, robot.to_plant_q(q_start))
    robot.plant.SetVelocities(pctx, np.zeros(robot.plant.num_velocities()))
    Pinv = np.linalg.pinv(robot.P)
    n, n_p = robot.n_q, robot.plant.num_positions()
    X = np.full((T + 1, 2 * n), np.nan)
    sim.Initialize()

    def sample(k: int) -> bool:
        xp = robot.plant.GetPositionsAndVelocities(pctx)
        if not np.all(np.isfinite(xp)):
            return False
        X[k] = np.concatenate([Pinv @ xp[:n_p], Pinv @ xp[n_p:]])
        return True

    ctrl_ctx = ctrl.GetMyContextFromRoot(sim.get_context())
    taus, saturated, clamped = [], [], []
    effort_plant = robot.plant_effort()
    ok = sample(0)
    for k in range(T):
        if not ok:
            break
        try:
            sim.AdvanceTo((k + 1) * dt)
        except RuntimeError:
            break
        asked = ctrl.commanded_torque(ctrl_ctx)
        wanted = asked + ctrl.noise_torque(ctrl_ctx)  # the command plus the process noise
        saturated.append(robot.P.T @ (np.abs(asked) > effort_plant + 1e-9) > 0)
        clamped.append(np.any(np.abs(wanted) > effort_plant + 1e-9))
        taus.append(robot.P.T @ (np.clip(wanted, -effort_plant, effort_plant) if cfg.clip_torques else wanted))
        ok = sample(k + 1)
        if progress is not None and (k + 1) % 10 == 0:
            progress(k + 1, T)
    U = np.array(ctrl.log_u[:T]).reshape(-1, n)
    tau = np.array(taus).reshape(-1, n)
    sat = np.array(saturated, bool).reshape(-1, n)
    metrics = execution_metrics(problem, X, plan["X"], tau, robot, dt, sat, effort_is_limit=execution != "continuous",
                                effort_clamped=clamped)
    if scene is not None:
        metrics.update(collision_metrics(problem, X, dt, metrics))
    extra = {}
    if mpc is not None:
        metrics.update(_mpc_metrics(mpc, period))
        extra = mpc.log.arrays()
    return ExecuteOutput(times=np.arange(T + 1) * dt, X=X, U=U, tau=tau, X_plan=plan["X"], metrics=metrics,
                         effort_at_limit=sat, problem=problem, robot=robot, mpc=extra)


# ----------------------------------------------------------------------------- a scene
def scene_of(desc: dict) -> list[dict] | None:
    """The scene of a plan's collision terms (``plants.scene``), or None where it has none."""
    for d in desc.get("terms", []):
        if d.get("term") == "collision":
            return d["map"]["scene"]
    return None


def _scene_hook(desc: dict, scene: list[dict]):
    """Registers the scene and the robot's own collision geometry, with contact, in the executed plant."""
    from plants.model_file import RobotSpec
    from plants.scene import register_scene, robot_shapes

    spec = desc.get("robot_true") or desc.get("robot")
    return register_scene(scene, robot_shapes(RobotSpec.from_dict(spec)) if spec else [])


def _no_self_contact(robot: Robot) -> None:
    """No contact between the robot's own links in the simulation (their convex hulls may overlap where
    the links do not): the robot against itself is judged by the distances (:func:`collision_metrics`)."""
    from pydrake.geometry import CollisionFilterDeclaration, GeometrySet, Role

    inspector = robot.scene_graph.model_inspector()
    ids = [g for g in inspector.GetAllGeometryIds(Role.kProximity)
           if robot.plant.GetBodyFromFrameId(inspector.GetFrameId(g)) is not None
           and robot.plant.GetBodyFromFrameId(inspector.GetFrameId(g)).index() != robot.plant.world_body().index()]
    robot.scene_graph.collision_filter_manager().Apply(CollisionFilterDeclaration().ExcludeWithin(GeometrySet(ids)))


def collision_metrics(problem, X: np.ndarray, dt: float, metrics: dict) -> dict:
    """The executed trajectory's smallest distance over the plan's collision terms' pairs (m, at the planning
    steps; ``min_distance_time`` s, ``min_distance_pair``) and ``contact`` (a distance below 0); a contact
    no later than any other failure makes the status ``collided`` (the reason names the first one)."""
    from planning.costs import Collision
    from plants.scene import ROBOT_PREFIX

    n = X.shape[1] // 2
    best, first = (math.inf, -1, ""), (len(X), "", 0.0)
    for term in problem.state_terms:
        if not isinstance(term, Collision):
            continue
        D = term.taskmap.evaluate(X[:, :n], jacobians=False)[0]
        D = np.where(np.isfinite(D) & term.active(np.arange(len(X)))[:, None], D, np.inf)
        kk, pp = (int(i) for i in np.unravel_index(int(np.argmin(D)), D.shape))
        names = [" | ".join(x.removeprefix(ROBOT_PREFIX) for x in pair) for pair in term.taskmap.pairs]
        if D[kk, pp] < best[0]:
            best = (float(D[kk, pp]), kk, names[pp])
        hit = np.flatnonzero(D.min(axis=1) < 0)
        if hit.size and hit[0] < first[0]:
            first = (int(hit[0]), names[int(np.argmin(D[hit[0]]))], float(D[hit[0]].min()))
    d, k, pair = best
    out: dict[str, Any] = {"min_distance": d, "min_distance_time": k * dt if k >= 0 else None,
                           "min_distance_pair": pair, "contact": bool(d < 0)}
    failed_at = metrics.get("failure_time")
    kc, pc, dc = first
    if d < 0 and (metrics["status"] in ("ok", "limits") or failed_at is None or kc * dt <= failed_at + 1e-12):
        out.update(status="collided", failure_time=kc * dt,
                   reason=f"contact: {pc} at t = {kc * dt:.3g} s ({1e3 * dc:.3g} mm)")
    return out


# ----------------------------------------------------------------------------- free-standing Nao
def feedforward(robot: Robot, X_plan: np.ndarray, U_plan: np.ndarray, control_kind: str) -> np.ndarray:
    """Feed-forward generalized forces ``(T, n_plant)`` (fixed-base plant velocity order, N m):
    inverse dynamics of the fixed-base model along the plan (acceleration plans) or the planned
    torques shared among coupled joints (torque plans)."""
    from pydrake.multibody.tree import MultibodyForces_

    P, n = robot.P, robot.n_q
    if control_kind != "acceleration":
        split = P / np.maximum(P.sum(axis=0), 1.0)
        return U_plan @ split.T
    plant = robot.plant
    ctx = plant.CreateDefaultContext()
    forces = MultibodyForces_[float](plant)
    out = np.empty((len(U_plan), plant.num_velocities()))
    for k, u in enumerate(U_plan):
        plant.SetPositions(ctx, P @ X_plan[k, :n])
        plant.SetVelocities(ctx, P @ X_plan[k, n:])
        plant.CalcForceElementsContribution(ctx, forces)
        out[k] = plant.CalcInverseDynamics(ctx, P @ u, forces)
    return out


def planned_stance(robot: Robot, X_plan: np.ndarray) -> dict[str, np.ndarray]:
    """The plan on the fixed-base model (left sole at the world origin): torso height and z axis,
    sole corner positions ``(T+1, 2, 4, 3)``."""
    from plants.free_nao import SOLES, sole_corners_local

    plant, n = robot.plant, robot.n_q
    ctx = plant.CreateDefaultContext()
    torso = plant.GetBodyByName("torso")
    K = len(X_plan)
    out = {"torso_height_plan": np.full(K, np.nan), "torso_z_plan": np.full((K, 3), np.nan),
           "corners_plan": np.full((K, 2, 4, 3), np.nan)}
    local = sole_corners_local()
    for k in range(K):
        if not np.all(np.isfinite(X_plan[k])):
            continue
        plant.SetPositions(ctx, robot.to_plant_q(X_plan[k, :n]))
        Xt = plant.EvalBodyPoseInWorld(ctx, torso)
        out["torso_height_plan"][k] = Xt.translation()[2]
        out["torso_z_plan"][k] = Xt.rotation().matrix()[:, 2]
        for s, name in enumerate(SOLES):
            Xs = plant.GetFrameByName(name).CalcPoseInWorld(ctx)
            out["corners_plan"][k, s] = local @ Xs.rotation().matrix().T + Xs.translation()
    return out


def _execute_free_nao(cfg: ExecuteConfig, desc: dict, plan: dict, problem, rng, progress) -> ExecuteOutput:
    """The plan tracked on the free-standing Nao (see the module docstring): the start state and the
    reference, the simulator with its controller, the simulation sampled at every planning step, then
    the arrays and metrics of the rollout."""
    from plants.free_nao import TIME_STEP, load_free_nao

    dt, T = float(desc["dt"]), int(desc["T"])
    sub = int(round(dt / TIME_STEP))
    if abs(sub * TIME_STEP - dt) > 1e-9 or sub < 1:
        raise ValueError(f"the Nao's planning step {dt} s is not a multiple of the plant step {TIME_STEP} s")
    free = load_free_nao(pd=cfg.controller == "pd")  # the stabilizer commands torques only: no PD actuators
    fixed = free.fixed
    X_plan, qp0, stance, tilt = _free_nao_start(cfg, desc, plan, free, rng)
    ff = feedforward(fixed, X_plan, np.asarray(plan["U"], float), desc["control_kind"])[:, free.act_fixed_idx]
    lift_from = _lift_step(desc)  # a single-support plan's lift step (None: both soles stay down)
    run = _FreeNaoRun(free, cfg, X_plan, np.asarray(plan["X"], float), dt, problem, lift_from, qp0, ff[0])
    log = _FreeNaoLog.empty(T + 1, fixed.n_q, free.plant.num_positions())
    applied, asked, U_log = run.simulate(log, ff, cfg.process_noise, rng, T, sub, progress)
    if run.stab is not None:
        _stabilizer_commands(run.stab, applied, asked, dt, TIME_STEP)
    nao, metrics, tau, at_limit = _free_nao_results(free, problem, plan, X_plan, log, applied, asked, dt, tilt,
                                                    stance, lift_from, run.stab)
    return ExecuteOutput(times=np.arange(T + 1) * dt, X=log.X, U=U_log, tau=tau, X_plan=X_plan, metrics=metrics,
                         effort_at_limit=at_limit, nao=nao, problem=problem, robot=fixed)


def _free_nao_start(cfg: ExecuteConfig, desc: dict, plan: dict, free, rng
                    ) -> tuple[np.ndarray, np.ndarray, dict, float]:
    """The start state and the joint reference: ``(X_plan (T+1, 2 n_q), qp0 (free plant's positions),
    stance, tilt rad)``. The plan's ``q0`` plus noise, put on its feet: the standing start projects it to
    a double-support stance (``stance``: its projection's sizes) and shifts the plan by that projection
    (constant over the horizon, so that the plan's held right sole stays flat on the ground to first
    order instead of being pulled back to the uneven pose of the plan's start); the plan's start tilts
    it until it stands (``tilt``)."""
    fixed, n = free.fixed, free.fixed.n_q
    X_plan = np.asarray(plan["X"], float)
    q_start = _initial_q(desc, fixed, cfg, rng)
    if cfg.start != "standing":
        qp0, tilt = free.standing_positions(q_start)
        return X_plan, qp0, {}, tilt
    qp0, stance = free.stance_positions(q_start)
    X_plan = X_plan.copy()
    X_plan[:, :n] += free.planning_q(qp0) - q_start
    return X_plan, qp0, stance, 0.0


@dataclass
class _FreeNaoLog:
    """What is sampled at every planning step (``K = T + 1`` samples, NaN until reached): the state in
    planning coordinates ``X (K, 2 n_q)``, the free plant's positions ``q_free (K, nq)``, the CoG
    ``(K, 3)`` m, the sole corners ``(K, 2, 4, 3)`` m, the soles' normal forces ``(K, 2)`` N, the
    zero-moment point ``(K, 2)`` m, the torso's position and z axis ``(K, 3)`` each, and the contact
    points (one ``(k, 3)`` array per sample)."""

    X: np.ndarray
    q_free: np.ndarray
    cog: np.ndarray
    corners: np.ndarray
    force: np.ndarray
    zmp: np.ndarray
    torso_p: np.ndarray
    torso_z: np.ndarray
    points: list

    @classmethod
    def empty(cls, K: int, n: int, nq_free: int) -> _FreeNaoLog:
        """A log of ``K`` samples of a plan of ``n`` planning joints on a free plant of ``nq_free`` positions."""
        return cls(X=np.full((K, 2 * n), np.nan), q_free=np.full((K, nq_free), np.nan), cog=np.full((K, 3), np.nan),
                   corners=np.full((K, 2, 4, 3), np.nan), force=np.full((K, 2), np.nan), zmp=np.full((K, 2), np.nan),
                   torso_p=np.full((K, 3), np.nan), torso_z=np.full((K, 3), np.nan), points=[])

    def sample(self, free, pctx, k: int) -> bool:
        """Sample ``k`` from the plant's context; False (nothing written) when its state is not finite."""
        plant = free.plant
        qp, vp = plant.GetPositions(pctx), plant.GetVelocities(pctx)
        if not (np.all(np.isfinite(qp)) and np.all(np.isfinite(vp))):
            return False
        self.X[k] = np.concatenate([free.planning_q(qp), free.planning_v(vp)])
        self.q_free[k] = qp
        self.cog[k] = plant.CalcCenterOfMassPositionInWorld(pctx)
        self.corners[k] = free.sole_corners(pctx)
        # contact results exist after the first plant step; at t = 0 the force is unknown (NaN)
        f, pts = free.contacts(pctx) if k > 0 else (np.full(2, np.nan), np.zeros((0, 3)))
        self.zmp[k] = free.zmp(pctx) if k > 0 else np.nan
        self.force[k] = f
        self.points.append(pts)
        Xt = free.torso_pose(pctx)
        self.torso_p[k], self.torso_z[k] = Xt.translation(), Xt.rotation().matrix()[:, 2]
        return True


class _FreeNaoRun:
    """The free Nao in Drake's simulator with its controller: Drake's joint PD on the plan plus the
    feed-forward (``pd``), or the whole-body stabilizer (``wbc``, ``stab``), which owns the actuation
    port and takes the process noise on its ``w`` input. Set to ``qp0`` at rest and initialized."""

    def __init__(self, free, cfg: ExecuteConfig, X_plan: np.ndarray, X_made: np.ndarray, dt: float, problem,
                 lift_from: int | None, qp0: np.ndarray, ff0: np.ndarray):
        """``X_plan (T+1, 2 n_q)``: the joint reference; ``X_made``: the plan as made (the stabilizer's CoG and
        frame tasks); ``ff0 (n_act,)`` N m: the first step's feed-forward."""
        from pydrake.systems.analysis import Simulator

        self.free, self.X_plan, self.dt = free, X_plan, dt
        plant, fixed, n = free.plant, free.fixed, free.fixed.n_q
        self.wbc = cfg.controller == "wbc"
        self.stab = None
        if self.wbc:
            from stages.wbc import make_stabilizer

            self.stab = free.builder.AddSystem(make_stabilizer(free, X_plan, dt, X_task=X_made,
                                                               frame_maps=_frame_tasks(problem),
                                                               swing=_swing_task(lift_from, fixed)))
            free.builder.Connect(plant.get_state_output_port(), self.stab.get_input_port(0))
            free.builder.Connect(plant.get_generalized_contact_forces_output_port(free.model), self.stab.contact_port)
            free.builder.Connect(self.stab.get_output_port(0), plant.get_actuation_input_port())
        self.sim = Simulator(free.builder.Build())
        self.pctx = plant.GetMyMutableContextFromRoot(self.sim.get_mutable_context())
        self.sctx = self.stab.GetMyMutableContextFromRoot(self.sim.get_mutable_context()) if self.wbc else None
        plant.SetPositions(self.pctx, qp0)
        plant.SetVelocities(self.pctx, np.zeros(plant.num_velocities()))
        self.n_act = len(free.effort)
        self.desired_port = plant.get_desired_state_input_port(free.model)
        self.actuation_port = plant.get_actuation_input_port()
        self.set_desired(np.concatenate([free.A @ np.clip(X_plan[0, :n], fixed.lower, fixed.upper),
                                         free.A @ X_plan[0, n:]]))
        self.set_actuation(ff0, np.zeros(self.n_act))
        self.sim.Initialize()

    def set_desired(self, xd: np.ndarray) -> None:
        """The PD's desired actuated state ``(2 n_act,)``; the stabilizer drives torques only (Drake's PD
        actuators stay off, their port unconnected)."""
        if not self.wbc:
            self.desired_port.FixValue(self.pctx, xd)

    def set_actuation(self, u: np.ndarray, w: np.ndarray) -> None:
        """Feed-forward ``u`` plus noise ``w`` (n_act,) N m; with the stabilizer, which owns the actuation
        port and has no feed-forward, the noise is added to its held command (and the sum clamped at the
        effort limits, as the plant clamps the PD's total)."""
        if self.wbc:
            self.stab.noise_port.FixValue(self.sctx, w)
        else:
            self.actuation_port.FixValue(self.pctx, u + w)

    def simulate(self, log: _FreeNaoLog, ff: np.ndarray, noise: float, rng, T: int, sub: int, progress
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Run the ``T`` planning steps (``sub`` plant steps each), sampled into ``log``, until the end or a
        non-finite state or a simulator failure. Returns the torques the plant applied ``(T, n_act)`` N m,
        the controller's command without the noise (``asked``, the PD's here; the stabilizer's is filled in
        afterwards) and the planning controls ``(T, n_q)`` (NaN where not reached)."""
        from plants.free_nao import KD, KP, TIME_STEP

        free, plant, pctx, X_plan, dt, n_act = self.free, self.free.plant, self.pctx, self.X_plan, self.dt, self.n_act
        fixed, n, Aq = free.fixed, free.fixed.n_q, free.A
        applied = np.full((T, n_act), np.nan)
        asked = np.full((T, n_act), np.nan)  # the controller's command without the process noise, unclamped
        U_log = np.full((T, n), np.nan)
        act_q, act_v = free.joint_idx[free.act_fixed_idx], free.joint_vidx[free.act_fixed_idx]
        ok = log.sample(free, pctx, 0)
        for k in range(T):
            if not ok:
                break
            w = noise * rng.standard_normal(n_act) if noise > 0 else np.zeros(n_act)
            self.set_actuation(ff[k], w)
            U_log[k] = (ff[k] + w) @ Aq  # planning coordinates
            q_a, q_b, v_b = X_plan[k, :n], X_plan[k + 1, :n], X_plan[k + 1, n:]
            try:
                if self.wbc:  # the stabilizer updates itself (its own period): one advance per planning step
                    self.sim.AdvanceTo((k + 1) * dt)
                for s in range(0 if self.wbc else sub):
                    a = s / sub
                    q_d = np.clip((1 - a) * q_a + a * q_b, fixed.lower, fixed.upper)  # never past a limit
                    self.set_desired(np.concatenate([Aq @ q_d, Aq @ v_b]))
                    self.sim.AdvanceTo(k * dt + (s + 1) * TIME_STEP)
            except RuntimeError:
                break
            applied[k] = plant.get_net_actuation_output_port().Eval(pctx)[:n_act]
            if self.wbc:  # the stabilizer's held torques plus the noise, clamped (planning coordinates)
                U_log[k] = applied[k] @ Aq
            else:  # the PD law at the step's end state (SAP's implicit PD evaluates it there) plus the feed-forward
                asked[k] = (KP * (Aq @ q_d - plant.GetPositions(pctx)[act_q])
                            + KD * (Aq @ v_b - plant.GetVelocities(pctx)[act_v]) + ff[k])
            ok = log.sample(free, pctx, k + 1)
            if progress is not None and (k + 1) % 10 == 0:
                progress(k + 1, T)
        return applied, asked, U_log


def _stabilizer_commands(stab, applied: np.ndarray, asked: np.ndarray, dt: float, time_step: float) -> None:
    """``asked (T, n_act)`` filled in place with the stabilizer's command (N m, before the noise) that the
    last plant step of each planning step applied: Drake's discrete updates at one time are simultaneous,
    so a plant step (``time_step`` s) starting at an update's time still applies the command held before
    it. Steps not reached (``applied`` not finite) stay NaN."""
    T, n_act = asked.shape
    t_cmd = np.array([c[0] for c in stab.commands])
    u_cmd = np.array([c[1] for c in stab.commands]).reshape(-1, n_act)
    i = np.searchsorted(t_cmd, np.arange(1, T + 1) * dt - time_step - 1e-9) - 1  # (T,) the last update before
    use = (i >= 0) & np.isfinite(applied).all(axis=1)
    asked[use] = u_cmd[i[use]]


def _free_nao_results(free, problem, plan: dict, X_plan: np.ndarray, log: _FreeNaoLog, applied: np.ndarray,
                      asked: np.ndarray, dt: float, tilt: float, stance: dict, lift_from: int | None, stab
                      ) -> tuple[dict, dict, np.ndarray, np.ndarray]:
    """The Nao's arrays of the rollout (``nao``), the execution's metrics, the applied torques in planning
    coordinates ``tau (T, n_q)`` N m and the effort-limit flags ``(T, n_q)``."""
    from plants.free_nao import MAX_TIP

    fixed, n = free.fixed, free.fixed.n_q
    K, T = len(log.X), len(applied)
    # an actuator at its effort limit: the controller asks for at least what the motor gives (per planning joint);
    # a motor that clamps the process noise is not the controller's limit (effort_clamped_fraction: the share of
    # samples with any motor clamped, the command plus the noise)
    at_effort = free.effort * (1 - 1e-9)  # N m per actuator: at its limit from here (rounding aside)
    at_limit = (np.abs(asked) >= at_effort) @ free.A > 0  # (T, n_q)
    tau = applied @ free.A  # planning coordinates (the coupled hip: the sum of its two joints)
    polys, margin = support_polygons(log.corners, log.force, log.cog)
    zmp_margin = point_margins(polys, log.zmp)
    planned = planned_stance(fixed, X_plan)
    if lift_from is not None and stance:
        # single support: the swing sole's planned heights are those of the plan as made (what the stabilizer
        # tracks once it releases that sole), not of the plan shifted by the start projection
        planned["corners_plan"][:, 1] = planned_stance(fixed, np.asarray(plan["X"], float))["corners_plan"][:, 1]
    nao = {"q_free": log.q_free, "cog": log.cog, "cog_margin": margin, "support": padded_polygons(polys),
           "corners": log.corners, "sole_force": log.force, "contact_points": _padded_points(log.points, K),
           "zmp": log.zmp, "zmp_margin": zmp_margin, "torque_asked": asked,
           "torso_p": log.torso_p, "torso_z": log.torso_z, "torso_height_plan": planned["torso_height_plan"],
           "torso_z_plan": planned["torso_z_plan"], "corners_plan": planned["corners_plan"],
           "start_tilt": np.array(tilt), "start_stands": np.array(tilt < MAX_TIP - 1e-9)}
    if stab is not None:
        nao["wbc_time"] = np.array([e[0] for e in stab.log])
        nao["wbc_solve_s"] = np.array([e[1] for e in stab.log])
        nao["wbc_corner_force"] = np.array([e[2] for e in stab.log]).reshape(-1, 8, 3)
    metrics = execution_metrics(problem, log.X, X_plan, tau, fixed, dt, at_limit,
                                nao={**nao, "torso_height": log.torso_p[:, 2]},
                                effort_clamped=np.any(np.abs(applied) >= at_effort, axis=1))
    metrics["start_tilt"] = tilt
    # what the reference asks that the free robot cannot give: joints past their range (the joint reference: the
    # plan, shifted by the start projection on the standing start), CoG via-points near the feet's edge
    metrics["reference_beyond_limits"] = plan_beyond_limits(X_plan[:, :n], fixed.lower, fixed.upper, fixed.joint_names)
    if np.all(np.isfinite(log.corners[0])):
        metrics.update(_reference_cog_metrics(problem, fixed, X_plan, log.corners[0], metrics.get("failure_time"),
                                              dt, T))
    if stance:
        nao["X_plan_unshifted"] = np.asarray(plan["X"], float)
        metrics.update(start_projection_norm=stance["projection_norm"], start_projection_max=stance["projection_max"],
                       start_cog_margin=stance["cog_margin"], start="standing")
    if stab is not None:
        metrics.update(controller="wbc", wbc_qp_failures=stab.failures, wbc_qp_fallbacks=stab.qp.fallbacks,
                       wbc_limp_time=stab.limp, wbc_qp_relaxed=len(stab.relaxed),
                       wbc_qp_median_s=float(np.median(nao["wbc_solve_s"])) if len(stab.log) else float("nan"))
    if lift_from is not None:  # single support: how high the right sole was held from the plan's lift step on
        metrics.update(single_support_lift(log.corners, lift_from),
                       wbc_release_time=(stab.released[0] if stab is not None and stab.released else None))
    return nao, metrics, tau, at_limit


def _reference_cog_metrics(problem, fixed, X_plan: np.ndarray, corners0: np.ndarray, failure_time: float | None,
                           dt: float, T: int) -> dict:
    """The CoG via-points' and the joint reference's CoG margins (m) against the feet's polygon at the start
    (``corners0 (2, 4, 3)`` m): the least margin and its time (s), and the margin where the run failed."""
    feet = convex_hull(corners0[:, :, :2].reshape(-1, 2))
    out: dict[str, Any] = {"cog_via_point_margins": cog_via_point_margins(problem, feet)}
    ref_margin = cog_margins(fixed, X_plan, feet)
    k_min = int(np.nanargmin(ref_margin))
    out.update(reference_cog_min_margin=float(ref_margin[k_min]), reference_cog_min_margin_time=k_min * dt)
    if failure_time is not None:  # where the reference's CoG was when the run failed
        k_fail = min(int(round(failure_time / dt)), T)
        out["reference_cog_margin_at_failure"] = float(ref_margin[k_fail])
    return out


def _lift_step(desc: dict) -> int | None:
    """The first step of the plan's right-sole lift (a ``--balance single`` plan), else None."""
    if (desc.get("balance") or {}).get("mode") != "single":
        return None
    term = next((t for t in desc["terms"] if t["name"] == "r_sole_lift"), None)
    return None if term is None else int(term["times"]["from"])


def _swing_task(lift_from: int | None, fixed):
    """The right sole's corners (``FramePoints`` of the fixed model) the stabilizer tracks once it releases
    that sole, for a single-support plan; None (both soles held) otherwise."""
    if lift_from is None:
        return None
    from plants.free_nao import sole_corners_local
    from plants.taskmaps import FramePoints

    return FramePoints(fixed, fixed.feet[1], sole_corners_local(), name="r_sole_swing")


def _frame_tasks(problem) -> list:
    """The frame-point maps of the problem's via-points (``FramePoints``), the held right sole left
    out (the stabilizer holds both soles by contact)."""
    from planning.costs import ViaPoint
    from plants.taskmaps import FramePoints

    return [t.taskmap for t in problem.state_terms if isinstance(t, ViaPoint) and isinstance(t.taskmap, FramePoints)
            and not t.name.startswith("r_sole")]


def _padded_points(points: list[np.ndarray], K: int) -> np.ndarray:
    """Per-sample contact points as one ``(K, kmax, 3)`` array, NaN-padded (m)."""
    kmax = max([len(p) for p in points] + [1])
    out = np.full((K, kmax, 3), np.nan)
    for k, p in enumerate(points):
        out[k, :len(p)] = p
    return out


# ----------------------------------------------------------------------------- stage
def _not_executed(desc: dict, plan: dict, problem, reason: str) -> ExecuteOutput:
    """A diverged plan: nothing is simulated; the execution's status is ``diverged``."""
    T, dt = int(desc["T"]), float(desc["dt"])
    n = len(desc["q0"])
    X = np.full((T + 1, 2 * n), np.nan)
    metrics = {"status": "diverged", "failure_time": 0.0, "reason": reason,
               "via_point_errors": via_point_errors(problem, X), "task": task_verdict(task_errors(problem, X)),
               "rmse_planned_executed": float("inf"),
               "max_tracking_error": float("inf"), "max_abs_torque": 0.0, "torque_saturation": 0.0,
               "effort_clamped_fraction": 0.0,
               "position_limit_fraction": 0.0, "limits_fraction": 0.0}
    if robot_for(desc).floating:
        metrics.update(stood=False, cog_inside_fraction=0.0, cog_min_margin=float("nan"))
    return ExecuteOutput(times=np.arange(T + 1) * dt, X=X, U=np.full((T, n), np.nan), tau=np.full((T, n), np.nan),
                         X_plan=np.asarray(plan["X"]), metrics=metrics, effort_at_limit=np.zeros((T, n), bool),
                         problem=problem)


def execute(cfg: ExecuteConfig, desc: dict, plan: dict, progress: Callable[[int, int], None] | None = None,
            plan_status: str | None = None, planning=None) -> ExecuteOutput:
    """Execute a plan (its arrays, stored problem description and status) in Drake (module docstring);
    ``planning``: the plan's planning problem (``--controller mpc``)."""
    cfg = cfg.normalized()
    cfg.validate()
    problem = objective_from_description(desc)
    nao = robot_for(desc).floating  # executed free on its soles (plants/free_nao.py)
    if nao and cfg.open_loop:
        raise ValueError("--open-loop is the arms' and the pendulum's integration check; the Nao stands on its feet")
    needed = ("X", "U") if nao or cfg.open_loop else ("X", "o", "O")
    if not all(np.all(np.isfinite(plan[k])) for k in needed):
        return _not_executed(desc, plan, problem, "the plan is not finite: not executed")
    rng = np.random.default_rng(cfg.seed)
    if nao:
        out = _execute_free_nao(cfg, desc, plan, problem, rng, progress)
    else:
        out = _execute_fixed(cfg, desc, plan, problem, rng, progress, planning)
    if plan_status == "diverged":  # executed (its data may still be of use), never reported as a success
        out.metrics.update(status="diverged", failure_time=0.0,
                           reason=f"the plan diverged (executed: {out.metrics['reason']})")
        if nao:
            out.metrics["stood"] = False
    return out


def planning_problem(plan: Artifact):
    """The plan's planning problem rebuilt from its config (the MPC's model; its start is the plan's)."""
    from stages.plan.stage import PlanConfig, build_problem

    pcfg = PlanConfig.from_dict(plan.config)
    if pcfg.model is not None or pcfg.dynamics == "learned":
        raise ValueError("--controller mpc on a plan of a learned model: not supported yet (plan with the model file)")
    problem = build_problem(pcfg)[2]
    problem.x0[:] = np.asarray(plan.document(PROBLEM_FILE)["x0"], float)
    return problem


def run(cfg: ExecuteConfig, inputs: dict[str, Artifact], progress: Callable[[int, int], None] | None = None
        ) -> StageOutput:
    """The execute stage: ``rollout.npz`` of the plan executed in Drake."""
    plan = inputs["plan"]
    planning = planning_problem(plan) if cfg.controller == "mpc" else None
    out = execute(cfg, plan.document(PROBLEM_FILE), plan.arrays(PLAN_FILE), progress, plan_status=plan.status,
                  planning=planning)
    return StageOutput(status=out.metrics["status"], metrics=out.metrics, arrays={ROLLOUT_FILE: out.arrays()},
                       payload=out)


STAGE = Stage(name="execute", config_cls=ExecuteConfig, run=run,
              sources=("plants", "planning", "stages.execute", "stages.wbc", "stages.plan", "stages.base",
                       "stages.evaluate.metrics"),
              data_files=(ROLLOUT_FILE,),
              description=DESCRIPTIONS["execute"],
              progress_total=lambda cfg: 0)
