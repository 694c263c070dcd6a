"""Claims of the thesis checked against measured summaries, each by a stated criterion.

A claim function takes ``S`` (variant label -> summary of :func:`raico.stages.evaluate.summary.summarize`)
and ``execs`` (metric dicts of the executions) and returns ``(claim, criterion, measured, holds)``, or a
list of such tuples where the thesis's sentence is judged per setting (per alpha, per sigma*).
The functions are pure, so each is unit-tested on synthetic summaries whose verdict is known.

A claim of the thesis is judged with the thesis's own solvers (iLQG, AICO, R-AICO with a fixed alpha),
at the figure's iteration budget, from the thesis's start, on the figure its sentence is written about
(:data:`THESIS`, :data:`SECTION_FIGURES`); comparisons with crocoddyl FDDP, long-budget runs, ablations and
executions on the free-standing robot are claims beyond the thesis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from raico.stages.evaluate.summary import EXECUTED_VIA_TOL, executed_achieved


def _fmt(x: float) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return f"{x:.3g}"


def _pct(x: float) -> str:
    """A fraction as a percentage ("n/a" when not finite)."""
    return "n/a" if x is None or not math.isfinite(x) else f"{100 * x:.3g} %"


# ----------------------------------------------------------------------------- margins
NEAR = 0.05  # a margin within 5 % of its limit is fragile whatever the runs' spread
_NOT = {"<=": ">", ">=": "<", "<": ">=", ">": "<=", "=": "!="}


@dataclass(frozen=True)
class Check:
    """One condition of a criterion, in the criterion's own terms: the measured ``value`` of ``what`` against its
    ``limit`` (``op`` one of ``<=``, ``>=``, ``<``, ``>``, ``=``); ``unit`` follows each number (" m", "x", "/10").
    ``spread``: the quantity's spread over the runs (their interquartile range) where it has one: a margin inside
    it is a margin that a change below the numbers' spread closes."""

    what: str
    value: float
    op: str
    limit: float
    unit: str = ""
    spread: float = math.nan

    @property
    def ok(self) -> bool:
        v, lim = self.value, self.limit
        if v is None or (isinstance(v, float) and math.isnan(v)):
            return False
        return {"<=": v <= lim, ">=": v >= lim, "<": v < lim, ">": v > lim, "=": v == lim}[self.op]

    @property
    def margin(self) -> float:
        """How far the value is from its limit, positive on the side where the condition holds."""
        if self.value is None or not math.isfinite(self.value) or not math.isfinite(self.limit):
            return math.inf if self.ok else -math.inf
        d = self.limit - self.value if self.op in ("<=", "<") else self.value - self.limit
        return -abs(d) if self.op == "=" else d

    def text(self) -> str:
        """``what value (holds at op limit; margin m)``."""
        m = self.margin
        tail = f"; margin {_fmt(abs(m))}{self.unit}" if math.isfinite(m) and self.op != "=" else ""
        return f"{self.what} {_fmt(self.value)}{self.unit} (holds at {self.op} {_fmt(self.limit)}{self.unit}{tail})"

    def said(self) -> str:
        """The condition as measured: ``what value op limit`` with the operator that is true."""
        op = self.op if self.ok else _NOT[self.op]
        return f"{self.what} {_fmt(self.value)}{self.unit} {op} {_fmt(self.limit)}{self.unit}"

    def near(self) -> bool:
        """The margin is inside the quantity's spread over the runs, or within ``NEAR`` of the limit where the runs
        agree (their spread is then no measure of how little it takes). A quantity without a per-run spread (a fit to
        the median run) is judged by leaving seeds out instead (:func:`evaluate_claims`)."""
        m = self.margin
        if not math.isfinite(m) or self.op == "=" or not math.isfinite(self.spread):
            return False
        return abs(m) < self.spread or abs(m) < NEAR * abs(self.limit)


def iqr(values) -> float:
    """The interquartile range of the finite ``values`` (of two: their distance; NaN with fewer)."""
    v = np.asarray([x for x in values if x is not None], float)
    v = v[np.isfinite(v)]
    return float(np.subtract(*np.percentile(v, [75, 25]))) if v.size >= 3 else float(np.ptp(v)) if v.size == 2 \
        else math.nan


def judged(checks: list[Check], rule: str = "all", prefix: str = "") -> dict:
    """The margin and the reason of a verdict decided by ``checks`` (``rule`` "all": every one must hold; "any":
    one is enough): the margin lists every check against its limit; the reason names the checks that decided it
    (where it fails: the failed ones, those that held beside them), composed from the measured numbers."""
    ok = all(c.ok for c in checks) if rule == "all" else any(c.ok for c in checks)
    # the checks whose flip alone would flip the verdict: all of them where every one holds ("all") or none does
    # ("any"); otherwise only a lone failed ("all") or lone held ("any") check
    side = [c for c in checks if c.ok != (rule == "all")]
    deciding = checks if not side else side if len(side) == 1 else []
    failed = [c.said() for c in checks if not c.ok]
    held = [c.said() for c in checks if c.ok]
    if rule == "all":
        why = "; ".join(failed) + (f" (while {'; '.join(held)})" if held and failed else "")
    else:
        why = "none holds: " + "; ".join(failed)
    near = [f"{c.what}: margin {_fmt(abs(c.margin))}{c.unit}, inside the runs' spread ({_fmt(c.spread)}{c.unit})"
            if math.isfinite(c.spread) and abs(c.margin) < c.spread else
            f"{c.what}: margin {_fmt(abs(c.margin))}{c.unit}, within {NEAR:.0%} of its limit" for c in deciding
            if c.near()]
    pre = f"{prefix}: " if prefix else ""
    return {"ok": ok, "margin": pre + "; ".join(c.text() for c in checks), "why": pre + why if not ok else "",
            "near": near}


def merge(*parts: dict, rule: str = "all") -> dict:
    """One verdict's margin and reason from those of its parts (``rule`` as in :func:`judged`)."""
    ok = all(p["ok"] for p in parts) if rule == "all" else any(p["ok"] for p in parts)
    deciding = [p for p in parts if not p["ok"]] if not ok else parts
    return {"ok": ok, "margin": " | ".join(p["margin"] for p in parts),
            "why": "; ".join(p["why"] for p in deciding if p["why"]) if not ok else "",
            "near": [n for p in parts for n in p["near"]]}


ADAPTIVE = "R-AICO adaptive"  # label prefix of R-AICO with the adaptive alpha schedule (beyond the thesis)
THESIS_SOLVERS = ("iLQG", "AICO", "R-AICO a=1", "R-AICO a=10")  # the thesis's solvers (labels), fixed alpha, gamma 1


def _thesis_variant(label: str) -> bool:
    """A variant the thesis ran: not an ablation (gamma != 1, the rollout start, no sweep relinearization)."""
    return ", " not in label and "no sweep" not in label


def _raico(S: dict) -> dict:
    """The thesis's R-AICO variants (fixed alpha schedule, gamma = 1, x0 held)."""
    return {k: v for k, v in S.items() if k.startswith("R-AICO") and not k.startswith(ADAPTIVE) and _thesis_variant(k)}


def _thesis_solvers(S: dict) -> dict:
    """The figure's runs of the thesis's own solvers at the figure's budget (:data:`THESIS_SOLVERS`)."""
    return {k: S[k] for k in THESIS_SOLVERS if k in S}


FLAT_RATE = 0.01  # "flat": the median run's cost changes by at most 1 % per iteration, on average ...
FLAT_ITERS = 5  # ... over its last 5 iterations (a change of at most 5 % from 5 iterations before the end)
FAST_ITERS = 10  # "converge fast": the median run's cost within 1 % of its final value from iteration 10 on
LOW_COST = 1.5  # "a low cost": a median final cost within 1.5x the best of the thesis's solvers on the figure ...
HIGH_COST = 2.0  # "cannot infer solutions with low costs": diverged, above 2x that best, or the via-points missed
VIA_TOL = 0.01  # m: a via-point is met when the run's largest via-point error is at most 1 cm
OUTPERFORM = 0.5  # "considerably outperformed": at most half the competitor's final cost, paired by initial state
# "the costs decay exponentially fast" (§3.5), read on the log cost (as the report's figures plot it): the gap to
# the final cost shrinks by a constant factor per iteration, and the decay is over within the budget
DECAY_RHO = 0.8  # the gap shrinks by at least 20 % per iteration (rho <= 0.8) ...
DECAY_BAND = 0.01  # ... read over the iterations more than 1 % above the final cost (below, the gap is noise) ...
DECAY_FACTOR = 2.0  # ... with at least 80 % of them within a factor 2 of the exponential through them ...
DECAY_FIT = 0.8
# ... and the log cost changing by at most FLAT_RATE per iteration over the last FLAT_ITERS (the tail)


def per_iteration_change(s: dict) -> float:
    """The median run's mean relative cost change per iteration over its last ``FLAT_ITERS`` iterations."""
    moved = s.get("flat_last5_median", math.nan)
    return moved / FLAT_ITERS if math.isfinite(moved) else math.nan


def is_flat(s: dict) -> bool:
    """No run diverged and the median run's cost is flat at the end of the budget (``per_iteration_change``
    at most ``FLAT_RATE``)."""
    return s["diverged"] == 0 and per_iteration_change(s) <= FLAT_RATE


def thesis_best(S: dict) -> float:
    """The lowest median final cost of the thesis's own solvers on the figure (its budget, its start)."""
    vals = [s["final_cost_median"] for s in _thesis_solvers(S).values() if math.isfinite(s["final_cost_median"])]
    return min(vals) if vals else math.nan


def low_cost(s: dict, best: float) -> bool:
    """A low-cost solution: no run diverged, a median final cost within ``LOW_COST`` of ``best`` (the best of the
    thesis's solvers) and the via-points met (median largest via-point error at most ``VIA_TOL``)."""
    return (s["diverged"] == 0 and math.isfinite(best) and s["final_cost_median"] <= LOW_COST * best
            and s["max_via_error_median"] <= VIA_TOL)


def not_low_cost(s: dict, best: float) -> bool:
    """No low-cost solution: a run diverged, or the median final cost exceeds ``HIGH_COST`` times ``best``, or the
    via-points are missed (median largest via-point error above ``VIA_TOL``)."""
    return (s["diverged"] > 0 or not math.isfinite(s["final_cost_median"])
            or s["final_cost_median"] > HIGH_COST * best or not s["max_via_error_median"] <= VIA_TOL)


LOW_TEXT = (f"low cost: no run diverged, median final cost within {LOW_COST:g}x the best of the thesis's solvers on "
            f"the figure (its budget, its start) and the via-points met (median largest via-point error <= "
            f"{VIA_TOL * 100:g} cm)")
NOT_LOW_TEXT = (f"no low-cost solution: a run diverged, or its median final cost exceeds {HIGH_COST:g}x the best of "
                f"the thesis's solvers on the figure, or its median largest via-point error exceeds "
                f"{VIA_TOL * 100:g} cm")
FLAT_TEXT = (f"flat: no run diverged and the median run's cost changes by at most {FLAT_RATE:.0%} per iteration over "
             f"its last {FLAT_ITERS} iterations")


def _solver_nums(k: str, s: dict, best: float) -> str:
    return (f"{k}: final median {_fmt(s['final_cost_median'])} ({_fmt(s['final_cost_median'] / best)}x the best "
            f"thesis solver), largest via-point error median {_fmt(s['max_via_error_median'])} m, cost change "
            f"{_pct(per_iteration_change(s))} per iteration over the last {FLAT_ITERS}, diverged "
            f"{s['diverged']}/{s['runs']}")


def _diverged(k: str, s: dict) -> Check:
    return Check(f"{k}'s diverged runs", s["diverged"], "=", 0, f"/{s['runs']}")


def _flat_check(k: str, s: dict) -> Check:
    """The median run's cost change per iteration over its last ``FLAT_ITERS`` iterations, in %."""
    return Check(f"{k}'s cost change per iteration over its last {FLAT_ITERS}", 100 * per_iteration_change(s), "<=",
                 100 * FLAT_RATE, " %")


def _cost_check(k: str, s: dict, best: float, op: str, limit: float, against: str = "the best thesis solver's") -> Check:
    """The median final cost over ``best``, its spread the interquartile range of the runs' final costs over it."""
    costs = [x for x in s.get("final_costs") or [] if math.isfinite(x)]
    return Check(f"{k}'s median final cost / {against}", s["final_cost_median"] / best if best else math.nan, op,
                 limit, "x", spread=iqr(costs) / best if best else math.nan)


def _via_check(k: str, s: dict, op: str = "<=") -> Check:
    return Check(f"{k}'s median largest via-point error", s["max_via_error_median"], op, VIA_TOL, " m",
                 spread=iqr(s.get("via_errors") or []))


