"""The layout: the floors hold and no module imports itself back.

The imports of raico's packages ``plants``, ``planning``, ``stages``, ``pipeline`` and ``thesis`` are read with ``ast`` (nothing
is imported), every ``import`` statement counted, the ones inside functions too (a lazy import
still ties the modules together; only ``if TYPE_CHECKING:`` blocks are left out):

- the floors, ``thesis -> pipeline -> stages -> planning -> plants``: ``plants`` imports none of the others,
  ``planning`` (the planner as a library) neither ``stages`` nor ``pipeline``, ``stages`` not ``pipeline``,
  and none of the tool's layers the thesis (its figures, claims, report and ``raico reproduce``, which
  it registers through an entry point);
- no stage's code version reads a file of the thesis (editing a claim keeps every cached run);
- inside ``pipeline`` the floors ``interface -> experiments -> engine -> recordings`` (``raico.pipeline.errors``
  and ``raico.pipeline.lifecycle`` the base of all);
- no solver imports another (``raico.planning.aico``, ``raico.planning.ilqg``, ``raico.planning.crocoddyl``);
- no import cycle between modules;
- no import cycle between packages (``raico.stages.plan``, ``raico.stages.evaluate``, ``raico.plants.codegen``, ...)
  beyond :data:`KNOWN_PACKAGE_LOOPS` (none since the planner moved to ``planning``);
  a loop that is gone must leave the list.

Run it alone: ``python -m pytest tests/test_layout.py``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("plants", "planning", "stages", "pipeline", "thesis")
# package -> the top-level packages it must not import: thesis -> pipeline -> stages -> planning -> plants
FLOORS = {"plants": {"planning", "stages", "pipeline", "thesis"}, "planning": {"stages", "pipeline", "thesis"},
          "stages": {"pipeline", "thesis"}, "pipeline": {"thesis"}}
# inside ``pipeline``: sub-package -> the sub-packages it must not import (interface -> experiments -> engine
# -> recordings; ``raico.pipeline.errors`` and ``raico.pipeline.lifecycle`` are the shared base below them all)
_PIPELINE_SUBS = {"raico.pipeline.recordings", "raico.pipeline.engine", "raico.pipeline.experiments", "raico.pipeline.interface"}
PIPELINE_FLOORS = {"raico.pipeline.recordings": {"raico.pipeline.engine", "raico.pipeline.experiments", "raico.pipeline.interface"},
                   "raico.pipeline.engine": {"raico.pipeline.experiments", "raico.pipeline.interface"},
                   "raico.pipeline.experiments": {"raico.pipeline.interface"},
                   "raico.pipeline.errors": _PIPELINE_SUBS | {"raico.pipeline.lifecycle"}, "raico.pipeline.lifecycle": _PIPELINE_SUBS}
# Package-level loops allowed, each as the sorted packages of one strongly connected set (none left).
KNOWN_PACKAGE_LOOPS: set[tuple[str, ...]] = set()
SOLVERS = ("raico.planning.aico", "raico.planning.ilqg", "raico.planning.crocoddyl")


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of :data:`PACKAGES` (a package is its ``__init__``)."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((REPO / "raico" / pkg).rglob("*.py")):
            parts = path.relative_to(REPO).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _imported_names(tree: ast.AST, module: str, is_package: bool) -> list[str]:
    """Dotted names an import statement anywhere in ``tree`` may load (``from a import b``: ``a.b``
    and ``a``; relative imports resolved)."""
    names: list[str] = []
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and _is_type_checking(node):
            skip.update(id(n) for b in node.body for n in ast.walk(b))
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_package else module.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module or ""
            names.append(prefix)
            names += [f"{prefix}.{a.name}" for a in node.names]
    return names


def import_graph() -> dict[str, set[str]]:
    """Module -> the modules of :data:`PACKAGES` it imports (the longest existing dotted prefix of
    each imported name; a module's imports of itself are left out)."""
    mods = _modules()
    graph: dict[str, set[str]] = {}
    for mod, path in mods.items():
        tree = ast.parse(path.read_text(), str(path))
        targets = set()
        for name in _imported_names(tree, mod, path.name == "__init__.py"):
            parts = name.split(".")
            while parts and ".".join(parts) not in mods:
                parts.pop()
            if parts and ".".join(parts) != mod:
                targets.add(".".join(parts))
        graph[mod] = targets
    return graph


def strongly_connected(graph: dict[str, set[str]]) -> list[set[str]]:
    """Tarjan's strongly connected sets of more than one node (the import cycles)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[set[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(comp)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _package(mod: str, mods: dict[str, Path]) -> str:
    """The unit of the package-level graph a module belongs to: its subpackage (``raico.stages.plan``,
    ``raico.plants.codegen``; a package's ``__init__`` is the package itself), or, for a module directly
    in a top-level package (``raico.stages.base``, ``raico.stages.execute``), the module itself: the top-level
    packages hold the floors' shared bases beside their users, which is no loop."""
    pkg = mod if mods[mod].name == "__init__.py" else mod.rsplit(".", 1)[0]
    return mod if pkg in {f"raico.{p}" for p in PACKAGES} else pkg


def _cycle_path(graph: dict[str, set[str]], comp: set[str]) -> list[str]:
    """One cycle through ``comp`` (a shortest one through its first module), for the failure message."""
    start = min(comp)
    prev: dict[str, str | None] = {start: None}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v] & comp):
                if w == start:
                    path = [v]
                    while prev[path[-1]] is not None:
                        path.append(prev[path[-1]])
                    return [*reversed(path), start]
                if w not in prev:
                    prev[w] = v
                    nxt.append(w)
        frontier = nxt
    return sorted(comp)


