"""A whole-body stabilizer for a floating robot: task-space inverse dynamics.

Every ``CONTROL_PERIOD`` one quadratic program is solved by ``proxsuite``'s dense PROXQP (portable build,
warm-started: :class:`ProxQP`; Clarabel takes the rare program it does not solve). Decision variables
``x = (vdot (nv,), f (nc, 3))``: the free plant's generalized accelerations and the ground forces at the
soles' corners (the Nao: 8); the joint torques are affine in ``x`` through the equations of motion.

- Constraints: the floating base's rows of the equations of motion, the torques within the effort
  limits, linearized friction cones (``MU``) with a bounded normal force and no force on a lifted
  corner, each sole's centre of pressure off its edges (``COP_SHARE``), joint limits as acceleration
  bounds (``LIMIT_MARGIN``, ``KP_LIMIT``, ``KD_LIMIT``).
- Cost (weights ``W_*``, gains: the robot's ``stand.stabilizer``, ``raico.plants.stand``): both soles held,
  the CoG (the joint reference's, held ``COG_MARGIN`` inside the support polygon, its capture point
  too), the via-point frames, the joints along the plan, a regularization.
- Safeguards: a program no solver solves is solved again without the joint-limit bounds, else the
  previous torque is held; a disturbance observer (``DISTURBANCE_OBSERVER``); a fallen robot
  (``LIMP_TILT``) goes limp; single support releases the other sole once the CoG is over the stance
  one (``RELEASE_MARGIN``, ``RELEASE_EARLIEST``).

The program term by term: docs/stabilizer.md ("The program"); why each weight, gain, bound and solver
setting is what it is (measured): the rest of that page.
"""

from __future__ import annotations

import atexit
import time
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np

CONTROL_PERIOD = 4e-3  # s, one QP per period (zero-order hold in between)
# the acceleration gains (joints, CoG, soles' contact, via-point frames) are the robot's: its stand.stabilizer
W_JOINT, W_COG, W_FRAME, W_CONTACT, W_REG, W_FORCE = 1.0, 1000.0, 1000.0, 1000.0, 1e-4, 1e-5
COG_FROM_JOINT_PLAN = True  # the CoG reference: the joint reference's CoG (True) or the plan's as made
COG_MARGIN = 0.015  # m, the CoG reference is held this far inside the feet's support polygon
LIMIT_MARGIN = 0.02  # rad, the joints are kept this far inside their position limits (None: no bounds)
LIMIT_MARGIN_OBS = 0.01  # rad, the disturbance observer leaves out a joint this near a limit (the plant's limit acts)
DISTURBANCE_OBSERVER = True  # estimate the joint torque the model does not explain and compensate it (docstring)
LIMP_TILT = 0.8  # rad, the torso this far from upright: fallen, the stabilizer stops (zero torques, no programs)
KP_LIMIT, KD_LIMIT = 400.0, 40.0  # 1/s^2, 1/s: the acceleration bound towards a limit
MU = 0.5  # friction coefficient of the linearized cone (the simulated ground has 0.8)
CORNER_UP = 2e-3  # m, a sole corner higher than this carries no force in the program (None: every corner may)
COP_SHARE = 0.1  # each corner of a sole carries at least this share of the sole's mean corner load
FZ_MIN = 0.0  # N, the least normal force on a corner in contact (docs/stabilizer.md: why 0)
FZ_MAX = 200.0  # N, a bound on each corner's normal force (keeps the program bounded)
# single support (a plan made with --balance single): the right sole is released once the CoG is over the
# left sole, then tracks the plan's right-sole corners
RELEASE_EARLIEST = 0.2  # s, not before (the start's settling)
RELEASE_MARGIN = 0.01  # m, the executed CoG's ground projection this far inside the left sole


