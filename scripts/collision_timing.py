"""Time of the signed-distance queries against a planning iteration: the shipped xArm7 reach (7 DOF, T = 100)
with a scene of four objects and a collision term on every link against them and the robot against itself
(its SRDF's allowed pairs left out), planned by R-AICO. Prints the pairs, the iterations, the time per
iteration and the share of it the distances take (their values and Jacobians at every step).

    PYTHONPATH=. .venv/bin/python scripts/collision_timing.py [ITERATIONS]
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

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

[costs.avoid]
type = "collision"
pairs = [["robot", "scene"]]
self = true
allow = "srdf"
margin = 0.02
"""


def main(iterations: int = 20) -> None:
    from raico.plants.scene import SignedDistances
    from raico.stages.plan.stage import PlanConfig, plan

    src = (ROOT / "raico" / "problems" / "examples" / "xarm7_reach.toml").read_text()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "xarm7_scene.toml"
        path.write_text(src.replace("[costs.reach]", SCENE + "\n[costs.reach]", 1))
        spent = {"s": 0.0, "calls": 0, "pairs": 0}
        evaluate = SignedDistances.evaluate

        def timed(self, Q, jacobians=True):
            t = time.perf_counter()
            try:
                return evaluate(self, Q, jacobians)
            finally:
                spent["s"] += time.perf_counter() - t
                spent["calls"] += 1
                spent["pairs"] = self.dim

        SignedDistances.evaluate = timed
        try:
            out = plan(PlanConfig(problem=str(path), solver="raico", iterations=iterations).normalized())
        finally:
            SignedDistances.evaluate = evaluate
    m = out.metrics()
    per = m["wall_time_s"] / max(m["iterations"], 1)
    print(f"pairs {spent['pairs']}, T 100, {m['iterations']} iterations in {m['wall_time_s']:.2f} s "
          f"({1e3 * per:.1f} ms each); distance queries {spent['s']:.2f} s in {spent['calls']} batches of 101 "
          f"steps ({1e3 * spent['s'] / max(spent['calls'], 1):.1f} ms each, "
          f"{1e3 * spent['s'] / max(m['iterations'], 1):.1f} ms per iteration, "
          f"{100 * spent['s'] / m['wall_time_s']:.0f} % of the planning time; planning and setting up)")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "xarm7.toml"
        path.write_text(src)
        base = plan(PlanConfig(problem=str(path), solver="raico", iterations=iterations).normalized()).metrics()
    without = base["wall_time_s"] / max(base["iterations"], 1)
    print(f"without the collision term: {1e3 * without:.1f} ms per iteration; the term's share of an iteration "
          f"with it: {100 * (per - without) / per:.0f} %")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20)