def low_cost_checks(k: str, s: dict, best: float) -> list[Check]:
    """:func:`low_cost` as checks (every one must hold)."""
    return [_diverged(k, s), _cost_check(k, s, best, "<=", LOW_COST), _via_check(k, s)]


def not_low_cost_checks(k: str, s: dict, best: float) -> list[Check]:
    """:func:`not_low_cost` as checks (one is enough)."""
    return [Check(f"{k}'s diverged runs", s["diverged"], ">", 0, f"/{s['runs']}"),
            _cost_check(k, s, best, ">", HIGH_COST), _via_check(k, s, ">")]


REFERENCE_TEXT = ("the lowest median final cost any solver reaches on the figure's initial states, the long-budget "
                  "runs included: adaptive R-AICO at 100 iterations, and crocoddyl FDDP at 100 on the analytic arm")


def reference_cost(S: dict) -> float:
    """The reference optimum of a figure's problem (``REFERENCE_TEXT``), for the claims beyond the thesis: the
    lowest median final cost any solver run in the figure on all its initial states reaches: the thesis's
    solvers, the ablations, and the long-budget runs (``raico.thesis.figures.REFERENCE``, adaptive R-AICO at
    100 iterations; crocoddyl FDDP at 100 where the figure has it). Variants run on fewer initial states, such
    as the FDDP rule ablations, are left out: a median over other problems."""
    full = max((s.get("runs", 0) for s in S.values()), default=0)
    vals = [s["final_cost_median"] for s in S.values()
            if s.get("runs", 0) == full and math.isfinite(s.get("final_cost_median", math.nan))]
    return min(vals) if vals else math.nan


def _flat_and_low(s: dict, ref: float) -> bool:
    """A variant converged (the rule of the claims beyond the thesis): flat (``is_flat``) and a median final cost
    within ``LOW_COST`` of ``ref`` (the reference optimum)."""
    return is_flat(s) and s["final_cost_median"] <= LOW_COST * ref


@dataclass(frozen=True)
class Decay:
    """How a cost curve decays, read on its log: ``rho`` the factor its gap to the final cost shrinks by per
    iteration (the Theil-Sen slope of ``ln(c_k - c_end)`` over the iterations more than ``DECAY_BAND`` above the end,
    exponentiated; 0 where fewer than three are); ``fit`` the share of those iterations whose log gap lies within
    ``ln DECAY_FACTOR`` of that line; ``tail`` the log cost's mean change per iteration over the last ``FLAT_ITERS``
    (as a relative rate, ``exp(|slope|) - 1``); ``points`` how many iterations the slope was read from."""

    rho: float
    fit: float
    tail: float
    points: int


def decay_fit(curve) -> Decay:
    """:class:`Decay` of the finite values of a cost curve (all the iterations of the figure's budget), NaNs with
    fewer than ``FLAT_ITERS + 1`` values or a non-positive cost. Read on the log of the cost, as the report's
    figures plot it: an exponential decay to a floor is a straight line in ``ln(c_k - c_end)``, whatever the scale
    of the first iterate. The slope is a median of pairwise slopes, which one iterate cannot move far: a first
    iterate 12x the end and one 1.7x it, the rest the same, read the same rate."""
    c = np.asarray(curve, float)
    c = c[np.isfinite(c)]
    if c.size < FLAT_ITERS + 1 or np.any(c <= 0):
        return Decay(math.nan, math.nan, math.nan, 0)
    tail = math.expm1(abs(math.log(c[-1] / c[-1 - FLAT_ITERS])) / FLAT_ITERS)
    k = np.nonzero(c - c[-1] > DECAY_BAND * c[-1])[0]
    if k.size < 3:  # within the band from the third iteration on: converged at once
        return Decay(0.0, 1.0, tail, int(k.size))
    y = np.log(c[k] - c[-1])
    i, j = np.triu_indices(k.size, 1)
    slope = float(np.median((y[j] - y[i]) / (k[j] - k[i])))
    line = float(np.median(y - slope * k)) + slope * k
    fit = float(np.mean(np.abs(y - line) <= math.log(DECAY_FACTOR)))
    return Decay(math.exp(slope), fit, tail, int(k.size))


def _decays(curve) -> tuple[bool, Decay]:
    d = decay_fit(curve)
    return bool(d.rho <= DECAY_RHO and d.fit >= DECAY_FIT and d.tail <= FLAT_RATE), d


DECAY_TEXT = (f"read on the log of the median run's cost over all the iterations of the figure's budget: the gap to "
              f"its final cost shrinks by at least {1 - DECAY_RHO:.0%} per iteration (rho <= {DECAY_RHO}: the median "
              f"of the pairwise slopes of ln(c_k - c_end) over the iterations more than {DECAY_BAND:.0%} above the "
              f"end), at least {DECAY_FIT:.0%} of those iterations lie within a factor {DECAY_FACTOR:g} of that "
              f"exponential (an exponential describes the decay), and the decay is over by the end (the log cost "
              f"changes by at most {FLAT_RATE:.0%} per iteration over the last {FLAT_ITERS}: \"decay\" reaches its "
              f"floor within the budget); no run diverged")


def decay_checks(k: str, s: dict, d: Decay) -> list[Check]:
    """:func:`_decays` as checks (every one must hold), with the runs' divergences."""
    return [Check(f"{k}'s gap shrink factor rho", d.rho, "<=", DECAY_RHO),
            Check(f"{k}'s iterations on the exponential", d.fit, ">=", DECAY_FIT),
            Check(f"{k}'s log-cost change per iteration over its last {FLAT_ITERS}", 100 * d.tail, "<=",
                  100 * FLAT_RATE, " %"),
            _diverged(k, s)]


def _decay_nums(curve, d: Decay) -> str:
    n = iterations_to_final(curve)
    return (f"rho {_fmt(d.rho)} (from {d.points} iterations above the {DECAY_BAND:.0%} band), "
            f"{_pct(d.fit)} of them within a factor {DECAY_FACTOR:g} of the exponential, log-cost change "
            f"{_pct(d.tail)} per iteration over the last {FLAT_ITERS}; within 1 % of its final cost from iteration "
            f"{n if n is not None else 'n/a'} of {len(curve)}; cost {_fmt(_at(curve, 0))} at iteration 1, "
            f"{_fmt(_at(curve, 9))} at 10, {_fmt(_at(curve, len(curve) - 1))} at {len(curve)}")


def claim_raico_decays_fast(S, execs):
    """One row per R-AICO alpha: its median run's cost curve over the figure's budget decays exponentially
    (:data:`DECAY_TEXT`)."""
    rows = []
    for k, s in _raico(S).items():
        curve = s.get("cost_curve_median") or []
        ok, d = _decays(curve)
        j = judged(decay_checks(k, s, d))
        rows.append((f"{k}: the costs decay exponentially fast", DECAY_TEXT, _decay_nums(curve, d),
                     bool(ok and s["diverged"] == 0), s["runs"], j))
    return rows or [("R-AICO's costs decay exponentially fast", "needs R-AICO runs", "no runs", False)]


def _at(curve, k: int) -> float:
    c = list(curve or [])
    return float(c[min(k, len(c) - 1)]) if c and c[min(k, len(c) - 1)] is not None else math.nan


def iterations_to_final(curve, tol: float = 0.01) -> int | None:
    """The first iteration (1-based) from which a cost curve stays within ``tol`` of its last value (None if
    it is empty or not finite at the end)."""
    c = np.asarray(curve, float)
    if c.size == 0 or not np.isfinite(c[-1]):
        return None
    off = ~(np.abs(c - c[-1]) <= tol * abs(c[-1]))
    return int(np.nonzero(off)[0][-1] + 2) if off.any() else 1


def claim_raico_converges(S, execs):
    """Beyond the thesis: on the arm the thesis says nothing of R-AICO's convergence (its sentence is about the
    Nao's balancing). Each R-AICO variant is flat at the end of the figure's budget and within ``LOW_COST`` of
    the reference optimum (long-budget runs and crocoddyl FDDP included)."""
    R = _raico(S)
    ref = reference_cost(S)
    ok = bool(R) and math.isfinite(ref) and all(_flat_and_low(s, ref) for s in R.values())
    budget = max((len(s.get("cost_curve_median") or []) for s in R.values()), default=0)
    nums = "; ".join(f"{k}: cost change {_pct(per_iteration_change(s))} per iteration over the last {FLAT_ITERS}, "
                     f"final median {_fmt(s['final_cost_median'])} ({_fmt(s['final_cost_median'] / ref)}x the "
                     f"reference), diverged {s['diverged']}/{s['runs']}, largest via-point error median "
                     f"{_fmt(s['max_via_error_median'])} m" for k, s in R.items())
    j = judged([c for k, s in R.items() for c in (_diverged(k, s), _flat_check(k, s),
                                                   _cost_check(k, s, ref, "<=", LOW_COST, "the reference"))])
    return (f"beyond the thesis: R-AICO converges on the arm within the figure's budget ({budget} iterations)",
            f"for each R-AICO variant: {FLAT_TEXT}, and its median final cost is within {LOW_COST:g}x the reference "
            f"optimum ({REFERENCE_TEXT})", f"{nums}; reference optimum {_fmt(ref)}", ok, None, j)


def claim_raico_converged_25(S, execs):
    """Fig. 3.4B, one row per alpha in {1, 10}: after the thesis's 25 iterations the cost is flat and the CoG
    via-points are met."""
    rows = []
    for k, s in _raico(S).items():
        n = len(s.get("cost_curve_median") or [])
        j = judged([_diverged(k, s), _flat_check(k, s), _via_check(k, s)])
        ok = is_flat(s) and s["max_via_error_median"] <= VIA_TOL
        rows.append((f"{k} converged after 25 iterations",
                     f"after the figure's {n} iterations: {FLAT_TEXT}, and the CoG via-points met (median largest "
                     f"via-point error <= {VIA_TOL * 100:g} cm; the held right sole left out)",
                     f"cost change {_pct(per_iteration_change(s))} per iteration over the last {FLAT_ITERS}; final "
                     f"median {_fmt(s['final_cost_median'])}; largest via-point error median "
                     f"{_fmt(s['max_via_error_median'])} m; diverged {s['diverged']}/{s['runs']}", ok, s["runs"], j))
    return rows or [("R-AICO converged after 25 iterations", "needs R-AICO runs", "no runs", False)]


def _best_raico(S) -> float:
    return min((s["final_cost_median"] for s in _raico(S).values()), default=math.nan)


def claim_aico_unstable(S, execs):
    a, best = S["AICO"], thesis_best(S)
    curve = np.asarray(a.get("cost_curve_median") or [], float)
    rose = bool(curve.size and np.isfinite(curve).all() and curve[-1] > (1 + FLAT_RATE) * curve.min())
    unstable = a["diverged"] > 0 or not is_flat(a) or rose
    ok = unstable and not_low_cost(a, best)
    lowest = float(np.min(curve)) if curve.size else math.nan
    j = merge(judged([Check("AICO's diverged runs", a["diverged"], ">", 0, f"/{a['runs']}"),
                      Check(f"AICO's cost change per iteration over its last {FLAT_ITERS}",
                            100 * per_iteration_change(a), ">", 100 * FLAT_RATE, " %"),
                      Check("AICO's final / lowest median cost", curve[-1] / lowest if curve.size and lowest else math.nan,
                            ">", 1 + FLAT_RATE, "x")], "any", "unstable"),
              judged(not_low_cost_checks("AICO", a, best), "any", "no low-cost solution"))
    return ("plain AICO is unstable and infers no low-cost solution",
            f"unstable: a run diverged, or the median run's cost is not flat at the end of the budget ({FLAT_TEXT}), "
            f"or it ends more than {FLAT_RATE:.0%} above its lowest value; and {NOT_LOW_TEXT}",
            f"{_solver_nums('AICO', a, best)}; its median cost curve's lowest {_fmt(float(np.min(curve)) if curve.size else math.nan)}; "
            f"best thesis solver {_fmt(best)}", ok, a["runs"], j)


def claim_aico_unstable_without_relinearization(S, execs):
    a, best = S["AICO (no sweep relinearization)"], _best_raico(S)
    ok = a["diverged"] > 0 or a["final_cost_median"] > 2 * best or a["final_cost_max"] > 2 * best
    j = judged([Check("diverged runs", a["diverged"], ">", 0, f"/{a['runs']}"),
                Check("median final cost / the best R-AICO's", a["final_cost_median"] / best, ">", 2, "x"),
                Check("worst final cost / the best R-AICO's", a["final_cost_max"] / best, ">", 2, "x")], "any")
    return ("ablation: AICO taking full Gauss-Newton steps (theta = inf) is unstable",
            "it diverges in some run, or its median or worst final cost exceeds 2x the best R-AICO's median",
            f"AICO without relinearization: final median {_fmt(a['final_cost_median'])}, worst "
            f"{_fmt(a['final_cost_max'])}, diverged {a['diverged']}/{a['runs']}; best R-AICO {_fmt(best)}", ok, None, j)


