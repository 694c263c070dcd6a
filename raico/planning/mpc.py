"""Receding-horizon control (MPC) with AICO / R-AICO or crocoddyl's FDDP (docs/mpc.md tells it in full).

A problem of ``T`` steps is controlled tick by tick: at tick ``k`` (absolute step ``k``) the
controller takes the measured state ``x``, solves a window problem of ``H`` steps starting at
``x`` with a fixed number of solver iterations (default 1) or a time budget, warm-started from
the previous tick's solution shifted by one step, and returns the first control ``u_0`` and
the window's first feedback gains ``O_0 (n_u, n_x)``, so that between solves (the plant's
faster steps) ``u = o_0 + O_0 x`` can be applied.

Time in the window: window step ``j`` is the absolute step ``k + j``; a state term with ``times`` keeps
its absolute times (a state target per step, its targets: :func:`follow_references`), a term at the problem's last step ``T`` follows the receding end (the window's last
step while ``T`` lies beyond it, ``T - k`` once inside); the windows' times are computed once.

Warm start (shift by one step, as aico.cpp's ``shiftSolution`` and crocoddyl's MPC examples), by the
solver spec's ``caps.mpc``: ``"aico"``: with the fixed schedule one workspace
(:class:`raico.planning.aico.shift.ShiftedAICO`: messages, beliefs, task terms, controller, multipliers,
alpha) shifted by a step, its start reset to the measured state, the shifted controller's rollout the start
of the tick's iterations; the other schedules a run of ``aico()`` from that rollout; ``"fddp"``: one
crocoddyl window moved by ``circularAppend`` (the terminal node replaced where its terms change), ``xs``/``us``
shifted.

Per-tick records (preallocated arrays in ``TickLog``): solve wall time, iterations, the window's cost,
whether the tick went past its budget, the window's excess beyond its hard bounds. AICO / R-AICO run
``iterations`` in one call without a budget, one at a time while the next fits with one; FDDP runs
``iterations`` in one ``solve``, the budget only recorded.
"""

from __future__ import annotations

import collections
import copy
import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from raico.planning.aico import aico
from raico.planning.aico.shift import ShiftedAICO, SplitTick
from raico.planning.aico.sweeps import NumericalError
from raico.planning.problem import Problem
from raico.planning.solvers import SOLVERS, get_solver

# the solvers with a shift warm start (their spec's ``caps.mpc``: "aico" or "fddp"; iLQG has none: rejected)
WARM_STARTABLE = tuple(name for name, spec in SOLVERS.items() if spec.caps.mpc is not None)
# those whose window runs on the problem's own model, whatever it is (a learned one too); crocoddyl's window is
# built from the model file in Pinocchio and has no learned model
OWN_MODEL = tuple(name for name in WARM_STARTABLE if SOLVERS[name].caps.mpc == "aico")


def learned_model(dynamics: Any) -> Any:
    """The learned layer of a controller's model, or ``None``: ``dynamics`` itself or the model inside its
    wrappers (``ActuatedDynamics``, ``SubstepDynamics``: their ``inner``) that carries a GP
    (``raico.plants.learned.LearnedDynamics``; ``ResidualDynamics``: the model file plus the residual GP)."""
    from raico.plants.learned import LearnedDynamics

    d = dynamics
    while d is not None and not isinstance(d, LearnedDynamics):
        d = getattr(d, "inner", None)
    return d