def plan_cog(robot, X_plan: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Planned CoG position, velocity and acceleration ``(K, 3)`` each (m, m/s, m/s^2) of the plan
    ``X_plan (K, 2 n_q)`` on the fixed-base model (left sole at the world origin); the velocity at
    sample ``k`` is ``J_com(q_k) v_k``, the acceleration a forward difference of it (zero at the end)."""
    from pydrake.multibody.tree import JacobianWrtVariable

    plant, n = robot.plant, robot.n_q
    ctx = plant.CreateDefaultContext()
    world = plant.world_frame()
    K = len(X_plan)
    c, cd = np.empty((K, 3)), np.empty((K, 3))
    for k in range(K):
        plant.SetPositions(ctx, robot.to_plant_q(X_plan[k, :n]))
        c[k] = plant.CalcCenterOfMassPositionInWorld(ctx)
        J = plant.CalcJacobianCenterOfMassTranslationalVelocity(ctx, JacobianWrtVariable.kV, world, world)
        cd[k] = J @ (robot.P @ X_plan[k, n:])
    cdd = np.zeros((K, 3))
    cdd[:-1] = np.diff(cd, axis=0) / dt
    return c, cd, cdd


def plan_points(taskmap, X_plan: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A task map's values along the plan ``X_plan (K, 2 n_q)``: positions, velocities ``J v`` and
    forward-difference accelerations ``(K, dim)`` each (m, m/s, m/s^2)."""
    n = X_plan.shape[1] // 2
    phi, J = taskmap.values_and_jacobians(X_plan[:, :n])
    phid = np.einsum("kij,kj->ki", J, X_plan[:, n:])
    phidd = np.zeros_like(phid)
    phidd[:-1] = np.diff(phid, axis=0) / dt
    return phi, phid, phidd


class Reference:
    """The plan as a reference at any time ``t`` (s): joint positions, velocities and accelerations
    of the free plant's tree joints ``(26,)`` each from ``X_joint (K, 2 n_q)``; the CoG's ``(3,)``
    each and every frame task's ``(dim,)`` each from ``X_task`` (the plan as made: its CoG and
    via-point frames are what the task asks for)."""

    def __init__(self, free, X_joint: np.ndarray, X_task: np.ndarray, dt: float, frame_maps=()):
        fixed = free.fixed
        n = fixed.n_q
        self.dt, self.T = dt, len(X_joint) - 1
        Q = np.clip(X_joint[:, :n], fixed.lower, fixed.upper)
        V = X_joint[:, n:]
        A = np.zeros_like(V)
        A[:-1] = np.diff(V, axis=0) / dt
        P = fixed.P  # (n_tree, n_q)
        self.fixed = fixed
        self.Q, self.V, self.A = Q @ P.T, V @ P.T, A @ P.T
        self.c, self.cd, self.cdd = plan_cog(fixed, X_joint if COG_FROM_JOINT_PLAN else X_task, dt)
        self.frames = [plan_points(m, X_task, dt) for m in frame_maps]

    def follow(self, k: int, X: np.ndarray) -> None:
        """From step ``k`` on, the joints (and the CoG, with ``COG_FROM_JOINT_PLAN``) follow ``X (m, 2 n_q)``
        (a receding-horizon controller's predicted window, ``X[0]`` at step ``k``): its first three samples
        overwrite steps ``k .. k+2``, what the updates of one planning step read (accelerations ``k, k+1``)."""
        fixed, n = self.fixed, self.fixed.n_q
        m = min(3, len(X), self.T + 1 - k)
        Xw = X[:m]
        P = fixed.P
        self.Q[k:k + m] = np.clip(Xw[:, :n], fixed.lower, fixed.upper) @ P.T
        self.V[k:k + m] = Xw[:, n:] @ P.T
        self.A[k:k + m - 1] = np.diff(self.V[k:k + m], axis=0) / self.dt
        if COG_FROM_JOINT_PLAN:
            c, cd, cdd = plan_cog(fixed, Xw, self.dt)
            self.c[k:k + m], self.cd[k:k + m], self.cdd[k:k + m - 1] = c, cd, cdd[:m - 1]

    def _pick(self, k: int, s: float, pos, vel, acc):
        if k >= self.T:
            return pos[-1], 0 * vel[-1], 0 * acc[-1]
        return (1 - s) * pos[k] + s * pos[k + 1], vel[k + 1], acc[k]

    def at(self, t: float) -> tuple:
        """``(joints, cog, frames)``, each a ``(position, velocity, acceleration)`` triple (frames: a
        list of them): inside step ``k`` the position is interpolated linearly from ``k`` to
        ``k + 1``, the velocity is that of ``k + 1``, the acceleration ``(v_{k+1} - v_k)/dt``
        (semi-implicit Euler). Past the horizon the plan's last state, at rest."""
        k = int(np.floor(t / self.dt + 1e-9))
        s = t / self.dt - k
        return (self._pick(k, s, self.Q, self.V, self.A), self._pick(k, s, self.c, self.cd, self.cdd),
                [self._pick(k, s, *f) for f in self.frames])


def clamp_to_polygon(p: np.ndarray, A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The point of the convex polygon ``{x : A x <= b}`` (``A (m, 2)`` unit rows, ``b (m,)`` m)
    nearest to ``p (2,)`` (m); ``p`` itself when inside. Exact: from outside, the nearest point is
    the projection of ``p`` onto an edge's line or a vertex (two lines' intersection), whichever
    feasible candidate is nearest (``m + m (m - 1) / 2`` candidates, one vectorized pass)."""
    if np.all(A @ p <= b + 1e-12):
        return p
    proj = p - (A @ p - b)[:, None] * A                      # (m, 2) onto each line
    i, j = np.triu_indices(len(b), 1)
    M = np.stack([A[i], A[j]], axis=1)                       # (k, 2, 2)
    det = M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] * M[:, 1, 0]
    ok = np.abs(det) > 1e-12                                 # parallel lines meet nowhere
    rhs = np.stack([b[i], b[j]], axis=1)[ok]
    Mi, d = M[ok], det[ok]
    vert = np.stack([(Mi[:, 1, 1] * rhs[:, 0] - Mi[:, 0, 1] * rhs[:, 1]) / d,
                     (Mi[:, 0, 0] * rhs[:, 1] - Mi[:, 1, 0] * rhs[:, 0]) / d], axis=1)
    C = np.vstack([proj, vert])
    viol = (C @ A.T - b).max(axis=1)
    if not np.any(viol <= 1e-9):      # an empty polygon (a margin wider than the feet): least violation
        return C[np.argmin(viol)]
    C = C[viol <= 1e-9]
    return C[np.argmin(((C - p) ** 2).sum(axis=1))]


def rotation_log(R: np.ndarray) -> np.ndarray:
    """The rotation vector ``(3,)`` (axis times angle, rad) of the rotation matrix ``R (3, 3)``."""
    w = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])  # sin(angle) axis
    c = min(max(0.5 * (np.trace(R) - 1.0), -1.0), 1.0)
    s = np.linalg.norm(w)
    angle = np.arctan2(s, c)
    if s < 1e-12:
        if c > 0:
            return w  # the identity to first order
        from pydrake.math import RotationMatrix  # a half turn: the axis from Drake's angle-axis

        aa = RotationMatrix(R).ToAngleAxis()
        return aa.angle() * aa.axis()
    return (angle / s) * w


@dataclass
class QPData:
    """One stabilizer program: minimize ``0.5 x'Hx + g'x`` subject to ``Aeq x = beq``, ``l <= C x <= u``
    and ``lb <= x <= ub`` (``inf`` where unbounded); ``x (n,)``."""

    H: np.ndarray
    g: np.ndarray
    Aeq: np.ndarray
    beq: np.ndarray
    C: np.ndarray
    l: np.ndarray
    u: np.ndarray
    lb: np.ndarray
    ub: np.ndarray


_LIVE: weakref.WeakSet = weakref.WeakSet()  # every ProxQP alive, released at exit


@atexit.register
def _release_solvers() -> None:
    for solver in list(_LIVE):
        solver.release()


def portable_proxsuite():
    """``proxsuite`` with its portable build (``proxsuite_pywrap``, no AVX) loaded, not the AVX2/AVX-512 one its
    package picks by CPU: the AVX2 build's results depend on where its work arrays lie in memory (measured: the
    first program of two identical executions in one process solved 1.5e-12 apart, the identical inputs included;
    the noisy fig3.4 executions' via-point errors then moved by up to 1.4 cm between reproduce runs, always the
    same statuses), and each CPU's build rounds differently. The package chooses its build when first imported:
    before that, its CPU probe is answered "no AVX" (every later import in the process gets the same build)."""
    import sys
    import types

    if "proxsuite" not in sys.modules:
        probe = types.ModuleType("proxsuite.instructionset")
        probe.has_AVX2 = probe.has_AVX512F = lambda: False
        sys.modules["proxsuite.instructionset"] = probe
        try:
            import proxsuite  # noqa: F401
        finally:
            del sys.modules["proxsuite.instructionset"]
    import proxsuite

    return proxsuite


class ProxQP:
    """The stabilizer's QP solver: ``proxsuite``'s dense PROXQP (a primal-dual proximal augmented
    Lagrangian method) with box constraints, warm-started from the previous control step's solution
    and multipliers; converged to ``EPS`` (absolute, on the primal and dual residuals). A program it
    does not solve within ``MAX_ITER`` outer (``MAX_ITER_IN`` inner) iterations goes to Clarabel
    (Drake's interior-point solver, one persistent ``MathematicalProgram``): on a fig3.4-inside run,
    one program of 1500 took proxsuite 5 million iterations (110 s) uncapped; ``fallbacks`` counts them."""

    EPS = 1e-9
    MAX_ITER, MAX_ITER_IN = 10, 20
    BIG = 1e20  # proxsuite's stand-in for an infinite bound
    INFEASIBLE = 1e-12

    def __init__(self, n: int, n_eq: int, n_in: int):
        proxsuite = portable_proxsuite()
        self._qp = proxsuite.proxqp.dense.QP(n, n_eq, n_in, True)
        st = self._qp.settings
        st.eps_abs, st.eps_rel, st.verbose = self.EPS, 0.0, False
        st.max_iter, st.max_iter_in = self.MAX_ITER, self.MAX_ITER_IN
        # infeasibility is declared only at these residuals: at the default 1e-4, proxsuite called 9-22 of 1500
        # feasible programs of a fig3.4-inside run primal infeasible (Clarabel solved each; with 1e-12 so does this)
        st.eps_primal_inf = st.eps_dual_inf = self.INFEASIBLE
        self._warm = proxsuite.proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
        self._cold = proxsuite.proxqp.InitialGuess.NO_INITIAL_GUESS
        self._solved = proxsuite.proxqp.QPSolverOutput.PROXQP_SOLVED
        self._started = False
        self._fallback: ClarabelProgram | None = None
        self.fallbacks = 0
        _LIVE.add(self)

    def release(self) -> None:
        """Free proxsuite's solver (at exit: one still referenced by a Drake diagram would otherwise make
        nanobind print leak warnings on stderr)."""
        self._qp = None

    def solve(self, d: QPData) -> tuple[np.ndarray, bool, str]:
        """The minimizer ``(n,)``, success, and the status (proxsuite's, or Clarabel's after a fallback)."""
        big = self.BIG
        args = (d.H, d.g, d.Aeq, d.beq, d.C, np.maximum(d.l, -big), np.minimum(d.u, big),
                np.maximum(d.lb, -big), np.minimum(d.ub, big))
        if self._started:
            self._qp.update(*args, update_preconditioner=True)
        else:  # (a warm start before a first solve crashes proxsuite 0.8.0: the first one is cold)
            self._qp.init(*args)
            self._started = True
        self._qp.solve()
        status = self._qp.results.info.status
        if status == self._solved:
            self._qp.settings.initial_guess = self._warm
            return np.array(self._qp.results.x), True, str(status)
        self.fallbacks += 1
        self._qp.settings.initial_guess = self._cold  # the next program starts afresh
        if self._fallback is None:
            self._fallback = ClarabelProgram(len(d.g), len(d.beq), len(d.l))
        return self._fallback.solve(d)


class ClarabelProgram:
    """The same program by Drake's ``MathematicalProgram`` and ``ClarabelSolver`` (an interior-point
    method), built once, its coefficients updated per solve: :class:`ProxQP`'s fallback and the tests'
    independent check of it."""

    def __init__(self, n: int, n_eq: int, n_in: int):
        from pydrake.solvers import ClarabelSolver, MathematicalProgram, SolverOptions

        self._prog = prog = MathematicalProgram()
        self._x = x = prog.NewContinuousVariables(n, "x")
        self._cost = prog.AddQuadraticCost(np.eye(n), np.zeros(n), x, is_convex=True).evaluator()
        self._eq = prog.AddLinearEqualityConstraint(np.zeros((n_eq, n)), np.zeros(n_eq), x).evaluator()
        self._in = prog.AddLinearConstraint(np.zeros((n_in, n)), np.full(n_in, -np.inf), np.full(n_in, np.inf),
                                            x).evaluator()
        self._box = prog.AddBoundingBoxConstraint(np.full(n, -np.inf), np.full(n, np.inf), x).evaluator()
        self._solver = ClarabelSolver()
        self._options = SolverOptions()
        # Clarabel's equilibration off: 2.17 -> 1.66 ms a program, the same solutions to 1e-8
        self._options.SetOption(ClarabelSolver.id(), "equilibrate_enable", False)

    def solve(self, d: QPData) -> tuple[np.ndarray, bool, str]:
        """The minimizer ``(n,)``, success, and Clarabel's status."""
        self._cost.UpdateCoefficients(d.H, d.g)
        self._eq.UpdateCoefficients(d.Aeq, d.beq)
        self._in.UpdateCoefficients(d.C, d.l, d.u)
        self._box.set_bounds(d.lb, d.ub)
        result = self._solver.Solve(self._prog, None, self._options)
        return result.GetSolution(self._x), result.is_success(), f"clarabel: {result.get_solution_result()}"


