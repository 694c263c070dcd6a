"""AICO's and R-AICO's options (:class:`AICOOptions`) and the plan-stage flags that set them."""

from __future__ import annotations

import math
from dataclasses import dataclass

from raico.planning.problem import Flag, OptionsBase, check_range

SCHEDULES = ("fixed", "adaptive", "robust")
LAMBDA_FALLS = ("nielsen", "accelerated")
RANGE_METHODS = ("al", "ep")
CONTROL_BOXES = ("lagrangian", "boxddp")   # raico.planning.aico.boxqp.METHODS


def _resolve_schedule(value: str, problem_file: bool) -> str:
    """The schedule in force: the one given, else robust for a problem file, the thesis's fixed one else."""
    return value or ("robust" if problem_file else "fixed")


@dataclass(frozen=True)
class AICOOptions(OptionsBase):
    """Options of AICO / R-AICO (frozen; ``from_dict`` rejects unknown keys); each field's comment says
    what it does, the schedules are told in full in docs/planning.md (R-AICO's step size).

    ``FLAGS``: the options the plan stage exposes (``raico plan --alpha ... --alpha-schedule ...``).
    """

    FLAGS = (
        Flag("alpha", float, 1.0, "R-AICO regularization alpha (raico only).", unused=0.0),
        Flag("gamma", float, 1.0, "alpha^[n] = alpha^[n-1] gamma (raico only).", unused=1.0,
             only=("alpha_schedule", ("fixed",), "the fixed schedule's (--alpha-schedule fixed)")),
        Flag("alpha_schedule", str, "",
             "R-AICO: fixed (thesis: alpha^[n] = alpha^[n-1] gamma), adaptive (alpha shrinks after an iteration "
             "that lowers the cost, grows and retries after one that raises it) or robust (Levenberg-Marquardt "
             "style: alpha relative to the cost's curvature, acceptance by actual against predicted decrease; "
             "--alpha is its first relative value). Default: robust for --problem FILE, fixed for --plant/--task "
             "(the thesis's).", unused="fixed", option="schedule", resolve=_resolve_schedule),
        Flag("relinearize", bool, True, "AICO: relinearize inside the sweeps (theta rule).", unused=True,
             option="theta", to_option=lambda on: None if on else math.inf,
             only=("alpha_schedule", ("fixed", "adaptive"),
                   "not used by the robust schedule (one linearization per trial)")),
        Flag("belief_rate", float, 1.0, "AICO/R-AICO: learning rate on the belief update (Algorithm 1 line 13), "
             "in (0, 1].", unused=1.0,
             only=("alpha_schedule", ("fixed", "adaptive"),
                   "not used by the robust schedule (one linearization per trial)")),
        Flag("controller_rate", float, 1.0, "AICO/R-AICO: learning rate on the controller (Algorithm 1 line 18): "
             "the new controller blended with the previous one, in (0, 1].", unused=1.0),
        Flag("control_box", str, "lagrangian", "AICO/R-AICO: how the effort limits of torque controls are kept: "
             "lagrangian (the augmented Lagrangian, with the joint ranges) or boxddp (a box QP on each step's "
             "controls inside the backward pass, BoxDDP's; the joint ranges stay on the Lagrangian).",
             unused="lagrangian"),
    )

    #: maximum number of iterations (>= 1)
    iterations: int = 100
    #: R-AICO regularization ``alpha^[1]`` (>= 0; 0 is plain AICO), per (state unit)^2
    alpha: float = 0.0
    #: ``alpha^[n] = alpha^[n-1] gamma`` (> 0)
    gamma: float = 1.0
    #: relinearization threshold on ``||b_t - x_t||`` (state units; ``inf``: never relinearize within the
    #: sweeps; then the forward sweep is skipped, as it cannot change the controller, and run once at the
    #: end for the beliefs)
    theta: float = 0.1
    #: cap on the repeats of one time step within a sweep (>= 0); reached, the step keeps its last linearization
    max_repeats: int = 3
    #: plain AICO's learning rate on the belief: a repeat moves the linearization point
    #: ``x_t += rate (b_t - x_t)``, in (0, 1] (Algorithm 1, line 13)
    belief_rate: float = 1.0
    #: the other classic learning rate (Algorithm 1, line 18): an iteration's controller ``o, O`` is
    #: ``(1 - rate)`` times the previous one plus ``rate`` times the new one, in (0, 1] (1: the thesis's)
    controller_rate: float = 1.0
    #: ``q`` in ``Q = q I`` (> 0)
    process_noise: float = 1e-9
    #: ``S_0 = start_variance I`` (tight prior around ``x0``, > 0)
    start_variance: float = 1e-10
    #: converged when the relative cost change of two iterations is at most this
    tol_rel: float = 1e-9
    #: diverged when the cost exceeds this times the initial cost
    divergence_factor: float = 1e6
    #: ``"fixed"`` (thesis: ``alpha^[n] = alpha^[n-1] gamma`` whatever happens), ``"adaptive"`` (trust-region
    #: style: ``alpha *= shrink`` after an iteration that lowers the cost, else the iterate is rejected and
    #: ``alpha *= grow`` for the retry) or ``"robust"`` (Levenberg-Marquardt style: ``alpha = lambda kappa``,
    #: ``kappa`` the cost's curvature, acceptance by actual against predicted decrease; one linearization
    #: per trial). Each trial counts as an iteration. In full: docs/planning.md
    schedule: str = "fixed"
    #: the adaptive schedule's factor on alpha after an accepted iteration
    shrink: float = 0.3
    #: the adaptive schedule's factor on alpha after a rejected one
    grow: float = 4.0
    #: the adaptive schedule's least alpha
    alpha_min: float = 1e-4
    #: the adaptive schedule's largest alpha
    alpha_max: float = 1e8
    #: the robust schedule's factor on lambda (crocoddyl FDDP's x10 and /10)
    lm_factor: float = 10.0
    #: the robust schedule accepts a trial whose actual decrease is at least this times the predicted one
    accept: float = 0.1
    #: the robust schedule lowers lambda after a trial whose ratio is at least this
    decrease_above: float = 0.5
    #: the robust schedule's least lambda
    lambda_min: float = 1e-9
    #: the robust schedule's largest lambda (a trial rejected there stops the run: max-iterations)
    lambda_max: float = 1e9
    #: the robust schedule keeps the cost's cross term ``l_ux`` (the control toward gravity's), by a change of
    #: control variables (:mod:`raico.planning.aico.cross`); ``False``: dropped, as the other schedules do
    cross_terms: bool = True
    #: the robust schedule's fall of lambda after a good step: ``"accelerated"`` (the k-th very good step in a
    #: row divides it by ``lm_factor**k``, up to ``lm_factor**3``; the first trial from a start that is no
    #: trajectory judged so too) or ``"nielsen"`` (Nielsen's rule, at most ``/lm_factor``; the rule before):
    #: :func:`raico.planning.aico.steps.lambda_after`; Nielsen's by default (docs/planning.md: why)
    lambda_fall: str = "nielsen"
    #: the hard joint ranges and velocity limits: ``"al"`` (the augmented Lagrangian, :mod:`raico.planning.aico.bounds`)
    #: or ``"ep"`` (truncated-Gaussian EP messages into the task messages, :mod:`raico.planning.aico.truncated`)
    ranges: str = "al"
    #: ``ranges = "ep"``: the posterior ``exp(-cost / ep_temperature)`` whose truncated moments the sites match (1:
    #: AICO's own posterior; smaller: nearer the constrained optimum, stiffer sites)
    ep_temperature: float = 1.0
    #: ``ranges = "ep"``: at a feasible stationary point the temperature falls tenfold, down to this (an
    #: interior method's path; ``None``: it stays at ``ep_temperature``)
    ep_temperature_min: float | None = None
    #: ``ranges = "ep"``: the new site's share in a site update, in (0, 1]
    ep_damping: float = 1.0
    #: how the effort limits (a box on torque controls) are kept: ``"lagrangian"`` (the augmented Lagrangian
    #: with the joint ranges, :mod:`raico.planning.aico.bounds`) or ``"boxddp"`` (a box QP inside the backward
    #: pass, BoxDDP's: :mod:`raico.planning.aico.boxqp`; the sweeps then run in Python)
    control_box: str = "lagrangian"

    def validate(self) -> None:
        if self.schedule not in SCHEDULES:
            raise ValueError(f"option schedule must be one of {', '.join(SCHEDULES)}, got {self.schedule!r}")
        if self.lambda_fall not in LAMBDA_FALLS:
            raise ValueError(f"option lambda_fall must be one of {', '.join(LAMBDA_FALLS)}, got {self.lambda_fall!r}")
        if self.ranges not in RANGE_METHODS:
            raise ValueError(f"option ranges must be one of {', '.join(RANGE_METHODS)}, got {self.ranges!r}")
        check_range("ep_temperature", self.ep_temperature, lo=0.0, lo_open=True)
        if self.ep_temperature_min is not None:
            check_range("ep_temperature_min", self.ep_temperature_min, lo=0.0, lo_open=True)
        check_range("ep_damping", self.ep_damping, lo=0.0, hi=1.0, lo_open=True)
        if self.control_box not in CONTROL_BOXES:
            raise ValueError(f"option control_box must be one of {', '.join(CONTROL_BOXES)}, got {self.control_box!r}")
        check_range("lm_factor", self.lm_factor, lo=1.0, lo_open=True)
        check_range("accept", self.accept, lo=0.0, hi=1.0)
        check_range("decrease_above", self.decrease_above, lo=self.accept)
        check_range("lambda_min", self.lambda_min, lo=0.0, lo_open=True)
        check_range("lambda_max", self.lambda_max, lo=self.lambda_min)
        check_range("shrink", self.shrink, lo=0.0, hi=1.0, lo_open=True)
        check_range("grow", self.grow, lo=1.0, lo_open=True)
        check_range("alpha_min", self.alpha_min, lo=0.0, lo_open=True)
        check_range("alpha_max", self.alpha_max, lo=self.alpha_min)
        if self.schedule != "fixed" and not self.alpha > 0:
            raise ValueError(f"the {self.schedule} schedule needs alpha > 0 (R-AICO)")
        check_range("iterations", self.iterations, lo=1, integer=True)
        check_range("alpha", self.alpha, lo=0.0)
        check_range("gamma", self.gamma, lo=0.0, lo_open=True)
        check_range("theta", self.theta, lo=0.0, lo_open=True)
        check_range("max_repeats", self.max_repeats, lo=0, integer=True)
        check_range("belief_rate", self.belief_rate, lo=0.0, hi=1.0, lo_open=True)
        check_range("controller_rate", self.controller_rate, lo=0.0, hi=1.0, lo_open=True)
        check_range("process_noise", self.process_noise, lo=0.0, lo_open=True)
        check_range("start_variance", self.start_variance, lo=0.0, lo_open=True)
        check_range("tol_rel", self.tol_rel, lo=0.0)
        check_range("divergence_factor", self.divergence_factor, lo=1.0, lo_open=True)
        if not math.isfinite(self.alpha) or not math.isfinite(self.gamma):
            raise ValueError("options alpha and gamma must be finite")
