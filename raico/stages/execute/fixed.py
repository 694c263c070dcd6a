"""Fixed-base execution: an arm or the pendulum driven by the plan's feedback controller (or re-planned by
``--controller mpc``, pushed by ``--push``), in its problem's scene where it has one (docs/execution.md)."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from raico.plants.robots import Robot, load_robot_for, robot_for
from raico.stages.evaluate.metrics import execution_metrics
from raico.stages.execute.config import ARM_FINAL_TARGET, ExecuteConfig, ExecuteOutput, initial_q


def _controller(robot: Robot, plan: dict, pseudo: bool, cfg: ExecuteConfig, dt: float, rng, mpc=None,
                period: float | None = None, online=None):
    """LeafSystem: plant state in, held actuation out; logs the commanded controls. With ``mpc``
    (``raico.planning.mpc.MPC``) the control is re-planned every ``period`` s (a divisor of ``dt``) from the measured
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
                if online is not None and first:   # the learned model's online update (every K steps)
                    online.observe(x, u)
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
    from raico.planning.mpc import MPC

    period = dt if cfg.period is None else float(cfg.period)
    if period < sim_step - 1e-12:
        raise ValueError(f"--period {period:g} s is shorter than the simulation step {sim_step:g} s")
    every = dt / period
    if period > dt + 1e-12 or abs(every - round(every)) > 1e-9:
        raise ValueError(f"--period {period:g} s must divide the planning step {dt:g} s")
    horizon = cfg.mpc_horizon(problem.T)
    if horizon > problem.T:
        raise ValueError(f"--horizon {horizon} is longer than the problem's {problem.T} steps")
    if cfg.rti and period < dt - 1e-12:
        raise ValueError(f"--rti prepares the next planning step: --period {period:g} s must be the planning step")
    mpc = MPC(problem, horizon, cfg.solver, None,  # the solver's defaults (R-AICO: alpha 1)
              iterations=cfg.iterations_per_tick, budget=period, ticks=problem.T * int(round(every)),
              keep_predictions=True, split=cfg.rti, receding_end=cfg.receding_end(ARM_FINAL_TARGET))
    mpc.start_from(np.asarray(plan["X"]), np.asarray(plan["U"]), np.asarray(plan["o"]), np.asarray(plan["O"]))
    return mpc, period


def mpc_aim(mpc, X_plan: np.ndarray, every: int) -> np.ndarray:
    """``(T+1, n_x)``: what a receding-horizon controller aimed each sample at, its prediction of step ``k``
    from the first tick of step ``k - 1`` (that window's second state: ``every`` ticks per planning step);
    the plan's start at ``k = 0``, NaN after the last tick (a run that stopped)."""
    aim = np.full(X_plan.shape, np.nan)
    aim[0] = X_plan[0]
    pred = mpc.log.predicted[:mpc.log.n:every, 1] if mpc.log.predicted is not None else np.empty((0, 0))
    k = min(len(pred), len(aim) - 1)
    aim[1:1 + k] = pred[:k]
    return aim


def _online_for(cfg: ExecuteConfig, mpc):
    """The learned model's online update of ``--online-every`` (``raico.planning.mpc.OnlineResidual``), or None."""
    if mpc is None or cfg.online_every <= 0:
        return None
    from raico.planning.mpc import OnlineResidual

    return OnlineResidual(mpc, cfg.online_every)


def _mpc_metrics(mpc, period: float) -> dict:
    """The MPC's tick statistics: ticks, median and 99th-percentile solve time (s), ticks past the period."""
    t = mpc.log.solve_time[:mpc.log.n]
    if t.size == 0:
        return {"mpc_ticks": 0}
    return {"mpc_ticks": int(t.size), "mpc_period": period, "mpc_horizon": mpc.H, "mpc_solver": mpc.solver,
            "mpc_median_tick_s": float(np.median(t)), "mpc_p99_tick_s": float(np.percentile(t, 99)),
            "mpc_over_period": int(mpc.log.over_budget[:mpc.log.n].sum()),
            "mpc_iterations": int(mpc.log.iterations[:mpc.log.n].sum()),
            "mpc_max_violation": [float(v) for v in mpc.log.violation[:mpc.log.n].max(axis=0)],
            **({} if mpc.log.feedback_time is None else   # the split: the feedback phase's own time
               {"mpc_median_feedback_s": float(np.median(mpc.log.feedback_time[:mpc.log.n]))})}


def execute_fixed(cfg: ExecuteConfig, desc: dict, plan: dict, problem, rng, progress, planning=None) -> ExecuteOutput:
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
    q_start = initial_q(desc, robot, cfg, rng)
    sim_step = step if discrete else dt / math.ceil(dt / step - 1e-9)
    mpc, period = _mpc_for(cfg, planning, plan, dt, sim_step) if cfg.controller == "mpc" else (None, dt)
    online = _online_for(cfg, mpc)
    ctrl = robot.builder.AddSystem(_controller(robot, plan, desc["control_kind"] == "acceleration", cfg, dt, rng,
                                               mpc, period, online))
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
    wall = time.perf_counter()
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
    wall = time.perf_counter() - wall
    U = np.array(ctrl.log_u[:T]).reshape(-1, n)
    tau = np.array(taus).reshape(-1, n)
    sat = np.array(saturated, bool).reshape(-1, n)
    aim = None if mpc is None else mpc_aim(mpc, np.asarray(plan["X"], float), int(round(dt / period)))
    metrics = execution_metrics(problem, X, plan["X"], tau, robot, dt, sat, effort_is_limit=execution != "continuous",
                                effort_clamped=clamped, X_track=aim)
    if scene is not None:
        metrics.update(collision_metrics(problem, X, dt, metrics))
    extra = {}
    if mpc is not None:
        metrics.update(_mpc_metrics(mpc, period))
        if online is not None:   # the learned model's online updates: how many, and the points they fed
            metrics.update({"mpc_online_updates": online.updates, "mpc_online_points": online.points})
        # the closed loop's simulated time over its wall time (Drake's steps, the controller's ticks, the logs)
        metrics["mpc_real_time_factor"] = float(sum(1 for x in X if np.isfinite(x).all()) - 1) * dt / wall
        extra = mpc.log.arrays()
    return ExecuteOutput(times=np.arange(T + 1) * dt, X=X, U=U, tau=tau, X_plan=plan["X"], metrics=metrics,
                         effort_at_limit=sat, problem=problem, robot=robot, mpc=extra)


# ----------------------------------------------------------------------------- a scene
def scene_of(desc: dict) -> list[dict] | None:
    """The scene of a plan's collision terms (``raico.plants.scene``), or None where it has none."""
    for d in desc.get("terms", []):
        if d.get("term") == "collision":
            return d["map"]["scene"]
    return None


def _scene_hook(desc: dict, scene: list[dict]):
    """Registers the scene and the robot's own collision geometry, with contact, in the executed plant."""
    from raico.plants.model_file import RobotSpec
    from raico.plants.scene import register_scene, robot_shapes

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
    from raico.planning.costs import Collision
    from raico.plants.scene import ROBOT_PREFIX

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