@dataclass
class FreePlantLayout:
    """What the stabilizer's programs need of the free plant, fixed for its life: the plant and one
    context of it, the soles' frames and corners ``(3, k)`` (m, sole frame), the sizes (``nq``, ``nv``,
    ``n_act`` actuators, ``nc = 2 k`` corners, ``nf = 3 nc`` forces, ``nx = nv + nf`` decision variables),
    the floating base's six velocity rows ``base_rows``, each actuator's velocity ``jv (n_act,)``, the tree
    joints' velocities in the reference's order ``joint_v (26,)``, each actuator's tree joint
    ``act_joint (n_act,)``, the effort limits ``(n_act,)`` N m and the tree joints' position limits
    ``lower_q, upper_q (26,)`` rad, and the robot's acceleration gains ``gains`` (its ``stand.stabilizer``)."""

    plant: Any
    ctx: Any
    world: Any
    frames: list
    corners: np.ndarray
    joint_idx: np.ndarray
    joint_v: np.ndarray
    jv: np.ndarray
    act_joint: np.ndarray
    base_rows: np.ndarray
    effort: np.ndarray
    lower_q: np.ndarray
    upper_q: np.ndarray
    nq: int
    nv: int
    n_act: int
    nc: int
    nf: int
    nx: int
    gains: dict

    @classmethod
    def of(cls, free) -> FreePlantLayout:
        """The layout of ``raico.plants.floating.FloatingRobot`` ``free`` (its plant without PD actuators)."""
        from raico.plants.floating import sole_corners_local

        corners = sole_corners_local(free.spec).T
        if len(free.soles) != 2:
            raise ValueError(f"the whole-body stabilizer holds two soles; this robot has {len(free.soles)}")
        plant = free.plant
        nv = plant.num_velocities()
        B = plant.MakeActuationMatrix()  # (nv, n_act) selection, gear ratio 1
        jv = np.array([plant.get_joint_actuator(i).joint().velocity_start() for i in plant.GetJointActuatorIndices()])
        frames = [plant.GetFrameByName(s) for s in free.soles]
        nc = corners.shape[1] * len(frames)
        return cls(plant=plant, ctx=plant.CreateDefaultContext(), world=plant.world_frame(), frames=frames,
                   corners=corners, joint_idx=free.joint_idx, joint_v=free.joint_vidx, jv=jv,
                   act_joint=np.array([list(free.joint_vidx).index(j) for j in jv]),
                   base_rows=np.flatnonzero(np.abs(B).sum(axis=1) == 0), effort=free.effort,
                   lower_q=plant.GetPositionLowerLimits()[free.joint_idx],
                   upper_q=plant.GetPositionUpperLimits()[free.joint_idx],
                   nq=plant.num_positions(), nv=nv, n_act=B.shape[1], nc=nc, nf=3 * nc, nx=nv + 3 * nc,
                   gains=dict(free.spec.stand.stabilizer))