GRAPH = import_graph()


@pytest.mark.parametrize("lower", sorted(FLOORS))
def test_floors(lower):
    """A floor never imports the floors above it."""
    bad = sorted(f"{m} -> {t}" for m, ts in GRAPH.items() if m.split(".")[1] == lower
                 for t in ts if t.split(".")[1] in FLOORS[lower])
    assert not bad, f"{lower} imports a floor above it:\n" + "\n".join(bad)


@pytest.mark.parametrize("lower", sorted(PIPELINE_FLOORS))
def test_pipeline_floors(lower):
    """Inside the pipeline: the recordings know nothing of the engine (the runner passes them what they
    read), the engine nothing of experiments or the interface."""
    def sub(mod: str) -> str:
        return ".".join(mod.split(".")[:3])

    bad = sorted(f"{m} -> {t}" for m, ts in GRAPH.items() if sub(m) == lower for t in ts if sub(t) in PIPELINE_FLOORS[lower])
    assert any(sub(m) == lower for m in GRAPH), f"no modules in {lower}"
    assert not bad, f"{lower} imports a sub-package above it:\n" + "\n".join(bad)


def test_no_stage_code_version_reads_the_thesis():
    """A stage's code version hashes its ``sources``: none of them lies in the thesis, so editing a claim
    (raico/thesis/claims.py) leaves every cached run, the evaluate stage's too, valid."""
    import importlib

    from raico.stages.registry import get_stage, stage_names

    thesis = REPO / "raico" / "thesis"
    for name in stage_names():
        for src in get_stage(name).sources:
            if src.startswith("files:"):
                assert not src[len("files:"):].startswith("thesis"), (name, src)
                continue
            path = Path(importlib.import_module(src).__file__).resolve()
            assert thesis not in path.parents, f"stage {name} hashes {src} ({path})"
    assert "raico.thesis.claims" not in {s for n in stage_names() for s in get_stage(n).sources}


def test_no_module_import_cycle():
    cycles = strongly_connected(GRAPH)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(_cycle_path(GRAPH, c)) for c in cycles)


def test_package_loops_only_the_known_ones():
    mods = _modules()
    pgraph: dict[str, set[str]] = {}
    for m, ts in GRAPH.items():
        p = _package(m, mods)
        pgraph.setdefault(p, set()).update(_package(t, mods) for t in ts if _package(t, mods) != p)
    loops = {tuple(sorted(c)) for c in strongly_connected(pgraph)}
    new = sorted(loops - KNOWN_PACKAGE_LOOPS)
    gone = sorted(KNOWN_PACKAGE_LOOPS - loops)
    assert not new, "new package-level import loops:\n" + "\n".join(
        f"{' <-> '.join(c)}: " + "; ".join(f"{m} -> {t}" for m, ts in GRAPH.items() if _package(m, mods) in c
                                         for t in sorted(ts) if _package(t, mods) in c and _package(t, mods) != _package(m, mods))
        for c in new)
    assert not gone, f"these loops are gone, remove them from KNOWN_PACKAGE_LOOPS: {gone}"


def test_no_solver_imports_another():
    """Solvers share the problem (its rollout, its options contract), never each other's code."""
    def solver(mod: str) -> str | None:  # the solver a module belongs to (a solver may be a package)
        return next((s for s in SOLVERS if mod == s or mod.startswith(s + ".")), None)

    bad = sorted({f"{m} -> {t}" for m, ts in GRAPH.items() for t in ts
                  if solver(m) and solver(t) and solver(m) != solver(t)})
    assert not bad, f"a solver imports another: {bad}"


def test_the_walk_sees_the_known_edges():
    """The walk itself: edges this layout is known to have (so an empty graph cannot pass)."""
    assert "raico.plants.codegen.c_backend" in GRAPH["raico.planning.kernels"]
    assert "raico.planning.kernels" in GRAPH["raico.planning.aico.sweeps"]       # a lazy or module-level import
    assert "raico.pipeline.engine.cache" in GRAPH["raico.pipeline.interface.cli.common"]
    assert "raico.thesis.claims" in GRAPH["raico.thesis.report"] and "raico.pipeline.engine.cache" in GRAPH["raico.thesis.report"]
    assert "raico.thesis.cli" in GRAPH and not any(t.startswith("raico.thesis") for t in GRAPH["raico.pipeline.interface.cli"])
    assert len(GRAPH) > 50


C_FUNCTION = __import__("re").compile(r"\b(?:static\s+)?(?:void|int|double|long)\s+\w+\s*\([^)]*\)\s*\{")


