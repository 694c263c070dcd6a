"""Motor babbling (thesis §4.1): random desired trajectories tracked by a PD controller.

Each episode starts at rest in the robot's default posture (the pendulum: hanging down, the
stable equilibrium). A random desired trajectory (a clamped cubic spline through random knots
around the start posture, inside the joint limits) is tracked by
``u = clip(Kp (q_des - q) + Kd (qdot_des - qdot), -u_max, u_max)`` with ``u_max`` the smaller
of 10 N m and each joint's effort limit, built from Drake's own blocks; Drake's Simulator
integrates the plant with ``runge_kutta5`` at a fixed step of ``dt / substeps``. Every ``dt`` the
tuple ``(q, qdot, qddot, u)`` is sampled; ``qddot`` is the plant's own time derivative there.

A robot from a problem file (``--problem FILE``; ``[robot.true]``'s robot where the file states one)
babbles the same way with the model file's gravity compensation ``g(q)`` added to the PD's torques,
and **per-joint random torques** (``torque_noise``) that excite the dynamics beyond what the tracking
asks, bounded so that the PD keeps every joint inside its range (:func:`noise_bound`). Each joint
babbles in its own unit (:func:`joint_gains`, :func:`joint_amplitudes`: revolute in rad, prismatic in
m). The details: docs/learning.md, "Babbling".

Output arrays are in planning coordinates, shaped ``(episodes, K, n_q)`` with
``K = round(duration / dt) + 1`` samples per episode; ``t`` is ``(K,)`` in seconds.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import CubicSpline

from raico.plants.robots import PLANTS, load_robot
from raico.stages.base import Stage, StageConfig, StageOutput
from raico.stages.evaluate.metrics import prismatic_joints
from raico.stages.registry import DESCRIPTIONS

DATA_FILE = "data.npz"


@dataclass(frozen=True)
class BabbleConfig(StageConfig):
    """Declared parameters of the babble stage (all part of its cache key; defaults stated here only)."""

    HELP = {"plant": "pendulum, cartpole, arm5, biorob or nao (or --problem FILE).",
            "problem": "A problem file (TOML) whose robot babbles (its model file; [robot.true]'s robot where "
                       "stated); replaces --plant.",
            "torque_noise": "Per-joint random torques added to the PD, as a fraction of the effort limit "
                            "(default: 0 for a built-in plant, 0.1 for a problem file's robot).",
            "episodes": "Number of babbling episodes.",
            "duration": "Seconds per episode.", "dt": "Sample period (s).",
            "kp": "PD stiffness of a revolute joint (N m/rad).", "kd": "PD damping of a revolute joint (N m s/rad).",
            "amplitude": "Spread of a revolute joint's random knots (rad).",
            "kp_prismatic": "PD stiffness of a prismatic joint (N/m).",
            "kd_prismatic": "PD damping of a prismatic joint (N s/m).",
            "amplitude_prismatic": "Spread of a prismatic joint's random knots (m).",
            "knots": "Random knots per episode.", "integrator": "Drake integrator scheme.",
            "substeps": "Fixed integrator steps per sample."}

    plant: str = ""
    problem: str | None = None  # a problem file's path; normalized: its canonical content (JSON)
    torque_noise: float | None = None  # fraction of u_max; None: 0 (built-in plant) or TORQUE_NOISE (problem file)
    episodes: int = 5
    seed: int = 0
    duration: float = 1.0  # s per episode
    dt: float = 0.002  # s between samples
    kp: float = 50.0  # N m/rad, a revolute joint's PD stiffness
    kd: float = 5.0  # N m s/rad
    amplitude: float = 0.6  # rad, spread of a revolute joint's random knots around the start posture
    kp_prismatic: float = 1000.0  # N/m, a prismatic joint's PD stiffness (a lift carrying a few kg)
    kd_prismatic: float = 100.0  # N s/m
    amplitude_prismatic: float = 0.1  # m, spread of a prismatic joint's random knots
    knots: int = 4  # random knots per episode (after the start)
    integrator: str = "runge_kutta5"
    substeps: int = 2  # fixed integrator steps per sample

    def problem_file(self):
        """The problem file of ``--problem`` (a path, or the canonical content once normalized)."""
        from raico.planning.problem_file import ProblemFile, read_problem

        text = str(self.problem)
        return ProblemFile(json.loads(text)) if text.lstrip().startswith("{") else read_problem(text)

    def normalized(self) -> BabbleConfig:
        """One spelling per meaning (cache key): a problem file as its canonical content (its robot's label
        as ``plant``; a built-in plant's file as that plant), the random torques' default spelled out."""
        if self.problem is None:
            return replace(self, torque_noise=0.0 if self.torque_noise is None else self.torque_noise)
        try:
            pf = self.problem_file()
        except ValueError:
            return self  # validate() says what is wrong
        if pf.plant is not None:
            return replace(self, problem=None, plant=pf.plant).normalized()
        noise = TORQUE_NOISE if self.torque_noise is None else self.torque_noise
        return replace(self, problem=pf.canonical(), plant=pf.robot_label, torque_noise=noise)

    def validate(self) -> None:
        if self.problem is not None:
            if self.plant and self.problem_file().plant is None and self.plant != self.problem_file().robot_label:
                raise ValueError("give --plant or --problem, not both")
            babble_robots(self)
        elif self.plant not in PLANTS:
            raise ValueError(f"unknown plant '{self.plant}': choose one of {', '.join(PLANTS)}"
                             + ("" if self.plant else " (or --problem FILE)"))
        checks = [(self.torque_noise is None or 0 <= self.torque_noise <= 1,
                   "torque-noise must be in [0, 1] (a fraction of the effort limit)"),(self.episodes >= 1, "episodes must be >= 1"),
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
                  (self.kp_prismatic >= 0 and self.kd_prismatic >= 0, "kp-prismatic and kd-prismatic must be >= 0"),
                  (0 <= self.amplitude <= 3.2, "amplitude must be in [0, 3.2] rad"),
                  (0 <= self.amplitude_prismatic <= 2.0, "amplitude-prismatic must be in [0, 2] m"),
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


TORQUE_NOISE = 0.1  # a problem file's robot: per-joint random torques, fraction of the effort limit
UNLIMITED_EFFORT = 1000.0  # N m, the babbling's torque bound on a joint whose file states no effort limit
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


MARGIN = 0.05  # the desired trajectory's knots stay this share of each joint's range inside it


def joint_amplitudes(prismatic: np.ndarray, cfg: BabbleConfig) -> np.ndarray:
    """Per joint, the spread of the random knots: ``amplitude`` (rad) or ``amplitude_prismatic`` (m)."""
    return np.where(prismatic, cfg.amplitude_prismatic, cfg.amplitude)


def joint_gains(prismatic: np.ndarray, cfg: BabbleConfig) -> tuple[np.ndarray, np.ndarray]:
    """Per joint, the PD's ``(kp, kd)``: N m/rad and N m s/rad on a revolute joint, N/m and N s/m on a
    prismatic one."""
    return (np.where(prismatic, cfg.kp_prismatic, cfg.kp).astype(float),
            np.where(prismatic, cfg.kd_prismatic, cfg.kd).astype(float))


def desired_trajectory(rng: np.random.Generator, q0: np.ndarray, lower: np.ndarray,
                       upper: np.ndarray, cfg: BabbleConfig, prismatic: np.ndarray | None = None) -> CubicSpline:
    """A clamped cubic spline ``q_des(t)`` from ``q0`` at rest through random knots (rad, m on a prismatic
    joint: ``prismatic (n,)`` bool, None: none), uniform within each joint's amplitude
    (:func:`joint_amplitudes`) and ``MARGIN`` of its range inside it."""
    times = np.linspace(0.0, cfg.duration, cfg.knots + 1)
    amp = joint_amplitudes(np.zeros(q0.size, bool) if prismatic is None else prismatic, cfg)
    knots = q0 + rng.uniform(-amp, amp, size=(cfg.knots, q0.size))
    with np.errstate(invalid="ignore"):   # an unlimited joint (the cart-pole's pole): no margin, no clipping
        margin = np.where(np.isfinite(upper - lower), MARGIN * (upper - lower), 0.0)
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
    kp, kd = joint_gains(P @ prismatic_joints(robot) > 0, cfg)   # per plant joint
    builder = robot.builder
    source = builder.AddSystem(TrajectorySource(PiecewisePolynomial(np.zeros(n_plant)), 1, True))
    pid = builder.AddSystem(PidController(kp, np.zeros(n_plant), kd))
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


def babble_robots(cfg: BabbleConfig):
    """``(planning robot, spec of the robot babbled on)`` of a problem file's babbling (the spec: the
    true robot's where ``[robot.true]`` states one, else the model file's); ``ValueError`` for a model
    file that does not load or a frame the true robot names that it lacks."""
    from raico.plants.model_file import ModelError, shared_model

    pf = cfg.problem_file()
    spec = pf.robot_spec()
    if spec is None:
        raise ValueError("a problem file of a built-in plant babbles as --plant")
    true = pf.true_spec() or spec
    try:
        robot = shared_model(spec)
        shared_model(true)
    except ModelError as e:
        raise ValueError(str(e)) from None
    return robot, true


def robot_description(config: dict) -> dict:
    """The babbled robot as a plan's ``problem.json`` states it (``plant``, and for a problem file's
    robot ``robot``: the planning model's spec, ``robot_true``: the robot babbled on), from a babble
    artifact's stored ``config``: what the fit stage needs to name, load and model it."""
    if not config.get("problem"):
        return {"plant": str(config["plant"])}
    cfg = BabbleConfig.from_dict(config)
    robot, true = babble_robots(cfg)
    if robot.builtin:   # a problem file on a built-in plant: its plans store the name only
        return {"plant": robot.name}
    out = {"plant": robot.name, "robot": robot.spec.to_dict()}
    if true != robot.spec:
        out["robot_true"] = true.to_dict()
    return out


