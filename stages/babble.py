"""Motor babbling (thesis §4.1): random desired trajectories tracked by a PD controller.

Each episode starts at rest in the robot's default posture (the pendulum: hanging down, the
stable equilibrium). A random desired trajectory (a clamped cubic spline through random knots
around the start posture, inside the joint limits) is tracked by
``u = clip(Kp (q_des - q) + Kd (qdot_des - qdot), -u_max, u_max)`` with ``u_max`` the smaller
of 10 N m and each joint's effort limit, built from Drake's own blocks (``TrajectorySource``,
``PidController``, ``Saturation``: no Python runs inside the integrator's steps, 2-5x faster than the
former Python ``LeafSystem``, equal to rounding). Drake's Simulator integrates the plant (continuous
time) with its ``runge_kutta5`` scheme at a fixed step of ``dt / substeps`` (Drake 1.51 has no
RK4). Every ``dt`` the
tuple ``(q, qdot, qddot, u)`` is sampled; ``qddot`` is the plant's own time derivative at
that instant.

Output arrays are in planning coordinates, shaped ``(episodes, K, n_q)`` with
``K = round(duration / dt) + 1`` samples per episode; ``t`` is ``(K,)`` in seconds.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from plants.robots import PLANTS, load_robot
from stages.base import Stage, StageConfig, StageOutput
from stages.registry import DESCRIPTIONS

DATA_FILE = "data.npz"


@dataclass(frozen=True)
class BabbleConfig(StageConfig):
    """Declared parameters of the babble stage (all part of its cache key; defaults stated here only)."""

    HELP = {"plant": "pendulum, arm5, biorob or nao.", "episodes": "Number of babbling episodes.",
            "duration": "Seconds per episode.", "dt": "Sample period (s).", "kp": "PD stiffness (N m/rad).",
            "kd": "PD damping (N m s/rad).", "amplitude": "Spread of the random knots (rad).",
            "knots": "Random knots per episode.", "integrator": "Drake integrator scheme.",
            "substeps": "Fixed integrator steps per sample."}

    plant: str
    episodes: int = 5
    seed: int = 0
    duration: float = 1.0  # s per episode
    dt: float = 0.002  # s between samples
    kp: float = 50.0
    kd: float = 5.0
    amplitude: float = 0.6  # rad, spread of the random knots around the start posture
    knots: int = 4  # random knots per episode (after the start)
    integrator: str = "runge_kutta5"
    substeps: int = 2  # fixed integrator steps per sample

    def validate(self) -> None:
        if self.plant not in PLANTS:
            raise ValueError(f"unknown plant '{self.plant}': choose one of {', '.join(PLANTS)}")
        checks = [(self.episodes >= 1, "episodes must be >= 1"),
                  (self.episodes <= 10000, "episodes must be <= 10000"),
                  (0 <= self.seed < 2**32, "seed must be in [0, 2^32 - 1]"),
                  (0 < self.dt <= 0.1, "dt must be in (0, 0.1] s"),
                  (self.dt <= self.duration <= 600, "duration must be in [dt, 600] s"),
                  (self.samples <= MAX_SAMPLES, f"duration / dt gives {self.samples:.3g} samples per episode; "
                                                f"at most {MAX_SAMPLES:,} (raise dt or shorten the duration)"),
                  (self.episodes * self.samples <= MAX_TOTAL_SAMPLES,
                   f"episodes x samples per episode = {self.episodes * self.samples:.3g}; at most "
                   f"{MAX_TOTAL_SAMPLES:,} samples in one run"),
                  (self.episodes * self.samples * self.substeps <= MAX_STEPS,
                   f"episodes x samples x substeps = {self.episodes * self.samples * self.substeps:.3g} "
                   f"integrator steps; at most {MAX_STEPS:,}"),
                  (self.kp >= 0 and self.kd >= 0, "kp and kd must be >= 0"),
                  (0 <= self.amplitude <= 3.2, "amplitude must be in [0, 3.2] rad"),
                  (1 <= self.knots <= MAX_KNOTS, f"knots must be in [1, {MAX_KNOTS:,}]"),
                  (1 <= self.substeps <= 1000, "substeps must be in [1, 1000]")]
        for ok, msg in checks:
            if not ok:
                raise ValueError(msg)

    @property
    def samples(self) -> float:
        """Samples per episode, ``round(duration / dt) + 1`` (a float: checked before it is an allocation)."""
        if not (self.dt > 0 and math.isfinite(self.duration / self.dt)):
            return math.inf
        return float(round(self.duration / self.dt) + 1)


MAX_SAMPLES = 1_000_000  # per episode (the arrays are episodes x samples x joints)
MAX_TOTAL_SAMPLES = 2_000_000  # per run: the Nao's six arrays then take 2.4 GB
MAX_STEPS = 200_000_000  # integrator steps per run
MAX_KNOTS = 100_000  # random knots per episode (the learn loop: one per 0.25 s of babbling)


@dataclass
class BabbleData:
    """Sampled tuples; arrays ``(episodes, K, n_q)``, ``t (K,)`` s, plus the desired trajectories."""

    t: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    qddot: np.ndarray
    u: np.ndarray
    q_des: np.ndarray
    joint_names: tuple[str, ...]

    def arrays(self) -> dict[str, np.ndarray]:
        return {"t": self.t, "q": self.q, "qdot": self.qdot, "qddot": self.qddot, "u": self.u,
                "q_des": self.q_des, "joint_names": np.array(self.joint_names)}

    def metrics(self) -> dict:
        return {"episodes": int(self.q.shape[0]), "samples": int(self.q.shape[0] * self.q.shape[1]),
                "max_abs_u": float(np.abs(self.u).max()),
                "rms_tracking_error": float(np.sqrt(np.mean((self.q - self.q_des) ** 2)))}


def desired_trajectory(rng: np.random.Generator, q0: np.ndarray, lower: np.ndarray,
                       upper: np.ndarray, cfg: BabbleConfig) -> CubicSpline:
    """A clamped cubic spline ``q_des(t)`` from ``q0`` at rest through random knots (rad)."""
    times = np.linspace(0.0, cfg.duration, cfg.knots + 1)
    knots = q0 + rng.uniform(-cfg.amplitude, cfg.amplitude, size=(cfg.knots, q0.size))
    margin = 0.05 * (upper - lower)
    knots = np.clip(knots, lower + margin, upper - margin)
    return CubicSpline(times, np.vstack([q0, knots]), bc_type="clamped")


def plant_spline(spline: CubicSpline, P: np.ndarray):
    """The desired trajectory in plant coordinates, ``P @ q_des(t)``, as Drake's clamped cubic
    (``CubicWithContinuousSecondDerivatives`` with zero end velocities: scipy's ``bc_type="clamped"``
    spline through the same knots, equal to rounding; the spline is linear in its knots)."""
    from pydrake.trajectories import PiecewisePolynomial

    samples = P @ np.asarray(spline(spline.x)).T
    zero = np.zeros(P.shape[0])
    return PiecewisePolynomial.CubicWithContinuousSecondDerivatives(spline.x, samples, zero, zero)


def _simulator(robot, cfg: BabbleConfig):
    """Diagram: plant (+ scene graph) tracking a settable desired trajectory, every block Drake's own
    (no Python in the integrator's loop): ``TrajectorySource`` (q_des, qdot_des) -> ``PidController``
    (``kp``, ``kd``; zero ``ki``) -> ``Saturation`` at ``u_max`` -> ``MatrixGain`` to the actuation port."""
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
    from pydrake.systems.controllers import PidController
    from pydrake.systems.primitives import MatrixGain, Saturation, TrajectorySource
    from pydrake.trajectories import PiecewisePolynomial

    plant, P = robot.plant, robot.P
    n_plant = plant.num_positions()
    pinv = np.linalg.pinv(P)
    u_max = P @ robot.babble_torque_limit()  # per plant joint (coupled joints share the motor limit)
    builder = robot.builder
    source = builder.AddSystem(TrajectorySource(PiecewisePolynomial(np.zeros(n_plant)), 1, True))
    pid = builder.AddSystem(PidController(np.full(n_plant, float(cfg.kp)), np.zeros(n_plant),
                                          np.full(n_plant, float(cfg.kd))))
    sat = builder.AddSystem(Saturation(-u_max, u_max))
    act = builder.AddSystem(MatrixGain(robot.B_act.T))
    builder.Connect(plant.get_state_output_port(), pid.get_input_port_estimated_state())
    builder.Connect(source.get_output_port(), pid.get_input_port_desired_state())
    builder.Connect(pid.get_output_port_control(), sat.get_input_port())
    builder.Connect(sat.get_output_port(), act.get_input_port())
    builder.Connect(act.get_output_port(), plant.get_actuation_input_port())
    diagram = builder.Build()
    sim = Simulator(diagram)
    integrator = ResetIntegratorFromFlags(sim, cfg.integrator, cfg.dt)
    integrator.set_fixed_step_mode(True)
    integrator.set_maximum_step_size(cfg.dt / cfg.substeps)
    return sim, diagram, source, pid, act, pinv


def babble(cfg: BabbleConfig, progress: Callable[[int, int], None] | None = None) -> BabbleData:
    """Simulate ``cfg.episodes`` babbling episodes on the Drake plant; see the module docstring."""
    cfg.validate()
    robot = load_robot(cfg.plant)
    sim, diagram, source, pid, act, pinv = _simulator(robot, cfg)
    plant = robot.plant
    root = sim.get_mutable_context()
    pctx = plant.GetMyMutableContextFromRoot(root)
    pid_ctx = pid.GetMyMutableContextFromRoot(root)
    act_ctx = act.GetMyContextFromRoot(root)
    n_plant = plant.num_positions()
    K = int(round(cfg.duration / cfg.dt)) + 1
    t = np.arange(K) * cfg.dt
    rng = np.random.default_rng(cfg.seed)
    E, n = cfg.episodes, robot.n_q
    out = {k: np.zeros((E, K, n)) for k in ("q", "qdot", "qddot", "u", "q_des")}
    q0 = robot.default_q
    for e in range(E):
        spline = desired_trajectory(rng, q0, robot.lower, robot.upper, cfg)
        source.UpdateTrajectory(plant_spline(spline, robot.P))
        root.SetTime(0.0)
        plant.SetPositions(pctx, robot.to_plant_q(q0))
        plant.SetVelocities(pctx, np.zeros(n_plant))
        pid_ctx.SetContinuousState(np.zeros(n_plant))  # the (unused, ki = 0) error integral
        sim.Initialize()
        for k in range(K):
            if k > 0:
                sim.AdvanceTo(t[k])
            x = plant.GetPositionsAndVelocities(pctx)
            tau = robot.B_act @ act.get_output_port().Eval(act_ctx)
            xdot = plant.EvalTimeDerivatives(pctx).CopyToVector()
            out["q"][e, k] = pinv @ x[:n_plant]
            out["qdot"][e, k] = pinv @ x[n_plant:]
            out["qddot"][e, k] = pinv @ xdot[n_plant:]
            out["u"][e, k] = robot.P.T @ tau
        out["q_des"][e] = spline(t)
        if progress:
            progress(e + 1, E)
    return BabbleData(t=t, joint_names=robot.joint_names, **out)


def run(cfg: BabbleConfig, inputs: dict | None = None, progress: Callable[[int, int], None] | None = None
        ) -> StageOutput:
    """The babble stage: ``data.npz`` with the sampled tuples of every episode."""
    data = babble(cfg, progress)
    return StageOutput(status="ok", metrics=data.metrics(), arrays={DATA_FILE: data.arrays()}, payload=data)


STAGE = Stage(name="babble", config_cls=BabbleConfig, run=run, sources=("plants", "stages.babble", "stages.base"),
              data_files=(DATA_FILE,),
              description=DESCRIPTIONS["babble"],
              progress_total=lambda cfg: cfg.episodes)
