"""Docstrings fit a screen: every docstring (module, class, function) of the project's packages is shorter
than :data:`MAX_LINES` lines. What a user needs beyond that is on the matching docs/*.md page.

The files are read with ``ast`` (nothing is imported). Run it alone:
``python -m pytest tests/test_docstrings.py``; the failure lists every docstring over the limit with its
file, name and length.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("plants", "planning", "stages", "pipeline", "thesis", "bench")
MAX_LINES = 30   # a docstring of this many lines or more does not fit a screen


def _package_dir(pkg: str) -> Path:
    """The package's folder: raico's subpackages, and bench/ at the repository's root."""
    return REPO / pkg if pkg == "bench" else REPO / "raico" / pkg


def long_docstrings(max_lines: int = MAX_LINES) -> list[tuple[str, str, int]]:
    """``(file, name, lines)`` of every docstring of :data:`PACKAGES` with ``max_lines`` lines or more."""
    out = []
    for pkg in PACKAGES:
        for path in sorted(_package_dir(pkg).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in ast.walk(tree):
                if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                    doc = ast.get_docstring(node, clean=False)
                    if doc and doc.count("\n") + 1 >= max_lines:
                        out.append((str(path.relative_to(REPO)), getattr(node, "name", "<module>"),
                                    doc.count("\n") + 1))
    return out


def test_the_packages_are_found():
    for pkg in PACKAGES:
        assert (_package_dir(pkg) / "__init__.py").is_file(), pkg


def test_every_docstring_fits_a_screen():
    """A docstring of :data:`MAX_LINES` lines or more fails here, named with its file and length."""
    long = long_docstrings()
    assert not long, (f"{len(long)} docstrings of {MAX_LINES}+ lines (move the user documentation to the "
                      "matching docs/*.md page):\n" + "\n".join(f"  {f} {n}: {k} lines" for f, n, k in long))


def test_a_long_docstring_is_found(tmp_path, monkeypatch):
    pkg = tmp_path / "raico" / "plants"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text('"""' + "line\n" * MAX_LINES + '"""\n')
    (pkg / "short.py").write_text('def f():\n    """One line."""\n')
    here = sys.modules[__name__]
    monkeypatch.setattr(here, "REPO", tmp_path)
    monkeypatch.setattr(here, "PACKAGES", ("plants",))
    assert long_docstrings() == [("raico/plants/__init__.py", "<module>", MAX_LINES + 1)]