def test_c_lives_in_c_files_shipped_as_package_data():
    """No C source inside a Python string (C tooling and the duplicate checks see
    every line); every .c file beside the module that compiles it is package data of its package."""
    import ast
    import fnmatch
    import tomllib

    root = Path(__file__).resolve().parents[1]
    offenders = []
    for py in [*root.glob("raico/plants/**/*.py"), *root.glob("raico/planning/**/*.py"), *root.glob("raico/stages/**/*.py")]:
        for node in ast.walk(ast.parse(py.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.count("\n") > 10 and (
                    "#include" in node.value or C_FUNCTION.search(node.value)):
                offenders.append(f"{py.relative_to(root)}:{node.lineno}")
    assert not offenders, f"C source inside Python strings: {offenders}"
    data = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    c_files = [*root.glob("raico/plants/**/*.c"), *root.glob("raico/planning/**/*.c"), *root.glob("raico/stages/**/*.c")]
    assert len(c_files) >= 4
    for c in c_files:
        pkg, rel = c.relative_to(root).parts[0], "/".join(c.relative_to(root).parts[1:])
        assert any(fnmatch.fnmatch(rel, pat) for pat in data.get(pkg, [])), f"{c} is not package data"


# --------------------------------------------------------------------- one route to a robot
PLANT_NAMES = ("pendulum", "arm5", "biorob", "nao")


def _plant_name_tests(tree: ast.AST) -> list[int]:
    """Lines of ``tree`` where a built-in plant's name decides something: compared (``==``, ``!=``,
    ``in``/``not in`` a literal tuple, list or set of names) or a key of a literal dict (a table per plant)."""
    def named(node) -> bool:
        return isinstance(node, ast.Constant) and node.value in PLANT_NAMES

    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            parts = [node.left, *node.comparators]
            for part in parts:
                if named(part) or (isinstance(part, (ast.Tuple, ast.List, ast.Set)) and any(map(named, part.elts))):
                    lines.append(node.lineno)
                    break
        elif isinstance(node, ast.Dict) and any(named(k) for k in node.keys if k is not None):
            lines.append(node.lineno)
    return lines


def test_no_plant_name_decides_outside_plants_and_the_thesis():
    """What a built-in plant's name decided is a fact of its Robot (floating or welded, soles, hands,
    execution, learning defaults) read from ``raico/plants/models/NAME.toml``: the tool's layers above
    ``plants`` never test a plant's name."""
    found = []
    for package in ("planning", "stages", "pipeline"):
        for path in sorted((REPO / "raico" / package).rglob("*.py")):
            for line in _plant_name_tests(ast.parse(path.read_text(), str(path))):
                found.append(f"{path.relative_to(REPO)}:{line}")
    assert found == []


def test_the_plant_name_grep_finds_what_it_looks_for():
    src = ('a = plant == "nao"\nb = "arm5" != x\nc = name in ("arm5", "biorob")\nd = {"pendulum": 1}\n'
           'e = TASKS[("nao", "reach")]\nf = robot.floating\n')
    assert _plant_name_tests(ast.parse(src)) == [1, 2, 3, 4]


# --------------------------------------------------------------------- no robot named in generic code
def _robot_named_identifiers(tree: ast.AST, name: str = "nao") -> list[tuple[int, str]]:
    """``(line, identifier)`` of every identifier in ``tree`` that contains ``name`` (case-insensitive):
    names, attributes, functions, classes, arguments, keywords and imported names (strings are not
    identifiers: a message may name the robot its facts name)."""
    out = []
    for node in ast.walk(tree):
        ids: list[str] = []
        if isinstance(node, ast.Name):
            ids = [node.id]
        elif isinstance(node, ast.Attribute):
            ids = [node.attr]
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            ids = [node.name]
        elif isinstance(node, ast.arg):
            ids = [node.arg]
        elif isinstance(node, ast.keyword) and node.arg is not None:
            ids = [node.arg]
        elif isinstance(node, ast.alias):
            ids = [node.name, node.asname or ""]
        elif isinstance(node, ast.ImportFrom):
            ids = [node.module or ""]
        out += [(getattr(node, "lineno", 0), i) for i in ids if name in i.lower()]
    return out


def test_no_robot_named_in_stages_and_pipeline():
    """A robot's kind of execution (fixed or floating), its soles and gains are its facts: the stages and the
    pipeline speak of a floating robot, never of the Nao by an identifier."""
    found = []
    for package in ("stages", "pipeline"):
        for path in sorted((REPO / "raico" / package).rglob("*.py")):
            for line, ident in _robot_named_identifiers(ast.parse(path.read_text(), str(path))):
                found.append(f"{path.relative_to(REPO)}:{line} {ident}")
    assert found == []


def test_the_robot_name_walk_finds_what_it_looks_for():
    src = ('nao = 1\nx.free_nao\ndef run_nao(): pass\nclass _FreeNao: pass\ndef f(NAO_MASS): pass\n'
           'g(nao=1)\nfrom plants.free_nao import load\nmsg = "the Nao"\n')
    assert sorted({line for line, _ in _robot_named_identifiers(ast.parse(src))}) == [1, 2, 3, 4, 5, 6, 7]
