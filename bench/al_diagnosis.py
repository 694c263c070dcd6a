"""Why the augmented Lagrangian of bounded R-AICO stalls: ``python -m bench.al_diagnosis LABEL [ITERATIONS]
[--process-noise F]``.

Plans the suite problem ``LABEL`` with the default plan (``R-AICO robust, bounded``; ``ITERATIONS``: its budget,
default the suite's) and prints one line per trial of the robust schedule: the merit at the current iterate, the
regularization ``lambda``, the trial step's linear term ``g . d`` of the merit's quadratic model (``g``: the model's
gradient, ``d``: the trial's change of states and controls; > 0: the step ascends the model), the predicted and
actual decrease, the largest joint-range, velocity and control excess, the penalty over its start and the
multiplier updates so far. ``--process-noise F`` multiplies the messages' process noise by ``F``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from typing import Any

import numpy as np


def diagnose(label: str, iterations: int | None = None, noise: float = 1.0, say=print) -> dict:
    """The trials of the default plan of suite problem ``label``, one line each through ``say``; returns the
    final status, cost and iterations, and the first iteration whose trial ascends the model at ``lambda > 1``."""
    from raico.pipeline.experiments import suite as S
    from raico.planning.aico import solve as aico_solve
    from raico.planning.aico import steps
    from raico.planning.solvers import solve
    from raico.stages.plan.stage import PlanConfig, build_problem, quasi_static_controls

    suite = S.load(None)
    p = next(p for p in suite.problems if p.label == label)
    s = next(s for s in suite.solvers if s.label == "R-AICO robust, bounded")
    opts = S.options(p, s)
    if iterations:
        opts["iterations"] = int(iterations)
    cfg = PlanConfig(**opts).normalized()
    _, _, problem, q0, _ = build_problem(cfg)
    init = {"rollout": lambda: {"U_init": np.zeros((problem.T, problem.n_u))},
            "quasi-static": lambda: {"U_init": quasi_static_controls(problem, q0)}}.get(cfg.start, dict)()
    b, out = problem.bounds, dict[str, Any](first_ascent=None)
    trial, inner = steps.RobustStep._trial, aico_solve._aico

    def traced(self, cur):
        st = trial(self, cur)
        new, al = st.iterate, self.sw.al
        if self.cur_cost is None or self._model is None or not np.all(np.isfinite(new.X)):
            return st
        lx, _, lu, _, _ = self._model
        gd = float(np.einsum("ti,ti->", lx, new.X - cur.X) + np.einsum("ti,ti->", lu, new.U - cur.U))
        q, u = b.violation(new.X, new.U) if b is not None else (0.0, 0.0)
        v = b.velocity_violation(new.X) if b is not None and b.has_velocities else 0.0
        if gd > 0 and self.lam > 1.0 and out["first_ascent"] is None:
            out["first_ascent"] = self._it
        say(f"it {self._it:4d} merit {self.cur_cost:12.6g} lambda {self.lam:9.3g} g.d {gd:10.3g} "
            f"predicted {self._predicted_decrease(cur, new):10.3g} actual {self.cur_cost - st.cost:10.3g} "
            f"range {q:8.2g} velocity {v:8.2g} control {u:8.2g} penalty {al.mu / al.mu0 if al else 0:8.3g} "
            f"updates {al.updates if al else 0}")
        return st

    call = steps.RobustStep.__call__

    def counted(self, it, cur):
        self._it = it
        return call(self, it, cur)

    def noisy(problem, o, *a, **k):
        return inner(problem, dataclasses.replace(o, process_noise=o.process_noise * noise), *a, **k)

    wrapped = {(steps.RobustStep, "_trial"): traced, (steps.RobustStep, "__call__"): counted, (aico_solve, "_aico"): noisy}
    kept = {k: getattr(*k) for k in wrapped}
    for (owner, name), fn in wrapped.items():
        setattr(owner, name, fn)
    try:
        res = solve(problem, cfg.solver, cfg.solver_options(), **init)
    finally:
        for (owner, name), fn in kept.items():
            setattr(owner, name, fn)
    cost = problem.cost(res.X, res.U)
    out.update(status=res.status.value, cost=cost if math.isfinite(cost) else None, iterations=res.iterations,
               message=res.message)
    say(f"{res.status.value} after {res.iterations} iterations, cost {cost:.6g}: {res.message}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("label", help="a suite problem's label")
    ap.add_argument("iterations", nargs="?", type=int, default=None)
    ap.add_argument("--process-noise", type=float, default=1.0, help="factor on the process noise")
    args = ap.parse_args()
    out = diagnose(args.label, args.iterations, args.process_noise)
    print(f"first trial ascending the merit's model at lambda > 1: iteration {out['first_ascent']}")


if __name__ == "__main__":
    main()
