"""The execute stage (SPEC §8): a plan's feedback controller in closed loop with the Drake plant.

The controller ``u_k = o_k + O_k x_k`` is a Drake LeafSystem with a periodic discrete
update every planning step ``dt`` (zero-order hold of ``u_k``). Plans on the analytic model
command torques directly; pseudo-dynamics plans command accelerations, turned into torques by
computed torque, evaluated continuously (an inner loop at the integrator rate; inverse
dynamics of the full plant: for the Nao all 26 tree joints follow ``P @ u``, so the coupled
hip joints move together). Drake's plant saturates actuation at the effort limits by
itself, so ``clip_torques`` only changes what is logged; ``torque_saturation`` reports the
fraction of steps at which some joint asked for more than its limit. Optional initial-state noise (rad) and
process noise (torque, N m, per step); torques are clipped at the joint effort limits.
Drake's Simulator integrates with ``runge_kutta5`` at a fixed step of at most 1 ms.

Outputs: executed states ``X (T+1, n_x)``, applied planning controls ``U (T, n_u)`` and
torques ``tau (T, n_q)`` (sampled at the end of each step) in planning coordinates; for the Nao, the CoG against the support
polygon of both soles at every step.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

from plants.robots import Robot, load_robot
from stages.base import Artifact, Stage, StageConfig, StageOutput
from stages.evaluate.metrics import execution_metrics
from stages.plan.stage import PLAN_FILE, PROBLEM_FILE, objective_from_description

ROLLOUT_FILE = "rollout.npz"
MAX_STEP = 1e-3  # s, integrator step bound


@dataclass(frozen=True)
class ExecuteConfig(StageConfig):
    """Declared parameters of the execute stage; ``plan`` is its input (a plan artifact)."""

    INPUTS = ("plan",)
    INPUT_STAGES = {"plan": "plan"}
    HELP = {"plan": "Key (or prefix) of a plan artifact.", "x0_noise": "Std of initial joint-angle noise (rad).",
            "process_noise": "Std of torque noise per planning step (N m).",
            "clip_torques": "Clip the logged torques at the effort limits."}

    plan: str | None = None  # key, key prefix or plan/KEY of the plan to execute
    x0_noise: float = 0.0  # rad, std of noise on the initial joint angles
    process_noise: float = 0.0  # N m, std of torque noise per planning step
    seed: int = 0
    clip_torques: bool = True

    def validate(self) -> None:
        if not 0 <= self.x0_noise <= 1.0:
            raise ValueError("x0-noise must be in [0, 1] rad")
        if not 0 <= self.process_noise <= 100.0:
            raise ValueError("process-noise must be in [0, 100] N m")
        if self.plan is None:
            raise ValueError("execute needs --plan KEY")


@dataclass
class ExecuteOutput:
    times: np.ndarray  # (T+1,) s
    X: np.ndarray  # (T+1, n_x) executed
    U: np.ndarray  # (T, n_u) commanded planning controls
    tau: np.ndarray  # (T, n_q) applied torques, N m
    X_plan: np.ndarray
    metrics: dict
    cog: np.ndarray | None = None  # (T+1, 3) Nao
    cog_margin: np.ndarray | None = None  # (T+1,) m, signed distance inside the support polygon
    support: list | None = None  # per step (k, 2) polygon vertices
    problem: object = None  # the plan's problem (task terms for recordings)
    robot: Robot | None = None

    def arrays(self) -> dict[str, np.ndarray]:
        d = {"times": self.times, "X": self.X, "U": self.U, "tau": self.tau, "X_plan": self.X_plan}
        if self.cog is not None:
            d.update(cog=self.cog, cog_margin=self.cog_margin, support=padded_polygons(self.support or []))
        return d


def padded_polygons(polys: list) -> np.ndarray:
    """Polygons of different vertex counts as one ``(K, kmax, 2)`` array, NaN-padded (m)."""
    kmax = max((len(p) for p in polys), default=0)
    out = np.full((len(polys), kmax, 2), np.nan)
    for k, p in enumerate(polys):
        out[k, :len(p)] = p
    return out


def _controller(robot: Robot, plan: dict, pseudo: bool, cfg: ExecuteConfig, dt: float, rng):
    """LeafSystem: plant state in, held actuation out; logs the commanded controls."""
    from pydrake.multibody.tree import MultibodyForces_
    from pydrake.systems.framework import BasicVector, LeafSystem

    plant, P = robot.plant, robot.P
    n_plant = plant.num_positions()
    Pinv = np.linalg.pinv(P)
    o, O = plan["o"], plan["O"]
    T = o.shape[0]
    effort = P @ robot.effort
    ctx_id = plant.CreateDefaultContext()
    forces = MultibodyForces_[float](plant)
    split = P / np.maximum(P.sum(axis=0), 1.0)  # planning torque shared by coupled joints

    class FeedbackController(LeafSystem):
        """Holds ``u_k = o_k + O_k x_k`` for a planning step (periodic discrete update, ZOH).

        Torque output: analytic plans apply the held torque; pseudo plans hold the planned
        acceleration and evaluate computed torque continuously (inner loop at the integrator
        rate), as a torque-controlled robot would.
        """

        def __init__(self):
            super().__init__()
            self.log_u: list[np.ndarray] = []
            self.state_port = self.DeclareVectorInputPort("x", 2 * n_plant)
            self.held = self.DeclareDiscreteState(2 * o.shape[1])  # (u, noise)
            self.DeclareVectorOutputPort("tau", BasicVector(plant.num_actuators()), self._torque,
                                         {self.all_sources_ticket()})
            self.DeclarePeriodicDiscreteUpdateEvent(dt, 0.0, self._update)

        def _update(self, context, discrete_state):
            xp = self.state_port.Eval(context)
            k = min(int(round(context.get_time() / dt)), T - 1)
            x = np.concatenate([Pinv @ xp[:n_plant], Pinv @ xp[n_plant:]])
            u = o[k] + O[k] @ x
            w = cfg.process_noise * rng.standard_normal(u.size) if cfg.process_noise > 0 else 0 * u
            self.log_u.append(u)
            discrete_state.get_mutable_vector().SetFromVector(np.concatenate([u, w]))

        def plant_torque(self, context, clip: bool = True) -> np.ndarray:
            """Generalized forces (plant velocity order, N m) at this instant."""
            xp = self.state_port.Eval(context)
            uw = context.get_discrete_state_vector().CopyToVector()
            u, w = uw[:uw.size // 2], uw[uw.size // 2:]
            if pseudo:  # computed torque: all tree joints follow P @ u
                plant.SetPositionsAndVelocities(ctx_id, xp)
                plant.CalcForceElementsContribution(ctx_id, forces)
                tau = plant.CalcInverseDynamics(ctx_id, P @ u, forces)
            else:
                tau = split @ u
            tau = tau + split @ w
            return np.clip(tau, -effort, effort) if clip and cfg.clip_torques else tau

        def _torque(self, context, output):
            output.SetFromVector(robot.actuation(self.plant_torque(context)))

    return FeedbackController()


def support_polygon(robot: Robot, ctx, soles=("l_sole", "r_sole")) -> np.ndarray:
    """Convex hull ``(k, 2)`` (m, world xy) of the soles' outlines at the plant context."""
    pts = []
    outline = np.c_[robot.support_polygon, np.zeros(len(robot.support_polygon))]
    for sole in soles:
        X = robot.plant.GetFrameByName(sole).CalcPoseInWorld(ctx)
        pts.append((X.rotation().matrix() @ outline.T).T[:, :2] + X.translation()[:2])
    pts = np.vstack(pts)
    return pts[ConvexHull(pts).vertices]


