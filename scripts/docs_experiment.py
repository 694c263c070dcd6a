"""The README's (and docs/experiment-files.md's) experiment images: docs/exp_arm_alpha_cost.png (``raico plot arm-alpha --kind curve``) and
docs/compare_arm_alpha.png (``raico compare --exp arm-alpha --where "seed == 0"``, its recording rendered in the
headless Rerun viewer as a user opens it, the time cursor at 1 s).

    .venv/bin/python scripts/docs_experiment.py [--artifacts artifacts] [--out docs]

Runs experiments/arm_alpha.toml first if its runs table is missing (60 plans, about a minute on 2 cores). The
screenshot needs the viewer's renderer (``apt-get install mesa-vulkan-drivers``); without it the plot is made and
the script says why it made no screenshot (exit 2).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from raico.pipeline.engine.cache import Cache
from raico.pipeline.experiments import compare, expfile, plots
from raico.pipeline.recordings.screenshots import read_png, render_screenshot, renderer_unavailable, robot_mask

ROOT = Path(__file__).resolve().parent.parent
FILE = ROOT / "experiments" / "arm_alpha.toml"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--artifacts", default="artifacts")
    ap.add_argument("--out", default=str(ROOT / "docs"))
    args = ap.parse_args(argv)
    cache, out = Cache(Path(args.artifacts)), Path(args.out)
    if not (expfile.table_dir(cache, "arm-alpha") / "runs.json").exists():
        raico = str(Path(sys.executable).with_name("raico"))
        subprocess.run([raico, "exp", "run", str(FILE), "--artifacts", args.artifacts], check=True)
    df, swept = expfile.read_table(cache, "arm-alpha")
    png = plots.curve_plot(df, swept, out / "exp_arm_alpha_cost.png", "arm-alpha", cache).path
    print(f"plot: {png}")
    why = renderer_unavailable()
    if why:
        print(f"docs_experiment: no screenshot: {why}", file=sys.stderr)
        return 2
    runs = compare.load_runs(cache, compare.runs_of_experiment(cache, "arm-alpha", "seed == 0"))
    compare.label_runs(runs)
    rrd = compare.write(cache, runs, compare.default_path(cache, runs))

    def drawn(viewer, ids) -> bool:   # every run's 3D view shows its robot
        return all(r.label in ids and robot_mask(read_png(viewer.take_screenshot(ids[r.label]))).mean() > 3e-4
                   for r in runs)

    shot = render_screenshot(rrd, out / "compare_arm_alpha.png", timeline="sim_time", time=1.0, ready=drawn,
                             timeout_s=60.0)
    print(f"compare: {rrd} -> {shot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
