"""The babbling screenshots of docs/stages.md (docs/babble_<plant>.png): a short babbling run of each plant
in a temporary cache, its recording rendered in the headless Rerun viewer as a user opens it.

    .venv/bin/python scripts/docs_screenshots.py [--out docs]

Needs the viewer's renderer (``apt-get install mesa-vulkan-drivers``); says why and exits 2 without it.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from raico.pipeline.interface import api
from raico.pipeline.recordings.screenshots import render_screenshot, renderer_unavailable
from raico.plants.robots import PLANTS


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="docs")
    ap.add_argument("--episodes", type=int, default=2)
    args = ap.parse_args(argv)
    why = renderer_unavailable()
    if why:
        print(f"docs_screenshots: cannot render: {why}", file=sys.stderr)
        return 2
    out = Path(args.out)
    with tempfile.TemporaryDirectory() as tmp:
        for plant in PLANTS:
            run = api.babble(tmp, plant=plant, episodes=args.episodes, quiet=True)
            png = render_screenshot(run.recording, out / f"babble_{plant}.png", timeline="sim_time", time=1.0)
            print(f"{plant}: {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