@dataclass
class TickLog:
    """Per-tick records, preallocated for ``ticks`` ticks.

    Attributes:
        solve_time: wall time of each tick's solve (s), ``(ticks,)``.
        iterations: solver iterations run in the tick, ``(ticks,)``.
        cost: the window's cost after the solve, ``(ticks,)``.
        over_budget: whether the solve took longer than the time budget, ``(ticks,)`` (False
            without a budget).
        violation: the window's largest excess beyond the hard bounds after the solve, ``(ticks, 2)``:
            joint positions (rad) and controls (0 inside, and without hard bounds).
        predicted: the window's predicted states after each solve, ``(ticks, H+1, n_x)`` float32 (the
            predicted horizon; ``None`` unless asked for).
        n: ticks recorded so far.
    """

    solve_time: np.ndarray
    iterations: np.ndarray
    cost: np.ndarray
    over_budget: np.ndarray
    violation: np.ndarray
    predicted: np.ndarray | None = None
    n: int = 0
    feedback_time: np.ndarray | None = None   # the split's feedback phase, wall time (s), (ticks,)

    @classmethod
    def empty(cls, ticks: int, window: tuple[int, int] | None = None) -> TickLog:
        """Records for ``ticks`` ticks (NaN / zero until recorded); ``window = (H+1, n_x)``: keep the
        predicted horizons too."""
        predicted = None if window is None else np.full((ticks, *window), np.nan, dtype=np.float32)
        return cls(np.full(ticks, np.nan), np.zeros(ticks, dtype=np.int64), np.full(ticks, np.nan),
                   np.zeros(ticks, dtype=bool), np.zeros((ticks, 2)), predicted)

    def grow(self, extra: int) -> None:
        """Room for ``extra`` more ticks."""
        for name in ("solve_time", "iterations", "cost", "over_budget", "violation", "predicted", "feedback_time"):
            a = getattr(self, name)
            if a is None:
                continue
            setattr(self, name, np.concatenate([a, np.zeros((extra, *a.shape[1:]), a.dtype)]))

    def arrays(self) -> dict[str, np.ndarray]:
        """The recorded ticks as arrays named ``mpc_*`` (for an artifact)."""
        k = self.n
        return {"mpc_solve_time": self.solve_time[:k].copy(), "mpc_iterations": self.iterations[:k].copy(),
                "mpc_cost": self.cost[:k].copy(), "mpc_over_budget": self.over_budget[:k].copy(),
                "mpc_violation": self.violation[:k].copy(),
                **({} if self.predicted is None else {"mpc_predicted": self.predicted[:k].copy()}),
                **({} if self.feedback_time is None else {"mpc_feedback_time": self.feedback_time[:k].copy()})}


def window_times(times: np.ndarray | None, T: int, H: int, k: int, receding_end: bool = True) -> np.ndarray | None:
    """A state term's window times at tick ``k``: its absolute ``times`` in ``[k, min(k+H, T))`` shifted
    by ``-k``, plus ``min(H, T - k)`` if it costs the problem's last step ``T`` (the receding end, until
    the problem's end enters the window; without ``receding_end`` only once it is inside); ``None`` stays
    ``None`` (every step)."""
    if times is None:
        return None
    t = np.asarray(times, dtype=int)
    inside = t[(t >= k) & (t < min(k + H, T))] - k
    if np.any(t == T) and (receding_end or T - k <= H):
        inside = np.append(inside, min(H, T - k))
    return np.unique(inside)


def _window_problem(problem: Problem, H: int, receding_end: bool = True) -> tuple[Problem, list[tuple[Any, list]]]:
    """The window problem (``H`` steps, its own copies of the terms) and, per state term with times,
    ``(copy, [its window times at tick k for k = 0..T-1])``."""
    T = problem.T
    state_terms, timed = [], []
    for term in problem.state_terms:
        c = copy.copy(term)
        times = getattr(term, "times", None)
        if times is not None:
            per_tick = [window_times(times, T, H, k, receding_end) for k in range(T)]
            c._set_times(per_tick[0])
            timed.append((c, per_tick))
        state_terms.append(c)
    joint_terms = []
    for term in problem.joint_terms:
        c = copy.copy(term)
        c.T, c.times = H, np.arange(H)
        joint_terms.append(c)
    window = Problem(problem.dynamics, problem.x0.copy(), H, state_terms, list(problem.control_terms),
                     joint_terms, problem.bounds)
    return window, timed


def _window_references(window: Problem, problem: Problem) -> list[tuple[Any, np.ndarray]]:
    """The window's state targets with a target per step (``StateTarget.per_step``): each copy given its own
    ``(H+1, n_x)`` target buffer (the compiled task messages read it in place), paired with the problem's
    ``(T+1, n_x)`` targets; filled for tick 0."""
    refs = []
    for i, term in enumerate(window.state_terms):
        if getattr(term, "per_step", False):
            full = problem.state_terms[i].target
            if full.shape[0] != problem.T + 1:
                raise ValueError(f"state term {term.name!r}: {full.shape[0]} targets for a problem of "
                                 f"{problem.T + 1} steps")
            term.target = np.empty((window.T + 1, full.shape[1]))
            refs.append((term, full))
    follow_references(refs, 0)
    return refs