def claim_aico_fails(S, execs):
    a, best = S["AICO"], _best_raico(S)
    ok = a["diverged"] >= a["runs"] / 2 or a["final_cost_median"] > 10 * best
    j = judged([Check("AICO's diverged runs", a["diverged"], ">=", a["runs"] / 2, f"/{a['runs']}"),
                Check("AICO's median final cost / the best R-AICO's", a["final_cost_median"] / best if best else math.nan,
                      ">", 10, "x")], "any")
    return ("plain AICO fails on the analytic model", "AICO diverges in at least half the runs, or its median "
            "final cost exceeds 10x the best R-AICO's", f"AICO final median {_fmt(a['final_cost_median'])}, "
            f"diverged {a['diverged']}/{a['runs']}; best R-AICO {_fmt(best)}", ok, a["runs"], j)


def claim_ilqg_stalls(S, execs):
    i, best = S["iLQG"], thesis_best(S)
    return ("iLQG cannot generate movement policies with low costs on the analytic model", NOT_LOW_TEXT,
            f"{_solver_nums('iLQG', i, best)}; best thesis solver {_fmt(best)}", not_low_cost(i, best), i["runs"],
            judged(not_low_cost_checks("iLQG", i, best), "any"))


def claim_ilqg_performs_well(S, execs):
    """§3.4 "iLQG performed well for the pseudo dynamics model", a sentence about cost: iLQG converged (flat, no run
    diverged) to a median final cost within ``LOW_COST`` of the best of the thesis's solvers on the figure; its
    via-point misses are reported beside it, not judged (the sentence says nothing of them)."""
    i = S["iLQG"]
    best = thesis_best({k: v for k, v in S.items() if k != "iLQG"})  # the others: a best with iLQG in cannot fail
    j = judged([_diverged("iLQG", i), _flat_check("iLQG", i),
                _cost_check("iLQG", i, best, "<=", LOW_COST, "the best other thesis solver's")])
    vias = [x for x in i.get("via_errors") or [] if math.isfinite(x)]
    missed = sum(x > VIA_TOL for x in vias)
    return ("iLQG performs well on the pseudo-dynamics model",
            f"iLQG converged at the figure's budget ({FLAT_TEXT}) to a median final cost within {LOW_COST:g}x the best "
            f"of the other thesis solvers on the figure (AICO, R-AICO; its budget, its start); the via-point errors "
            f"are reported beside it, not judged (the sentence is about cost)",
            f"iLQG: final median {_fmt(i['final_cost_median'])} ({_fmt(i['final_cost_median'] / best)}x the best other "
            f"thesis solver), cost change {_pct(per_iteration_change(i))} per iteration over the last {FLAT_ITERS}, "
            f"diverged {i['diverged']}/{i['runs']}; best other thesis solver {_fmt(best)}; runs missing a via-point by "
            f"more than {VIA_TOL * 100:g} cm: {missed}/{len(vias)}", j["ok"], i["runs"], j)


def paired(a: dict, b: dict, key: str) -> list[tuple[float, float]]:
    """Per initial state the values ``key`` (a per-run list of :func:`summarize`) of two variants run on the same
    seeds (the shorter list decides)."""
    return list(zip(a.get(key) or [], b.get(key) or []))


def _ratio(x: float, y: float) -> float:
    """``x / y`` of two costs, a diverged (infinite) ``y`` giving 0 and a diverged ``x`` infinity."""
    if not math.isfinite(x):
        return math.inf
    if not math.isfinite(y):
        return 0.0
    return x / y if y > 0 else math.inf


def claim_raico_outperforms(S, execs):
    """Fig. 3.2C,D, one row per alpha: R-AICO against iLQG and plain AICO from the same initial states at the
    thesis's budget, paired by seed: its final cost at most ``OUTPERFORM`` times the competitor's and its largest
    via-point error smaller, each in the median over the seeds."""
    rows = []
    rivals = {k: S[k] for k in ("iLQG", "AICO") if k in S}
    for k, r in _raico(S).items():
        ok, parts, checks = bool(rivals), [], []
        for c, s in rivals.items():
            cost = np.median([_ratio(x, y) for x, y in paired(r, s, "final_costs")] or [math.nan])
            via = [x < y for x, y in paired(r, s, "via_errors") if not (math.isnan(x) or math.isnan(y))]
            better = sum(via)
            ok = ok and cost <= OUTPERFORM and 2 * better > len(via)
            checks += [Check(f"median final cost ratio to {c}", float(cost), "<=", OUTPERFORM, "x"),
                       Check(f"seeds with the smaller via-point error than {c}", better, ">", len(via) / 2,
                             f"/{len(via)}")]
            parts.append(f"against {c}: final cost ratio median {_fmt(float(cost))} (diverged {s['diverged']}/"
                         f"{s['runs']} of {c}'s runs, counted as infinite cost), via-point error smaller in "
                         f"{better}/{len(via)} seeds ({_fmt(r['max_via_error_median'])} vs "
                         f"{_fmt(s['max_via_error_median'])} m, medians)")
        rows.append((f"{k} considerably outperforms iLQG and plain AICO",
                     f"paired by initial state, against each of iLQG and AICO: the median over the seeds of R-AICO's "
                     f"final cost over the competitor's is at most {OUTPERFORM:g} (a diverged competitor run counts "
                     f"as an infinite cost), and R-AICO's largest via-point error is the smaller in more than half the "
                     f"seeds", "; ".join(parts) or "no competitor runs", ok, r["runs"], judged(checks)))
    return rows or [("R-AICO considerably outperforms iLQG and AICO", "needs R-AICO runs", "no runs", False)]


BASELINE = "crocoddyl FDDP"
FDDP_HELD = "crocoddyl FDDP (x0 held)"
FDDP_ROLLOUT = "crocoddyl FDDP (rollout start)"
FDDP_ACCEPT_ANY = "crocoddyl FDDP (rollout start), iLQG's acceptance rule"
FDDP_ILQG_SCHEDULE = "crocoddyl FDDP (rollout start), iLQG's regularization schedule"
FDDP_WITHIN = 1.10  # "reaches FDDP's cost": within 10 %


def claim_raico_reaches_fddp(S, execs):
    f, fr = S[FDDP_HELD], S.get(FDDP_ROLLOUT)
    R = _raico(S)
    lab = min(R, key=lambda k: R[k]["final_cost_median"]) if R else None
    r = R[lab] if lab else None
    rf, ff = (r["final_cost_median"] if r else math.nan), f["final_cost_median"]
    ok = r is not None and math.isfinite(rf) and math.isfinite(ff) and rf <= FDDP_WITHIN * ff
    j = judged([Check("the best R-AICO's median final cost / FDDP's", rf / ff if ff else math.nan, "<=", FDDP_WITHIN,
                      "x")])
    nums = (f"best R-AICO ({lab}): final median {_fmt(rf)} after {_fmt(r['wall_time_median_s'])} s; " if r else
            "no R-AICO runs; ")
    nums += (f"crocoddyl FDDP (x0 held): {_fmt(ff)} after {_fmt(f['wall_time_median_s'])} s "
             f"(R-AICO/FDDP {_fmt(rf / ff if ff else math.nan)})")
    if fr:
        nums += f"; FDDP from the rollout start: {_fmt(fr['final_cost_median'])} after {_fmt(fr['wall_time_median_s'])} s"
    return ("beyond the thesis: R-AICO reaches a modern DDP's cost (crocoddyl FDDP, same problem, same start)",
            f"the best R-AICO variant's median final cost is at most {FDDP_WITHIN:g}x crocoddyl FDDP's from the same "
            "start (x0 held at every node); wall times are medians of whole runs (R-AICO: the thesis's iteration "
            "budget; FDDP: its own), the figure's right panel shows cost against wall time", nums, ok, None, j)


def claim_adaptive_reaches_fddp(S, execs):
    a = next((v for k, v in S.items() if k.startswith(ADAPTIVE) and _thesis_variant(k.replace(" (a0=", "("))), None)
    f, fr = S[FDDP_HELD], S.get(FDDP_ROLLOUT)
    if a is None:
        return ("beyond the thesis: adaptive R-AICO reaches FDDP's cost within FDDP's wall time",
                "needs an adaptive R-AICO variant", "no adaptive R-AICO runs", False)
    ca, cf = a["final_cost_median"], f["final_cost_median"]
    ta, tf = a["wall_time_median_s"], f["wall_time_median_s"]
    ok = (a["diverged"] == 0 and all(math.isfinite(x) for x in (ca, cf, ta, tf))
          and ca <= FDDP_WITHIN * cf and ta <= tf)
    j = judged([_diverged(a["label"], a), Check("median final cost / FDDP's", ca / cf if cf else math.nan, "<=",
                                                FDDP_WITHIN, "x"),
                Check("median wall time / FDDP's", ta / tf if tf else math.nan, "<=", 1.0, "x")])
    nums = (f"{a['label']}: final median {_fmt(ca)} after {_fmt(ta)} s (diverged {a['diverged']}/{a['runs']}); "
            f"crocoddyl FDDP (x0 held): {_fmt(cf)} after {_fmt(tf)} s (ratio {_fmt(ca / cf if cf else math.nan)})")
    if fr:
        nums += (f"; FDDP from the zero-torque rollout: {_fmt(fr['final_cost_median'])} after "
                 f"{_fmt(fr['wall_time_median_s'])} s (ratio {_fmt(ca / fr['final_cost_median'] if fr['final_cost_median'] else math.nan)}"
                 "; not the same start)")
    return ("beyond the thesis: adaptive R-AICO reaches FDDP's cost within FDDP's wall time (same start)",
            f"the adaptive R-AICO's median final cost is at most {FDDP_WITHIN:g}x crocoddyl FDDP's from the same "
            "start (x0 held), no run diverged, and its median wall time for the whole run is at most FDDP's "
            "(both at FDDP's iteration budget)", nums, ok, None, j)


GAMMA2 = "R-AICO a=1, gamma=2"
ROLLOUT = "R-AICO a=1, rollout start"
ADAPTIVE_ROLLOUT = "R-AICO adaptive (a0=1, rollout start)"


def claim_gamma_ablation(S, execs):
    g, r, ref = S.get(GAMMA2), S.get("R-AICO a=1"), reference_cost(S)
    if not (g and r):
        return ("ablation: R-AICO with a growing alpha (gamma = 2)", "needs both variants", "no runs", False)
    ok = math.isfinite(ref) and _flat_and_low(g, ref)
    j = judged([_diverged("gamma=2", g), _flat_check("gamma=2", g), _cost_check("gamma=2", g, ref, "<=", LOW_COST,
                                                                                   "the reference")])
    return ("ablation: R-AICO with alpha doubled after every iteration (gamma = 2) converges",
            f"for the gamma = 2 variant: {FLAT_TEXT}, and its median final cost is within {LOW_COST:g}x the reference "
            f"optimum ({REFERENCE_TEXT})",
            f"gamma=2: final median {_fmt(g['final_cost_median'])} ({_fmt(g['final_cost_median'] / ref)}x the "
            f"reference {_fmt(ref)}), cost change {_pct(per_iteration_change(g))} per iteration over the last "
            f"{FLAT_ITERS}, diverged {g['diverged']}/{g['runs']}; gamma=1: final median {_fmt(r['final_cost_median'])} "
            f"({_fmt(r['final_cost_median'] / ref)}x)", ok, None, j)


FD_AICO = "AICO, finite differences"


def claim_fd_ablation(S, execs):
    a, f = S.get("AICO"), S.get(FD_AICO)
    if not (a and f):
        return ("ablation: plain AICO with finite-difference linearizations fails as with exact ones",
                "needs both variants", "no runs", False)
    ok = f["diverged"] >= f["runs"] / 2 and a["diverged"] >= a["runs"] / 2
    j = judged([Check("finite differences: diverged runs", f["diverged"], ">=", f["runs"] / 2, f"/{f['runs']}"),
                Check("exact: diverged runs", a["diverged"], ">=", a["runs"] / 2, f"/{a['runs']}")])
    return ("ablation: plain AICO with the thesis's finite-difference linearizations fails as with exact ones "
            "(the derivatives are not the difference)",
            "both plain AICO variants, exact and finite-difference (central, 1e-6) linearizations of the analytic "
            "model, diverge in at least half the runs",
            f"finite differences: diverged {f['diverged']}/{f['runs']}, final median {_fmt(f['final_cost_median'])}; "
            f"exact: diverged {a['diverged']}/{a['runs']}, final median {_fmt(a['final_cost_median'])}", ok, None, j)


# Appendix C: the three pseudo-dynamics integrators. A variant of the comparison is labelled
# "<solver>, <integrator> pseudo-dynamics"; its summary also holds ``integration_*`` medians of the open-loop
# Drake integrations of its plans (``raico.stages.evaluate.summary.integration_summary``).
INTEGRATORS = ("backward Euler", "Euler", "Heun")
INTEGRATOR_COST_RATIO = 1.10  # "no significant difference": median final costs within 10 % of each other ...
INTEGRATOR_VIA_SPREAD = 1e-3  # ... and the Drake-integrated via-point error medians within 1 mm (m) of each other