def _model_simulator(robot, model, cfg: BabbleConfig):
    """Diagram of a problem file's robot (``robot``: the one babbled on, ``model``: the planning model):
    ``u = clip(g_model(q) + PD(q_des - q) + r(t), -u_max, u_max)`` (module docstring), Drake's blocks only:
    ``InverseDynamics`` (gravity compensation on ``model``'s plant), ``PidController``, a
    ``TrajectorySource`` each for ``(q_des, qdot_des)`` and the random torques ``r``, an ``Adder``,
    ``Saturation`` and ``MatrixGain`` to the actuation port."""
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
    from pydrake.systems.controllers import InverseDynamics, PidController
    from pydrake.systems.primitives import Adder, MatrixGain, Saturation, TrajectorySource
    from pydrake.trajectories import PiecewisePolynomial

    plant, n = robot.plant, robot.plant.num_positions()
    u_max = babble_effort(robot)
    kp, kd = joint_gains(prismatic_joints(robot), cfg)
    builder = robot.builder
    source = builder.AddSystem(TrajectorySource(PiecewisePolynomial(np.zeros(n)), 1, True))
    noise = builder.AddSystem(TrajectorySource(PiecewisePolynomial(np.zeros(n)), 0, True))
    pid = builder.AddSystem(PidController(kp, np.zeros(n), kd))
    gravity = builder.AddSystem(InverseDynamics(model.plant, InverseDynamics.InverseDynamicsMode.kGravityCompensation))
    add = builder.AddSystem(Adder(3, n))
    sat = builder.AddSystem(Saturation(-u_max, u_max))
    act = builder.AddSystem(MatrixGain(robot.B_act.T))
    builder.Connect(plant.get_state_output_port(), pid.get_input_port_estimated_state())
    builder.Connect(plant.get_state_output_port(), gravity.get_input_port_estimated_state())
    builder.Connect(source.get_output_port(), pid.get_input_port_desired_state())
    builder.Connect(pid.get_output_port_control(), add.get_input_port(0))
    builder.Connect(gravity.get_output_port_generalized_force(), add.get_input_port(1))
    builder.Connect(noise.get_output_port(), add.get_input_port(2))
    builder.Connect(add.get_output_port(), sat.get_input_port())
    builder.Connect(sat.get_output_port(), act.get_input_port())
    builder.Connect(act.get_output_port(), plant.get_actuation_input_port())
    sim = Simulator(builder.Build())
    integrator = ResetIntegratorFromFlags(sim, cfg.integrator, cfg.dt)
    integrator.set_fixed_step_mode(True)
    integrator.set_maximum_step_size(cfg.dt / cfg.substeps)
    return sim, source, noise, pid, act