def signed_margin(poly: np.ndarray, p: np.ndarray) -> float:
    """Distance (m) of ``p (2,)`` to the boundary of convex ``poly``: > 0 inside, < 0 outside."""
    hull = ConvexHull(poly)
    d = hull.equations[:, :2] @ p + hull.equations[:, 2]  # outward normals: d <= 0 inside
    return float(-d.max())


def execute(cfg: ExecuteConfig, desc: dict, plan: dict,
            progress: Callable[[int, int], None] | None = None) -> ExecuteOutput:
    """Execute a plan (its arrays and stored problem description) on the Drake plant in closed loop."""
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator

    cfg.validate()
    problem = objective_from_description(desc)
    dt, T = float(desc["dt"]), int(desc["T"])
    q0 = np.asarray(desc["q0"], float)
    robot = load_robot(desc["plant"])
    rng = np.random.default_rng(cfg.seed)
    ctrl = robot.builder.AddSystem(_controller(robot, plan, desc["control_kind"] == "acceleration", cfg, dt, rng))
    robot.builder.Connect(robot.plant.get_state_output_port(), ctrl.get_input_port(0))
    robot.builder.Connect(ctrl.get_output_port(0), robot.plant.get_actuation_input_port())
    sim = Simulator(robot.builder.Build())
    integ = ResetIntegratorFromFlags(sim, "runge_kutta5", dt / math.ceil(dt / MAX_STEP - 1e-9))
    integ.set_fixed_step_mode(True)
    pctx = robot.plant.GetMyMutableContextFromRoot(sim.get_mutable_context())
    q_start = q0 + cfg.x0_noise * rng.standard_normal(q0.size)
    robot.plant.SetPositions(pctx, robot.to_plant_q(q_start))
    robot.plant.SetVelocities(pctx, np.zeros(robot.plant.num_velocities()))
    Pinv = np.linalg.pinv(robot.P)
    n = robot.n_q
    X = np.full((T + 1, 2 * n), np.nan)
    nao = robot.name == "nao"
    cog = np.full((T + 1, 3), np.nan) if nao else None
    margin = np.full(T + 1, np.nan) if nao else None
    stance = np.full(T + 1, np.nan) if nao else None
    polys = [] if nao else None
    sim.Initialize()

    def sample(k: int) -> bool:
        xp = robot.plant.GetPositionsAndVelocities(pctx)
        if not np.all(np.isfinite(xp)):
            return False
        X[k] = np.concatenate([Pinv @ xp[:robot.plant.num_positions()], Pinv @ xp[robot.plant.num_positions():]])
        if nao:
            c = robot.plant.CalcCenterOfMassPositionInWorld(pctx)
            poly = support_polygon(robot, pctx)
            cog[k], margin[k] = c, signed_margin(poly, c[:2])
            stance[k] = signed_margin(support_polygon(robot, pctx, ("l_sole",)), c[:2])
            polys.append(poly)
        return True

    ctrl_ctx = ctrl.GetMyContextFromRoot(sim.get_context())
    taus, saturated = [], []
    effort_plant = robot.P @ robot.effort
    ok = sample(0)
    for k in range(T):
        if not ok:
            break
        try:
            sim.AdvanceTo((k + 1) * dt)
        except RuntimeError:
            break
        wanted = ctrl.plant_torque(ctrl_ctx, clip=False)
        saturated.append(bool(np.any(np.abs(wanted) > effort_plant + 1e-9)))
        taus.append(robot.P.T @ (np.clip(wanted, -effort_plant, effort_plant) if cfg.clip_torques else wanted))
        ok = sample(k + 1)
        if progress is not None and (k + 1) % 10 == 0:
            progress(k + 1, T)
    U = np.array(ctrl.log_u[:T]).reshape(-1, n)
    tau = np.array(taus).reshape(-1, n)
    X_plan = plan["X"]
    metrics = execution_metrics(problem, X, X_plan, tau, cog, margin, robot)
    metrics["torque_saturation"] = float(np.mean(saturated)) if saturated else 0.0
    if nao:
        metrics["cog_inside_stance_fraction"] = float(np.mean(stance > 0))
        metrics["cog_min_stance_margin"] = float(np.nanmin(stance))
    return ExecuteOutput(times=np.arange(T + 1) * dt, X=X, U=U, tau=tau, X_plan=X_plan, metrics=metrics,
                         cog=cog, cog_margin=margin, support=polys, problem=problem, robot=robot)


def run(cfg: ExecuteConfig, inputs: dict[str, Artifact], progress: Callable[[int, int], None] | None = None
        ) -> StageOutput:
    """The execute stage: ``rollout.npz`` of the plan's controller run in Drake."""
    plan = inputs["plan"]
    out = execute(cfg, plan.document(PROBLEM_FILE), plan.arrays(PLAN_FILE), progress)
    return StageOutput(status=out.metrics["status"], metrics=out.metrics, arrays={ROLLOUT_FILE: out.arrays()},
                       payload=out)


STAGE = Stage(name="execute", config_cls=ExecuteConfig, run=run,
              sources=("plants", "stages.execute", "stages.plan", "stages.base", "stages.evaluate.metrics"), data_files=(ROLLOUT_FILE,),
              description="Run a plan's feedback controller in closed loop with the Drake plant (Drake's Simulator).",
              progress_total=lambda cfg: 0)