def integrator_groups(S: dict) -> dict[str, dict[str, dict]]:
    """Solver label -> integrator name -> summary, from labels "<solver>, <integrator> pseudo-dynamics"."""
    out: dict[str, dict[str, dict]] = {}
    for label, s in S.items():
        head, sep, tail = label.rpartition(", ")
        if sep and tail.endswith(" pseudo-dynamics") and tail[:-len(" pseudo-dynamics")] in INTEGRATORS:
            out.setdefault(head, {})[tail[:-len(" pseudo-dynamics")]] = s
    return out


def claim_integrators_agree(S, execs):
    groups = integrator_groups(S)
    verdicts, parts, checks = [], [], []
    for solver, by in groups.items():
        full = all(k in by for k in INTEGRATORS)
        costs = [by[k]["final_cost_median"] for k in INTEGRATORS if k in by]
        vias = [by[k].get("integration_via_error_median", math.nan) for k in INTEGRATORS if k in by]
        fin = full and all(math.isfinite(x) and x > 0 for x in costs) and all(math.isfinite(x) for x in vias)
        diverged = sum(by[k]["diverged"] for k in by)
        ratio = max(costs) / min(costs) if fin else math.nan
        spread = max(vias) - min(vias) if fin else math.nan
        verdicts.append(fin and diverged == 0 and ratio <= INTEGRATOR_COST_RATIO and spread <= INTEGRATOR_VIA_SPREAD)
        checks += [Check(f"{solver}: integrators run", len(by), "=", len(INTEGRATORS)),
                   Check(f"{solver}: diverged runs", diverged, "=", 0),
                   Check(f"{solver}: largest / smallest median final cost", ratio, "<=", INTEGRATOR_COST_RATIO, "x"),
                   Check(f"{solver}: spread of the via-point error medians", spread, "<=", INTEGRATOR_VIA_SPREAD, " m")]
        rows = ", ".join(f"{k} {_fmt(v['final_cost_median'])} / {_fmt(v.get('integration_via_error_median'))} m / "
                         f"{_fmt(v.get('integration_rmse_median'))} rad" for k, v in by.items())
        parts.append(f"{solver} ({min(v['runs'] for v in by.values())} initial states; final cost / via-point error "
                     f"of Drake's integration / RMS joint error against Drake): {rows}; costs differ by "
                     f"{_fmt(100 * (ratio - 1))}%, via-point medians by {_fmt(spread)} m, diverged {diverged}")
    ok = bool(verdicts) and all(verdicts)
    return ("the three pseudo-dynamics integrators (Euler, backward Euler, Heun) differ in no significant way",
            f"for each solver run with all three on the same initial states: no run diverged, the median final "
            f"costs are within {INTEGRATOR_COST_RATIO - 1:.0%} of each other (largest / smallest <= "
            f"{INTEGRATOR_COST_RATIO:g}), and the medians of the largest via-point error of the trajectory Drake "
            f"integrates from the planned controls (open loop) are within {INTEGRATOR_VIA_SPREAD * 1e3:g} mm of "
            f"each other (a tenth of the 1 cm reach of the via-point rule)",
            "; ".join(parts) or "no runs (not in --quick)", ok, None,
            judged(checks or [Check("solvers run with every integrator", 0, ">=", 1)]))


BELIEF_RATE = "AICO, belief rate 0.5"
CONTROLLER_RATE = "AICO, controller rate 0.5"


def claim_learning_rates_fail(S, execs):
    ref = reference_cost(S)
    vs = {k: S[k] for k in (BELIEF_RATE, CONTROLLER_RATE) if k in S}
    if len(vs) < 2:
        return ("plain AICO with a learning rate does not converge", "needs both variants", "no runs", False)
    ok = math.isfinite(ref) and all(not _flat_and_low(v, ref) for v in vs.values())
    j = merge(*(judged([Check(f"{k}: diverged runs", v["diverged"], ">", 0, f"/{v['runs']}"),
                        Check(f"{k}: cost change per iteration over its last {FLAT_ITERS}",
                              100 * per_iteration_change(v), ">", 100 * FLAT_RATE, " %"),
                        _cost_check(k, v, ref, ">", LOW_COST, "the reference")], "any", f"{k} does not converge")
                for k, v in vs.items()))
    nums = "; ".join(f"{k}: final median {_fmt(v['final_cost_median'])} ({_fmt(v['final_cost_median'] / ref)}x the "
                     f"reference), cost change {_pct(per_iteration_change(v))} per iteration over the last "
                     f"{FLAT_ITERS}, diverged {v['diverged']}/{v['runs']}" for k, v in vs.items())
    return ("ablation: plain AICO with a learning rate (0.5) on the belief update or on the controller does not "
            "converge", f"neither variant converges: {FLAT_TEXT}, with a median final cost within {LOW_COST:g}x the "
            f"reference optimum ({REFERENCE_TEXT})", f"{nums}; reference optimum {_fmt(ref)}", ok, None, j)


def claim_rollout_start_reaches_fddp(S, execs):
    f = S.get(FDDP_ROLLOUT)
    vs = {k: S[k] for k in (ROLLOUT, ADAPTIVE_ROLLOUT) if k in S}
    if not (f and vs):
        return ("beyond the thesis: R-AICO from the zero-control rollout reaches FDDP's cost from that start",
                "needs FDDP and R-AICO from the rollout start", "no runs", False)
    cf = f["final_cost_median"]
    best = min(vs, key=lambda k: vs[k]["final_cost_median"])
    ok = math.isfinite(cf) and vs[best]["diverged"] == 0 and vs[best]["final_cost_median"] <= FDDP_WITHIN * cf
    j = judged([_diverged(best, vs[best]), _cost_check(best, vs[best], cf, "<=", FDDP_WITHIN, "FDDP's")])
    nums = "; ".join(f"{k}: final median {_fmt(v['final_cost_median'])} ({_fmt(v['final_cost_median'] / cf)}x), "
                     f"cost change {_pct(per_iteration_change(v))} per iteration over its last {FLAT_ITERS} "
                     f"iterations, diverged {v['diverged']}/{v['runs']}" for k, v in vs.items())
    why = ""
    rate = per_iteration_change(vs[best])
    if not ok and math.isfinite(rate):  # the measured reason: still descending when the budget ended, or flat above FDDP (another optimum)
        why = (f"; {best} was still descending when its budget ended ({_pct(rate)} per iteration > {FLAT_RATE:.0%} "
               "over its last iterations): the gap is the iteration budget" if rate > FLAT_RATE else
               f"; {best} is flat ({_pct(rate)} per iteration over its last iterations) above FDDP's cost: it stops "
               "in another local optimum, not for want of iterations")
    return ("beyond the thesis: R-AICO started from the zero-control rollout reaches crocoddyl FDDP's cost from "
            "that start", f"the better of R-AICO a=1 and adaptive R-AICO, both from the rollout start, ends within "
            f"{FDDP_WITHIN:g}x FDDP's median final cost from the rollout start, no run diverged",
            f"{nums}; FDDP (rollout start) {_fmt(cf)}{why}", ok, None, j)


def claim_ilqg_stall_ablation(S, execs):
    i, fr = S["iLQG"], S[FDDP_ROLLOUT]
    a = fr["final_cost_median"]
    rules = {"acceptance rule (take a step if actual/expected decrease > 0, crocoddyl: > 0.1)": S[FDDP_ACCEPT_ANY],
             "regularization schedule (lower it after every accepted step, raise it only when the line search "
             "reaches its last step; crocoddyl: lower after steps >= 0.5, raise after steps <= 0.01)":
             S[FDDP_ILQG_SCHEDULE]}
    ratio = {k: (v["final_cost_median"] / a if a else math.nan) for k, v in rules.items()}
    stall = [k.split(" (")[0] for k, r in ratio.items() if not math.isfinite(r) or r >= 2]
    ok = math.isfinite(a) and bool(stall)
    j = judged([Check(f"with iLQG's {k.split(' (')[0]}: final cost / FDDP's", r, ">=", 2, "x")
                for k, r in ratio.items()], "any")
    parts = "; ".join(f"with iLQG's {k}: {_fmt(v['final_cost_median'])} ({_fmt(ratio[k])}x)" for k, v in rules.items())
    why = (f"iLQG's {' and '.join(stall)} alone makes FDDP stall" if ok else
           "neither rule alone makes FDDP stall")
    return ("ablation: why iLQG stalls where FDDP does not from the same rollout start",
            "FDDP from the zero-torque rollout with one of iLQG's rules swapped in (all else crocoddyl's) ends at "
            "least 2x above FDDP's own median final cost",
            f"FDDP (rollout start) final median {_fmt(a)}; {parts}; iLQG {_fmt(i['final_cost_median'])} after the "
            f"thesis's budget: {why}", ok, None, j)


def claim_all_converge_aico_fastest(S, execs):
    """Fig. 3.2A, "converge fast for all algorithms, with the standard AICO algorithm showing the best performance":
    all the algorithms of Fig. 3.2A and its paragraph, the thesis's solvers (:data:`THESIS_SOLVERS`: iLQG, AICO and
    R-AICO with alpha 1 and 10). Two rows: each converges (flat at the end, no run diverged, via-points met) with
    AICO the best (within 1 % of its final cost in no more iterations than any other, at a final cost no higher than
    the lowest of the others' to 1 %); and "fast", which cannot be tested: the thesis gives neither an iteration axis
    for the arm nor a rule for fast (the iterations each takes to get within 1 % of its final cost are reported)."""
    V = _thesis_solvers(S)
    if "AICO" not in V or len(V) < 2:
        return ("all algorithms converge, plain AICO best", "needs AICO and the others", "no runs", False)
    n = {k: iterations_to_final(s.get("cost_curve_median") or []) for k, s in V.items()}
    a = V["AICO"]
    others = {k: s for k, s in V.items() if k != "AICO"}
    nan = math.nan
    fastest = min((n[k] for k in others if n[k] is not None), default=None)
    rival = min(others, key=lambda k: others[k]["final_cost_median"]
                if math.isfinite(others[k]["final_cost_median"]) else math.inf)
    low = others[rival]["final_cost_median"]
    checks = [c for k, s in V.items() for c in (_diverged(k, s), _flat_check(k, s), _via_check(k, s))]
    checks += [Check("AICO's iterations to within 1 % of its final cost - the fewest of the others'",
                     n["AICO"] - fastest if n["AICO"] is not None and fastest is not None else nan, "<=", 0),
               Check(f"AICO's median final cost / the lowest of the others' ({rival})",
                     a["final_cost_median"] / low if low else nan, "<=", 1 + FLAT_RATE, "x",
                     spread=iqr([x for x in a.get("final_costs") or [] if math.isfinite(x)]) / low if low else nan)]
    j = judged(checks)
    nums = "; ".join(f"{k}: within 1 % of its final cost from iteration {n[k] if n[k] is not None else 'n/a'} on, "
                     f"final median {_fmt(s['final_cost_median'])}, cost change {_pct(per_iteration_change(s))} per "
                     f"iteration over the last {FLAT_ITERS}, largest via-point error median "
                     f"{_fmt(s['max_via_error_median'])} m, diverged {s['diverged']}/{s['runs']}" for k, s in V.items())
    runs = min(s["runs"] for s in V.values())
    names = ", ".join(V)
    return [(f"the costs of all algorithms ({names}) converge, plain AICO best",
             f"each of {names}: {FLAT_TEXT} at the end of the budget, and the via-points met (median largest "
             f"via-point error <= {VIA_TOL * 100:g} cm); and AICO gets within 1 % of its final cost in no more "
             f"iterations than any other, at a median final cost at most 1 % above the lowest of the others'", nums,
             j["ok"], runs, j),
            (f"the costs of all algorithms ({names}) converge fast",
             "cannot be tested: the thesis gives no iteration axis for the arm and no rule for 'fast' (raico's "
             "iteration budget for the arm is its own choice); the iterations each takes to get within 1 % of its "
             "final cost are reported", nums, None, runs)]


def claim_raico_reaches_aico_not(S, execs):
    """Fig. 3.3B: R-AICO a=1 infers a low-cost solution and plain AICO does not, both judged against the thesis's
    own solvers on the figure and the task's via-points."""
    r, a, best = S["R-AICO a=1"], S["AICO"], thesis_best(S)
    ok = low_cost(r, best) and not_low_cost(a, best)
    j = merge(judged(low_cost_checks("R-AICO a=1", r, best), "all", "R-AICO a=1 low cost"),
              judged(not_low_cost_checks("AICO", a, best), "any", "AICO no low-cost solution"))
    return ("R-AICO a=1 infers low-cost reaching solutions, plain AICO does not",
            f"R-AICO a=1 has a {LOW_TEXT}; AICO has {NOT_LOW_TEXT}",
            f"{_solver_nums('R-AICO a=1', r, best)}; {_solver_nums('AICO', a, best)}; best thesis solver {_fmt(best)}",
            ok, min(r["runs"], a["runs"]), j)