def babble_effort(robot) -> np.ndarray:
    """Per joint of a problem file's robot: its effort limit (N m), ``UNLIMITED_EFFORT`` where none is stated."""
    return np.where(np.isfinite(robot.effort), robot.effort, UNLIMITED_EFFORT)


def noise_bound(u_max: np.ndarray, kp: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                cfg: BabbleConfig) -> np.ndarray:
    """Per joint, the random torques' bound (N m; N on a prismatic joint): ``torque_noise u_max``, at most
    what the PD's stiffness ``kp`` holds within half the desired trajectory's margin (``kp MARGIN range / 2``,
    the other half left to the tracking error): a random torque can then push a joint at most half the margin
    off its desired position, which stays ``MARGIN`` of the range inside it. Without the cap a lift of
    0-0.4 m (300 N effort limit, 30 N of noise against 50 N/m) was pushed to 0.68 m."""
    cap = 0.5 * kp * MARGIN * np.where(np.isfinite(upper - lower), upper - lower, np.inf)
    return np.minimum(cfg.torque_noise * u_max, cap)


def random_torques(rng: np.random.Generator, spline: CubicSpline, bound: np.ndarray):
    """Per-joint random torques ``r(t)`` (N m, N on a prismatic joint) as Drake's clamped cubic through
    ``U(-1, 1) bound`` (:func:`noise_bound`) at the desired trajectory's knot times (zero at the start)."""
    from pydrake.trajectories import PiecewisePolynomial

    u_max = np.asarray(bound, float)
    knots = rng.uniform(-1.0, 1.0, size=(len(spline.x) - 1, u_max.size)) * u_max
    samples = np.vstack([np.zeros(u_max.size), knots]).T
    zero = np.zeros(u_max.size)
    return PiecewisePolynomial.CubicWithContinuousSecondDerivatives(spline.x, samples, zero, zero)


