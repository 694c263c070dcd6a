"""No solver's name decides anything in ``stages`` or ``pipeline``: what a solver can do (its starts,
warm starts, bounds, sweeps, schedules, MPC warm start, options and their flags) is declared by its
``raico.planning.solvers.SolverSpec``, and the tool's layers ask the spec. Read with ``ast``, as
``tests/test_layout.py`` reads the plant names."""

from __future__ import annotations

import ast
from pathlib import Path

from raico.planning.solvers import CROCODDYL_SOLVERS, SOLVERS

REPO = Path(__file__).resolve().parents[1]
SOLVER_NAMES = frozenset((*SOLVERS, *CROCODDYL_SOLVERS))   # crocoddyl's too where it is not installed


# "raico" is also the program's name and a problem file's cost convention: compared with something
# that names no solver (``sys.argv[0]``, ``convention``) it is not the solver's name
PROJECT_NAME = "raico"


def solver_name_tests(tree: ast.AST) -> list[int]:
    """Lines of ``tree`` where a registered solver's name is compared (``==``, ``!=``, ``in``, ``not in``,
    alone or in a literal tuple, list or set); :data:`PROJECT_NAME` only where the other side's source
    mentions a solver."""
    def named(node: ast.AST) -> bool:
        return isinstance(node, ast.Constant) and node.value in SOLVER_NAMES

    lines = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Compare):
            continue
        parts = (node.left, *node.comparators)
        for part in parts:
            names = [part] if named(part) else (
                [e for e in part.elts if named(e)] if isinstance(part, (ast.Tuple, ast.List, ast.Set)) else [])
            others = " ".join(ast.unparse(q) for q in parts if q is not part)
            if any(n.value != PROJECT_NAME or "solver" in others for n in names):
                lines.append(node.lineno)
                break
    return lines


def test_no_solver_name_decides_in_stages_and_pipeline():
    found = [f"{path.relative_to(REPO)}:{line}"
             for package in ("stages", "pipeline")
             for path in sorted((REPO / "raico" / package).rglob("*.py"))
             for line in solver_name_tests(ast.parse(path.read_text(), str(path)))]
    assert found == []


def test_the_solver_name_grep_finds_what_it_looks_for():
    src = ('a = solver != "raico"\nb = "ilqg" == s\nc = s not in ("aico", "raico")\nd = s in {"fddp"}\n'
           'e = s == "snopt"\nf = spec.caps.sweeps\ng = "raico"\nh = convention == "raico"\n'
           'i = o.get("solver") == "raico"\n')
    assert solver_name_tests(ast.parse(src)) == [1, 2, 3, 4, 9]