def claim_aico_no_balancing(S, execs):
    """§3.6.2, "AICO was not able to infer successful balancing solutions, which is illustrated in Figure 3.4B":
    Fig. 3.4B is a cost panel, so a run is successful when it did not diverge and ends at a low cost, within
    ``LOW_COST`` of the best R-AICO's median final cost (the solutions the same panel shows to succeed); none of
    AICO's runs is. The runs meeting every CoG via-point to ``VIA_TOL`` are counted beside it, not judged."""
    a, best = S["AICO"], _best_raico(S)
    costs = [c if c is not None else math.inf for c in a.get("final_costs") or []]
    ratios = [c / best if math.isfinite(best) and best > 0 else math.nan for c in costs]
    success = sum(r <= LOW_COST for r in ratios)
    errs = a.get("via_errors") or []
    met = sum(e <= VIA_TOL for e in errs)
    fin = [e for e in errs if math.isfinite(e)]
    fails = [r for r in ratios if r > LOW_COST and math.isfinite(r)]
    j = judged([Check("AICO runs ending within 1.5x the best R-AICO's median final cost", success, "=", 0,
                      f"/{len(costs)}")])
    near = Check("the lowest unsuccessful AICO run's final cost / the best R-AICO's median", min(fails) if fails
                 else math.nan, ">", LOW_COST, "x", spread=iqr([r for r in ratios if math.isfinite(r)]))
    j["margin"] += f"; {near.text()}"
    if success == 0 and near.near():
        j["near"] = [f"one run would flip it: {near.what} is {_fmt(near.margin)}x over the rule, inside the runs' "
                     f"spread ({_fmt(near.spread)}x)"]
    if not (costs and math.isfinite(best)):
        j["ok"], j["why"] = False, "no AICO runs, or no R-AICO run to read the cost panel against"
    elif success:
        j["why"] = (f"AICO runs ending within {LOW_COST:g}x the best R-AICO's median final cost {success}/{len(costs)} "
                    f"!= 0: {', '.join(_fmt(r) + 'x' for r in sorted(ratios) if r <= LOW_COST)}")
    return ("plain AICO infers no successful balancing solution",
            f"on Fig. 3.4B's cost panel: none of AICO's runs is successful, a successful run being one that did not "
            f"diverge and ends within {LOW_COST:g}x the best R-AICO's median final cost; the runs meeting every CoG "
            f"via-point to {VIA_TOL * 100:g} cm (the held right sole left out) are counted beside it, not judged (the "
            f"sentence points at the cost panel)",
            f"successful AICO runs {success}/{len(costs)}; AICO's final cost / the best R-AICO's median: median "
            f"{_fmt(float(np.median(ratios)) if ratios else math.nan)}x, lowest "
            f"{_fmt(min((r for r in ratios if math.isfinite(r)), default=math.nan))}x (best R-AICO {_fmt(best)}); "
            f"diverged {a['diverged']}/{a['runs']}; beside it: runs meeting every CoG via-point to "
            f"{VIA_TOL * 100:g} cm {met}/{len(errs)}, largest CoG via-point error "
            f"{_fmt(min(fin) if fin else math.nan)}-{_fmt(max(fin) if fin else math.nan)} m (median "
            f"{_fmt(a['max_via_error_median'])} m)", bool(costs) and math.isfinite(best) and success == 0, a["runs"], j)


COUNTER_HAND = 0.01  # m: the left hand "moves" when it travels at least 1 cm (raico's: the reach's tolerance) ...
COUNTER_HEAD = 0.05  # rad: ... and the head when a head joint turns at least 0.05 rad (raico's: the start's spread)


def claim_counterbalance(S, execs):
    """Fig. 3.3 caption, "To counter balance, the robot moves its left hand and the head": read whole, the motion
    is there and it serves balance. On the R-AICO a=1 plans (medians over the runs): the left hand and the head move
    (``COUNTER_HAND``, ``COUNTER_HEAD``: raico's thresholds, the thesis gives none), and the CoG drifts less from its
    start over the plan with that motion than with the head and left-arm joints held at their start angles (the same
    plan without it: ``raico.thesis.figures.counterbalance``)."""
    r = S.get("R-AICO a=1") or {}
    hand, head = r.get("left_hand_excursion_median", math.nan), r.get("head_joint_excursion_median", math.nan)
    arm = r.get("left_arm_joint_excursion_median", math.nan)
    drift, held = r.get("cog_drift_median", math.nan), r.get("cog_drift_held_median", math.nan)
    ratio = drift / held if math.isfinite(drift) and math.isfinite(held) and held > 0 else math.nan
    j = judged([Check("the left hand's travel", hand, ">=", COUNTER_HAND, " m"),
                Check("the largest head joint turn", head, ">=", COUNTER_HEAD, " rad"),
                Check("the CoG's largest drift with the motion / with the head and left arm held", ratio, "<", 1.0,
                      "x")])
    return ("to counterbalance, the robot moves its left hand and its head (no objective names them)",
            f"median over the R-AICO a=1 plans: the left hand travels >= {COUNTER_HAND:g} m from its start and a head "
            f"joint turns >= {COUNTER_HEAD:g} rad (raico's thresholds: the reach's tolerance and the start's spread; "
            f"the thesis gives none), and that motion serves balance: the CoG's largest horizontal distance from its "
            f"start (over the support the plan starts on) is smaller than in the same plan with the head and left-arm "
            f"joints held at their start angles. Not tested: whether the motion appears only with the CoG term (the "
            f"figure has no plan without it)",
            f"left hand {_fmt(hand)} m (left-arm joints up to {_fmt(arm)} rad), head joints up to {_fmt(head)} rad; "
            f"the CoG's largest drift from its start {_fmt(drift)} m with the motion, {_fmt(held)} m with the head and "
            f"left arm held (ratio {_fmt(ratio)})", j["ok"], None, j)


def _stood_counts(execs: list[dict]) -> tuple[int, str]:
    """How many executions stood (status neither ``fell`` nor ``diverged``) and the status counts."""
    st = [str(e.get("status", "?")) for e in execs]
    stood = sum(s not in ("fell", "diverged") for s in st)
    counts = ", ".join(f"{k} {st.count(k)}" for k in ("ok", "limits", "tracking-lost", "fell", "diverged", "collided", "?")
                       if st.count(k))
    return stood, counts


def _joint_pd(execs: list[dict]) -> list[dict]:
    """The executions with the joint PD controller (the execution rows of the thesis's set-up); the
    stabilizer's have their own claim."""
    return [e for e in execs if e.get("controller", "pd") == "pd"]


def claim_cog_support(S, execs):
    execs = _joint_pd(execs)
    claim = "CoG stays over the support polygon of the feet (R-AICO a=1 executed on the free-standing Nao)"
    criterion = ("every executed run stood (status neither fell nor diverged) and its CoG ground projection was "
                 "inside the polygon of the sole corners in contact at every sample")
    if not execs:
        return claim, criterion, "no executions", False
    stood, counts = _stood_counts(execs)
    inside = [e.get("cog_inside_fraction", math.nan) for e in execs]
    margin = [e.get("cog_min_margin", math.nan) for e in execs]
    sat = [e.get("torque_saturation", math.nan) for e in execs]
    ok = stood == len(execs) and all(f >= 1.0 for f in inside)
    j = judged([Check("runs that stood", stood, "=", len(execs), f"/{len(execs)}"),
                Check("runs with the CoG inside at every sample", sum(f >= 1.0 for f in inside), "=", len(execs),
                      f"/{len(execs)}")])
    return (claim, criterion,
            f"stood {stood}/{len(execs)} runs (statuses: {counts}); CoG inside the contact polygon: median "
            f"{_pct(float(np.median(inside)))} of the samples, worst margin {_fmt(float(np.nanmin(margin)))} m; steps "
            f"with an actuator at its effort limit: median {_pct(float(np.median(sat)))}", ok, None, j)


def claim_executed_reaches(S, execs):
    """The task achieved in execution: status ``ok`` (stood, tracked, within limits) and the via-points reached."""
    from raico.stages.evaluate.summary import largest_via_error

    execs = _joint_pd(execs)
    claim = "the executed R-AICO a=1 plans achieve the task on the free-standing Nao"
    criterion = (f"every executed run has status ok (stood, tracked the plan, within its limits) and its largest "
                 f"executed via-point error (the held right sole left out) is <= {EXECUTED_VIA_TOL} m")
    if not execs:
        return claim, criterion, "no executions", False
    stood, counts = _stood_counts(execs)
    errs = [largest_via_error(e) for e in execs]
    achieved = sum(map(executed_achieved, execs))
    ok = achieved == len(execs)
    j = judged([Check("runs achieving it", achieved, "=", len(execs), f"/{len(execs)}")])
    return (claim, criterion,
            f"achieved in {achieved}/{len(execs)} runs; stood {stood}/{len(execs)} (statuses: {counts}); largest "
            f"executed via-point error median {_fmt(float(np.nanmedian(errs)) if errs else math.nan)} m", ok, None, j)


def claim_stabilizer_stands(S, execs):
    """Beyond the thesis: the whole-body stabilizer's executions (metrics ``controller`` ``wbc``) stand and
    reach their via-points; the joint-PD executions of the same figure are counted beside them."""
    from raico.stages.evaluate.summary import largest_via_error

    claim = "the whole-body stabilizer carries out the R-AICO a=1 plans on the free-standing Nao"
    criterion = (f"every execution with the stabilizer stood and has status ok and its largest executed via-point "
                 f"error (the held right sole left out) is <= {EXECUTED_VIA_TOL} m")
    wbc = [e for e in execs if e.get("controller") == "wbc"]
    pd = _joint_pd(execs)
    if not wbc:
        return claim, criterion, "no executions with the stabilizer", False
    stood, counts = _stood_counts(wbc)
    errs = [largest_via_error(e) for e in wbc]
    achieved = sum(map(executed_achieved, wbc))
    base = (f"; joint PD beside it: stood {_stood_counts(pd)[0]}/{len(pd)}, achieved "
            f"{sum(map(executed_achieved, pd))}/{len(pd)}"
            if pd else "")
    return (claim, criterion,
            f"achieved in {achieved}/{len(wbc)} runs; stood {stood}/{len(wbc)} (statuses: {counts}); largest executed "
            f"via-point error median {_fmt(float(np.nanmedian(errs)))} m{base}", achieved == len(wbc), None,
            judged([Check("runs achieving it", achieved, "=", len(wbc), f"/{len(wbc)}")]))


NOISE_STOOD = 0.9  # ">= 9/10 stand" under noise


def claim_stabilizer_stands_under_noise(S, execs):
    """Beyond the thesis: under the noise sweep's noise (initial joint angles and process torques) the
    stabilizer's executions stand in at least ``NOISE_STOOD`` of the runs (``execs``: the sweep's noisy runs)."""
    claim = "the stabilizer keeps the Nao standing under noise"
    wbc = [e for e in execs if e.get("controller") == "wbc"]
    levels = sorted({tuple(e["noise_level"]) for e in wbc}) if wbc else []
    level = (f"x0 {levels[0][0]:g} rad, process {levels[0][1]:g} N m" if len(levels) == 1
             else "the sweep's noise" if not levels else "every noisy level")
    criterion = (f"at least {NOISE_STOOD:.0%} of the executions with the stabilizer at {level} stood (status neither "
                 f"fell nor diverged)")
    pd = _joint_pd(execs)
    if not wbc:
        return (claim, criterion, "no executions with the stabilizer under noise" +
                (f" (joint PD: stood {_stood_counts(pd)[0]}/{len(pd)})" if pd else ""), False)
    stood, counts = _stood_counts(wbc)
    ok = sum(e.get("status") == "ok" for e in wbc)
    base = f"; joint PD beside it: stood {_stood_counts(pd)[0]}/{len(pd)}" if pd else ""
    return (claim, criterion, f"stood {stood}/{len(wbc)} (statuses: {counts}); status ok {ok}/{len(wbc)}{base}",
            stood >= NOISE_STOOD * len(wbc), None,
            judged([Check("runs that stood", stood, ">=", NOISE_STOOD * len(wbc), f"/{len(wbc)}")]))