def babble(cfg: BabbleConfig, progress: Callable[[int, int], None] | None = None) -> BabbleData:
    """Simulate ``cfg.episodes`` babbling episodes on the Drake plant; see the module docstring."""
    cfg.validate()
    if cfg.problem is not None:
        return _babble_model_file(cfg, progress)
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
    prismatic = prismatic_joints(robot)
    for e in range(E):
        spline = desired_trajectory(rng, q0, robot.lower, robot.upper, cfg, prismatic)
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


def _babble_model_file(cfg: BabbleConfig, progress: Callable[[int, int], None] | None) -> BabbleData:
    """:func:`babble` for a problem file's robot (module docstring): the random desired trajectory and
    random torques drawn per episode, in that order, from one generator of ``cfg.seed``."""
    from raico.plants.model_file import load_model

    model, true = babble_robots(cfg)
    robot = load_model(true)
    sim, source, noise, pid, act = _model_simulator(robot, model, cfg)
    plant = robot.plant
    root = sim.get_mutable_context()
    pctx = plant.GetMyMutableContextFromRoot(root)
    pid_ctx = pid.GetMyMutableContextFromRoot(root)
    act_ctx = act.GetMyContextFromRoot(root)
    n = robot.n_q
    K = int(round(cfg.duration / cfg.dt)) + 1
    t = np.arange(K) * cfg.dt
    rng = np.random.default_rng(cfg.seed)
    E = cfg.episodes
    out = {k: np.zeros((E, K, n)) for k in ("q", "qdot", "qddot", "u", "q_des")}
    q0 = np.clip(robot.default_q, robot.lower, robot.upper)
    prismatic = prismatic_joints(robot)
    bound = noise_bound(babble_effort(robot), joint_gains(prismatic, cfg)[0], robot.lower, robot.upper, cfg)
    for e in range(E):
        spline = desired_trajectory(rng, q0, robot.lower, robot.upper, cfg, prismatic)
        source.UpdateTrajectory(plant_spline(spline, robot.P))
        noise.UpdateTrajectory(random_torques(rng, spline, bound))
        root.SetTime(0.0)
        plant.SetPositions(pctx, q0)
        plant.SetVelocities(pctx, np.zeros(n))
        pid_ctx.SetContinuousState(np.zeros(n))
        sim.Initialize()
        for k in range(K):
            if k > 0:
                sim.AdvanceTo(t[k])
            x = plant.GetPositionsAndVelocities(pctx)
            out["q"][e, k], out["qdot"][e, k] = x[:n], x[n:]
            out["qddot"][e, k] = plant.EvalTimeDerivatives(pctx).CopyToVector()[n:]
            out["u"][e, k] = robot.B_act @ act.get_output_port().Eval(act_ctx)
        out["q_des"][e] = spline(t)
        if progress:
            progress(e + 1, E)
    return BabbleData(t=t, joint_names=robot.joint_names, **out)


def run(cfg: BabbleConfig, inputs: dict | None = None, progress: Callable[[int, int], None] | None = None
        ) -> StageOutput:
    """The babble stage: ``data.npz`` with the sampled tuples of every episode."""
    data = babble(cfg, progress)
    return StageOutput(status="ok", metrics=data.metrics(), arrays={DATA_FILE: data.arrays()}, payload=data)


STAGE = Stage(name="babble", config_cls=BabbleConfig, run=run,
              sources=("raico.plants", "raico.stages.babble", "raico.stages.base", "raico.planning.problem_file", "raico.planning.problem_terms",
                       "raico.planning.term_kinds", "raico.stages.evaluate.metrics"),
              data_files=(DATA_FILE,),
              description=DESCRIPTIONS["babble"],
              progress_total=lambda cfg: cfg.episodes)
