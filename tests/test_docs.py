"""The documentation: a README of at most 300 lines that links its pages, generated blocks that live in one
file each, every command's ``--help`` ending with its page, and the reference tables the site generates from
the code's own schema (``scripts/docs_hooks.py``), and numbers typed in the prose that a generated table or a
test owns (the claims table's counts, a test's bound) equal to theirs. ``make docs`` builds the site itself."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from raico.pipeline.interface.cli import app
from raico.pipeline.interface.cli.common import DOCS_PAGES
from scripts import docs_hooks, readme_numbers

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_the_readme_is_short_and_keeps_the_walk_throughs():
    assert len(README.splitlines()) <= 300
    for heading in ("## Set-up", "## A five-minute tour", "## Your own experiment", "## Your own robot",
                    "## Documentation"):
        assert re.search(rf"^{re.escape(heading)}", README, re.M), heading


def test_every_docs_link_of_the_readme_and_the_pages_names_a_page_that_exists():
    links = re.findall(r"\]\((docs/[^)#]+)", README)
    assert len(links) >= 15
    missing = [link for link in links if not (ROOT / link).is_file()]
    assert missing == []
    assert set(DOCS_PAGES.values()) <= {p.name for p in (ROOT / "docs").glob("*.md")}


@pytest.mark.parametrize("name, home", [("headline", "README.md"), ("exp", "README.md"),
                                        ("results", "docs/results.md"), ("bench", "docs/benchmarks.md"),
                                        ("suite", "docs/benchmarks.md"), ("problems", "docs/crocoddyl.md"),
                                        ("learn_any", "docs/learning.md"), ("exp-ur5", "docs/problem-files.md"),
                                        ("cartpole", "docs/learning.md"), ("payload", "docs/learning.md"), ("mpc", "docs/mpc.md"),
                                        ("nao_mpc", "docs/mpc.md"),
                                        ("baseline", "docs/learning.md"),
                                        ("executors", "docs/executors.md"), ("suite-exec", "docs/suite.md"),
                                        ("constraints", "docs/suite.md")])
def test_each_generated_block_lives_in_exactly_one_file(name, home):
    assert readme_numbers.home(name) == ROOT / home


def test_a_block_in_two_files_or_none_is_refused(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "README.md").write_text("<!-- bench:begin -->\nx\n<!-- bench:end -->\n")
    (tmp_path / "docs" / "b.md").write_text("<!-- bench:begin -->\ny\n<!-- bench:end -->\n")
    with pytest.raises(SystemExit, match="found in README.md, docs/b.md"):
        readme_numbers.home("bench", tmp_path)
    with pytest.raises(SystemExit, match="found in no file"):
        readme_numbers.home("suite", tmp_path)


def _commands(cmd, ctx, path=""):
    """Every command of the click tree below ``cmd`` as (path, command)."""
    yield path, cmd
    if isinstance(cmd, typer.core.TyperGroup):
        for name in cmd.list_commands(ctx):
            yield from _commands(cmd.get_command(ctx, name), ctx, f"{path} {name}".strip())


def test_every_command_names_its_page_and_the_page_exists():
    group = typer.main.get_command(app)
    ctx = typer.Context(group)
    paths = {path: cmd.epilog for path, cmd in _commands(group, ctx)}
    assert {"", "plan", "learn", "exp run", "bench suite", "ls"} <= set(paths)
    assert set(paths) == set(DOCS_PAGES), set(paths) ^ set(DOCS_PAGES)
    for path, epilog in paths.items():
        page = re.fullmatch(r"Docs: (docs/[\w-]+\.md)", epilog or "")
        assert page and (ROOT / page.group(1)).is_file(), (path, epilog)


@pytest.mark.parametrize("args", [[], ["plan"], ["exp", "run"], ["bench", "suite"]])
def test_help_ends_with_the_page(args):
    res = CliRunner().invoke(app, [*args, "--help"])
    assert res.exit_code == 0, res.output
    assert res.output.strip().splitlines()[-1].strip() == f"Docs: docs/{DOCS_PAGES[' '.join(args)]}"


def test_the_options_table_lists_every_field_of_the_stage_config():
    from raico.stages.plan.stage import PlanConfig

    table = docs_hooks.options_table("plan")
    flags = re.findall(r"^\| `(--[\w-]+)` \|", table, re.M)
    assert flags == [f"--{f.name.replace('_', '-')}" for f in dataclasses.fields(PlanConfig)]
    assert "| `--alpha-schedule` | `str` | `unset` |" in table


def test_the_problem_file_table_lists_every_key_set_of_the_loader():
    from raico.planning import problem_file as pf
    from raico.planning.term_kinds import COST_KINDS

    table = docs_hooks.problem_file_table()
    for kind in COST_KINDS:
        row = next(line for line in table.splitlines() if line.startswith(f"| `{kind.type}` |"))
        assert set(re.findall(r"`(\w+)`", row)[1:]) == set(kind.keys), kind.type
    assert all(f"`{k}`" in table for k in pf.ROBOT_KEYS | pf.TRUE_KEYS | pf.HORIZON_KEYS)


def test_markers_become_tables_and_an_unknown_marker_stops_the_build():
    out = docs_hooks.on_page_markdown("a\n<!-- schema: experiment-file -->\nb", None, None, None)
    assert "<!-- schema" not in out and "| top level | `name`" in out
    with pytest.raises(ValueError, match="unknown schema marker: nonsense"):
        docs_hooks.on_page_markdown("<!-- schema: nonsense -->", None, None, None)


# ----------------------------------------------------------------------------- typed numbers a generator owns
CARRY, NOISE = ("the whole-body stabilizer carries out the R-AICO a=1 plans on the free-standing Nao",
                "the stabilizer keeps the Nao standing under noise")
STOOD, ACHIEVED, PD_STOOD = r"stood (\d+)/10", r"achieved in (\d+)/10", r"joint PD beside it: stood (\d+)/10"
# A number typed in a page's prose (outside the generated blocks) that the claims table of docs/results.md
# also gives: (page, the sentence with the number as its group, whitespace as single spaces; the figure and
# claim of the table's row; the number in that row). ``optional``: a sentence that went (its number now read
# from the table), kept so that it cannot come back with a number the table contradicts.
TYPED_COUNTS = [
    ("docs/results.md", r"\(fig3\.4-inside\) stand in (\d+) of 10 runs", "fig3.4-inside", CARRY, STOOD),
    ("docs/results.md", r"and reach their via-points in (\d+), so those claims", "fig3.4-inside", CARRY, ACHIEVED),
    ("docs/results.md", r"under noise (\d+) of 10 stand \(the claim", "fig3.4-inside", NOISE, STOOD),
    ("docs/results.md", r"reaches the planned points in (\d+) of 10 runs", "fig3.4-support", CARRY, ACHIEVED),
    ("docs/results.md", r"reaches the planned points in \d+ of 10 runs, (\d+) of 10 stand under noise",
     "fig3.4-support", NOISE, STOOD),
    ("docs/results.md", r"the joint PD stands in (\d+) of 10", "fig3.4-support", CARRY, PD_STOOD),
    ("docs/results.md", r"\((\d+) of 10 without the term\)", "fig3.4-inside", CARRY, PD_STOOD),
    ("docs/results.md", r"the stabilizer stands in (\d+) of 10 runs with status ok", "fig3.4-single",
     "the Nao balances on its left foot with the right foot lifted (stabilizer, free-standing)", STOOD),
    ("docs/stabilizer.md", r"reached to 1 cm (\d+) of 10", "fig3.4-inside", CARRY, ACHIEVED),
    ("docs/stabilizer.md", r"stood (\d+) of 10 \(seed 0 falls", "fig3.4-inside", CARRY, STOOD),
    ("docs/stabilizer.md", r"under noise fig3\.3 (\d+) of 10", "fig3.3", NOISE, STOOD),
    ("docs/stabilizer.md", r"fig3\.4-support (\d+) of 10 stood", "fig3.4-support", NOISE, STOOD),
    ("docs/stabilizer.md", r"fig3\.4-inside plans: (\d+) of 10 stood with it", "fig3.4-inside", NOISE, STOOD),
    ("docs/stabilizer.md", r"fig3\.3: (\d+) and \d+ of 10", "fig3.3", NOISE, STOOD),
]
OPTIONAL_COUNTS = [
    ("docs/stabilizer.md", r"with both\); under noise (\d+) of 10 stood", "fig3.4-inside", NOISE, STOOD),
]


def _prose(page: str) -> str:
    """The page without its generated blocks, whitespace as single spaces."""
    text = re.sub(r"<!-- ([\w-]+):begin -->.*?<!-- \1:end -->", "", (ROOT / page).read_text(), flags=re.S)
    return " ".join(text.split())


def _claims_row(figure: str, claim: str) -> str:
    """The row of ``figure``'s ``claim`` in the generated claims table of docs/results.md."""
    block = re.search(r"<!-- results:begin -->(.*?)<!-- results:end -->", (ROOT / "docs" / "results.md").read_text(),
                      re.S)
    assert block, "docs/results.md has no generated results block"
    rows = [ln for ln in block.group(1).splitlines() if ln.startswith(f"| {figure} | {claim} |")]
    assert len(rows) == 1, f"{len(rows)} rows of {figure}: {claim}"
    return rows[0]