def claim_single_support_stands(S, execs):
    """Beyond the thesis: a single-support plan (``--balance single``) carried out by the stabilizer: every run
    stood, has status ok and held the right sole at least ``LIFT`` high from the plan's lift step to the end."""
    from raico.stages.evaluate.metrics import LIFT
    from raico.stages.evaluate.summary import largest_via_error

    claim = "the Nao balances on its left foot with the right foot lifted (stabilizer, free-standing)"
    criterion = (f"every execution with the stabilizer stood, has status ok and held the right sole's lowest "
                 f"corner >= {LIFT} m above the ground from the plan's lift step to the end")
    wbc = [e for e in execs if e.get("controller") == "wbc"]
    if not wbc:
        return claim, criterion, "no executions with the stabilizer", False
    stood, counts = _stood_counts(wbc)
    lifts = np.array([e.get("r_sole_lift", math.nan) for e in wbc], float)
    ok = sum(e.get("status") == "ok" and bool(e.get("lifted")) for e in wbc)
    errs = [largest_via_error(e) for e in wbc]
    pd = _joint_pd(execs)
    base = f"; joint PD beside it: stood {_stood_counts(pd)[0]}/{len(pd)}" if pd else ""
    return (claim, criterion,
            f"stood with the foot lifted in {ok}/{len(wbc)} runs; stood {stood}/{len(wbc)} (statuses: {counts}); right "
            f"sole's lowest corner from the lift step on: median {_fmt(float(np.nanmedian(lifts)))} m (min "
            f"{_fmt(float(np.nanmin(lifts)) if np.isfinite(lifts).any() else math.nan)} m); largest executed CoG "
            f"via-point error median {_fmt(float(np.nanmedian(errs)))} m{base}", ok == len(wbc), None,
            judged([Check("runs standing with the foot lifted", ok, "=", len(wbc), f"/{len(wbc)}")]))


# ----------------------------------------------------------------------------- learning (thesis §4)
HELD = ", x0 held"  # label suffix of the settings run from the thesis's start (x0 held at every evaluation)


def _small_weight(L: dict) -> dict:
    return {k: v for k, v in L.items() if "w=0.01" in k and not k.endswith(HELD)}


TO_ZERO = 0.01  # "converges to zero": each of the last three episodes at most 1 % of the first three's mean
FLAT = 0.10  # "converges": each of the last three episodes within 10 % of their mean
CONVERGES_TEXT = ("each of the last three episodes within 10 % of their mean, which is not above the first three "
                  "episodes' mean")


def _curve(s: dict, key: str) -> np.ndarray:
    return np.array(s.get(f"{key}_curve") or [], float)


def converges_to_zero(curve: np.ndarray) -> bool:
    """A per-episode curve converges to zero: its last three values are finite and each at most
    ``TO_ZERO`` times the mean of its first three (at least six episodes)."""
    c = np.asarray(curve, float)
    if len(c) < 6 or not np.all(np.isfinite(c[-3:])) or not np.isfinite(np.nanmean(c[:3])):
        return False
    return bool(np.all(c[-3:] <= TO_ZERO * np.nanmean(c[:3])))


def converges(curve: np.ndarray) -> bool:
    """A per-episode curve converges (to a value, not necessarily zero): its last three values are
    finite, each within ``FLAT`` of their mean, and that mean is not above the first three's."""
    c = np.asarray(curve, float)
    if len(c) < 6 or not np.all(np.isfinite(c[-3:])):
        return False
    m = float(np.mean(c[-3:]))
    return bool(np.all(np.abs(c[-3:] - m) <= FLAT * abs(m)) and m <= np.nanmean(c[:3]))


def to_zero_check(what: str, curve) -> Check:
    """:func:`converges_to_zero` as a check: the largest of the last three over the first three's mean."""
    c = np.asarray(curve, float)
    v = float(np.max(c[-3:]) / np.nanmean(c[:3])) if len(c) >= 6 and np.all(np.isfinite(c[-3:])) else math.nan
    return Check(f"{what}: the largest of the last three / the first three's mean", v, "<=", TO_ZERO)


def converges_checks(what: str, curve) -> list[Check]:
    """:func:`converges` as checks: the last three's largest deviation from their mean (relative), and their mean
    over the first three's."""
    c = np.asarray(curve, float)
    if len(c) < 6 or not np.all(np.isfinite(c[-3:])):
        return [Check(f"{what}: episodes (finite last three)", len(c), ">=", 6)]
    m = float(np.mean(c[-3:]))
    return [Check(f"{what}: the last three's largest deviation from their mean", float(np.max(np.abs(c[-3:] - m)) / abs(m))
                  if m else 0.0, "<=", FLAT),
            Check(f"{what}: the last three's mean / the first three's", m / float(np.nanmean(c[:3])), "<=", 1.0, "x")]


def _last3(c: np.ndarray) -> str:
    return ", ".join(_fmt(x) for x in c[-3:])


def claim_gp_error_falls(L, execs):
    S = _small_weight(L)
    ok = bool(S) and all(converges_to_zero(_curve(s, "gp_error")) for s in S.values())
    nums = "; ".join(f"{k}: first three {_fmt(s['gp_error_first3'])}, last three {_last3(_curve(s, 'gp_error'))} "
                     f"rad/s^2 (held-out babbling: last {_fmt(s.get('gp_error_heldout_last3', math.nan))})"
                     for k, s in S.items())
    return ("the GP's prediction error converges to zero for a small C_sigma (w = 1e-2)",
            "for every sigma* with w = 1e-2, the median over seeds of the GP error on the next execution (a true "
            "prediction: that motion is not yet in the data) in each of the last three episodes is at most 1% of "
            "its mean over the first three", nums or "no runs", ok, None,
            judged([to_zero_check(f"{k} GP error", _curve(s, "gp_error")) for k, s in S.items()]))


def claim_rmse_falls(L, execs):
    S = _small_weight(L)
    ok = bool(S) and all(converges(_curve(s, "rmse_planned_executed")) for s in S.values())
    nums = "; ".join(f"{k}: first three {_fmt(s['rmse_planned_executed_first3'])}, last three "
                     f"{_last3(_curve(s, 'rmse_planned_executed'))} rad" for k, s in S.items())
    return ("the planned-vs-executed RMSE converges for a small C_sigma (w = 1e-2)",
            "for every sigma* with w = 1e-2, the median over seeds of the RMSE in each of the last three episodes "
            "is within 10% of their mean, which is not above the first three's (converged, not necessarily to "
            "zero: the planner's Euler step against Drake's integrator leaves a floor)", nums or "no runs", ok, None,
            judged([c for k, s in S.items() for c in converges_checks(f"{k} RMSE", _curve(s, "rmse_planned_executed"))]))


def _converging(w: str, s: dict, conv: dict) -> str:
    """The last three episodes of a setting's GP error and RMSE, and whether each converges (``conv``)."""
    return "; ".join(f"{w} {name}: last three {_last3(_curve(s, key))} "
                     f"({'converges' if conv[key] else 'does not converge'})"
                     for key, name in (("gp_error", "GP error (rad/s^2)"), ("rmse_planned_executed", "RMSE (rad)")))


EXPLORE_HIGH = 10.0  # "explores too much": the error stays at least 10x where the small weight's settles ...
# ... and does not settle itself (a last three within FLAT of their mean is a loop that stopped: converged, or frozen)


def explores_checks(what: str, curve, small) -> list[Check]:
    """A per-episode error curve stays high and unsettled (every one must hold): each of its last three episodes at
    least ``EXPLORE_HIGH`` times the largest of the small weight's last three (``small``), and their largest deviation
    from their mean above ``FLAT`` (a flat curve converged, to a worse value or frozen, and explores no more)."""
    c, m = np.asarray(curve, float), np.asarray(small, float)
    if len(c) < 6 or not np.all(np.isfinite(c[-3:])) or len(m) < 3 or not np.all(np.isfinite(m[-3:])):
        return [Check(f"{what}: episodes with a finite last three (diverged executions left out), both weights",
                      min(len(c), len(m)) if np.all(np.isfinite(c[-3:])) and np.all(np.isfinite(m[-3:])) else 0,
                      ">=", 6)]
    mean = float(np.mean(c[-3:]))
    return [Check(f"{what}: the last three's lowest / the small weight's highest", float(np.min(c[-3:]) / np.max(m[-3:]))
                  if np.max(m[-3:]) > 0 else math.inf, ">=", EXPLORE_HIGH, "x"),
            Check(f"{what}: the last three's largest deviation from their mean", float(np.max(np.abs(c[-3:] - mean))
                                                                                       / abs(mean)) if mean else 0.0,
                  ">", FLAT)]


def _explores(w: str, s: dict, small: dict) -> dict:
    """With the large weight: the GP error or the RMSE stays high and unsettled (:func:`explores_checks`; one of the
    two is enough)."""
    return merge(*(judged(explores_checks(f"{w} {name}", _curve(s, key), _curve(small, key)), "all",
                          f"{w} {name} stays high")
                   for key, name in (("gp_error", "GP error"), ("rmse_planned_executed", "RMSE"))), rule="any")


def _high_text(w: str, s: dict, small: dict) -> str:
    """The large weight's last three of the GP error and RMSE against the small weight's."""
    return "; ".join(f"{w} {name}: last three {_last3(_curve(s, key))} against w=0.01's {_last3(_curve(small, key))}"
                     for key, name in (("gp_error", "GP error (rad/s^2)"), ("rmse_planned_executed", "RMSE (rad)")))


def claim_large_weight_explores(L, execs):
    """Fig. 4.2, one row per sigma* in {0.2, 1} and per start (raico's: the previous plan's controls; the thesis's:
    x0 held, the settings labelled ``HELD``): with the large weight (w = 1e2) the GP error or the planned-vs-executed
    RMSE stays high and unsettled (:func:`explores_checks`), while with the small weight (w = 1e-2) both converge.
    The curves are medians over seeds of the executions that did not diverge (``raico.thesis.figures.summarize_learns``);
    the diverged executions are counted beside them."""
    rows = []
    for tail in ("", HELD):
        for sigma in ("0.2", "1"):
            big, small = L.get(f"sigma*={sigma}, w=100{tail}"), L.get(f"sigma*={sigma}, w=0.01{tail}")
            if not (big and small):
                continue
            j = merge(_explores("w=100", big, small),
                      judged([c for key, name in (("gp_error", "GP error"), ("rmse_planned_executed", "RMSE"))
                              for c in converges_checks(f"w=0.01 {name}", _curve(small, key))], "all",
                             "w=0.01 converges"))
            conv = {key: converges(_curve(small, key)) for key in ("gp_error", "rmse_planned_executed")}
            said = (f"{_high_text('w=100', big, small)}; {_converging('w=0.01', small, conv)}; diverged executions (left out of the curves): w=100 "
                    f"{_diverged_text(big)}, w=0.01 {_diverged_text(small)}")
            start = " (with the thesis's start: x0 held at every evaluation)" if tail else ""
            # the executions of the last episodes diverged in every seed: no error level is left to judge
            lost = sum(big.get("diverged_by_seed") or []) > 0 and not any(
                np.all(np.isfinite(_curve(big, key)[-3:])) and len(_curve(big, key)) >= 3
                for key in ("gp_error", "rmse_planned_executed"))
            rows.append((f"sigma* = {sigma}: a large weight (w = 1e2) explores too much{start}",
                         "with w = 100 the median over seeds of the GP error on the next execution or of the planned-vs-"
                         f"executed RMSE stays high and unsettled: each of the last three episodes at least "
                         f"{EXPLORE_HIGH:g}x the highest of w = 0.01's last three, and the last three not within "
                         f"{FLAT:.0%} of their mean (a flat curve has settled, on a worse value or frozen: it explores "
                         f"no more); while with w = 0.01 both converge (converges: {CONVERGES_TEXT}); diverged "
                         f"executions are left out of the curves and counted; cannot be tested where the w = 100 "
                         f"executions of the last episodes diverged in every seed (no error level left to judge)",
                         said, None if lost else j["ok"], min(big["runs"], small["runs"]), j))
    return rows or [("a large weight explores too much", "needs w = 100 and w = 0.01 runs", "no runs", False)]


def _diverged_text(s: dict) -> str:
    """The diverged executions of a learn setting per seed (``diverged_by_seed`` of ``summarize_learns``)."""
    d = s.get("diverged_by_seed")
    if d is None:
        return "n/a"
    n = s.get("episodes")
    return (f"{sum(d)} of {n * len(d) if n else '?'} executions ({len(d)} seeds of {n or '?'} episodes; per seed "
            f"{', '.join(map(str, d))})")


def claim_large_weight_converges_without_exploration(L, execs):
    runs = {k: L.get(k) for k in ("sigma*=0, w=100", "sigma*=none") if L.get(k)}
    ok = len(runs) == 2 and all(converges_to_zero(_curve(s, "gp_error")) and converges(_curve(s, "rmse_planned_executed"))
                                for s in runs.values())
    nums = "; ".join(f"{k}: GP error first three {_fmt(s['gp_error_first3'])}, last three "
                     f"{_last3(_curve(s, 'gp_error'))} rad/s^2; RMSE last three {_last3(_curve(s, 'rmse_planned_executed'))}"
                     f" rad" for k, s in runs.items())
    return ("with the large weight (w = 1e2), sigma* = 0 converges, and so does planning without the uncertainty term",
            "for sigma* = 0 with w = 100 and for sigma* = none: the GP error converges to zero (each of the last "
            "three episodes at most 1% of the first three's mean) and the RMSE converges (the last three within 10% "
            "of their mean), medians over seeds", nums or "no runs", ok, None,
            judged([c for k, x in runs.items() for c in [to_zero_check(f"{k} GP error", _curve(x, "gp_error")),
                                                        *converges_checks(f"{k} RMSE", _curve(x, "rmse_planned_executed"))]]))


