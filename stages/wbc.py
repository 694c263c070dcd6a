"""A whole-body stabilizer for the free-standing Nao: task-space inverse dynamics.

Every ``CONTROL_PERIOD`` one quadratic program is solved by ``proxsuite``'s dense PROXQP, warm-started
from the previous step (:class:`ProxQP`; Clarabel, through Drake's ``MathematicalProgram``, takes the
rare program it does not solve within its iteration cap). Decision variables
``x = (vdot (nv,), f (8, 3))``: the free plant's generalized accelerations (floating base included)
and the ground forces at the eight sole corners (world frame). The joint torques are an affine
function of ``x`` through the equations of motion (not variables of their own: 26 fewer)::

    M vdot + C(q, v) v - tau_g(q) = B u + sum_c J_c^T f_c

Constraints (hard):

- the floating base's six rows of the equations of motion: ``M_b vdot + h_b = J_b^T f``;
- torques ``u = B^T (M vdot + h - J^T f)`` within the model's effort limits;
- each corner force unilateral inside a linearized friction cone (four faces, ``|f_x|, |f_y| <= MU f_z``,
  ``MU`` 0.5 below the simulated 0.8), at most ``FZ_MAX``; a corner more than ``CORNER_UP`` above the
  ground carries none;
- every loaded corner carries at least ``COP_SHARE`` of its sole's mean corner load (each sole's
  centre of pressure kept off its edges);
- joint position limits as acceleration bounds: ``vdot_j <= KP_LIMIT (q_max - LIMIT_MARGIN - q_j) -
  KD_LIMIT v_j`` and the mirror bound at the lower limit (every joint is kept ``LIMIT_MARGIN`` inside
  its range, also where the reference lies at the limit: the hands, closed at 0, are held 0.02 rad open).

Cost (weight times squared acceleration error):

- soles ``W_CONTACT``: both soles held (every Nao task keeps both feet down; single support: the right
  one until its release): each sole's spatial acceleration ``-KP_CONTACT e - KD_CONTACT V`` towards its pose at the start laid flat;
- CoG ``W_COG``: ``cddot = cddot_r + KP_COG (c_r - c) + KD_COG (cdot_r - cdot)``; the reference is the
  CoG of the joint reference (fixed-base model, left sole at the world origin as on the free robot),
  held ``COG_MARGIN`` inside the feet's support polygon (:func:`clamp_to_polygon`) and its capture point
  ``c + cdot / omega`` too (the reference velocity cut);
- via-point frames ``W_FRAME`` (the hand of the reach task): their points along the plan as made;
- joints ``W_JOINT``: ``vdot_j = a_r + KP (q_r - q) + KD (v_r - v)`` on the 26 tree joints (the
  reference: the plan, shifted by the start-state projection when the start is ``standing``;
  positions interpolated within a planning step, the step's velocity ``v_{k+1}`` and acceleration
  ``(v_{k+1} - v_k) / dt``);
- regularization ``W_REG |vdot|^2 + W_FORCE |f|^2``.

Safeguards and modes:

- ``proxsuite``'s portable build (:func:`portable_proxsuite`: bit-for-bit repeatable executions); a
  program it does not solve within its iteration cap goes to Clarabel (``wbc_qp_fallbacks``); one
  no solver solves is solved again without the joint-limit bounds that ask for an acceleration
  (``wbc_qp_relaxed``); one that still fails holds the previous torque (``wbc_qp_failures``).
- A disturbance observer (``DISTURBANCE_OBSERVER``): the joint torque the model does not explain
  over the last period, ``w = [M (v - v_prev) / dt + h - tau_c]_joints - u_prev`` (``tau_c``: the
  plant's generalized contact forces of its last step; none for a joint within ``LIMIT_MARGIN_OBS``
  of a limit), clamped at the effort limits and compensated by the next command
  (``u = At x + h_j - w``, the torque bounds shifted by it).
- A fallen robot (torso more than ``LIMP_TILT`` from upright) goes limp: zero torques, no more
  programs (``wbc_limp_time``).
- Single support (a ``--balance single`` plan, ``swing``): the right sole is released (its corners
  carry no force, it is no longer held) once the executed CoG's ground projection is
  ``RELEASE_MARGIN`` inside the left sole, not before ``RELEASE_EARLIEST``; from then on the CoG
  reference is clamped to the left sole's polygon and the right sole's corners track the plan as
  made (the frame task's weight and gains).

Why each weight, gain, bound and solver setting is what it is (measured): ``docs/stabilizer.md``.
"""

