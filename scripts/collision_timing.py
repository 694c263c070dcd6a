"""Time of the signed-distance queries against a planning iteration: the shipped xArm7 reach (7 DOF, T = 100)
with a scene of five objects and a hard collision term on every link against them and the robot against
itself (its SRDF's allowed pairs left out: 51 pairs), planned by R-AICO. Prints, as medians over REPEATS
runs, the time per iteration, the time of the distance queries within the iterations (values and Jacobians
of the batches the solver's iterations ask for; the start's cost, the notes before planning and the
status after left out) and their
share (of the wall time and, steadier on a loaded machine, of the processor time), and the time per iteration
without the term; once with the pairs of a convex mesh measured by the
compiled GJK (``raico.plants.scene``, distance.c; the default) and once with every pair queried from Drake's
SceneGraph (the route before it); and the two routes' distances on the last batch of one plan (every pair
within ``max_distance``, no cull).

    PYTHONPATH=. .venv/bin/python scripts/collision_timing.py [ITERATIONS] [REPEATS]
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = """
[[scene]]
name = "table"
type = "box"
size = [0.8, 1.2, 0.04]
pose = [0.55, 0.0, -0.03, 0.0, 0.0, 0.0]

[[scene]]
name = "pole"
type = "cylinder"
radius = 0.03
length = 1.0
pose = [0.45, 0.3, 0.5, 0.0, 0.0, 0.0]

[[scene]]
name = "ball"
type = "sphere"
radius = 0.06
pose = [0.35, -0.3, 0.45, 0.0, 0.0, 0.0]

[[scene]]
name = "shelf"
type = "box"
size = [0.3, 0.6, 0.02]
pose = [0.7, 0.0, 0.7, 0.0, 0.0, 0.0]

[[scene]]
name = "wall"
type = "box"
size = [1.0, 0.04, 1.0]
pose = [0.4, -0.55, 0.5, 0.0, 0.0, 0.0]

[costs.avoid]
type = "collision"
pairs = [["robot", "scene"]]
self = true
allow = "srdf"
margin = 0.02
"""


def _run(path: Path, iterations: int, compiled: bool = True) -> tuple[float, float, int, int, str, float, float]:
    """Time per iteration (s), query time per iteration (s), pairs, iterations, status, pair queries per
    iteration and the queries' share of the iterations' processor time of one plan (``compiled``: False, every
    pair by Drake)."""
    from raico.plants.scene import SignedDistances
    from raico.stages.plan.stage import PlanConfig, plan

    spent: dict = {"s": 0.0, "cpu": 0.0, "pairs": 0, "inside": 0}
    evaluate = SignedDistances.evaluate

    def timed(self, Q, jacobians=True, **kw):
        self.compiled = self.compiled and compiled
        t, c, n = time.perf_counter(), time.process_time(), self.queries
        try:
            return evaluate(self, Q, jacobians, **kw)
        finally:
            dt, dc = time.perf_counter() - t, time.process_time() - c
            if spent["inside"]:   # within the iterations
                spent["s"] += dt
                spent["cpu"] += dc
                spent["queries"] = spent.get("queries", 0) + self.queries - n
            spent["pairs"] = self.dim
            spent["last"] = (self, np.array(Q))

    import raico.planning.aico.solve as solve

    drive = solve.drive

    def timed_drive(*a, **kw):   # the iterations' span: the driver's call, callbacks and all
        t, c = time.perf_counter(), time.process_time()
        spent["inside"] += 1
        try:
            return drive(*a, **kw)
        finally:
            spent["inside"] -= 1
            spent["drive"] = spent.get("drive", 0.0) + time.perf_counter() - t
            spent["drive_cpu"] = spent.get("drive_cpu", 0.0) + time.process_time() - c

    SignedDistances.evaluate, solve.drive = timed, timed_drive
    try:
        out = plan(PlanConfig(problem=str(path), solver="raico", iterations=iterations).normalized())
    finally:
        SignedDistances.evaluate, solve.drive = evaluate, drive
    m = out.metrics()
    n = max(m["iterations"], 1)
    if compiled and "last" in spent:
        _LAST[:] = [spent["last"]]
    return (spent["drive"] / n, spent["s"] / n, spent["pairs"], m["iterations"], m["status"], spent.get("queries", 0) / n,
            spent["cpu"] / spent["drive_cpu"])


_LAST: list = []


def _routes_compared() -> str:
    """The compiled and Drake's distances at the last batch a compiled run asked for (no cull): pairs within
    ``max_distance`` on both, the largest difference, and how many are larger by Drake (its witness points are on
    the shapes, so Drake's distance is never below the true one; the compiled one is certified by a separating
    plane, tests/plants/test_gjk.py)."""
    tm, Q = _LAST[0]
    tm._batches, tm._known, tm.compiled = [], None, True
    D1 = tm.evaluate(Q, jacobians=False)[0]
    tm._batches, tm._known, tm.compiled = [], None, False
    D0 = tm.evaluate(Q, jacobians=False)[0]
    live = (D1 < tm.max_distance) & (D0 < tm.max_distance)
    diff = D0[live] - D1[live]
    return (f"the last batch by both routes: {int(live.sum())} pair distances within max_distance; Drake's minus the "
            f"compiled: largest {1e3 * diff.max():.3f} mm, smallest {1e3 * diff.min():.2g} mm; "
            f"{int((diff > 1e-6).sum())} above 1 um, {int((diff > 1e-3).sum())} above 1 mm")


def main(iterations: int = 20, repeats: int = 3) -> None:
    import os

    src = (ROOT / "raico" / "problems" / "examples" / "xarm7_reach.toml").read_text()
    with tempfile.TemporaryDirectory() as tmp:
        path, base = Path(tmp) / "xarm7_scene.toml", Path(tmp) / "xarm7.toml"
        path.write_text(src.replace("[costs.reach]", SCENE + "\n[costs.reach]", 1))
        base.write_text(src)
        load = [os.getloadavg()[0]]
        routes = {}
        for compiled in (True, False):
            routes[compiled] = [_run(path, iterations, compiled) for _ in range(repeats)]
        without = float(np.median([_run(base, iterations)[0] for _ in range(repeats)]))
        load.append(os.getloadavg()[0])
    runs = routes[True]
    print(f"pairs {runs[0][2]}, T 100, {runs[0][3]} iterations ({runs[0][4]}); medians of {repeats} runs, load "
          f"{min(load):.1f}-{max(load):.1f} on {os.cpu_count()} cores")
    for compiled, label in ((True, "compiled GJK on the meshes' hulls"), (False, "every pair by Drake")):
        runs = routes[compiled]
        per, q, nq = (float(np.median([r[k] for r in runs])) for k in (0, 1, 5))
        share = float(np.median([r[1] / r[0] for r in runs]))
        cpu = float(np.median([r[6] for r in runs]))
        print(f"with the term ({label}): {1e3 * per:.1f} ms per iteration, of them distance queries "
              f"{1e3 * q:.1f} ms ({100 * share:.0f} %; of the processor time {100 * cpu:.0f} %), "
              f"{nq:.0f} pair queries per iteration")
    print(f"without the term: {1e3 * without:.1f} ms per iteration")
    print(_routes_compared())


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
