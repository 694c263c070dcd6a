"""``raico exp run -S``: one value of an option that is no axis sets ``[base]``'s, so the ``[[point]]``
variants run with it too; a point that sets the option keeps its own, and the run and its dry run say
so; a new axis of several values says which points do not run along it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from raico.pipeline.errors import BadInput
from raico.pipeline.experiments import expfile

POINTS = '''
name = "points-only"
stages = ["plan", "execute"]
seeds = [0]
[base]
plant = "arm5"
task = "reach"
iterations = 2
alpha = 0.05
[[point]]
label = "R-AICO"
solver = "raico"
[[point]]
label = "R-AICO big"
alpha = 5.0
[[point]]
label = "iLQG"
solver = "ilqg"
'''


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "exp.toml"
    p.write_text(text)
    return p


def _alpha(exp: expfile.Experiment) -> dict[str, float]:
    return {v.label: v.options["plan"]["alpha"] for v in exp.variants}


def test_one_value_sets_the_base_for_every_variant_and_a_point_keeps_its_own(tmp_path):
    f = write(tmp_path, POINTS)
    assert _alpha(expfile.load(f)) == {"R-AICO": 0.05, "R-AICO big": 5.0, "iLQG": 0.05}
    exp = expfile.load(f, ["alpha=0.08"])
    assert [v.label for v in exp.variants] == ["R-AICO", "R-AICO big", "iLQG"]   # no grid variant beside them
    assert _alpha(exp) == {"R-AICO": 0.08, "R-AICO big": 5.0, "iLQG": 0.08} and exp.base["plan"]["alpha"] == 0.08
    assert exp.notes == ("-S alpha=0.08: in place of [base]'s 0.05 for every variant; the points that set alpha "
                         "keep their own: 'R-AICO big' (alpha=5.0)",)
    # a later stage's option, one the file does not set: the stage's default before
    exp = expfile.load(f, ["execute.x0_noise=0.01"])
    assert {v.options["execute"]["x0_noise"] for v in exp.variants} == {0.01}
    assert exp.notes == ("-S execute.x0_noise=0.01: in place of the stage's default for every variant",)
    with pytest.raises(BadInput, match="-S evaluate.x: evaluate is not a later stage"):
        expfile.load(f, ["evaluate.x=1"])


def test_several_values_make_an_axis_and_say_which_points_do_not_run_along_it(tmp_path):
    f = write(tmp_path, POINTS)
    exp = expfile.load(f, ["alpha=0.5,50"])
    assert [v.label for v in exp.variants] == ["alpha=0.5", "alpha=50", "R-AICO", "R-AICO big", "iLQG"]
    assert exp.notes == ("-S alpha=0.5,50: a grid axis; the points do not run along it: 'R-AICO', 'iLQG' at "
                         "[base]'s 0.05; 'R-AICO big' (alpha=5.0) at their own",)
    grid = write(tmp_path, POINTS.replace("[[point]]", "[grid]\ngamma = [1.0, 0.9]\n[[point]]", 1))
    exp = expfile.load(grid, ["alpha=0.08"])   # one value beside a grid of another option: still [base]'s
    assert [v.label for v in exp.variants][:2] == ["gamma=1.0", "gamma=0.9"]
    assert all(v.options["plan"]["alpha"] == (5.0 if v.label == "R-AICO big" else 0.08) for v in exp.variants)
    assert expfile.load(grid, ["gamma=0.5"]).grid == {"gamma": [1.0, 0.9, 0.5]}   # a file's axis: added to it


def test_the_dry_run_says_what_the_override_reaches(raico, tmp_path):
    f = write(tmp_path, POINTS)
    arts = tmp_path / "arts"
    res = raico("exp", "run", f, "-S", "alpha=0.08", "--dry-run", "--json", "--artifacts", arts)
    assert res.exit_code == 0, res.output
    said = [ln for ln in res.stderr.splitlines() if "-S alpha=0.08" in ln]
    assert said == ["exp points-only: -S alpha=0.08: in place of [base]'s 0.05 for every variant; the points "
                    "that set alpha keep their own: 'R-AICO big' (alpha=5.0)"], res.stderr
    assert json.loads(res.stdout.splitlines()[-1])["variants"] == 3
    assert not (arts / "plan").exists()


def test_one_problem_file_is_read_from_the_experiment_file_s_folder(tmp_path):
    (tmp_path / "sub").mkdir()
    f = tmp_path / "sub" / "exp.toml"
    f.write_text('name = "p"\n[base]\nproblem = "a.toml"\n')
    exp = expfile.load(f, ["problem=b.toml"])
    assert exp.base["plan"]["problem"] == str((tmp_path / "sub" / "b.toml").resolve())
