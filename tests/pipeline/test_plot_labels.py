"""``raico plot --kind line`` names each group by what its runs set and draws every group where it can be
seen: R-AICO's alpha and schedule beside AICO and iLQG points, which use neither (2 iterations, 2 seeds)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from raico.pipeline.engine.cache import Cache
from raico.pipeline.experiments import expfile, plots

MIXED = '''
name = "mixed"
stages = ["plan"]
seeds = "range(2)"
[base]
plant = "arm5"
task = "reach"
iterations = 2
[grid]
alpha = [0.5, 5.0]
alpha_schedule = ["fixed", "adaptive"]
[[point]]
label = "AICO"
solver = "aico"
[[point]]
label = "iLQG"
solver = "ilqg"
'''


@pytest.fixture(scope="module")
def arts(raico, tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("mixed")
    f = root / "mixed.toml"
    f.write_text(MIXED)
    res = raico("exp", "run", f, "--executor", "serial", "--artifacts", root / "arts")
    assert res.exit_code == 0, res.output
    return root / "arts"


def _styles(drawn: plots.Plot) -> list[tuple]:
    return [s["style"] for s in drawn.series.values()]


def test_points_that_use_none_of_the_grouping_options_are_named_by_their_variants(arts, tmp_path):
    """Against the solver, the groups are R-AICO's alpha and schedule: AICO and iLQG use neither (their
    normalized alpha is 0, their schedule fixed), so they are named as the file names them, never
    ``alpha_schedule=fixed``; each R-AICO variant is a point at its category, not a line across."""
    cache = Cache(arts)
    df, swept = expfile.read_table(cache, "mixed")
    drawn = plots.line_plot(df, swept, "solver", "plan.final_cost", tmp_path / "s.png", "mixed", cache)
    assert set(drawn.series) == {"alpha=0.5, alpha_schedule=fixed", "alpha=0.5, alpha_schedule=adaptive",
                                 "alpha=5, alpha_schedule=fixed", "alpha=5, alpha_schedule=adaptive", "AICO, iLQG"}
    assert drawn.series["AICO, iLQG"]["x"] == ["aico", "ilqg"]
    assert all(s["x"] == ["raico"] and s["drawn"] == "points" for label, s in drawn.series.items() if "alpha=" in label)
    assert len(set(_styles(drawn))) == len(drawn.series)


def test_no_line_hides_another_and_a_group_without_a_value_is_in_the_legend(arts, tmp_path):
    """Against alpha: two R-AICO lines, AICO and iLQG as baselines (they do not use alpha). Every group has
    its own colour, marker and line style, two baselines put their markers at different places (two at
    one value stay apart), and a group without a finite value is named with n=0 instead of left out."""
    from PIL import Image

    cache = Cache(arts)
    df, swept = expfile.read_table(cache, "mixed")
    df.loc[df["variant"] == "AICO", "plan.final_cost"] = np.inf     # as a diverged run's
    df.loc[df["variant"] == "iLQG", "plan.final_cost"] = 100.0
    out = tmp_path / "a.png"
    drawn = plots.line_plot(df, swept, "alpha", "plan.final_cost", out, "mixed", cache)
    assert set(drawn.series) == {"alpha_schedule=fixed, solver=raico", "alpha_schedule=adaptive, solver=raico",
                                 "solver=aico", "solver=ilqg"}
    assert drawn.series["solver=aico"]["n"] == [0] and drawn.series["solver=ilqg"]["x"] is None
    assert len(set(_styles(drawn))) == 4 and len({style[1] for style in _styles(drawn)}) == 4
    same = df.copy()   # two baselines at one value: their markers sit apart
    same.loc[same["variant"] == "AICO", "plan.final_cost"] = 100.0
    drawn = plots.line_plot(same, swept, "alpha", "plan.final_cost", tmp_path / "b.png", "mixed", cache)
    assert drawn.series["solver=aico"]["median"] == drawn.series["solver=ilqg"]["median"] == [100.0]
    assert drawn.series["solver=aico"]["marks_from"] != drawn.series["solver=ilqg"]["marks_from"]
    with Image.open(out) as im:
        assert im.size == (900, 600)
