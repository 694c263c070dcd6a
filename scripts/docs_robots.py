"""The robots from model files of docs/problem-files.md (docs/robots.png): each example-robot-data robot that the
tests plan for, loaded from its installed file, a short R-AICO reach (the arms) or CoM shift (the
humanoids on a welded sole) planned in a temporary cache, its recording's 3D view rendered in the
headless Rerun viewer at the plan's end, the views tiled with the robot's name.

    .venv/bin/python scripts/docs_robots.py [--out docs/robots.png]

Needs the viewer's renderer (``apt-get install mesa-vulkan-drivers``) and example-robot-data (the
``baseline`` extra); says why and exits 2 without them.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "plants"))



def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="docs/robots.png")
    ap.add_argument("--only", nargs="*", help="these robots only (to look at one)")
    args = ap.parse_args(argv)
    from test_model_file import ARMS, COM_SHIFT, HUMANOIDS, LIMITS, REACH, problem_text

    from raico.pipeline.interface import api
    from raico.pipeline.recordings.screenshots import read_png, render_screenshot, renderer_unavailable
    from raico.planning.problem_terms import resolve_frame
    from raico.plants.model_file import RobotSpec, example_robot_data, load_model
    from raico.plants.taskmaps import FramePoints

    why = renderer_unavailable() or (None if example_robot_data() else "example-robot-data is not installed")
    if why:
        print(f"docs_robots: cannot render: {why}", file=sys.stderr)
        return 2
    robots = example_robot_data() / "robots"
    tiles = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name, (file, extra, *rest) in {**ARMS, **HUMANOIDS}.items():
            if args.only and name not in args.only:
                continue
            uri = f"package://example-robot-data/robots/{file}"
            if rest:
                robot = load_model(RobotSpec.from_dict({"file": str(robots / file), **extra}))
                frame = resolve_frame(robot, rest[0], "reach")
                p = FramePoints(robot, frame).value(robot.default_q)
                costs = REACH.format(frame=rest[0], target=(-0.06 * p / np.linalg.norm(p)).tolist()) + LIMITS
                text, T = problem_text(uri, extra, costs.replace("weight = 1e4", "weight = 1e6")), 40
            else:
                text, T = problem_text(uri, extra, COM_SHIFT, T=30), 30
            path = tmp / f"{name}.toml"
            path.write_text(text)
            run = api.plan(tmp / "art", problem=str(path), solver="raico", iterations=20, quiet=True)
            png = tmp / f"{name}.png"
            render_screenshot(run.recording, tmp / f"{name}_window.png", views={"robot": png},
                              timeline="sim_time", time=T * 0.01)
            tiles.append((name, read_png(png)))
            print(f"{name}: {run.key}")
    _tile(tiles, Path(args.out))
    print(args.out)
    return 0


def _tile(tiles: list[tuple[str, np.ndarray]], out: Path, cols: int = 4) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = -(-len(tiles) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3.2 * rows), facecolor="black")
    for ax in np.ravel(axes):
        ax.axis("off")
    for ax, (name, img) in zip(np.ravel(axes), tiles):
        h, w = img.shape[:2]  # the view's middle: the robot (the view is wider than tall)
        x0 = max(0, (w - int(1.3 * h)) // 2)
        ax.imshow(img[:, x0:w - x0])
        ax.set_title(name, color="white", fontsize=12)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90, facecolor="black")


if __name__ == "__main__":
    sys.exit(main())
