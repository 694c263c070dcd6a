"""The Rerun viewer renders one recording per plant headless (SPEC §9): the robot is in frame.

Needs a Vulkan driver for the software renderer (`.ci/run` installs Debian's mesa-vulkan-drivers);
skipped, with the reason, where none is installed.
"""

import glob
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from pipeline.cli import app

RERUN = Path(sys.executable).with_name("rerun")
HAS_VULKAN = bool(glob.glob("/usr/share/vulkan/icd.d/*.json"))


def _robot_mask(path: Path) -> tuple[np.ndarray, np.ndarray]:
    import matplotlib.image as mpimg

    img = mpimg.imread(path)[..., :3]
    H, W = img.shape[:2]
    view = img[int(0.12 * H):int(0.92 * H), int(0.02 * W):int(0.56 * W)]  # inside the 3D view (left), below its title
    bright, sat = view.max(axis=2), view.max(axis=2) - view.min(axis=2)
    return (sat > 0.25) | (bright > 0.55), view  # coloured or light bodies; the grid is dim grey on black


def screenshot_robot_pixels(rrd: str, shot: Path, tries: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Open ``rrd`` in a headless viewer and screenshot it once the data has loaded (a screenshot
    taken before shows an empty scene: retry until robot pixels appear, or give up)."""
    import socket
    import time

    from rerun.experimental import ViewerClient

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    os.environ.setdefault("WGPU_BACKEND", "vulkan")
    viewer = ViewerClient.spawn(headless=True, port=port, executable_path=str(RERUN), hide_welcome_screen=True)
    try:
        viewer.open(rrd)
        for _ in range(tries):
            viewer.save_screenshot(str(shot))
            robot, view = _robot_mask(shot)
            if robot.mean() > 0.002:
                break
            time.sleep(1.0)
        return robot, view
    finally:
        viewer.quit()


@pytest.mark.skipif(not HAS_VULKAN, reason="no Vulkan driver (apt-get install mesa-vulkan-drivers)")
@pytest.mark.parametrize("plant", ["pendulum", "arm5", "biorob", "nao"])
def test_viewer_renders_the_robot(tmp_path, plant):
    res = CliRunner().invoke(app, ["babble", "--plant", plant, "--episodes", "1", "--duration", "0.2", "--json",
                                   "--quiet", "--artifacts", str(tmp_path)])
    assert res.exit_code == 0, res.output
    rrd = json.loads(res.stdout.strip().splitlines()[-1])["recording"]
    robot, view = screenshot_robot_pixels(rrd, tmp_path / "shot.png")
    rows, cols = np.nonzero(robot)
    assert robot.mean() > 0.002, f"no robot in the 3D view ({robot.mean():.4f} of its pixels)"
    # in frame: the robot's pixels do not hug the view's border
    assert rows.min() > 0 and cols.min() > 0 and rows.max() < view.shape[0] - 1 and cols.max() < view.shape[1] - 1