@pytest.mark.parametrize("page, sentence, figure, claim, cell", [*TYPED_COUNTS, *OPTIONAL_COUNTS])
def test_a_count_typed_in_the_prose_is_the_generated_tables(page, sentence, figure, claim, cell):
    said = re.search(sentence, _prose(page))
    if (page, sentence, figure, claim, cell) in OPTIONAL_COUNTS and said is None:
        return
    assert said, f"{page}: no sentence {sentence!r} (gone? then drop its entry)"
    generated = re.search(cell, _claims_row(figure, claim))
    assert generated, f"the row of {figure}: {claim} has no {cell!r}"
    assert said.group(1) == generated.group(1), (page, said.group(0), generated.group(0))


def test_a_row_the_prose_points_at_is_in_the_generated_table():
    """``the FIGURE row "CLAIM" of the generated table``: a pointer the prose uses instead of a typed number."""
    pointers = [m.groups() for page in sorted((ROOT / "docs").glob("*.md"))
                for m in re.finditer(r'the (fig[\w./-]+) row "([^"]+)" of the generated table', _prose(f"docs/{page.name}"))]
    assert ("fig3.4-inside", NOISE) in pointers   # docs/stabilizer.md's count under noise
    for figure, claim in pointers:
        _claims_row(figure, claim)