def contact_rows(lay: FreePlantLayout) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The inequality rows every program shares, ``l <= C x <= u`` with ``C (n_act + 5 nc, nx)``: ``n_act``
    torque rows (zero here: each program writes its torque map into them), the friction pyramid (four
    faces per corner, ``<= 0``) and each sole's centre of pressure kept off its edges (every corner
    carries at least ``COP_SHARE`` of its sole's mean corner load, ``>= 0``, its lower bound set per
    program). Returns ``C``, ``l``, ``u`` and the number of friction rows."""
    nv, nc, nx, n_act = lay.nv, lay.nc, lay.nx, lay.n_act
    k = lay.corners.shape[1]  # corners per sole
    Fr = np.zeros((4 * nc, nx))
    Cp = np.zeros((nc, nx))
    for c in range(nc):
        i = nv + 3 * c
        for r, (a, b) in enumerate(((1, 0), (-1, 0), (0, 1), (0, -1))):
            Fr[4 * c + r, [i, i + 1, i + 2]] = (a, b, -MU)
        s0 = k * (c // k)  # the first corner of its sole
        Cp[c, nv + 3 * np.arange(s0, s0 + k) + 2] = -COP_SHARE / k
        Cp[c, nv + 3 * c + 2] += 1.0
    n_in = n_act + len(Fr) + nc
    C = np.zeros((n_in, nx))
    C[n_act:n_act + len(Fr)] = Fr
    C[n_act + len(Fr):] = Cp
    l_in, u_in = np.full(n_in, -np.inf), np.full(n_in, np.inf)
    u_in[n_act:n_act + len(Fr)] = 0.0
    return C, l_in, u_in, len(Fr)


def constant_hessian(lay: FreePlantLayout) -> np.ndarray:
    """The cost's constant Hessian ``(nx, nx)``: the joint task and the regularization of the
    accelerations and forces."""
    nv = lay.nv
    H0 = np.zeros((lay.nx, lay.nx))
    H0[:nv, :nv] = 2 * W_REG * np.eye(nv)
    H0[lay.joint_v, lay.joint_v] += 2 * W_JOINT
    H0[nv:, nv:] = 2 * W_FORCE * np.eye(lay.nf)
    return H0


class StabilizerProgram:
    """The stabilizer's programs (module docstring) along one plan: :meth:`program` builds the QP of one
    update at a time and state, :meth:`solve` solves it. It keeps what the updates share: the soles'
    reference poses and the support polygons (fixed at the first update), the single-support release
    time, and logs of the failed (``failed``: time s, status) and relaxed programs (``relaxed``: times s)
    and of the observer's estimates (``observed``: ``(n_act,)`` N m per update)."""

    def __init__(self, free, X_plan: np.ndarray, dt: float, X_task=None, frame_maps=(), swing=None):
        from pydrake.multibody.tree import JacobianWrtVariable

        self.kV = JacobianWrtVariable.kV
        self.lay = lay = FreePlantLayout.of(free)
        plant = lay.plant
        maps = [*frame_maps, *([swing] if swing is not None else [])]
        self.ref = Reference(free, X_plan, X_plan if X_task is None else X_task, dt, maps)
        # (frame, points (3, k) in it, rows kept) of each frame task
        self.tasks = [(plant.GetFrameByName(m.frame.name()), np.ascontiguousarray(m.points.T), m.rows) for m in maps]
        self.n_tasks = len(frame_maps)  # the swing sole's task (last) joins once the sole is released
        self.swing = swing
        self.released: list[float] = []  # the time the right sole's contact was released (single support)
        self.left_only: list = []  # (A, b) of the left sole shrunk by COG_MARGIN, and its unshrunk b
        self.support: list = []  # (A, b) of the support polygon shrunk by COG_MARGIN (world xy), at the first call
        self.sole_ref: list = []  # the soles' poses (R (3, 3), p (3,)) at the first update, laid flat on the ground
        self.failed: list = []  # (time s, the solver's status) of every failed program
        self.observed: list = []  # the observer's disturbance estimate (n_act,) N m per update (zeros without it)
        self.relaxed: list = []  # times (s) of the programs solved again without the joint-limit bounds
        self.C, self.l_in, self.u_in, self.n_fr = contact_rows(lay)
        self.fz = lay.nv + 3 * np.arange(lay.nc) + 2  # the normal forces' indices in x
        self.solver = ProxQP(lay.nx, len(lay.base_rows), len(self.l_in))
        self.H0 = constant_hessian(lay)
        self.w_cog, self.origin, self.inf_x = np.full(3, W_COG), np.zeros(3), np.full(lay.nx, np.inf)
        self.ones = np.ones(max([12, *(3 * len(m.points) for m in maps)]))  # task weights per row

    def _first_call(self, poses) -> None:
        """The soles' reference poses (at the first update, laid flat: roll and pitch 0, z 0) and the
        support polygons (both soles', the left sole's) shrunk by ``COG_MARGIN``."""
        from pydrake.math import RollPitchYaw
        from scipy.spatial import ConvexHull

        corners = self.lay.corners
        for X in poses:
            yaw = RollPitchYaw(X.rotation()).yaw_angle()
            self.sole_ref.append((RollPitchYaw(0.0, 0.0, yaw).ToRotationMatrix().matrix(),
                                  np.r_[X.translation()[:2], 0.0]))
        pts = np.vstack([(R @ corners)[:2].T + p[:2] for R, p in self.sole_ref])
        eqs = ConvexHull(pts).equations  # a . p + b <= 0 inside, |a| = 1
        self.support.extend([eqs[:, :2], -eqs[:, 2] - COG_MARGIN])
        R, p = self.sole_ref[0]
        eqs = ConvexHull((R @ corners)[:2].T + p[:2]).equations
        self.left_only.extend([eqs[:, :2], -eqs[:, 2] - COG_MARGIN, -eqs[:, 2]])

    def _observed_torque(self, M: np.ndarray, h: np.ndarray, v: np.ndarray, qj: np.ndarray, obs) -> np.ndarray:
        """The disturbance observer's estimate ``(n_act,)`` N m: the joint torque the model does not explain
        over the last period, ``M (v - v_prev)/dt + h - tau_c - u_prev`` at the joints, clamped at the
        effort limits; none for a joint within ``LIMIT_MARGIN_OBS`` of a limit (there the plant's limit
        force acts, not a disturbance), and zeros without ``obs = (v_prev, dt, tau_c, u_prev)``."""
        lay = self.lay
        w_hat = np.zeros(lay.n_act)
        if obs is not None and obs[1] > 0:
            v_prev, dt_obs, tau_c, u_prev = obs
            w_hat = np.clip((M @ ((v - v_prev) / dt_obs) + h - tau_c)[lay.jv] - u_prev, -lay.effort, lay.effort)
            near = (qj <= lay.lower_q + LIMIT_MARGIN_OBS) | (qj >= lay.upper_q - LIMIT_MARGIN_OBS)
            w_hat[near[lay.act_joint]] = 0.0
        return w_hat

    def _soles(self, poses) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The soles at the context's state: their spatial Jacobians ``Js (12, nv)`` (per sole: angular,
        translational, at its origin) and bias accelerations ``bs (12,)``, the corners' translational
        Jacobians ``Jc (nf, nv)``, the soles' pose errors from their references ``(12,)`` (rotation
        vector rad, position m) and the corners' heights ``zc (nc,)`` m."""
        lay, kV = self.lay, self.kV
        plant, ctx, world, origin, nv = lay.plant, lay.ctx, lay.world, self.origin, lay.nv
        Js = np.vstack([plant.CalcJacobianSpatialVelocity(ctx, kV, fr, origin, world, world)
                        for fr in lay.frames])  # (12, nv): per sole (angular, translational) at its origin
        bs = np.concatenate([plant.CalcBiasSpatialAcceleration(ctx, kV, fr, origin, world, world).get_coeffs()
                             for fr in lay.frames])
        # each corner's translational Jacobian from its sole's spatial one: v_c = v_o + w x r = Jv - [r]x Jw
        Jc = np.empty((lay.nf, nv))
        sole_err = np.empty(12)
        zc = np.empty(lay.nc)
        k = lay.corners.shape[1]  # corners per sole
        for s_, X in enumerate(poses):
            R, p = X.rotation().matrix(), X.translation()
            r = R @ lay.corners  # (3, k) world offsets of the corners
            zc[k * s_:k * s_ + k] = r[2] + p[2]
            Jw, Jv = Js[6 * s_:6 * s_ + 3], Js[6 * s_ + 3:6 * s_ + 6]
            rx, ry, rz = r[0][:, None], r[1][:, None], r[2][:, None]  # (k, 1) each
            Jc_s = Jc[3 * k * s_:3 * k * (s_ + 1)].reshape(k, 3, nv)  # (corner, xyz, nv), a view of Jc
            Jc_s[:, 0] = Jv[0] - (ry * Jw[2] - rz * Jw[1])
            Jc_s[:, 1] = Jv[1] - (rz * Jw[0] - rx * Jw[2])
            Jc_s[:, 2] = Jv[2] - (rx * Jw[1] - ry * Jw[0])
            R_ref, p_ref = self.sole_ref[s_]
            sole_err[6 * s_:6 * s_ + 3] = rotation_log(R @ R_ref.T)
            sole_err[6 * s_ + 3:6 * s_ + 6] = p - p_ref
        return Js, bs, Jc, sole_err, zc

    def _single_support(self, t: float, com: np.ndarray) -> bool:
        """Whether the right sole is released at time ``t`` s (single support), releasing it now if the
        executed CoG ``com (3,)`` m is ``RELEASE_MARGIN`` inside the left sole and ``t`` is past
        ``RELEASE_EARLIEST``."""
        if self.swing is not None and not self.released and t >= RELEASE_EARLIEST - 1e-9:
            A, _, b = self.left_only
            if np.min(b - A @ com[:2]) >= RELEASE_MARGIN:  # the CoG is over the left sole
                self.released.append(t)
        return bool(self.released)

    def _cog_reference(self, cog_ref: tuple, single: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The CoG reference ``(c, cdot, cddot)`` ``(3,)`` each (m, m/s, m/s^2) held inside the support
        polygon (the left sole's in single support): a planned CoG too near an edge is held at the
        margin, at rest in the plane; else its capture point ``c + cdot / omega`` is held inside by
        cutting the planned velocity."""
        c_r, cd_r, cdd_r = cog_ref
        polygon = (self.left_only[0], self.left_only[1]) if single else self.support
        c_xy = clamp_to_polygon(c_r[:2], *polygon)
        if np.any(c_xy != c_r[:2]):
            return np.r_[c_xy, c_r[2]], np.r_[0.0, 0.0, cd_r[2]], np.r_[0.0, 0.0, cdd_r[2]]
        omega = np.sqrt(9.81 / max(c_r[2], 0.05))
        xi = clamp_to_polygon(c_r[:2] + cd_r[:2] / omega, *polygon)
        if np.any(xi != c_r[:2] + cd_r[:2] / omega):
            cd_r = np.r_[omega * (xi - c_r[:2]), cd_r[2]]
            cdd_r = np.r_[0.0, 0.0, cdd_r[2]]
        return c_r, cd_r, cdd_r

    def _task_rows(self, v: np.ndarray, cog_rows: tuple, frame_refs: list, Js: np.ndarray, bs: np.ndarray,
                   sole_err: np.ndarray, single: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The acceleration tasks as one weighted least-squares ``||W^(1/2) (J vdot - a)||^2``: ``J (k, nv)``,
        ``a (k,)``, ``w (k,)`` over the CoG's rows ``cog_rows = (J, a, w)``, the frame tasks' points
        (the swing sole's once released) and the held soles (a heavy cost, not a constraint: a sole the
        compliant ground has let rise a little must not make the program infeasible; released: the left
        sole alone)."""
        lay, kV = self.lay, self.kV
        plant, ctx, world = lay.plant, lay.ctx, lay.world
        gains = lay.gains
        rows_J, rows_a, rows_w = [cog_rows[0]], [cog_rows[1]], [cog_rows[2]]
        tasks = self.tasks[:len(self.tasks) if single else self.n_tasks]
        for (fr, pts, rows), (p_r, pd_r, pdd_r) in zip(tasks, frame_refs):
            Jp = plant.CalcJacobianTranslationalVelocity(ctx, kV, fr, pts, world, world)[rows]
            bp = plant.CalcBiasTranslationalAcceleration(ctx, kV, fr, pts, world, world).T.reshape(-1)[rows]
            p = plant.CalcPointsPositions(ctx, fr, pts, world).T.reshape(-1)[rows]
            rows_J.append(Jp)
            rows_a.append(pdd_r + gains["kp_frame"] * (p_r - p) + gains["kd_frame"] * (pd_r - Jp @ v) - bp)
            rows_w.append(W_FRAME * self.ones[:len(Jp)])
        held = slice(0, 6) if single else slice(0, 12)
        Jh = Js[held]
        rows_J.append(Jh)
        rows_a.append(-bs[held] - gains["kd_contact"] * (Jh @ v) - gains["kp_contact"] * sole_err[held])
        rows_w.append(W_CONTACT * self.ones[:Jh.shape[0]])
        return np.vstack(rows_J), np.concatenate(rows_a), np.concatenate(rows_w)

    def _cost(self, J: np.ndarray, a: np.ndarray, w: np.ndarray, a_joint: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The cost ``0.5 x'Hx + g'x``: ``H (nx, nx)``, ``g (nx,)`` of the weighted acceleration tasks
        ``(J, a, w)``, the joint task towards ``a_joint (26,)`` rad/s^2 and the regularization."""
        nv = self.lay.nv
        H = self.H0.copy()  # the constant part: joints, regularization
        g = np.zeros(self.lay.nx)
        Jw_ = J * (2 * w)[:, None]
        H[:nv, :nv] += J.T @ Jw_
        g[:nv] = -Jw_.T @ a
        g[self.lay.joint_v] -= 2 * W_JOINT * a_joint
        return H, g

    def _bounds(self, M: np.ndarray, h: np.ndarray, Jc: np.ndarray, w_hat: np.ndarray, zc: np.ndarray,
                qj: np.ndarray, vj: np.ndarray, single: bool) -> tuple:
        """The constraints: the floating base's dynamics ``Aeq (6, nx)``; the rows ``C`` with the torque
        map ``At (n_act, nx)`` (``u = At x + h_j``, ``h_j (n_act,)`` N m compensating the observed
        disturbance) within the effort limits ``l, u``; the box ``lb, ub (nx,)``: a corner more than
        ``CORNER_UP`` above the ground (or of the released right sole) carries no force, and the joint
        position limits as acceleration bounds. Returns ``(Aeq, C, l, u, lb, ub, At, h_j)``."""
        lay = self.lay
        n_act, jv, effort, n_fr = lay.n_act, lay.jv, lay.effort, self.n_fr
        Aeq = np.hstack([M[lay.base_rows], -Jc[:, lay.base_rows].T])
        At = np.hstack([M[jv], -Jc[:, jv].T])  # torques u = B^T (M vdot + h - Jc^T f)
        Cm = self.C.copy()
        Cm[:n_act] = At
        l, u = self.l_in.copy(), self.u_in.copy()
        hj = h[jv] - w_hat  # the command compensates the observed disturbance: u = At x + h_j - w_hat
        l[:n_act], u[:n_act] = -effort - hj, effort - hj
        # a corner more than CORNER_UP above the ground carries no force (the ground cannot pull it back)
        up = zc > (CORNER_UP if CORNER_UP is not None else np.inf)
        if single:
            up[self.lay.corners.shape[1]:] = True   # the released right sole carries nothing
        l[n_act + n_fr:] = np.where(up, -np.inf, 0.0)  # a lifted corner: no share of its sole's load
        lb, ub = -self.inf_x, self.inf_x.copy()
        lb[self.fz], ub[self.fz] = FZ_MIN * ~up, np.where(up, 0.0, FZ_MAX)
        if LIMIT_MARGIN is not None:  # joint position limits as acceleration bounds
            a_hi = KP_LIMIT * (lay.upper_q - LIMIT_MARGIN - qj) - KD_LIMIT * vj
            a_lo = KP_LIMIT * (lay.lower_q + LIMIT_MARGIN - qj) - KD_LIMIT * vj
            lb[lay.joint_v], ub[lay.joint_v] = np.minimum(a_lo, a_hi), np.maximum(a_lo, a_hi)
        return Aeq, Cm, l, u, lb, ub, At, hj

    def program(self, t: float, q: np.ndarray, v: np.ndarray, obs=None) -> tuple[QPData, tuple]:
        """The program of one update at time ``t`` s and state ``(q (nq,), v (nv,))``, and the torque map
        ``(At (n_act, nx), h_j (n_act,))`` (``u = At x + h_j``). ``obs``: the disturbance observer's data
        ``(v_prev, dt, tau_contact, u_prev)`` (the last update's velocities and command, the time since,
        the plant's generalized contact forces)."""
        lay, kV = self.lay, self.kV
        plant, ctx, world = lay.plant, lay.ctx, lay.world
        plant.SetPositions(ctx, q)
        plant.SetVelocities(ctx, v)
        M = plant.CalcMassMatrix(ctx)
        h = plant.CalcBiasTerm(ctx) - plant.CalcGravityGeneralizedForces(ctx)
        qj, vj = q[lay.joint_idx], v[lay.joint_v]
        w_hat = self._observed_torque(M, h, v, qj, obs)
        self.observed.append(w_hat)
        poses = [fr.CalcPoseInWorld(ctx) for fr in lay.frames]
        if not self.sole_ref:
            self._first_call(poses)
        Js, bs, Jc, sole_err, zc = self._soles(poses)
        Jcom = plant.CalcJacobianCenterOfMassTranslationalVelocity(ctx, kV, world, world)
        bcom = plant.CalcBiasCenterOfMassTranslationalAcceleration(ctx, kV, world, world)
        com = plant.CalcCenterOfMassPositionInWorld(ctx)
        (q_r, v_r, a_r), cog_ref, frame_refs = self.ref.at(t)
        single = self._single_support(t, com)
        c_r, cd_r, cdd_r = self._cog_reference(cog_ref, single)
        gains = lay.gains
        a_joint = a_r + gains["kp"] * (q_r - qj) + gains["kd"] * (v_r - vj)
        a_com = cdd_r + gains["kp_cog"] * (c_r - com) + gains["kd_cog"] * (cd_r - Jcom @ v)
        J, a, w = self._task_rows(v, (Jcom, a_com - bcom, self.w_cog), frame_refs, Js, bs, sole_err, single)
        H, g = self._cost(J, a, w, a_joint)
        Aeq, Cm, l, u, lb, ub, At, hj = self._bounds(M, h, Jc, w_hat, zc, qj, vj, single)
        return QPData(H, g, Aeq, -h[lay.base_rows], Cm, l, u, lb, ub), (At, hj)

    def solve(self, t: float, q: np.ndarray, v: np.ndarray, obs=None) -> tuple[np.ndarray, np.ndarray, bool]:
        """One QP at time ``t`` and state ``(q, v)`` (``obs``: the observer's data, see ``program``): actuation
        ``(n_act,)`` N m, corner forces ``(nc, 3)`` N, success."""
        lay = self.lay
        joint_v = lay.joint_v
        d, (At, hj) = self.program(t, q, v, obs)
        xs, ok, status = self.solver.solve(d)
        if not ok and LIMIT_MARGIN is not None:
            # a joint-limit bound that asks for an acceleration (a joint moving towards its limit) may ask more than
            # the joint's torque can give (a hand whose 0.29 N m the noise saturates): the program again without
            # such bounds (the limits then left to the plant's), without any if that does not suffice
            self.relaxed.append(t)
            lb, ub = d.lb[joint_v], d.ub[joint_v]
            asking = (lb > 0) | (ub < 0)
            d.lb[joint_v], d.ub[joint_v] = np.where(asking, -np.inf, lb), np.where(asking, np.inf, ub)
            xs, ok, status = self.solver.solve(d)
            if not ok:
                d.lb[joint_v], d.ub[joint_v] = -np.inf, np.inf
                xs, ok, status = self.solver.solve(d)
        if not ok:
            self.failed.append((t, status))
            return np.zeros(lay.n_act), np.full((lay.nc, 3), np.nan), False
        u = At @ xs + hj
        return np.clip(u, -lay.effort, lay.effort), xs[lay.nv:].reshape(lay.nc, 3), True


def _leaf_system(program: StabilizerProgram, period: float):
    """The Drake ``LeafSystem`` around ``program``: one program every ``period`` s (discrete state: the held
    command ``(n_act,)`` N m), its output the command plus the torque noise of its ``w`` input, clamped."""
    from pydrake.systems.framework import BasicVector, LeafSystem

    lay = program.lay
    nq, nv, n_act, effort = lay.nq, lay.nv, lay.n_act, lay.effort

    class Stabilizer(LeafSystem):
        """Task-space inverse dynamics (module docstring), one QP per ``period``."""

        def __init__(self):
            super().__init__()
            self.log: list[tuple[float, float, np.ndarray, bool]] = []
            # (update time s, the held command (n_act,) N m from then on, before the noise): every update
            self.commands: list[tuple[float, np.ndarray]] = []
            self.failures = 0
            self.state_port = self.DeclareVectorInputPort("x", nq + nv)
            # torque noise added to the held command (execution's process noise), the sum clamped at the effort
            # limits as an actuator would (unconnected: none)
            self.noise_port = self.DeclareVectorInputPort("w", n_act)
            # the generalized contact forces (nv,) of the plant's last step (the feet's force sensors), for the
            # disturbance observer (unconnected: no observer)
            self.contact_port = self.DeclareVectorInputPort("tau_contact", nv)
            self.previous = None  # (time, v, command) of the last update, for the observer
            self.limp = None  # the time the robot was found fallen (it then goes limp), else None
            self.DeclareDiscreteState(n_act)
            self.DeclareVectorOutputPort("u", BasicVector(n_act), self._output,
                                         {self.xd_ticket(), self.noise_port.ticket()})
            self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
            self.last_f = np.zeros((lay.nc, 3))
            self.released = program.released   # [time of the right sole's release] in single support, else []

        def _output(self, context, output):
            u = context.get_discrete_state_vector().CopyToVector()
            if self.noise_port.HasValue(context):
                u = np.clip(u + self.noise_port.Eval(context), -effort, effort)
            output.SetFromVector(u)

        def _fallen(self, t: float, xs: np.ndarray) -> bool:
            """Whether the robot is (or was) found fallen: the torso more than ``LIMP_TILT`` from upright."""
            qw, qx, qy, qz = xs[:4]  # the floating base's (the torso's) orientation
            if self.limp is not None or 1.0 - 2.0 * (qx * qx + qy * qy) < np.cos(LIMP_TILT):
                if self.limp is None:
                    self.limp = t
                return True
            return False

        def _update(self, context, discrete_state):
            t0 = time.perf_counter()
            xs = self.state_port.Eval(context)
            t, v = context.get_time(), xs[nq:]
            if self._fallen(t, xs):  # limp: zero torques, no more programs
                discrete_state.get_mutable_vector().SetFromVector(np.zeros(n_act))
                self.commands.append((t, np.zeros(n_act)))
                return
            obs = None
            if DISTURBANCE_OBSERVER and self.previous is not None and self.contact_port.HasValue(context):
                t_prev, v_prev, u_prev = self.previous
                obs = (v_prev, t - t_prev, self.contact_port.Eval(context), u_prev)
            u, f, ok = program.solve(t, xs[:nq], v, obs)
            if ok:
                discrete_state.get_mutable_vector().SetFromVector(u)
                self.last_f = f
            else:
                self.failures += 1
            self.previous = (t, v.copy(), context.get_discrete_state_vector().CopyToVector() if not ok else u)
            self.log.append((t, time.perf_counter() - t0, f, ok))
            self.commands.append((t, discrete_state.get_vector().CopyToVector()))

    return Stabilizer()


def make_stabilizer(free, X_plan: np.ndarray, dt: float, period: float | None = None, X_task=None,
                    frame_maps=(), swing=None):
    """The stabilizer as a Drake ``LeafSystem``: input the free plant's state ``(nq + nv,)``, output
    the actuation ``(26,)`` N m held for ``period`` s (discrete state, periodic update) plus the torque
    noise of its second input (if connected or fixed), clamped at the effort limits. It tracks
    the joints of ``X_plan (K, 2 n_q)``, and the CoG and the frame points of ``frame_maps``
    (``raico.plants.taskmaps.FramePoints`` of the fixed-base robot: the plan's via-point frames, tracked
    along the whole plan) of ``X_task`` (default ``X_plan``); ``swing``: the right sole's corners
    (``FramePoints``) tracked once that sole is released (single support), else None. Its
    attributes ``log`` (per update: time, solve seconds, corner forces ``(nc, 3)`` N, success) and
    ``failures`` (updates whose QP failed: the previous torque is held) are filled as it runs; its
    ``program(t, q, v)`` gives the :class:`QPData` of one update (for the tests), ``solve``, ``failed``,
    ``relaxed``, ``observed``, ``qp`` and ``reference`` (its :class:`Reference`) are :class:`StabilizerProgram`'s."""
    period = CONTROL_PERIOD if period is None else period
    program = StabilizerProgram(free, X_plan, dt, X_task, frame_maps, swing)
    system = _leaf_system(program, period)
    system.solve = program.solve
    system.program = program.program
    system.failed = program.failed
    system.relaxed = program.relaxed
    system.observed = program.observed
    system.qp = program.solver
    system.reference = program.ref
    return system
