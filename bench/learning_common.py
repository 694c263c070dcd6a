"""What the learning benches (``bench.learn_any``, ``bench.payload``, ``bench.cartpole_pilco``) share: their
command line (``--artifacts``, ``--render``), the machine's load as the pages print it, and the axes of a
per-episode plot, and how they read an experiment file's base and points."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def parser(description: str, json_name: str) -> argparse.ArgumentParser:
    """The bench's argument parser with ``--artifacts`` (default the checkout's ``artifacts/``) and
    ``--render`` (only write the page and plots again from ``artifacts/bench/<json_name>``)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--artifacts", default=str(ROOT / "artifacts"))
    ap.add_argument("--render", action="store_true",
                    help=f"only write the page and plot again from {json_name}")
    return ap


def load_text() -> str:
    """The 1-, 5- and 15-minute load averages, as the pages state them (``"0.52 0.61 0.70"``)."""
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def episode_axes(axes, fontsize: float = 8) -> None:
    """Integer episodes on x, plain numbers (``%g``) on a log y axis, and the legend, on each of ``axes``."""
    from matplotlib.ticker import FormatStrFormatter, MaxNLocator

    for a in axes:
        a.xaxis.set_major_locator(MaxNLocator(integer=True))
        a.yaxis.set_major_formatter(FormatStrFormatter("%g"))
        a.yaxis.set_minor_formatter(FormatStrFormatter("%g"))
        a.legend(fontsize=fontsize)


def experiment_points(path: Path) -> tuple[dict, list[dict]]:
    """The experiment file's ``[base]`` (its problem's path resolved against the file) and its ``[[point]]`` tables
    (label and overrides)."""
    import tomllib

    doc = tomllib.loads(path.read_text())
    base = dict(doc["base"])
    base["problem"] = str((path.parent / base["problem"]).resolve())
    return base, [dict(p) for p in doc["point"]]