def claim_swing_up_achieved(L, execs):
    s = L.get("sigma*=0, w=0.01")
    if not s:
        return ("the swing-up is achieved on the Drake pendulum", "", "no runs", False)
    secs = [x for x in s["seconds_to_success"] if math.isfinite(x)]
    ok = s["achieved_last"] == s["runs"]
    ends = [x for x in s.get("task_error_last_by_seed") or [] if math.isfinite(x)]
    j = judged([Check("seeds achieving it in the last episode", s["achieved_last"], "=", s["runs"], f"/{s['runs']}"),
                Check("the farthest seed's final angle to upright", max(ends) if ends else math.nan, "<=",
                      SWING_TOL, " rad", spread=iqr(ends))])
    return ("the swing-up is achieved on the Drake pendulum (sigma* = 0, w = 1e-2)",
            "in the last episode of every seed the executed pendulum ends within 0.1 rad of upright",
            f"achieved in the last episode: {s['achieved_last']}/{s['runs']} seeds; first success after "
            f"{', '.join(_fmt(x) for x in s['seconds_to_success'])} s of executed motion (babbling included)"
            + (f"; median {_fmt(float(np.median(secs)))} s" if secs else "")
            + (f"; final angle to upright per seed {', '.join(_fmt(x) for x in ends)} rad" if ends else ""),
            ok, s["runs"], j)


SWING_TOL = 0.1  # rad: the swing-up is achieved when the executed pendulum ends within this of upright
TIE = 1e-3  # rad: two executed end angles closer than this (1 % of the 0.1 rad swing-up tolerance) are a tie


def _episodes_to_success(s: dict) -> list[float]:
    """Per seed the episode (1-based) of a learn setting's first swing-up, ``inf`` where none succeeded."""
    return [math.inf if e is None else float(e) for e in s.get("first_success_episode") or []]


def claim_best_with_sigma_zero(L, execs):
    """Fig. 4.1 / §4.4: the best swing-up was found with sigma* = 0. Ranked by the episodes each setting takes to its
    first swing-up (the settings' plan costs are not comparable: their uncertainty terms differ; the executed end
    angle ranks nothing once within the tolerance), paired by seed over the seeds every setting ran (raico's start):
    a sigma* = 0 setting (either weight) needs the fewest in more than half the seeds, a tie counting for it. Where
    every seed ties, the measure cannot rank them: the claim cannot be tested (``None``)."""
    labels = [k for k in L if L[k].get("first_success_episode") and not k.endswith(HELD)]
    zero = [k for k in labels if k.startswith("sigma*=0,")]
    if not zero or len(labels) < 2:
        return ("the best swing-up was found with sigma* = 0", "needs sigma* = 0 and other settings", "no runs", False)
    eps = {k: _episodes_to_success(L[k]) for k in labels}
    shared = min(len(v) for v in eps.values())
    wins, ties, parts = 0, 0, []
    for seed in range(shared):
        z = min(eps[k][seed] for k in zero)
        other = min(eps[k][seed] for k in labels if k not in zero)
        wins += z < other
        ties += z == other
        parts.append(f"seed {seed}: sigma* = 0 first swing-up in episode {_fmt(z)}, the others' earliest {_fmt(other)}")
    ranked = shared - ties
    measured = "; ".join(parts) + (f"; sigma* = 0 strictly first in {wins} of the {ranked} seeds that rank them, a tie "
                                   f"in {ties}/{shared}; episodes to the first swing-up per setting: "
                                   + "; ".join(f"{k} {', '.join(_fmt(x) for x in eps[k][:shared])}" for k in labels))
    criterion = ("ranked by the episodes to the first swing-up (the executed pendulum ending within 0.1 rad of upright; "
                 "a diverged execution is no swing-up), paired by seed over the seeds every setting ran (raico's "
                 "start): a sigma* = 0 setting (w = 1e-2 or 1e2) needs strictly the fewest in more than half the seeds "
                 "that rank them (a tie ranks nothing); cannot be tested where every seed ties")
    ok = None if shared and ties == shared else bool(shared) and 2 * wins > ranked
    j = judged([Check("seeds where a sigma* = 0 setting swings up first, of those that rank them", wins, ">",
                      ranked / 2, f"/{ranked}")])
    return ("the best swing-up was found with sigma* = 0", criterion, measured, ok, shared, j)


PILCO_SECONDS = 17.5  # Deisenroth & Rasmussen, ICML 2011: real cart-pole swing-up after 17.5 s of interaction
PILCO_SOURCE = ("PILCO (Deisenroth and Rasmussen, ICML 2011) learned the cart-pole swing-up from scratch with "
                "17.5 s of interaction with the real system; this row is the fully actuated pendulum, an easier task: "
                "the cart-pole itself is measured by bench/cartpole_pilco.py, docs/learning.md")


def claim_pilco_efficiency(L, execs):
    s = L.get("sigma*=0, w=0.01")
    secs = s["seconds_to_success"] if s else []
    fin = [x for x in secs if math.isfinite(x)]
    med = float(np.median(secs)) if secs else math.inf
    ok = bool(secs) and med <= PILCO_SECONDS
    j = judged([Check("raico's median executed seconds", med, "<=", PILCO_SECONDS, " s")])
    return ("data efficiency against PILCO, on the pendulum (easier than PILCO's cart-pole): seconds of executed "
            "motion until the first swing-up",
            f"median over seeds of raico's executed seconds (babbling included) until the first episode that "
            f"ends within 0.1 rad of upright <= {PILCO_SECONDS} s ({PILCO_SOURCE})",
            f"raico: {', '.join(_fmt(x) for x in secs)} s over {len(secs)} seeds ({len(fin)} succeeded), "
            f"median {_fmt(med)} s; PILCO {PILCO_SECONDS} s", ok, None, j)


def claim_batch_cheaper(L, execs):
    e, b = L.get("every"), L.get("batch-100")
    if not (e and b):
        return ("batch-100 hyperparameter updates are much cheaper at similar error", "", "no runs", False)
    cheaper = b["fit_time_s_total"] <= 0.5 * e["fit_time_s_total"]
    similar = b["gp_error_last3"] <= 2 * e["gp_error_last3"]
    j = judged([Check("batch-100's total fit time / every's", b["fit_time_s_total"] / e["fit_time_s_total"], "<=", 0.5,
                      "x"),
                Check("batch-100's GP error over the last three / every's", b["gp_error_last3"] / e["gp_error_last3"],
                      "<=", 2.0, "x")])
    return ("batch-100 hyperparameter updates cost much less time than every-evaluation updates at similar "
            "prediction error", "total fit time of batch-100 at most half of every's, and its GP error over the "
            "last three evaluations at most twice every's",
            f"fit time {_fmt(b['fit_time_s_total'])} s (batch-100, {b['optimizations']} optimizations) vs "
            f"{_fmt(e['fit_time_s_total'])} s (every, {e['optimizations']}); GP error {_fmt(b['gp_error_last3'])} vs "
            f"{_fmt(e['gp_error_last3'])} rad/s^2", cheaper and similar, None, j)


def claim_reach_achieved(L, execs):
    got = {k: (s["achieved_last"], s["runs"], s["task_error_last3"]) for k, s in L.items()}
    ok = bool(got) and all(a == n for a, n, _ in got.values())
    j = judged([c for k, (a, n, e) in got.items()
                for c in (Check(f"{k}: seeds reaching it", a, "=", n, f"/{n}"),
                          Check(f"{k}: distance to the target over the last three", e, "<=", 0.05, " m"))])

    def extra(s):
        trunc = s.get("episodes_truncated") or []
        return (f", planned {_fmt(s.get('planned_task_error_last3', math.nan))} m; executions that lost tracking "
                f"{s.get('tracking_lost', 'n/a')} (their data cut at the failure: {sum(x or 0 for x in trunc)})")
    return ("the learned-model planner reaches the target on the Drake robot",
            "the last evaluation's execution achieves the task as execute judges it (every via-point within its "
            "tolerance, 1 cm here) and ends within 5 cm over the last three, for every schedule and seed",
            "; ".join(f"{k}: {a}/{n}, distance to the target over the last three {_fmt(e)} m executed" + extra(L[k])
                      for k, (a, n, e) in got.items()), ok, None, j)


CLAIMS = {k[len("claim_"):]: v for k, v in globals().items() if k.startswith("claim_")}
NOISE_CLAIMS = frozenset({"stabilizer_stands_under_noise"})  # judged on the noise sweep's noisy runs

# ----------------------------------------------------------------------------- what the thesis says, about which figure
ARM = ("fig3.2a", "fig3.2b", "fig3.2c", "fig3.2d")
# Each section (or caption) of the thesis a claim quotes -> the figures it is written about. A claim row quotes a
# sentence of one of these and is judged only on a figure its sentence is about (a test checks every experiment).
SECTION_FIGURES: dict[str, tuple[str, ...]] = {
    "§3.4": ARM,  # the arm's convergence (Fig. 3.2), AICO and iLQG, before R-AICO is introduced
    "§3.5": ARM,  # R-AICO on the same arm tasks (Fig. 3.2A-D)
    "§3.6.1": ("fig3.3",),  # the Nao's arm reaching (Fig. 3.3)
    "Fig. 3.3 caption": ("fig3.3",),
    "§3.6.2": ("fig3.4",),  # the Nao's balancing (Fig. 3.4)
    "Appendix C": ("fig3.2a", "fig3.2b", "fig3.3", "fig3.4"),  # the pseudo-dynamics integrators
    "§4.4": ("fig4.1/4.2",),  # the pendulum (Figs. 4.1, 4.2)
    "Fig. 4.1 caption": ("fig4.1/4.2",),
    "Fig. 4.2 caption": ("fig4.1/4.2",),
    "§4.5": ("fig4.3",),  # the BioRob's computation time (Fig. 4.3)
}


@dataclass(frozen=True)
class Quote:
    """Sentences of the thesis (``parts``: (section, verbatim text) each) and the figures they are written about."""

    about: tuple[str, ...]
    parts: tuple[tuple[str, str], ...]

    def text(self) -> str:
        return "; ".join(f'{sec}: "{t}"' for sec, t in self.parts)


def figure_names(ids) -> str:
    """Experiment ids as the thesis names its figures: ``fig3.2c``, ``fig3.2d`` -> ``Fig. 3.2C,D``."""
    by: dict[str, list[str]] = {}
    for f in ids:
        num = f[3:]  # "4.1/4.2": the pendulum's two figures, one experiment
        head, panel = (num[:-1], num[-1].upper()) if num[-1].isalpha() else (num, "")
        by.setdefault(head, []).append(panel)
    return "; ".join(f"Fig. {h}{','.join(p for p in ps if p)}" for h, ps in by.items())


