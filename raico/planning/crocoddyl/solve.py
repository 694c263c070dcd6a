"""crocoddyl's FDDP / BoxFDDP as a baseline on raico's own problems (docs/crocoddyl.md in full).

:func:`build` turns a raico :class:`~raico.planning.problem.Problem` (analytic dynamics) into a crocoddyl
``ShootingProblem`` of the same model, integrator and cost:

- the model: the robot's model file (a built-in plant's too) in Pinocchio, :func:`raico.planning.crocoddyl.model.
  pinocchio_robot` (the joint order mapped, continuous joints, the fixed base); the reflected motor
  inertia is ``model.armature``; joint damping enters through an actuation model ``tau = u - D qdot``;
- the integrator: ``IntegratedActionModelEuler`` over ``DifferentialActionModelFreeFwdDynamics``,
  i.e. semi-implicit Euler, raico's analytic step;
- the cost: crocoddyl's ``1/2 weight ||r||^2``, a running node's multiplied by ``dt``, so a raico term
  ``w ||r||_C^2`` is weight ``2 w / dt`` on a running node and ``2 w`` on the terminal one; each term's
  residual and activation: :mod:`raico.planning.crocoddyl.costs`.

What crocoddyl cannot express exactly is a ``NotExpressible`` (a ``ValueError``): pseudo-dynamics
(its action models take torques), a robot welded on a frame other than its root (the Nao's sole) or with
coupled joints, non-diagonal precisions, inequalities other than joint bounds, the learned model.

:func:`fddp` solves with FDDP (BoxFDDP where control limits exist) from ``x0`` held at every node
(``start="held"``, R-AICO's start), the zero-torque rollout (``"rollout"``) or crocoddyl's own cold start
(``"zero"``), and returns a raico ``Result`` in raico's coordinates: the controller ``o_t = U_t + K_t X_t``,
``O_t = -K_t`` from crocoddyl's gains, rolled out on raico's planning model; the history holds per
iteration the cost of the iterate's controller rolled out, its wall time, step length and regularization.
Registered as the solvers ``fddp*`` in :mod:`raico.planning.solvers` where crocoddyl is installed.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from raico.planning.crocoddyl.model import (
    AVAILABLE,
    CONTINUOUS,
    ActuatedMap,
    DampedActuation,
    NotExpressible,
    SelectedActuation,
    StateMap,
    add_frames,
    crocoddyl,
    pinocchio_of,
    problem_robot,
    require,
)
from raico.planning.problem import (
    Callback,
    IterationRecord,
    OptionsBase,
    Problem,
    Result,
    Status,
    bounds_status,
    check_range,
    controller_rollout,
)

STARTS = ("held", "rollout", "zero")


@dataclass
class CrocoddylProblem:
    """A raico problem in crocoddyl: the ``ShootingProblem`` and what built it.

    ``bounds``: ``(lower, upper)`` torque limits (N m, raico's joint order) of the problem's
    control-limit terms (hard bounds for BoxFDDP), or ``None``. ``smap``: raico's coordinates <->
    Pinocchio's (:class:`raico.planning.crocoddyl.model.StateMap`; the identity for the built-in
    plants). States and controls passed to and returned by the methods are raico's; ``shooting``
    and ``x0_pin`` are in Pinocchio's coordinates."""

    shooting: Any
    state: Any
    pmodel: Any
    T: int
    dt: float
    x0: np.ndarray
    bounds: tuple[np.ndarray, np.ndarray] | None
    smap: Any = None

    def __post_init__(self) -> None:
        if self.smap is None:
            self.smap = StateMap.identity(self.x0.size // 2)
        self.identity = self.smap.is_identity
        self.x0_pin = self.smap.x_to_pin(self.x0)
        # evaluation datas of their own (one per distinct node model): the solver's datas hold its
        # linearization and gaps and must not be touched between its iterations
        sp = self.shooting
        models = {id(m): m for m in [*sp.runningModels, sp.terminalModel]}
        self._datas = {k: m.createData() for k, m in models.items()}

    # -- coordinates
    def to_pin(self, X: np.ndarray) -> list:
        """raico states ``(K, n_x)`` -> a list of crocoddyl states."""
        return list(self.smap.x_to_pin(np.asarray(X, float)))

    def from_pin(self, xs) -> np.ndarray:
        """crocoddyl states (a list) -> raico states ``(K, n_x)`` (angles unwrapped from ``x0``)."""
        X = np.array(xs, float)
        return X if self.identity else self.smap.x_to_raico(X, self.x0[:self.smap.n], self.dt)

    def controls_to_pin(self, U: np.ndarray) -> list:
        return list(self.smap.u_to_pin(np.asarray(U, float)))

    def controls_from_pin(self, us) -> np.ndarray:
        return self.smap.u_to_raico(np.array(us, float))

    def gains_from_pin(self, K) -> np.ndarray:
        """crocoddyl's gains -> raico's ``(T, n_u, n_x)``."""
        K = np.array(K, float).reshape(self.T, -1, 2 * self.smap.nv)
        return K if self.identity else self.smap.gains_to_raico(K)

    def _nodes(self):
        sp = self.shooting
        return [(m, self._datas[id(m)]) for m in sp.runningModels]

    def _terminal(self):
        m = self.shooting.terminalModel
        return m, self._datas[id(m)]

    def rollout(self, U: np.ndarray) -> np.ndarray:
        """States ``(T+1, n_x)`` of the open-loop controls ``U (T, n_u)``."""
        return self.from_pin(self.shooting.rollout(self.controls_to_pin(U)))

    def cost(self, X: np.ndarray, U: np.ndarray) -> float:
        """The problem's cost of ``X (T+1, n_x)``, ``U (T, n_u)`` evaluated by crocoddyl."""
        total = 0.0
        Xp, Up = self.to_pin(X), self.controls_to_pin(U)
        for (m, d), x, u in zip(self._nodes(), Xp[:-1], Up):
            m.calc(d, x, u)
            total += d.cost
        m, d = self._terminal()
        m.calc(d, Xp[-1])
        return float(total + d.cost)

    def feedback_rollout(self, xs, us, K) -> tuple[np.ndarray, np.ndarray, float]:
        """Roll ``u = us_t - K_t (x - xs_t)`` (crocoddyl's iterate and gains, in its coordinates) out
        from ``x0`` through crocoddyl's models: raico's ``X (T+1, n_x)``, ``U (T, n_u)`` and the
        cost (``inf`` if not finite)."""
        X = np.empty((self.T + 1, self.x0_pin.size))
        U = np.empty((self.T, len(us[0])))
        X[0] = self.x0_pin
        xs, us, K = np.array(xs), np.array(us), np.array(K)  # one conversion each, not one per step
        diff = self.state.diff
        total = 0.0
        with np.errstate(all="ignore"):
            for t, (m, d) in enumerate(self._nodes()):
                if not math.isfinite(X[t].sum()):
                    return self._raico(X, U, math.inf)
                u = us[t] - K[t] @ (X[t] - xs[t] if self.identity else diff(xs[t], X[t]))
                if not math.isfinite(u.sum()):  # a NaN or inf in u or x (or a sum past 1e308)
                    return self._raico(X, U, math.inf)
                U[t] = u
                m.calc(d, X[t], u)
                total += d.cost
                X[t + 1] = d.xnext
            m, d = self._terminal()
            m.calc(d, X[-1])
        total += d.cost
        return self._raico(X, U, float(total) if math.isfinite(total) else math.inf)

    def _raico(self, X, U, cost):
        if self.identity:
            return X, U, cost
        if not math.isfinite(cost):
            return np.full((self.T + 1, self.x0.size), np.nan), np.full(U.shape, np.nan), cost
        return self.from_pin(X), self.controls_from_pin(U), cost


def build(problem: Problem, continuous: str = "angle", damping: bool = True) -> CrocoddylProblem:
    """The crocoddyl problem of a raico ``problem`` (analytic dynamics; ``NotExpressible`` for
    what crocoddyl cannot express exactly, see the module docstring and
    :mod:`raico.planning.crocoddyl.model`). ``continuous``: how Pinocchio holds a model file's continuous
    joints, ``"angle"`` (raico's cost exactly) or ``"cos-sin"`` (Pinocchio's own reading, as
    crocoddyl's examples; its state differences wrap at pi). ``damping=False`` leaves out the joint
    damping of the model file, as crocoddyl's examples do (Pinocchio's ABA ignores it): not raico's
    problem then (Drake's plant damps the joints), only crocoddyl's own."""
    nodes = _Nodes(problem, continuous, damping)
    T = problem.T

    def active_at(t: int) -> tuple[int, ...]:
        return tuple(i for i, term in enumerate(nodes.state_costs) if term.is_active_at(t))

    by_set: dict = {}
    running = []
    for t in range(T):  # one model per distinct set of active terms, shared by its nodes
        key = active_at(t)
        if key not in by_set:
            by_set[key] = nodes.model(key, False)
        running.append(by_set[key])
    terminal = nodes.model(active_at(T), True)
    x0 = np.asarray(problem.x0, float).copy()
    shooting = crocoddyl.ShootingProblem(nodes.smap.x_to_pin(x0), running, terminal)
    return CrocoddylProblem(shooting, nodes.state, nodes.pmodel, T, nodes.dt, x0, nodes.bounds, nodes.smap)


def node_models(problem: Problem, running, terminal, continuous: str = "angle",
                damping: bool = True) -> tuple[dict, dict]:
    """Running and terminal crocoddyl node models of ``problem``'s robot, controls and state terms, one per
    set of active state terms (tuples of indices into the terms with a nonzero weight, in order):
    ``({key: running model}, {key: terminal model})`` for the keys in ``running`` and ``terminal``, all on
    one Pinocchio model and one set of residuals (a receding horizon's nodes, built before its loop)."""
    nodes = _Nodes(problem, continuous, damping)
    return ({k: nodes.model(k, False) for k in dict.fromkeys(running)},
            {k: nodes.model(k, True) for k in dict.fromkeys(terminal)})


class _Nodes:
    """What :func:`build` and :func:`node_models` share: the robot in Pinocchio, the actuation, the control
    bounds and each term's residuals, built once; :meth:`model` makes a node of a set of active terms."""

    def __init__(self, problem: Problem, continuous: str, damping: bool):
        require()
        from raico.planning.costs import ControlGravity, ControlLimit
        from raico.planning.crocoddyl.costs import cost_items
        from raico.plants.dynamics import ActuatedDynamics

        robot = problem_robot(problem)
        if any(not isinstance(t, ControlGravity) for t in problem.joint_terms):
            raise NotExpressible("crocoddyl: the uncertainty term of the learned model has no equivalent")
        pmodel, smap = pinocchio_of(robot, continuous)
        pmodel.gravity.linear = np.asarray(robot.plant.gravity_field().gravity_vector(), float)  # the model file's g
        self.state_costs = [t for t in problem.state_terms if t.weight != 0]
        self.control_costs = [t for t in [*problem.control_terms, *problem.joint_terms] if t.weight != 0]
        add_frames(self.state_costs, pmodel, robot)  # before crocoddyl's state takes the model
        state = crocoddyl.StateMultibody(pmodel)
        D = np.asarray(pmodel.damping, float) if damping else np.zeros(pmodel.nv)
        if isinstance(problem.dynamics, ActuatedDynamics):   # motors on some joints only
            smap = ActuatedMap.of(smap, problem.dynamics.S)
            actuation = SelectedActuation(state, smap.sel, D)
        else:
            actuation = (DampedActuation(state, D) if np.any(D != 0)
                         else crocoddyl.ActuationModelFull(state))
        self.nu, self.dt = actuation.nu, float(problem.dynamics.dt)
        self.items = {id(t): cost_items(t, state, self.nu, pmodel, smap, robot)
                      for t in [*self.state_costs, *self.control_costs]}
        limits = [t for t in problem.control_terms if isinstance(t, ControlLimit)]
        n = problem.n_u
        boxes = [(np.broadcast_to(t.lower, (n,)), np.broadcast_to(t.upper, (n,))) for t in limits]
        if problem.bounds is not None and problem.bounds.has_controls:   # the model's effort limits, hard
            boxes.append((problem.bounds.u_lower, problem.bounds.u_upper))
        self.bounds = None if not boxes else (np.max([lo for lo, _ in boxes], axis=0),
                                              np.min([hi for _, hi in boxes], axis=0))
        self.state, self.pmodel, self.smap, self.actuation = state, pmodel, smap, actuation

    def _add(self, costs, term, scale: float) -> None:
        pairs = self.items[id(term)]
        for k, (res, act) in enumerate(pairs):
            name = term.name if len(pairs) == 1 else f"{term.name}/{k}"
            costs.addCost(name, crocoddyl.CostModelResidual(self.state, act, res), 2.0 * term.weight * scale)

    def model(self, active: tuple[int, ...], terminal: bool):
        """A node whose state terms are ``active`` (indices into ``state_costs``); running nodes add the
        control terms and the control box, and cost ``1/dt`` times a terminal node's."""
        costs = crocoddyl.CostModelSum(self.state, self.nu)
        scale = 1.0 if terminal else 1.0 / self.dt
        for i in active:
            self._add(costs, self.state_costs[i], scale)
        if not terminal:
            for term in self.control_costs:
                self._add(costs, term, scale)
        dam = crocoddyl.DifferentialActionModelFreeFwdDynamics(self.state, self.actuation, costs)
        if self.bounds is not None and not terminal:
            dam.u_lb, dam.u_ub = self.smap.u_to_pin(self.bounds[0]), self.smap.u_to_pin(self.bounds[1])
        return crocoddyl.IntegratedActionModelEuler(dam, 0.0 if terminal else self.dt)


# ----------------------------------------------------------------------------- the solver
@dataclass(frozen=True)
class FDDPOptions(OptionsBase):
    """Options of the crocoddyl baseline (frozen; ``from_dict`` rejects unknown keys).

    Attributes:
        iterations: maximum FDDP iterations (>= 1).
        start: ``"held"`` (``x0`` at every node, zero controls: infeasible, R-AICO's start),
            ``"rollout"`` (the zero-torque rollout, feasible) or ``"zero"`` (crocoddyl's own cold
            start, ``solve()`` without a guess: the zero state at every node, zero controls).
        continuous: a model file's continuous joints in Pinocchio, ``"angle"`` (raico's cost
            exactly) or ``"cos-sin"`` (crocoddyl's own reading; see :mod:`raico.planning.crocoddyl.model`).
        th_stop: crocoddyl's stopping threshold (expected improvement), its default 1e-9.
        reg_init: initial regularization (``None``: crocoddyl's default, 1e-9).
        box: ``"auto"`` (BoxFDDP where the problem has control limits, else FDDP), ``"yes"``, ``"no"``.
        th_accept: crocoddyl's acceptance ratio ``th_acceptStep`` (actual / expected), default 0.1.
        step_sizes: line-search step lengths (``None``: crocoddyl's ``2^-k``, k = 0..9).
        th_step_dec, th_step_inc: crocoddyl lowers the regularization after a step at least
            ``th_step_dec`` long (default 0.5) and raises it after one at most ``th_step_inc``
            long (default 0.01).
    """

    iterations: int = 150
    start: str = "held"
    th_stop: float = 1e-9
    reg_init: float | None = None
    box: str = "auto"
    th_accept: float = 0.1
    step_sizes: tuple | None = None
    th_step_dec: float = 0.5
    th_step_inc: float = 0.01
    continuous: str = "angle"

    def validate(self) -> None:
        check_range("iterations", self.iterations, lo=1, integer=True)
        if self.continuous not in CONTINUOUS:
            raise ValueError(f"option continuous must be one of {CONTINUOUS}, got {self.continuous!r}")
        if self.start not in STARTS:
            raise ValueError(f"option start must be one of {STARTS}, got {self.start!r}")
        check_range("th_stop", self.th_stop, lo=0.0)
        if self.reg_init is not None:
            check_range("reg_init", self.reg_init, lo=0.0)
        if self.box not in ("auto", "yes", "no"):
            raise ValueError(f"option box must be auto, yes or no, got {self.box!r}")
        check_range("th_accept", self.th_accept, lo=0.0, hi=1.0)
        check_range("th_step_dec", self.th_step_dec, lo=0.0, hi=1.0, lo_open=True)
        check_range("th_step_inc", self.th_step_inc, lo=0.0, hi=1.0, lo_open=True)
        if self.step_sizes is not None:
            a = tuple(float(x) for x in np.atleast_1d(np.asarray(self.step_sizes, float)))
            if not a or any(not 0.0 < x <= 1.0 for x in a):
                raise ValueError(f"option step_sizes must be a non-empty list in (0, 1], got {a}")
            object.__setattr__(self, "step_sizes", a)


if AVAILABLE:
    class _Recorder(crocoddyl.CallbackAbstract):
        """Per-iteration record: cost of the iterate's controller rolled out, wall times with this
        bookkeeping excluded. ``after``: during the solve only the clock and a copy of crocoddyl's
        iterate (``xs``, ``us``, and ``K`` while gaps remain); the rollouts of the infeasible iterates
        and the callbacks after it (:meth:`finish`), so that none of raico's work runs between the
        solver's iterations (the same records, the callbacks late)."""

        def __init__(self, cp: CrocoddylProblem, callback: Callback | None, after: bool = False):
            crocoddyl.CallbackAbstract.__init__(self)
            self.cp, self.callback, self.after = cp, callback, after
            self.history: list[IterationRecord] = []
            self.pending: list[tuple] = []   # after: per record (xs, us, K or None when feasible)
            self.t_last = self.t_start = time.perf_counter()
            self.elapsed = 0.0

        def __call__(self, solver, *args):
            now = time.perf_counter()
            dt = now - self.t_last
            self.elapsed += dt
            if self.after:
                feasible = bool(solver.isFeasible)
                self.history.append(IterationRecord(len(self.history) + 1, float(solver.cost) if feasible else math.nan,
                                                    dt, self.elapsed, float(solver.stepLength), float(solver.preg)))
                self.pending.append((np.array(solver.xs), np.array(solver.us),
                                     None if feasible else np.array(solver.K)))
                self.t_last = time.perf_counter()
                return
            if solver.isFeasible:
                cost, X, U = float(solver.cost), None, None
            else:
                X, U, cost = self.cp.feedback_rollout(solver.xs, solver.us, solver.K)
            rec = IterationRecord(len(self.history) + 1, cost if math.isfinite(cost) else math.inf,
                                  dt, self.elapsed, float(solver.stepLength), float(solver.preg))
            self.history.append(rec)
            if self.callback is not None and math.isfinite(cost):
                if X is None:
                    X, U = self.cp.from_pin(solver.xs), self.cp.controls_from_pin(solver.us)
                self.callback(rec, X, U)
            self.t_last = time.perf_counter()

        def finish(self) -> None:
            """``after``: each infeasible iterate's cost (its feedback rollout) into its record, and the
            callbacks in order, as the live recorder makes and calls them."""
            for i, (xs, us, K) in enumerate(self.pending):
                rec = self.history[i]
                if K is None:
                    X = U = None
                    cost = rec.cost
                else:
                    X, U, cost = self.cp.feedback_rollout(xs, us, K)
                rec.cost = cost if math.isfinite(cost) else math.inf
                if self.callback is not None and math.isfinite(cost):
                    if X is None:
                        X, U = self.cp.from_pin(xs), self.cp.controls_from_pin(us)
                    self.callback(rec, X, U)
            self.pending.clear()


def fddp(problem: Problem, options: FDDPOptions | None = None, *, U_init: np.ndarray | None = None,
         callback: Callback | None = None, croc: CrocoddylProblem | None = None, record: str = "live") -> Result:
    """Solve ``problem`` with crocoddyl's FDDP (BoxFDDP with control limits); see the module
    docstring. ``U_init``: warm-start controls (their rollout is the start); ``croc``: a
    prebuilt ``build(problem)``; ``record``: ``"live"`` (each iteration's record and callback as it
    ends) or ``"after"`` (the infeasible iterates rolled out and the callbacks made after the solve:
    nothing of raico's runs between crocoddyl's iterations; the bench's timing). Raises
    ``NotExpressible`` for problems crocoddyl cannot express."""
    require()
    if record not in ("live", "after"):
        raise ValueError(f"record must be 'live' or 'after', got {record!r}")
    o = options or FDDPOptions()
    cp = croc if croc is not None else build(problem, o.continuous)
    T, n_u = problem.T, problem.n_u
    U0 = np.zeros((T, n_u)) if U_init is None else np.array(U_init, float)
    if U0.shape != (T, n_u):
        raise ValueError(f"U_init has shape {U0.shape}, expected {(T, n_u)}")
    X_roll = cp.rollout(U0)
    initial_cost = problem.cost(X_roll, U0)
    box = o.box == "yes" or (o.box == "auto" and cp.bounds is not None)
    solver = (crocoddyl.SolverBoxFDDP if box else crocoddyl.SolverFDDP)(cp.shooting)
    solver.th_stop = o.th_stop
    solver.th_acceptStep = o.th_accept
    solver.th_stepDec, solver.th_stepInc = o.th_step_dec, o.th_step_inc
    if o.step_sizes is not None:
        solver.alphas = list(o.step_sizes)  # crocoddyl's name
    rec = _Recorder(cp, callback, after=record == "after")
    solver.setCallbacks([rec])
    us = cp.controls_to_pin(U0)
    if o.start == "zero" and U_init is None:
        xs, us, feasible = [], [], False  # crocoddyl fills in its zero state and zero controls
    elif o.start == "held" and U_init is None:
        xs, feasible = [cp.x0_pin.copy() for _ in range(T + 1)], False
    else:
        xs, feasible = cp.to_pin(X_roll), True
    args = (xs, us, int(o.iterations), feasible) + (() if o.reg_init is None else (float(o.reg_init),))
    rec.t_last = rec.t_start = time.perf_counter()
    try:
        converged = bool(solver.solve(*args))
    except (ArithmeticError, RuntimeError, ValueError) as e:
        rec.finish()
        return result(problem, None, rec.history, Status.DIVERGED, f"crocoddyl: {type(e).__name__}: {e}",
                       initial_cost, solver, X_roll, cp)
    rec.finish()
    costs = [h.cost for h in rec.history]
    if not all(math.isfinite(c) for c in costs[-1:]):
        return result(problem, solver, rec.history, Status.DIVERGED, "cost not finite", initial_cost, solver,
                       X_roll, cp)
    status = Status.CONVERGED if converged else Status.MAX_ITERATIONS
    n = len(rec.history)
    if converged:
        why = "stopping criterion below th_stop"
    elif n < o.iterations and float(solver.preg) >= float(solver.reg_max):
        # crocoddyl's other stop: no step was accepted and its regularization reached reg_max
        why = f"stopped after {n} of {o.iterations} iterations: its regularization reached reg_max {solver.reg_max:g}"
    else:
        why = f"reached {n} iterations"
    msg = f"crocoddyl {'BoxFDDP' if box else 'FDDP'}: {why}"
    return result(problem, solver, rec.history, status, msg, initial_cost, solver, X_roll, cp)


def result(problem: Problem, solved, history, status, message, initial_cost, solver, X_initial=None,
           cp: CrocoddylProblem | None = None) -> Result:
    """raico's ``Result`` of a crocoddyl ``solver`` (``solved=None``: a failed solve, NaN states):
    the controller from crocoddyl's iterate and gains in raico's coordinates, rolled out on the
    planning model (within its effort bounds), with the ``history`` and the ``status`` given."""
    T, n_x, n_u = problem.T, problem.n_x, problem.n_u
    if solved is None:
        X = np.full((T + 1, n_x), np.nan)
        U, K = np.zeros((T, n_u)), np.zeros((T, n_u, n_x))
    else:  # in raico's coordinates: u = U_t - K_t (x - X_t) with crocoddyl's state difference read as x - X_t
        X, U, K = cp.from_pin(solver.xs), cp.controls_from_pin(solver.us), cp.gains_from_pin(solver.K)
    o = U + np.einsum("tij,tj->ti", K, X[:-1])
    O = -K
    if solved is not None:  # the controller rolled out on raico's planning model (within its effort bounds)
        if problem.bounds is not None and problem.bounds.has_controls:
            X, U, o, O = problem.bounded_rollout(o, O)
        else:
            X, U = controller_rollout(problem.dynamics, problem.x0, o, O)
    res = Result(X=X, U=U, o=o, O=O, status=status, history=history, iterations=len(history),
                 message=message, initial_cost=initial_cost, solver="fddp", X_initial=X_initial)
    if problem.bounds is not None:
        bounds_status(problem, res)
    return res
