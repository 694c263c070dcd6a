"""Solver registry: ``solve(problem, name, options_dict)`` over ``SOLVERS``, each a :class:`SolverSpec`
that declares what the solver can do; the plan stage asks the spec, never the name.

``SOLVERS[name]``: the solver function and its options class (imported on first use, so listing or
checking a name loads neither; crocoddyl's ``fddp*`` are registered where crocoddyl and pinocchio are
installed), the defaults the name implies ("raico" is AICO with ``alpha = 1`` unless given and requires
``alpha > 0``; "aico" requires ``alpha = 0``), its :class:`Capabilities` and the plan-stage flags it
takes (its options class's ``FLAGS``, :class:`raico.planning.problem.Flag`).

A new solver: its function, its options class (with ``FLAGS`` for the options ``raico plan`` sets) and
one ``SolverSpec`` here; ``PlanConfig``'s fields, the CLI and its help follow from them.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from raico.planning.problem import Flag, IterateHistory, OptionsBase, Problem, Result, iterate_steps

CONTROL_KINDS = ("acceleration", "torque")   # pseudo-dynamics' controls, the analytic and learned models'


@dataclass(frozen=True)
class Capabilities:
    """What a solver takes and does, beyond its options.

    ``starts``: the first trajectories it takes without a warm start (``held``: ``x0`` at every step, or
    the solver's own start; ``rollout``: the zero-control rollout; ``quasi-static``: the torques that hold
    ``x0``, rolled out); ``warm_from``: what of an earlier plan starts it (``trajectory``: its states and
    controls; ``controls``: its controls rolled out); ``hard_bounds``: keeps the problem's joint ranges
    and velocity limits itself; ``control_box``: keeps effort limits as a box on the controls;
    ``control_box_methods``: the ways it can keep that box, its options' ``control_box`` values (AICO: the
    augmented Lagrangian, or BoxDDP's box QP in the backward pass; empty: one way, its own);
    ``sweeps``: AICO's sweeps (relinearization repeats per iteration); ``schedules``: its alpha
    schedules; ``control_kinds``: the dynamics' controls it takes; ``mpc``: its shift warm start in
    :mod:`raico.planning.mpc` (``"aico"``, ``"fddp"``), ``None`` where it has none; ``split``: its MPC tick
    splits into preparation and feedback (``MPC(..., split=True)``); ``range_messages``: keeps the ranges as
    truncated-Gaussian (EP) messages on request (option ``ranges = "ep"``)."""

    starts: tuple[str, ...] = ("held", "quasi-static")
    warm_from: tuple[str, ...] = ("controls",)
    hard_bounds: bool = False
    control_box: bool = False
    control_box_methods: tuple[str, ...] = ()
    sweeps: bool = False
    schedules: tuple[str, ...] = ()
    control_kinds: tuple[str, ...] = CONTROL_KINDS
    mpc: str | None = None
    split: bool = False
    range_messages: bool = False


@dataclass(frozen=True)
class SolverSpec:
    """A registered solver: ``run(problem, options, **init) -> Result``, named ``label`` in prose.

    ``run_ref`` and ``options_ref``: the function and the options class as ``"module:name"`` (imported
    on first use); ``takes``: the names of the options class's ``FLAGS`` it takes (``None``: all);
    ``require``: raises ``ValueError`` where the solver cannot run here."""

    name: str
    label: str
    run_ref: str
    options_ref: str
    caps: Capabilities = Capabilities()
    defaults: dict[str, Any] = field(default_factory=dict)
    check: Callable[[Any], None] | None = None
    takes: tuple[str, ...] | None = None
    require: Callable[[], None] | None = None

    @property
    def run(self) -> Callable[..., Result]:
        return _load(self.run_ref)

    @property
    def options_cls(self) -> type[OptionsBase]:
        return _load(self.options_ref)

    @property
    def flags(self) -> tuple[Flag, ...]:
        """The plan-stage flags of its options class it takes."""
        if self.takes == ():
            return ()
        return tuple(f for f in self.options_cls.FLAGS if self.takes is None or f.name in self.takes)

    def options(self, d: dict[str, Any] | OptionsBase | None = None) -> OptionsBase:
        """Validated options from a dict (unknown keys rejected) or an options object."""
        if self.require is not None:
            self.require()
        if isinstance(d, OptionsBase):
            if not isinstance(d, self.options_cls):
                raise TypeError(f"solver {self.name!r} takes {self.options_cls.__name__}, "
                                 f"got {type(d).__name__}")
            opts = d
        else:
            opts = self.options_cls.from_dict(d, **self.defaults)
        if self.check is not None:
            self.check(opts)
        return opts


def _load(ref: str) -> Any:
    module, _, name = ref.partition(":")
    return getattr(importlib.import_module(module), name)


def _check_aico(o) -> None:  # noqa: ANN001
    if o.alpha != 0:
        raise ValueError(f"solver 'aico' is plain AICO (alpha = 0), got alpha={o.alpha}; "
                         "use solver 'raico' for alpha > 0")


def _check_raico(o) -> None:  # noqa: ANN001
    if not o.alpha > 0:
        raise ValueError(f"solver 'raico' needs alpha > 0, got alpha={o.alpha}; "
                         "use solver 'aico' for alpha = 0")


_AICO_CAPS = Capabilities(starts=("held", "rollout", "quasi-static"), warm_from=("trajectory", "controls"),
                          hard_bounds=True, control_box=True, control_box_methods=("lagrangian", "boxddp"),
                          sweeps=True, mpc="aico", split=True, range_messages=True)

SOLVERS: dict[str, SolverSpec] = {
    "aico": SolverSpec("aico", "AICO", "raico.planning.aico:aico", "raico.planning.aico:AICOOptions", _AICO_CAPS,
                       {"alpha": 0.0}, _check_aico, takes=("relinearize", "belief_rate", "controller_rate",
                                                          "control_box")),
    "raico": SolverSpec("raico", "R-AICO", "raico.planning.aico:aico", "raico.planning.aico:AICOOptions",
                        dataclasses.replace(_AICO_CAPS, schedules=("fixed", "adaptive", "robust")),
                        {"alpha": 1.0}, _check_raico),
    "ilqg": SolverSpec("ilqg", "iLQG", "raico.planning.ilqg:ilqg", "raico.planning.ilqg:ILQGOptions"),
}


ACCEPT_ANY = 1e-12  # crocoddyl's th_acceptStep of "any step that lowers the cost" (iLQG's actual/expected > 0)
# iLQG's regularization schedule in crocoddyl's terms: lower the regularization after every accepted
# step (whatever its length), raise it only when the line search reaches its last step 2^-9
ILQG_SCHEDULE = {"th_step_dec": 1e-12, "th_step_inc": 0.002}
CROCODDYL_SOLVERS = ("fddp", "fddp-rollout", "fddp-rollout-accept-any", "fddp-rollout-ilqg-schedule", "boxfddp")


def _require_crocoddyl() -> None:
    from raico.planning import crocoddyl as cm

    if not cm.AVAILABLE:
        raise ValueError(f"crocoddyl's solvers cannot run here: {cm.UNAVAILABLE_REASON}")


def _crocoddyl_specs() -> dict[str, SolverSpec]:
    """The crocoddyl baseline (``raico.planning.crocoddyl``): ``fddp`` starts from ``x0`` held at every
    node (R-AICO's start), ``fddp-rollout`` from the zero-torque rollout; ``fddp-rollout-accept-any``
    and ``fddp-rollout-ilqg-schedule`` are the ablations with iLQG's acceptance rule and its
    regularization schedule; ``boxfddp`` insists on BoxFDDP (``fddp`` takes it where limits exist)."""
    def check(start: str):
        def _check(o) -> None:  # noqa: ANN001
            if o.start != start:
                raise ValueError(f"solver starts from '{start}', got start={o.start!r}")
        return _check

    caps = Capabilities(control_box=True, control_kinds=("torque",))
    # name -> (label, the options the name implies, the start it insists on, capabilities)
    rows: dict[str, tuple[str, dict[str, Any], str, Capabilities]] = {
            "fddp": ("FDDP", {"start": "held"}, "held", dataclasses.replace(caps, mpc="fddp")),
            "fddp-rollout": ("FDDP (rollout start)", {"start": "rollout"}, "rollout", caps),
            # ablation (why iLQG stalls): FDDP accepting any step that lowers the cost, iLQG's rule
            "fddp-rollout-accept-any": ("FDDP (iLQG's acceptance)", {"start": "rollout", "th_accept": ACCEPT_ANY},
                                        "rollout", caps),
            # ablation: FDDP with iLQG's regularization schedule (lower it after every accepted step)
            "fddp-rollout-ilqg-schedule": ("FDDP (iLQG's schedule)", {"start": "rollout", **ILQG_SCHEDULE},
                                           "rollout", caps),
            # BoxFDDP from x0 held: the control limits (the problem's hard effort bounds, its control-limit
            # terms) as BoxDDP's box on the control QP
            "boxfddp": ("BoxFDDP", {"start": "held", "box": "yes"}, "held", caps)}
    specs = {name: SolverSpec(name, label, "raico.planning.crocoddyl:fddp", "raico.planning.crocoddyl:FDDPOptions", c,
                              defaults, check(start), takes=(), require=_require_crocoddyl)
             for name, (label, defaults, start, c) in rows.items()}
    assert tuple(specs) == CROCODDYL_SOLVERS
    return specs


def _register_crocoddyl() -> None:
    """The crocoddyl baseline's names, where crocoddyl and pinocchio are installed (found, not imported:
    the first run imports them)."""
    from importlib.util import find_spec

    if find_spec("crocoddyl") is not None and find_spec("pinocchio") is not None:
        SOLVERS.update(_crocoddyl_specs())


_register_crocoddyl()


def flags() -> dict[str, Flag]:
    """Every registered solver's plan-stage flags by name (one flag per name, shared by the solvers that
    take it): the solver fields of ``raico.stages.plan.PlanConfig``."""
    taken = {f.name for spec in SOLVERS.values() for f in spec.flags}
    out: dict[str, Flag] = {}
    for spec in SOLVERS.values():   # in the order of their options classes' FLAGS
        for f in spec.options_cls.FLAGS if spec.flags else ():
            if f.name in taken and out.setdefault(f.name, f) is not f:
                raise ValueError(f"two solvers declare the flag {f.name!r} differently")
    return out


def takers(flag: str) -> list[SolverSpec]:
    """The registered solvers that take plan-stage flag ``flag``."""
    return [s for s in SOLVERS.values() if any(f.name == flag for f in s.flags)]


def make_options(solver_name: str, options: dict[str, Any] | OptionsBase | None = None):
    """The validated options object of ``solver_name`` built from ``options``."""
    return get_solver(solver_name).options(options)


def get_solver(solver_name: str) -> SolverSpec:
    """The registered solver called ``solver_name`` (``ValueError`` naming the valid ones)."""
    if solver_name not in SOLVERS:
        raise ValueError(f"unknown solver {solver_name!r}; valid solvers: {sorted(SOLVERS)}")
    return SOLVERS[solver_name]


def solve(problem: Problem, solver_name: str,
          options: dict[str, Any] | OptionsBase | None = None, **init: Any) -> Result:
    """Run ``solver_name`` on ``problem`` with options from a dict (or an options object).

    ``init`` is passed to the solver (``U_init``, ``X_init`` for AICO, ``callback``).

    The result's ``X_iterations (iterations + 1, K, n_x)`` (float32) holds every iteration's
    trajectory at the steps ``t_iterations = iterate_steps(problem)``, collected through the
    solver's callback (``IterateHistory``, called before the caller's ``callback``): row 0 the
    initial guess rolled out (``X_initial``, whose cost is ``initial_cost``), row ``i`` the iterate
    of iteration ``i``; iterations that diverged report nothing and stay NaN. The last row of a
    run whose last iteration did not diverge is the result's ``X`` itself (FDDP: its controller
    rolled out on the planning model, as the plan stores it, rather than crocoddyl's iterate).
    """
    spec = get_solver(solver_name)
    history = IterateHistory(iterate_steps(problem))
    user = init.get("callback")

    def callback(record, X, U) -> None:  # noqa: ANN001
        history(record, X, U)
        if user is not None:
            user(record, X, U)

    opts = spec.options(options)
    result = spec.run(problem, opts, **{**init, "callback": callback})
    result.solver = solver_name
    if result.X_initial is not None:
        history.set(0, result.X_initial)
    if result.history and result.history[-1].iteration in history.rows:
        history.set(result.history[-1].iteration, result.X)
    result.X_iterations = history.array(result.iterations, problem.n_x)
    result.t_iterations = history.steps
    return result