from __future__ import annotations

import atexit
import time
import weakref
from dataclasses import dataclass

import numpy as np

CONTROL_PERIOD = 4e-3  # s, one QP per period (zero-order hold in between)
KP, KD = 100.0, 20.0  # 1/s^2, 1/s: joint acceleration PD around the plan
KP_COG, KD_COG = 50.0, 14.0  # 1/s^2, 1/s: CoG acceleration PD around the planned CoG
KP_CONTACT, KD_CONTACT = 100.0, 20.0  # 1/s^2, 1/s: sole pose and velocity feedback in the contact constraint
W_JOINT, W_COG, W_FRAME, W_CONTACT, W_REG, W_FORCE = 1.0, 1000.0, 1000.0, 1000.0, 1e-4, 1e-5
KP_FRAME, KD_FRAME = 100.0, 20.0  # 1/s^2, 1/s: via-point frames (the hand) around the plan
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
        self.Q, self.V, self.A = Q @ P.T, V @ P.T, A @ P.T
        self.c, self.cd, self.cdd = plan_cog(fixed, X_joint if COG_FROM_JOINT_PLAN else X_task, dt)
        self.frames = [plan_points(m, X_task, dt) for m in frame_maps]

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
        self._fallback = None
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


def make_stabilizer(free, X_plan: np.ndarray, dt: float, period: float | None = None, X_task=None,
                    frame_maps=(), swing=None):
    """The stabilizer as a Drake ``LeafSystem``: input the free plant's state ``(nq + nv,)``, output
    the actuation ``(26,)`` N m held for ``period`` s (discrete state, periodic update) plus the torque
    noise of its second input (if connected or fixed), clamped at the effort limits. It tracks
    the joints of ``X_plan (K, 2 n_q)``, and the CoG and the frame points of ``frame_maps``
    (``plants.taskmaps.FramePoints`` of the fixed-base robot: the plan's via-point frames, tracked
    along the whole plan) of ``X_task`` (default ``X_plan``). Its
    attributes ``log`` (per update: time, solve seconds, corner forces ``(8, 3)`` N, success) and
    ``failures`` (updates whose QP failed: the previous torque is held) are filled as it runs; its
    ``program(t, q, v)`` gives the :class:`QPData` of one update (for the tests)."""
    from pydrake.multibody.tree import JacobianWrtVariable
    from pydrake.systems.framework import BasicVector, LeafSystem

    from plants.free_nao import SOLES, sole_corners_local

    period = CONTROL_PERIOD if period is None else period
    plant = free.plant
    kV = JacobianWrtVariable.kV
    nq, nv = plant.num_positions(), plant.num_velocities()
    B = plant.MakeActuationMatrix()  # (nv, n_act) selection, gear ratio 1
    n_act = B.shape[1]
    base_rows = np.flatnonzero(np.abs(B).sum(axis=1) == 0)  # the floating base's six velocities
    jv = np.array([plant.get_joint_actuator(i).joint().velocity_start() for i in plant.GetJointActuatorIndices()])
    # tree joints in the reference's order (the fixed plant's velocity order) -> free velocity index
    joint_v = free.joint_vidx
    effort = free.effort
    ctx = plant.CreateDefaultContext()
    world = plant.world_frame()
    frames = [plant.GetFrameByName(s) for s in SOLES]
    corners = sole_corners_local().T  # (3, 4)
    nc = 4 * len(frames)
    nf = 3 * nc
    nx = nv + nf
    maps = [*frame_maps, *([swing] if swing is not None else [])]
    ref = Reference(free, X_plan, X_plan if X_task is None else X_task, dt, maps)
    tasks = [(plant.GetFrameByName(m.frame.name()), np.ascontiguousarray(m.points.T), m.rows) for m in maps]
    n_tasks = len(frame_maps)  # the swing sole's task (last) joins once the sole is released
    released: list[float] = []  # the time the right sole's contact was released (single support)
    left_only: list = []  # (A, b) of the left sole shrunk by COG_MARGIN, and its unshrunk b
    # constant rows: the friction pyramid (four faces per corner, <= 0) and each sole's centre of pressure kept
    # off its edges (every corner carries at least COP_SHARE of its sole's mean corner load, >= 0)
    Fr = np.zeros((4 * nc, nx))
    Cp = np.zeros((nc, nx))
    for c in range(nc):
        i = nv + 3 * c
        for r, (a, b) in enumerate(((1, 0), (-1, 0), (0, 1), (0, -1))):
            Fr[4 * c + r, [i, i + 1, i + 2]] = (a, b, -MU)
        s0 = 4 * (c // 4)
        Cp[c, nv + 3 * np.arange(s0, s0 + 4) + 2] = -COP_SHARE / 4
        Cp[c, nv + 3 * c + 2] += 1.0
    n_eq, n_in = len(base_rows), n_act + len(Fr) + nc
    C = np.zeros((n_in, nx))
    C[n_act:n_act + len(Fr)] = Fr
    C[n_act + len(Fr):] = Cp
    l_in, u_in = np.full(n_in, -np.inf), np.full(n_in, np.inf)
    u_in[n_act:n_act + len(Fr)] = 0.0
    fz = nv + 3 * np.arange(nc) + 2  # the normal forces' indices in x
    lower_q = plant.GetPositionLowerLimits()[free.joint_idx]
    upper_q = plant.GetPositionUpperLimits()[free.joint_idx]
    solver = ProxQP(nx, n_eq, n_in)
    H0 = np.zeros((nx, nx))  # the cost's constant Hessian: joint task, regularization of accelerations and forces
    H0[:nv, :nv] = 2 * W_REG * np.eye(nv)
    H0[joint_v, joint_v] += 2 * W_JOINT
    H0[nv:, nv:] = 2 * W_FORCE * np.eye(nf)
    w_cog, origin, inf_x = np.full(3, W_COG), np.zeros(3), np.full(nx, np.inf)
    ones = np.ones(max([12, *(3 * len(m.points) for m in maps)]))  # task weights per row

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
            self.last_f = np.zeros((nc, 3))
            self.released = released   # [time of the right sole's release] in single support, else []

        def _output(self, context, output):
            u = context.get_discrete_state_vector().CopyToVector()
            if self.noise_port.HasValue(context):
                u = np.clip(u + self.noise_port.Eval(context), -effort, effort)
            output.SetFromVector(u)

        def _update(self, context, discrete_state):
            t0 = time.perf_counter()
            xs = self.state_port.Eval(context)
            t, v = context.get_time(), xs[nq:]
            qw, qx, qy, qz = xs[:4]  # the floating base's (the torso's) orientation
            if self.limp is not None or 1.0 - 2.0 * (qx * qx + qy * qy) < np.cos(LIMP_TILT):
                # fallen: the torso more than LIMP_TILT from upright; the robot goes limp (no more programs)
                if self.limp is None:
                    self.limp = t
                discrete_state.get_mutable_vector().SetFromVector(np.zeros(n_act))
                self.commands.append((t, np.zeros(n_act)))
                return
            obs = None
            if DISTURBANCE_OBSERVER and self.previous is not None and self.contact_port.HasValue(context):
                t_prev, v_prev, u_prev = self.previous
                obs = (v_prev, t - t_prev, self.contact_port.Eval(context), u_prev)
            u, f, ok = solve(t, xs[:nq], v, obs)
            if ok:
                discrete_state.get_mutable_vector().SetFromVector(u)
                self.last_f = f
            else:
                self.failures += 1
            self.previous = (t, v.copy(), context.get_discrete_state_vector().CopyToVector() if not ok else u)
            self.log.append((t, time.perf_counter() - t0, f, ok))
            self.commands.append((t, discrete_state.get_vector().CopyToVector()))

    failed: list = []  # (time s, the solver's status) of every failed program
    observed: list = []  # the observer's disturbance estimate (n_act,) N m per update (zeros without it)
    # each actuator's joint in the order of free.joint_idx (the tree joints' positions)
    act_joint = np.array([list(free.joint_vidx).index(j) for j in jv])
    relaxed: list = []  # times (s) of the programs solved again without the joint-limit bounds
    support: list = []  # (A, b) of the support polygon shrunk by COG_MARGIN (world xy), at the first call
    sole_ref: list = []  # the soles' poses (R (3, 3), p (3,)) at the first update, laid flat on the ground

    def first_call(poses) -> None:
        """The soles' reference poses (at the first update, laid flat: roll and pitch 0, z 0) and the
        support polygons (both soles', the left sole's) shrunk by ``COG_MARGIN``."""
        from pydrake.math import RollPitchYaw
        from scipy.spatial import ConvexHull

        for X in poses:
            yaw = RollPitchYaw(X.rotation()).yaw_angle()
            sole_ref.append((RollPitchYaw(0.0, 0.0, yaw).ToRotationMatrix().matrix(),
                             np.r_[X.translation()[:2], 0.0]))
        pts = np.vstack([(R @ corners)[:2].T + p[:2] for R, p in sole_ref])
        eqs = ConvexHull(pts).equations  # a . p + b <= 0 inside, |a| = 1
        support.extend([eqs[:, :2], -eqs[:, 2] - COG_MARGIN])
        R, p = sole_ref[0]
        eqs = ConvexHull((R @ corners)[:2].T + p[:2]).equations
        left_only.extend([eqs[:, :2], -eqs[:, 2] - COG_MARGIN, -eqs[:, 2]])

    def program(t: float, q: np.ndarray, v: np.ndarray, obs=None) -> tuple[QPData, np.ndarray]:
        """The program of one update at time ``t`` and state ``(q, v)``, and the torque map ``(At, h_j)``
        (``u = At x + h_j``). ``obs``: the disturbance observer's data ``(v_prev, dt, tau_contact, u_prev)``
        (the last update's velocities and command, the time since, the plant's generalized contact forces)."""
        plant.SetPositions(ctx, q)
        plant.SetVelocities(ctx, v)
        M = plant.CalcMassMatrix(ctx)
        h = plant.CalcBiasTerm(ctx) - plant.CalcGravityGeneralizedForces(ctx)
        qj, vj = q[free.joint_idx], v[joint_v]
        w_hat = np.zeros(n_act)
        if obs is not None and obs[1] > 0:
            # the joint torque the model does not explain over the last period: M (v - v_prev)/dt + h - tau_c - u_prev;
            # none for a joint within LIMIT_MARGIN of a limit (there the plant's limit force acts, not a disturbance)
            v_prev, dt_obs, tau_c, u_prev = obs
            w_hat = np.clip((M @ ((v - v_prev) / dt_obs) + h - tau_c)[jv] - u_prev, -effort, effort)
            near = (qj <= lower_q + LIMIT_MARGIN_OBS) | (qj >= upper_q - LIMIT_MARGIN_OBS)
            w_hat[near[act_joint]] = 0.0
        observed.append(w_hat)
        poses = [fr.CalcPoseInWorld(ctx) for fr in frames]
        if not sole_ref:
            first_call(poses)
        Js = np.vstack([plant.CalcJacobianSpatialVelocity(ctx, kV, fr, origin, world, world)
                        for fr in frames])  # (12, nv): per sole (angular, translational) at its origin
        bs = np.concatenate([plant.CalcBiasSpatialAcceleration(ctx, kV, fr, origin, world, world).get_coeffs()
                             for fr in frames])
        # each corner's translational Jacobian from its sole's spatial one: v_c = v_o + w x r = Jv - [r]x Jw
        Jc = np.empty((nf, nv))
        sole_err = np.empty(12)
        zc = np.empty(nc)
        for s_, X in enumerate(poses):
            R, p = X.rotation().matrix(), X.translation()
            r = R @ corners  # (3, 4) world offsets of the corners
            zc[4 * s_:4 * s_ + 4] = r[2] + p[2]
            Jw, Jv = Js[6 * s_:6 * s_ + 3], Js[6 * s_ + 3:6 * s_ + 6]
            rx, ry, rz = r[0][:, None], r[1][:, None], r[2][:, None]  # (4, 1) each
            Jc_s = Jc[12 * s_:12 * s_ + 12].reshape(4, 3, nv)          # (corner, xyz, nv), a view of Jc
            Jc_s[:, 0] = Jv[0] - (ry * Jw[2] - rz * Jw[1])
            Jc_s[:, 1] = Jv[1] - (rz * Jw[0] - rx * Jw[2])
            Jc_s[:, 2] = Jv[2] - (rx * Jw[1] - ry * Jw[0])
            R_ref, p_ref = sole_ref[s_]
            sole_err[6 * s_:6 * s_ + 3] = rotation_log(R @ R_ref.T)
            sole_err[6 * s_ + 3:6 * s_ + 6] = p - p_ref
        Jcom = plant.CalcJacobianCenterOfMassTranslationalVelocity(ctx, kV, world, world)
        bcom = plant.CalcBiasCenterOfMassTranslationalAcceleration(ctx, kV, world, world)
        com = plant.CalcCenterOfMassPositionInWorld(ctx)
        (q_r, v_r, a_r), (c_r, cd_r, cdd_r), frame_refs = ref.at(t)
        if swing is not None and not released and t >= RELEASE_EARLIEST - 1e-9:
            if np.min(left_only[2] - left_only[0] @ com[:2]) >= RELEASE_MARGIN:  # the CoG is over the left sole
                released.append(t)
        single = bool(released)
        polygon = (left_only[0], left_only[1]) if single else support
        c_xy = clamp_to_polygon(c_r[:2], *polygon)
        if np.any(c_xy != c_r[:2]):  # the planned CoG too near an edge of the feet: held at the margin
            c_r, cd_r, cdd_r = np.r_[c_xy, c_r[2]], np.r_[0.0, 0.0, cd_r[2]], np.r_[0.0, 0.0, cdd_r[2]]
        else:  # its capture point (c + cdot / omega) too: the planned CoG velocity cut so that it stays inside
            omega = np.sqrt(9.81 / max(c_r[2], 0.05))
            xi = clamp_to_polygon(c_r[:2] + cd_r[:2] / omega, *polygon)
            if np.any(xi != c_r[:2] + cd_r[:2] / omega):
                cd_r = np.r_[omega * (xi - c_r[:2]), cd_r[2]]
                cdd_r = np.r_[0.0, 0.0, cdd_r[2]]
        a_joint = a_r + KP * (q_r - qj) + KD * (v_r - vj)
        a_com = cdd_r + KP_COG * (c_r - com) + KD_COG * (cd_r - Jcom @ v)
        # cost 0.5 x'Hx + g'x: the acceleration tasks as one weighted least-squares ||W^(1/2) (J vdot - a)||^2
        rows_J, rows_a, rows_w = [Jcom], [a_com - bcom], [w_cog]
        for (fr, pts, rows), (p_r, pd_r, pdd_r) in zip(tasks[:len(tasks) if single else n_tasks], frame_refs):
            Jp = plant.CalcJacobianTranslationalVelocity(ctx, kV, fr, pts, world, world)[rows]
            bp = plant.CalcBiasTranslationalAcceleration(ctx, kV, fr, pts, world, world).T.reshape(-1)[rows]
            p = plant.CalcPointsPositions(ctx, fr, pts, world).T.reshape(-1)[rows]
            rows_J.append(Jp)
            rows_a.append(pdd_r + KP_FRAME * (p_r - p) + KD_FRAME * (pd_r - Jp @ v) - bp)
            rows_w.append(W_FRAME * ones[:len(Jp)])
        # the soles held (a heavy cost, not a constraint: a sole the compliant ground has let rise a
        # little must not make the program infeasible); released: the left sole alone
        held = slice(0, 6) if single else slice(0, 12)
        Jh = Js[held]
        rows_J.append(Jh)
        rows_a.append(-bs[held] - KD_CONTACT * (Jh @ v) - KP_CONTACT * sole_err[held])
        rows_w.append(W_CONTACT * ones[:Jh.shape[0]])
        J, a, w = np.vstack(rows_J), np.concatenate(rows_a), np.concatenate(rows_w)
        H = H0.copy()  # the constant part: joints, regularization
        g = np.zeros(nx)
        Jw_ = J * (2 * w)[:, None]
        H[:nv, :nv] += J.T @ Jw_
        g[:nv] = -Jw_.T @ a
        g[joint_v] -= 2 * W_JOINT * a_joint
        # equality: the floating base's dynamics (its six rows of the equations of motion)
        Aeq = np.hstack([M[base_rows], -Jc[:, base_rows].T])
        # torques: u = B^T (M vdot + h - Jc^T f) within the effort limits
        At = np.hstack([M[jv], -Jc[:, jv].T])
        Cm = C.copy()
        Cm[:n_act] = At
        l, u = l_in.copy(), u_in.copy()
        hj = h[jv] - w_hat  # the command compensates the observed disturbance: u = At x + h_j - w_hat
        l[:n_act], u[:n_act] = -effort - hj, effort - hj
        # a corner more than CORNER_UP above the ground carries no force (the ground cannot pull it back)
        up = zc > (CORNER_UP if CORNER_UP is not None else np.inf)
        if single:
            up[4:] = True   # the released right sole carries nothing
        l[n_act + len(Fr):] = np.where(up, -np.inf, 0.0)  # a lifted corner: no share of its sole's load
        lb, ub = -inf_x, inf_x.copy()
        lb[fz], ub[fz] = FZ_MIN * ~up, np.where(up, 0.0, FZ_MAX)
        if LIMIT_MARGIN is not None:  # joint position limits as acceleration bounds
            a_hi = KP_LIMIT * (upper_q - LIMIT_MARGIN - qj) - KD_LIMIT * vj
            a_lo = KP_LIMIT * (lower_q + LIMIT_MARGIN - qj) - KD_LIMIT * vj
            lb[joint_v], ub[joint_v] = np.minimum(a_lo, a_hi), np.maximum(a_lo, a_hi)
        return QPData(H, g, Aeq, -h[base_rows], Cm, l, u, lb, ub), (At, hj)

    def solve(t: float, q: np.ndarray, v: np.ndarray, obs=None) -> tuple[np.ndarray, np.ndarray, bool]:
        """One QP at time ``t`` and state ``(q, v)`` (``obs``: the observer's data, see ``program``): actuation
        ``(n_act,)`` N m, corner forces ``(8, 3)`` N, success."""
        d, (At, hj) = program(t, q, v, obs)
        xs, ok, status = solver.solve(d)
        if not ok and LIMIT_MARGIN is not None:
            # a joint-limit bound that asks for an acceleration (a joint moving towards its limit) may ask more than
            # the joint's torque can give (measured: a hand whose 0.29 N m the noise saturates): the program again
            # without such bounds (the limits then left to the plant's), without any if that does not suffice
            relaxed.append(t)
            lb, ub = d.lb[joint_v], d.ub[joint_v]
            asking = (lb > 0) | (ub < 0)
            d.lb[joint_v], d.ub[joint_v] = np.where(asking, -np.inf, lb), np.where(asking, np.inf, ub)
            xs, ok, status = solver.solve(d)
            if not ok:
                d.lb[joint_v], d.ub[joint_v] = -np.inf, np.inf
                xs, ok, status = solver.solve(d)
        if not ok:
            failed.append((t, status))
            return np.zeros(n_act), np.full((nc, 3), np.nan), False
        u = At @ xs + hj
        return np.clip(u, -effort, effort), xs[nv:].reshape(nc, 3), True

    system = Stabilizer()
    system.solve = solve
    system.program = program
    system.failed = failed
    system.relaxed = relaxed
    system.observed = observed
    system.qp = solver
    return system