def follow_references(refs: list[tuple[Any, np.ndarray]], k: int) -> None:
    """Tick ``k``: each window copy's per-step targets are the problem's at the absolute steps ``k..k+H``
    (past the problem's end its last one), written in place."""
    for term, full in refs:
        buf = term.target
        T = full.shape[0] - 1
        n = min(buf.shape[0], T + 1 - k)
        buf[:n] = full[k:k + n]
        buf[n:] = full[T]


class MPC:
    """A receding-horizon controller of ``problem`` (see the module docstring).

    Args:
        problem: the problem (its ``T`` is the number of ticks of a run; its terms' times absolute); its
            dynamics are the controller's model: a learned one (:func:`learned_model`: the model file plus a
            residual GP, refit between a learning loop's episodes) with its uncertainty term among the joint terms.
        horizon: window length ``H`` in planning steps (``1 <= H <= T``).
        solver: one of :data:`WARM_STARTABLE` (``"aico"``, ``"raico"``, ``"fddp"``: BoxFDDP where the problem has
            control limits).
        options: the solver's options (``AICOOptions`` / ``FDDPOptions`` or a dict, the solver's defaults
            applied: :meth:`raico.planning.solvers.SolverSpec.options`); their ``iterations`` is replaced by
            ``iterations``.
        iterations: solver iterations per tick (>= 1) when no ``budget`` is given; with a budget the
            most iterations per tick.
        budget: time budget per tick (s) or ``None``: with a budget, iterations run one at a time
            while the next (estimated by the last one's time) fits; at least one runs, and a tick
            whose solve took longer than the budget is recorded as over budget.
        ticks: ticks the log is preallocated for (default ``T``; it grows if more are run).
        keep_predictions: keep every tick's predicted window states in the log (``TickLog.predicted``).
        receding_end: a term at the problem's last step costs the window's last step until the problem's
            end enters the window (default); ``False``: only from then on (via-points alone pull before).
        split: the preparation / feedback split (:class:`raico.planning.aico.shift.SplitTick`; solvers whose
            spec has ``caps.split``, the fixed schedule; a tick per planning step).

    Raises:
        ValueError: a horizon outside ``[1, T]``, an unknown solver or one that cannot warm-start (or
            cannot run on a learned model), ``iterations < 1``, a budget that is not positive.
    """

    def __init__(self, problem: Problem, horizon: int, solver: str = "raico", options: Any = None,
                 iterations: int = 1, budget: float | None = None, ticks: int | None = None,
                 keep_predictions: bool = False, receding_end: bool = True, split: bool = False):
        if solver not in WARM_STARTABLE:
            raise ValueError(f"solver {solver!r} cannot warm-start a receding horizon here; "
                             f"use one of {', '.join(WARM_STARTABLE)}")
        if int(horizon) != horizon or not 1 <= horizon <= problem.T:
            raise ValueError(f"horizon {horizon} must be an integer in [1, T={problem.T}] (the problem's steps)")
        if int(iterations) != iterations or iterations < 1:
            raise ValueError(f"iterations per tick must be an integer >= 1, got {iterations}")
        if budget is not None and not (math.isfinite(budget) and budget > 0):
            raise ValueError(f"time budget must be a positive number of seconds, got {budget}")
        if solver not in OWN_MODEL and learned_model(problem.dynamics) is not None:
            raise ValueError(f"solver {solver!r} cannot control with a learned model (its window is the model "
                             f"file's in Pinocchio); use one of {', '.join(OWN_MODEL)}")
        if split and not get_solver(solver).caps.split:
            raise ValueError(f"solver {solver!r} has no preparation / feedback split")
        self.problem, self.H, self.solver = problem, int(horizon), solver
        self.warm = get_solver(solver).caps.mpc   # the shift warm start: "aico" or "fddp"
        self.iterations, self.budget = int(iterations), budget
        self.window, self._timed = _window_problem(problem, self.H, receding_end)
        self._refs = _window_references(self.window, problem)   # targets per step: they follow the window
        if self._refs and self.warm == "fddp":
            raise ValueError(f"solver {solver!r}: a state target per step is not expressible in its window")
        # per tick: an id of the window's pattern of term times (it changes where a timed term enters, leaves
        # or the problem's end enters the window)
        ids, last = np.zeros(problem.T, dtype=np.int64), None
        for k in range(problem.T):
            pattern = [pt[k] for _, pt in self._timed]
            same = last is not None and all(np.array_equal(a, b) for a, b in zip(pattern, last))
            ids[k] = ids[k - 1] if same else (ids[k - 1] + 1 if k else 0)
            last = pattern
        self._pattern = ids
        # per timed term, its window's active steps 0..H at each tick as a read-only mask (the term's cache of
        # ``active``, seeded at each tick: a term per step of a moving target makes hundreds of timed terms)
        self._steps = np.arange(self.H + 1)
        none = np.zeros(self.H + 1, dtype=bool)
        none.flags.writeable = False
        self._masks: list[list[np.ndarray]] = []
        for _, per_tick in self._timed:   # one mask per change of the term's window times (none: shared)
            masks: list[np.ndarray] = []
            for k, t in enumerate(per_tick):
                if len(t) == 0:
                    masks.append(none)
                elif k and np.array_equal(t, per_tick[k - 1]):
                    masks.append(masks[-1])
                else:
                    mask = np.zeros(self.H + 1, dtype=bool)
                    mask[t] = True
                    mask.flags.writeable = False
                    masks.append(mask)
            self._masks.append(masks)
        self._ws: ShiftedAICO | None = None
        H, n, m = self.H, problem.n_x, problem.n_u
        # the shifted solution, preallocated
        self.X = np.tile(problem.x0, (H + 1, 1))
        self.U = np.zeros((H, m))
        self.o = np.zeros((H, m))
        self.O = np.zeros((H, m, n))
        self._u = np.zeros(m)
        self.k = 0
        self.log = TickLog.empty(ticks or problem.T, (self.H + 1, problem.n_x) if keep_predictions else None)
        self._solved, self._ticks = False, 0
        self.opts: Any = None   # AICOOptions or FDDPOptions
        if self.warm == "fddp":
            self._init_fddp(options)
        else:
            self._init_aico(options)
        self.split = None if not split else SplitTick(self)
        if split and self._ws is None:
            raise ValueError("the preparation / feedback split runs the fixed schedule (one shifted workspace)")
        if split:
            self.log.feedback_time = np.full(self.log.solve_time.size, np.nan)

    # -- AICO / R-AICO
    def _init_aico(self, options: Any) -> None:
        opts: Any = get_solver(self.solver).options(options)   # its defaults applied (R-AICO's alpha) and checked
        self.opts = dataclasses.replace(opts, iterations=1 if self.budget is not None else self.iterations,
                                        tol_rel=0.0)
        self.alpha = float(opts.alpha)
        if opts.schedule == "fixed":    # one workspace shifted tick by tick (else: a run of aico() per tick)
            ws = self._ws = ShiftedAICO(self.window, self.opts)
            self.X, self.U, self.o, self.O = ws.X, ws.U, ws.o, ws.O
            self._ws_pattern = -1

    def _solve_shifted(self, shift: bool) -> tuple[int, float]:
        ws = self._ws
        assert ws is not None
        if shift:
            ws.shift()
        kk = min(self.k, self.problem.T - 1)
        if self._pattern[kk] != self._ws_pattern:
            ws.refresh_times()
            self._ws_pattern = int(self._pattern[kk])
        if not ws.start_at(self.window.x0):
            ws.solved = False          # the shifted controller leaves the finite states: a cold start
            ws.start_at(self.window.x0)
        its, t0, most = 0, time.perf_counter(), self.iterations
        while its < most:
            try:
                ws.iterate(1)
            except NumericalError:     # the shifted controller stays
                break
            its += 1
            if self.budget is not None:
                elapsed = time.perf_counter() - t0
                if elapsed + elapsed / its > self.budget:
                    break
        return its, (ws.cost if its else math.nan)

    def _start_aico(self, shift: bool) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The start of this tick: the previous controller, shifted by one step if ``shift`` (the last
        step repeated), rolled out from the window's ``x0``; ``None`` before the first solve or if that
        rollout is not finite (then AICO's own cold start)."""
        if not self._solved:
            return None, None
        if shift:
            self.o[:-1] = self.o[1:]
            self.O[:-1] = self.O[1:]
        X, U = self.window.controller_rollout(self.o, self.O)
        if not np.all(np.isfinite(X)):
            return None, None
        return X, U

    def _solve_aico(self, shift: bool) -> tuple[int, float]:
        if self._ws is not None:
            return self._solve_shifted(shift)
        X0, U0 = self._start_aico(shift)
        its, t0, cost = 0, time.perf_counter(), math.inf
        while True:
            opts = self.opts if self.alpha == self.opts.alpha else dataclasses.replace(self.opts, alpha=self.alpha)
            res = aico(self.window, opts, X_init=X0, U_init=U0)
            its += res.iterations
            if self.opts.schedule == "fixed":
                self.alpha *= self.opts.gamma ** res.iterations
            if res.status != "diverged" or its == res.iterations:
                self.X[:], self.U[:], self.o[:], self.O[:] = res.X, res.U, res.o, res.O
                cost = res.cost
            if self.budget is None or res.status == "diverged" or its >= self.iterations:
                break
            elapsed = time.perf_counter() - t0
            if elapsed + elapsed / its > self.budget:
                break
            X0, U0 = self.X, self.U
        return its, cost

    # -- FDDP
    def _init_fddp(self, options: Any) -> None:
        from raico.planning.crocoddyl.solve import require

        require()
        self.opts = get_solver(self.solver).options(options)
        self._croc: tuple | None = None   # (CrocoddylProblem, solver), built below
        # the window's nodes' active state terms (indices into the terms with a weight, crocoddyl's order):
        # per tick, of the node entering at the end (H-1) and of the terminal node
        costs = [t for t in self.window.state_terms if t.weight != 0]
        per_tick = {id(c): pt for c, pt in self._timed}
        T, H = self.problem.T, self.H

        def key(k: int, j: int) -> tuple[int, ...]:
            return tuple(i for i, c in enumerate(costs)
                         if id(c) not in per_tick or j in per_tick[id(c)][min(k, T - 1)])
        self._key = key
        self._costs = costs
        self._keys_end = [key(k, H - 1) for k in range(T)]
        self._keys_terminal = [key(k, H) for k in range(T)]
        # every node model the run appends (its running keys) or puts at the end (its terminal keys), built
        # before the loop on one Pinocchio model, each with a spare data; a dropped node's pair goes to the
        # spares of its key
        from raico.planning.crocoddyl import solve as cs

        running, terminal = cs.node_models(self.window, self._keys_end, self._keys_terminal, self.opts.continuous)
        self._node_models = running
        self._pool: dict[tuple, list] = {k: [(m, m.createData())] for k, m in running.items()}
        self._terminal_models = {k: (m, m.createData()) for k, m in terminal.items()}
        self._fddp_window()   # the window's crocoddyl problem and solver, before the first tick

    def _fddp_window(self) -> tuple:
        """The crocoddyl problem and solver of the window, built once (with the controller); each later
        tick moves it on by one node (:meth:`_advance_fddp`)."""
        if self._croc is None:
            from raico.planning.crocoddyl import solve as cs

            cp = cs.build(self.window, self.opts.continuous)
            box = self.opts.box == "yes" or (self.opts.box == "auto" and cp.bounds is not None)
            solver = (cs.crocoddyl.SolverBoxFDDP if box else cs.crocoddyl.SolverFDDP)(cp.shooting)
            solver.th_stop = self.opts.th_stop
            solver.th_acceptStep = self.opts.th_accept
            sp = cp.shooting
            kk = min(self.k, self.problem.T - 1)
            self._nodes = collections.deque(
                (self._key(kk, j), m, d) for j, (m, d) in enumerate(zip(sp.runningModels, sp.runningDatas)))
            self._terminal_key = self._key(kk, self.H)
            self._croc = (cp, solver)
        return self._croc

    def _advance_fddp(self) -> None:
        """crocoddyl's receding horizon: the first node dropped and a node appended at the end
        (``circularAppend``), the terminal node replaced where its terms changed; the nodes' models and
        data are reused (a dropped node's pair goes to the spares of its terms)."""
        cp, _ = self._fddp_window()
        kk = min(self.k, self.problem.T - 1)
        old_key, m0, d0 = self._nodes.popleft()
        self._pool.setdefault(old_key, []).append((m0, d0))
        key = self._keys_end[kk]
        spare = self._pool.get(key)
        if spare:
            m, d = spare.pop()
        else:   # the key's spare is still in the window
            m = self._node_models[key]
            d = m.createData()
        cp.shooting.circularAppend(m, d)
        self._nodes.append((key, m, d))
        tkey = self._keys_terminal[kk]
        if tkey != self._terminal_key:
            mt, dt = self._terminal_models[tkey]
            cp.shooting.updateNode(self.H, mt, dt)
            self._terminal_key = tkey

    def _solve_fddp(self, shift: bool) -> tuple[int, float]:
        if shift and self._croc is not None:
            self._advance_fddp()
        cp, solver = self._fddp_window()
        x_pin = cp.smap.x_to_pin(self.window.x0)
        cp.shooting.x0 = x_pin
        if self._solved:
            if shift:   # crocoddyl's MPC examples: xs[1:] + [xs[-1]], us[1:] + [us[-1]]
                self.X[:-1] = self.X[1:]
                self.U[:-1] = self.U[1:]
            xs, us = cp.to_pin(self.X), cp.controls_to_pin(self.U)
            xs[0] = x_pin
        else:
            # cold: x held at every node, the quasi-static controls (crocoddyl's examples' guess)
            xs = [x_pin.copy() for _ in range(self.H + 1)]
            us = list(cp.shooting.quasiStatic(xs[:-1]))
        solver.solve(xs, us, self.iterations, False)
        n = max(int(solver.iter), 1)
        X, U, K = cp.from_pin(solver.xs), cp.controls_from_pin(solver.us), cp.gains_from_pin(solver.K)
        self.X[:], self.U[:] = X, U
        self.O[:] = -K
        np.einsum("tij,tj->ti", K, X[:-1], out=self.o)
        self.o += U
        return n, float(solver.cost)

    # -- the tick
    def start_from(self, X: np.ndarray, U: np.ndarray, o: np.ndarray, O: np.ndarray) -> None:
        """Warm-start the first tick from a plan of the whole problem (its first ``H`` steps): states
        ``X (>= H+1, n_x)``, controls ``U``, controller ``o``, ``O (>= H, ...)``."""
        H = self.H
        self.X[:], self.U[:], self.o[:], self.O[:] = X[:H + 1], U[:H], o[:H], O[:H]
        self._solved = True
        if self._ws is not None:
            self._ws.solved = True

    def prepare(self, x: np.ndarray, iterations: int) -> None:
        """Solve tick 0's window from ``x (n_x,)`` with ``iterations`` iterations before the loop
        (not recorded); the first ``tick`` then starts from that solution."""
        saved = self.iterations, self.budget, self.opts
        self.iterations, self.budget = int(iterations), None
        if self.warm != "fddp":
            self.opts = dataclasses.replace(self.opts, iterations=int(iterations))
        self.window.x0[:] = x
        self._set_tick(0)
        self._solve_fddp(False) if self.warm == "fddp" else self._solve_aico(False)
        self.iterations, self.budget, self.opts = saved
        self._solved = True

    def _set_tick(self, k: int) -> None:
        kk = min(k, self.problem.T - 1)
        follow_references(self._refs, kk)
        for (c, per_tick), masks in zip(self._timed, self._masks):
            c.times = per_tick[kk]
            c._active_last = (self._steps, masks[kk])

    def tick(self, x: np.ndarray, advance: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One control period at the measured state ``x (n_x,)``.

        ``advance``: the window moves on by one planning step (the horizon shifted) unless this is the
        first tick; ``False`` for a control period shorter than the planning step (the same window
        solved again from the new measurement).

        Returns:
            ``(u, o, O)``: the first control ``u_0 = o_0 + O_0 x (n_u,)`` (views into the controller's
            buffers, valid until the next tick) and the feedback ``u = o + O x`` to apply until the next
            tick, ``o (n_u,)``, ``O (n_u, n_x)``.
        """
        if self.split is not None:
            if not advance:
                raise ValueError("the preparation / feedback split prepares the next planning step: one tick per step")
            return self.split.tick(x)
        shift = advance and self._ticks > 0
        if shift:
            self.k += 1
        self.window.x0[:] = x
        self._set_tick(self.k)
        t0 = time.perf_counter()
        its, cost = self._solve_fddp(shift) if self.warm == "fddp" else self._solve_aico(shift)
        dt = time.perf_counter() - t0
        self._solved = True
        self._ticks += 1
        log = self.log
        if log.n >= log.solve_time.size:   # more ticks than planning steps (sub-step periods): grow once
            log.grow(log.solve_time.size)
        i = log.n
        log.solve_time[i], log.iterations[i], log.cost[i] = dt, its, cost
        log.over_budget[i] = self.budget is not None and dt > self.budget
        bounds = self.window.bounds
        if bounds is not None:
            log.violation[i] = bounds.violation(self.X, self.U)
        if log.predicted is not None:
            log.predicted[i] = self.X
        log.n += 1
        np.matmul(self.O[0], x, out=self._u)
        self._u += self.o[0]      # u_0 = o_0 + O_0 x (FDDP's xs[0] may still be off x after a partial step)
        return self._u, self.o[0], self.O[0]


def simulate(mpc: MPC, step, x0: np.ndarray, ticks: int, push=None) -> tuple[np.ndarray, np.ndarray]:
    """Closed loop on a plant given by ``step(x, u, k) -> x'`` (one planning step ``dt``; ``push(k)``:
    an extra control-space disturbance ``(n_u,)`` added at tick ``k``, or ``None``). Returns the
    states ``(ticks+1, n_x)`` and the applied controls ``(ticks, n_u)``."""
    n, m = x0.size, mpc.problem.n_u
    X, U = np.empty((ticks + 1, n)), np.empty((ticks, m))
    X[0] = x0
    for k in range(ticks):
        u, _, _ = mpc.tick(X[k])
        U[k] = u
        w = U[k] if push is None else U[k] + push(k)
        X[k + 1] = step(X[k], w, k)
    return X, U


class OnlineResidual:
    """The MPC's learned model updated from the executed steps every ``every`` planning steps, inside the run.

    The controller's model is the model file plus a residual GP with fixed inducing inputs
    (``raico.plants.gp.SparseGPModel``); its hyperparameters, scaling and inducing inputs stay, and its posterior
    over the inducing outputs takes a rank-``k`` update (``SparseGPModel.add_points``). A step executed from
    ``(x_t, u_t)`` to the measured ``x_{t+1}`` gives the GP the sample ``(x_t, u_t) -> m(x_t, u_t) + (v_{t+1} -
    v_hat_{t+1}) / dt``: the current mean plus the velocity the model missed over the step, per second (``v_hat``:
    the model's own step, ``dt`` the planning step), so the mean moves towards what the step showed. The window's
    compiled model reads the new posterior (``ResidualKernel.refresh``), the uncertainty term the same GP.
    ``observe(x, u)`` at every planning step: the measured state and the control then applied.

    Raises:
        ValueError: ``every < 1`` or a model without a sparse residual GP.
    """

    def __init__(self, mpc: MPC, every: int):
        dyn = learned_model(mpc.problem.dynamics)
        if int(every) != every or every < 1:
            raise ValueError(f"the online update's interval must be an integer >= 1 planning steps, got {every}")
        if dyn is None or not hasattr(dyn.model, "add_points"):
            raise ValueError("the online update needs a learned model whose GP is sparse (fixed inducing points: "
                             "--gp sparse)")
        self.mpc, self.every, self.dyn = mpc, int(every), dyn
        n_x, n_u = mpc.problem.n_x, mpc.problem.n_u
        self._Z, self._Y = np.empty((self.every, n_x + n_u)), np.empty((self.every, n_x // 2))
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        self.n, self.updates, self.points = 0, 0, 0

    def observe(self, x: np.ndarray, u: np.ndarray) -> None:
        """The measured state ``x`` (the end of the previous step) and the control ``u`` applied from it."""
        model, n = self.mpc.problem.dynamics, self.mpc.problem.n_x // 2
        if self._last is not None:
            x0, u0 = self._last
            with np.errstate(all="ignore"):
                v_hat = model.step(x0, u0)[n:]
                z = np.concatenate([x0, u0])
                y = self.dyn.model.predict_mean(z[None])[0] + (x[n:] - v_hat) / model.dt
            if np.all(np.isfinite(y)) and np.all(np.isfinite(z)):
                self._Z[self.n], self._Y[self.n] = z, y
                self.n += 1
        self._last = (np.array(x, float), np.array(u, float))
        if self.n == self.every:
            self.dyn.model.add_points(self._Z, self._Y)
            getattr(model, "c_linearizer", lambda: None)()   # the compiled model refreshed (its substeps')
            self.dyn.c_linearizer()
            self.updates, self.points, self.n = self.updates + 1, self.points + self.n, 0