BEYOND = "beyond the thesis (raico's own test)"
THESIS: dict[str, Quote | str] = {
    "raico_decays_fast": Quote(ARM, (("§3.5", "For both models of the system dynamics, the pseudo-dynamics "
                                              "approximation (shown in Figure 3.2A,B) and the analytic model (illustrated "
                                              "in Figure 3.2C,D), AICO benefits from the regularization term and the "
                                              "costs decay exponentially fast"),)),
    "raico_outperforms": Quote(("fig3.2c", "fig3.2d"), (("§3.4", "Our regularization method for AICO, that we will "
                                                                 "present in the next Section, considerably "
                                                                 "outperformed both competing methods"),)),
    "ilqg_performs_well": Quote(("fig3.2a", "fig3.2b"), (("§3.4", "While the iLQG algorithm performed well for the "
                                                                  "pseudo dynamics model, the learning rate was "
                                                                  "automatically decreased to almost zero for the "
                                                                  "analytical dynamics model"),)),
    "all_converge_aico_fastest": Quote(("fig3.2a",), (("§3.4", "For the simple task in Figure 3.2A the inferred cost "
                                                               "values converge fast for all algorithms, with the "
                                                               "standard AICO algorithm showing the best performance"),)),
    "aico_unstable": Quote(("fig3.2b",), (("§3.4", "the second scenario illustrated in Figure 3.2B, where AICO is "
                                                   "unstable and cannot infer solutions with low costs"),)),
    "aico_fails": Quote(("fig3.2c", "fig3.2d"), (("§3.4", "When we used the analytic forward dynamics model (where "
                                                          "the linearizations are computed through finite differences) "
                                                          "instead of the pseudo dynamics model, computing the messages "
                                                          "in AICO became numerically unstable and no solutions could "
                                                          "be inferred"),)),
    "ilqg_stalls": Quote(("fig3.2c", "fig3.2d"), (("§3.5", "the differential dynamic programming method iLQG [26] that "
                                                           "implements a sophisticated regularization scheme cannot "
                                                           "generate movement policies with low costs when using the "
                                                           "analytic model. This is shown in Figure 3.2C,D"),)),
    "integrators_agree": Quote(("fig3.2a",), (("Appendix C", "We compared all methods, and could not find any "
                                                             "significant difference in terms of accuracy. However, for "
                                                             "our experiments we used the backward Euler method, as it "
                                                             "is computationally the most efficient"),)),
    "raico_reaches_aico_not": Quote(("fig3.3",), (("§3.6.1", "As in the robot arm experiments, the Approximate "
                                                             "Inference Control algorithm (AICO) benefits from the "
                                                             "regularization. As can be seen in Figure 3.3B, AICO cannot "
                                                             "infer movement solutions with low costs without "
                                                             "regularization"),)),
    "counterbalance": Quote(("fig3.3",), (("Fig. 3.3 caption", "To counter balance, the robot moves its left hand and "
                                                               "the head, which is shown in (D)"),)),
    "aico_no_balancing": Quote(("fig3.4",), (("§3.6.2", "The standard implementation of AICO was not able to infer "
                                                        "successful balancing solutions, which is illustrated in Figure "
                                                        "3.4B"),)),
    "raico_converged_25": Quote(("fig3.4",), (("§3.6.2", "In contrast, the regularized variant using α ∈ {1, 10} "
                                                         "converged after 25 iterations of the trajectory optimization "
                                                         "procedure"),)),
    "gp_error_falls": Quote(("fig4.1/4.2",), (("§4.4", "However, for small precision weights the planned trajectories, "
                                                       "torques and end effector positions converges to the optimal "
                                                       "during the learning process and the model prediction error "
                                                       "converges to zero"),
                                              ("Fig. 4.2 caption", "In (A) and (B), the prediction error of the "
                                                                   "Gaussian processes and the RMSE of the task "
                                                                   "performance converges for all desired model "
                                                                   "uncertainty values with the weight w = 10^-2"))),
    "rmse_falls": Quote(("fig4.1/4.2",), (("Fig. 4.2 caption", "In (A) and (B), the prediction error of the Gaussian "
                                                               "processes and the RMSE of the task performance converges "
                                                               "for all desired model uncertainty values with the weight "
                                                               "w = 10^-2"),)),
    "large_weight_converges_without_exploration": Quote(("fig4.1/4.2",), (("Fig. 4.2 caption", "In (C) and (D), "
                                                                           "convergence is guaranteed for the model "
                                                                           "uncertainty value σ* = 0 and if no model "
                                                                           "uncertainty feature was used"),)),
    "large_weight_explores": Quote(("fig4.1/4.2",), (("Fig. 4.2 caption", "For a high weight and the model uncertainty "
                                                                          "values σ* = 1 and σ* = 0.2 the algorithm "
                                                                          "explores to much"),)),
    "swing_up_achieved": Quote(("fig4.1/4.2",), (("Fig. 4.1 caption", "Swing-Up of the simple pendulum as toy task"),
                                                 ("§4.4", "To reach the upper stable posture, the algorithm has to plan "
                                                          "several swings to the left - and right direction"))),
    "best_with_sigma_zero": Quote(("fig4.1/4.2",), (("§4.4", "The best solution of the swing-up is illustrated in Figure "
                                                             "4.1, which was obtained with the model uncertainty feature "
                                                             "and σ* = 0"),)),
    "batch_cheaper": Quote(("fig4.3",), (("§4.5", "The prediction error of the Gaussian processes is for both cases "
                                                  "similar. But the computation time differs"),)),
    "reach_achieved": Quote(("fig4.3",), (("§4.5", "The algorithm achieves to reach the desired end effector "
                                                   "position"),)),
    # beyond the thesis
    "raico_converges": BEYOND + " (the thesis says \"converged after 25 iterations\" of the Nao's balancing, §3.6.2, "
                                "Fig. 3.4B; of R-AICO on the arm it says the costs \"decay exponentially fast\", §3.5)",
    "aico_unstable_without_relinearization": BEYOND + " (ablation of \"AICO is unstable\", §3.4)",
    "raico_reaches_fddp": BEYOND,
    "gamma_ablation": BEYOND + " (ablation; §3.5: \"we did not increase α and γ = 1\", Algorithm 1 allows "
                               "α^[n] = α^[n-1] γ)",
    "rollout_start_reaches_fddp": BEYOND,
    "learning_rates_fail": BEYOND + " (ablation of a general sentence of §3.5, about no figure and with variants the "
                                    "thesis did not run: \"the learning rate is either applied to the state update (in "
                                    "Line 13 in Algorithm 1) [29] or to the feedback controller (in Line 18 in Algorithm "
                                    "1) [22]. However, neither implementation can guarantee convergence in nonlinear "
                                    "systems\")",
    "fd_ablation": BEYOND + " (ablation; §3.4: \"When we used the analytic forward dynamics model (where the "
                            "linearizations are computed through finite differences) ... computing the messages in "
                            "AICO became numerically unstable\")",
    "adaptive_reaches_fddp": BEYOND,
    "ilqg_stall_ablation": BEYOND + " (ablation of \"iLQG ... cannot generate ... low costs\", §3.5)",
    "cog_support": BEYOND + " (the thesis plans on a welded foot and executes nothing)",
    "executed_reaches": BEYOND + " (the thesis plans on a welded foot and executes nothing)",
    "stabilizer_stands": BEYOND + " (a whole-body stabilizer between plan and robot)",
    "stabilizer_stands_under_noise": BEYOND + " (\"with noise >= 9/10 stand\", the noise sweep's x0 0.02 rad and "
                                     "process 0.5 N m)",
    "single_support_stands": BEYOND + " (§3.6.2: \"In this task the humanoid has to balance on one foot by moving its "
                             "center of gravity\": the thesis plans on a welded foot, both soles down)",
    "pilco_efficiency": BEYOND,
}


# ----------------------------------------------------------------------------- what else can drive a verdict
# The set-up deviations (the report's deviations table has them all) that can drive the verdicts of a figure's
# thesis rows, and of single claims.
SETUP_NOTES = {
    "arm5": "arm5 is raico's own light-weight arm (link lengths and masses chosen)",
    "arm budget pseudo": "40 iterations (the thesis gives no number for the arm)",
    "arm budget analytic": "25 iterations (the thesis gives no number for the arm)",
    "exact derivatives": "the analytic model linearized exactly (AutoDiff; the thesis: finite differences)",
    "nao start": "q0 about a posture leaning over the welded left sole, not about the zero posture",
    "right sole": "the right sole held at its initial pose by a task term at every step",
    "cog weights": "CoG weights read as 1e6 on the lateral axis (the thesis's x), 10 on the others",
    "nao reach": "hand target read in the torso frame at t = 0, via-point at the last step (the thesis gives none)",
    "pendulum horizon": "2 s horizon (the thesis's 300 ms cannot swing up under +-10 N m; at 1.5 s the upright is out of "
                        "reach)",
    "pendulum warm start": "each evaluation starts from the previous plan's controls (the thesis: x0 held)",
    "biorob": "BioRob-like arm (raico's own model), 10 R-AICO iterations per evaluation",
    "biorob hyperparameters": "every re-optimization starts at the previous fit's hyperparameters",
}
FIGURE_SETUP = {
    "fig3.2a": ("arm5", "arm budget pseudo"), "fig3.2b": ("arm5", "arm budget pseudo"),
    "fig3.2c": ("arm5", "arm budget analytic", "exact derivatives"),
    "fig3.2d": ("arm5", "arm budget analytic", "exact derivatives"),
    "fig3.3": ("nao start", "right sole", "nao reach"), "fig3.4": ("nao start", "right sole", "cog weights"),
    "fig4.1/4.2": ("pendulum horizon", "pendulum warm start"), "fig4.3": ("biorob", "biorob hyperparameters"),
}
CLAIM_SETUP = {  # claims whose verdict no figure-wide deviation can drive
    "integrators_agree": ("arm5",), "counterbalance": ("nao start", "right sole", "nao reach"),
    "batch_cheaper": ("biorob hyperparameters",), "reach_achieved": ("biorob",),
}


def setup_notes(name: str, figure: str) -> str:
    """The set-up deviations that can drive claim ``name``'s verdict on ``figure`` (``SETUP_NOTES``)."""
    keys = CLAIM_SETUP.get(name, FIGURE_SETUP.get(figure, ()))
    return "; ".join(SETUP_NOTES[k] for k in keys) or "none"


CANNOT = "cannot be tested"  # the verdict of a claim whose measure cannot decide (the criterion says when)


def _seeds(S: dict) -> str:
    """The runs per variant of a figure's summaries (``runs``), as a range when they differ."""
    n = sorted({int(s["runs"]) for s in S.values() if isinstance(s, dict) and "runs" in s})
    return "n/a" if not n else str(n[0]) if len(n) == 1 else f"{n[0]}-{n[-1]}"


def _verdict(ok) -> str:
    return CANNOT if ok is None else "holds" if ok else "does not hold"


def _rows_of(out) -> list[tuple]:
    return out if isinstance(out, list) else [out]


def evaluate_claims(names: tuple[str, ...], S: dict, execs: list[dict], figure: str,
                    noisy: list[dict] | None = None, without: dict | None = None) -> list[dict]:
    """Rows ``{"figure", "claim", "thesis", "section", "about", "criterion", "measured", "verdict", "seeds",
    "setup", "why", "margin", "fragile"}`` for the named claims (one per setting where a claim is judged per
    setting). ``thesis``: the sentence of the thesis the claim tests with its section and the figures it is about
    (:data:`THESIS`), or :data:`BEYOND`; a thesis claim on a figure its sentence is not about is refused.
    ``execs``: the figure's executions' metrics; ``noisy``: those of its noise sweep's runs at a noise level above
    0 (each with ``noise_level``), which the claims of :data:`NOISE_CLAIMS` judge instead.

    ``margin``: each condition's measured number against its limit (where the claim states them); ``why`` (a row
    that does not hold): the conditions that failed, with their numbers. ``without``: seed -> the summaries with that
    seed left out; a row is ``fragile`` where leaving out one seed flips its verdict, or where a deciding margin is
    inside its quantity's spread over the runs."""
    rows = []
    for c in names:
        quote = THESIS[c]
        if isinstance(quote, Quote) and figure not in quote.about:
            raise ValueError(f"claim {c} quotes a sentence about {figure_names(quote.about)}, not {figure}")
        ex = noisy or [] if c in NOISE_CLAIMS else execs
        out = _rows_of(CLAIMS[c](S, ex))
        flips: dict[int, list] = {}
        failed: list[str] = []  # seeds whose leave-one-out rerun raised: their flip is unknown, and said so
        for seed, S_minus in (without or {}).items():
            try:
                again = _rows_of(CLAIMS[c](S_minus, ex))
            except (KeyError, ValueError, ZeroDivisionError) as e:
                failed.append(f"{seed} ({type(e).__name__}: {e})")
                continue
            for i, r in enumerate(again[:len(out)]):
                if r[0] == out[i][0] and _verdict(r[3]) != _verdict(out[i][3]):
                    flips.setdefault(i, []).append(seed)
        for i, r in enumerate(out):
            claim, criterion, numbers, ok = r[:4]
            seeds = str(r[4]) if len(r) > 4 and r[4] is not None else _seeds(S)
            extra = r[5] if len(r) > 5 else {}
            verdict = _verdict(ok)
            fragile = [f"leaving out seed {', '.join(map(str, flips[i]))} flips it"
                       if len(flips[i]) == 1 else f"leaving out any one of seeds {', '.join(map(str, flips[i]))} flips it"
                       ] if i in flips else []
            fragile += extra.get("near", []) if verdict != CANNOT else []
            if failed:  # an unknown flip is no evidence of robustness: the row says which reruns failed
                fragile.append(f"not known whether leaving out seed {', '.join(failed)} flips it: the rerun without "
                               "it failed")
            row = {"figure": figure, "claim": claim, "criterion": criterion, "measured": numbers,
                   "verdict": verdict, "seeds": seeds, "margin": extra.get("margin", ""), "fragile": "; ".join(fragile)}
            if isinstance(quote, Quote):
                row.update(thesis=f"{quote.text()} (about {figure_names(quote.about)})",
                           section=", ".join(sec for sec, _ in quote.parts), about=list(quote.about),
                           setup=setup_notes(c, figure), why="" if ok is not False else extra.get("why", ""))
            else:
                row.update(thesis=quote, section="", about=[], setup="", why=extra.get("why", "") if ok is False else "")
            rows.append(row)
    return rows
