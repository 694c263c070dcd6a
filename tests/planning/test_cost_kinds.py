"""The problem-file table (``raico.planning.term_kinds.COST_KINDS``): every row's functions exist, its terms and
maps are rows of the other two tables, and every shipped problem file's terms have a row."""

from __future__ import annotations

from pathlib import Path

import pytest

from raico.planning import problem_terms
from raico.planning.achieved import TASK_TOLERANCES
from raico.planning.problem_file import read_problem
from raico.planning.term_kinds import COST_KINDS, MAP_KINDS, cost_kind, kind_named, term_kinds

PROBLEMS = Path(__file__).resolve().parents[2] / "raico" / "problems"


def test_every_cost_kind_names_its_functions_and_rows_that_exist():
    terms = {k.key for k in term_kinds()}
    for row in COST_KINDS:
        assert callable(getattr(problem_terms, row.check)) and callable(getattr(problem_terms, row.describe)), row.type
        assert set(row.terms) <= terms and all(kind_named(m) is not None for m in row.maps), row.type
        assert {"type", "weight"} <= row.keys, row.type
        if "tol" in row.keys:   # a via-point's own tolerance, in the kinds its map is judged by
            assert row.terms == ("via",) and row.tolerance_parts > 0, row.type
    assert cost_kind("frame_placement").tolerance_parts == 2 and cost_kind("nonsense") is None


def test_every_tolerance_kind_of_the_map_table_has_a_default():
    assert {kind for row in MAP_KINDS for kind, _ in row.tolerance} == set(TASK_TOLERANCES)


def test_every_shipped_problem_files_terms_have_a_row():
    files = [f for f in sorted(PROBLEMS.rglob("*.toml")) if f.name != "suite.toml"]
    assert len(files) > 20
    types = {t["type"] for f in files for t in read_problem(f).doc["costs"]["terms"].values()}
    assert types <= {row.type for row in COST_KINDS}


def test_a_kind_that_needs_geometry_is_refused_on_a_built_in_plant(tmp_path):
    """The ``geometry`` column, not the kind's name, refuses a collision term on a plant without a model file."""
    assert [row.type for row in COST_KINDS if row.geometry] == ["collision"]
    text = (PROBLEMS / "arm5_reach.toml").read_text() + (
        '\n[costs.clear]\ntype = "collision"\npairs = [["ee", "world"]]\nmargin = 0.01\n')
    (tmp_path / "p.toml").write_text(text)
    with pytest.raises(ValueError, match=r"\[costs.clear\] collision terms need a robot from a model file"):
        read_problem(tmp_path / "p.toml")