def test_the_sparse_gp_sentence_gives_the_bound_its_test_asserts():
    said = re.search(r"100 of 400 points on a 6-input toy, held-out RMSE within ([\d.]+)x", _prose("docs/learning.md"))
    test = (ROOT / "tests" / "plants" / "test_sparse_gp.py").read_text()
    bound = re.search(r"assert np\.all\(r100 < ([\d.]+)\)", test)
    assert said and bound and said.group(1) == bound.group(1), (said and said.group(0), bound and bound.group(0))


def _pages() -> list[Path]:
    """The README and every page under docs/ (the reference pages too)."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def test_every_test_file_the_docs_name_exists():
    """A page that says "tests/x.py checks it" names a file a reader can open (the suite's folders moved)."""
    named = {(page.relative_to(ROOT).as_posix(), path) for page in _pages()
             for path in re.findall(r"\btests/[\w/.-]*?\.py\b", page.read_text())}
    assert len(named) >= 10
    missing = sorted(f"{page}: {path}" for page, path in named if not (ROOT / path).is_file())
    assert missing == []


def test_every_import_in_the_docs_python_blocks_resolves():
    """``from raico.pipeline.interface import api`` as the pages write it: each import line of a ```python block names
    a module, and each name it takes from one is in it (an attribute or a submodule)."""
    import importlib
    import importlib.util

    checked, bad = 0, []
    for page in _pages():
        for block in re.findall(r"```python\n(.*?)```", page.read_text(), re.S):
            for module, names in re.findall(r"^from ([\w.]+) import ([\w, ]+)$", block, re.M):
                mod = importlib.import_module(module)
                for name in (n.strip() for n in names.split(",")):
                    checked += 1
                    if not hasattr(mod, name) and importlib.util.find_spec(f"{module}.{name}") is None:
                        bad.append(f"{page.relative_to(ROOT)}: from {module} import {name}")
            for module in re.findall(r"^import ([\w.]+)$", block, re.M):
                checked += 1
                if importlib.util.find_spec(module) is None:
                    bad.append(f"{page.relative_to(ROOT)}: import {module}")
    assert checked >= 1 and bad == []
