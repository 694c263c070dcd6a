"""Stage runner: the code version hashes the stage's sources, so an edit invalidates the cache."""

import hashlib
import sys

from raico.pipeline.engine.cache import Cache
from raico.pipeline.engine.keys import source_version
from raico.pipeline.engine.runner import run_stage


def _package(tmp_path, monkeypatch, name: str, files: dict[str, str]):
    """A package ``name`` with ``files`` (name -> text) importable from ``tmp_path``."""
    pkg = tmp_path / name
    pkg.mkdir()
    for fname, text in files.items():
        (pkg / fname).write_text(text)
    monkeypatch.syspath_prepend(str(tmp_path))
    return pkg


def test_source_version_follows_the_source(tmp_path, monkeypatch):
    pkg = _package(tmp_path, monkeypatch, "fakestage", {"__init__.py": "X = 1\n", "model.urdf": "<robot/>"})
    v1 = source_version("s-1", "fakestage")

    def expected(files):  # sha256 over (relative path, content) of the sources, in path order
        h = hashlib.sha256()
        for name, text in files:
            h.update(name.encode())
            h.update(text.encode())
        return "s-1+" + h.hexdigest()[:12]

    assert v1 == source_version("s-1", "fakestage") == expected([("__init__.py", "X = 1\n"),
                                                                 ("model.urdf", "<robot/>")])
    (pkg / "notes.txt").write_text("not a source")  # neither *.py nor *.urdf: no effect
    assert source_version("s-1", "fakestage") == v1
    (pkg / "model.urdf").write_text("<robot name='x'/>")
    v2 = source_version("s-1", "fakestage")
    assert v2 == expected([("__init__.py", "X = 1\n"), ("model.urdf", "<robot name='x'/>")]) != v1
    sys.modules.pop("fakestage", None)


def test_source_version_follows_a_compiled_kernel(tmp_path, monkeypatch):
    """A C kernel shipped in a stage's package (raico/planning/csweep.c) is code: editing it
    invalidates the cache like editing the Python."""
    pkg = _package(tmp_path, monkeypatch, "fakekernel",
                   {"__init__.py": "X = 1\n", "sweep.c": "int f(void) { return 1; }\n"})
    v1 = source_version("s-1", "fakekernel")
    (pkg / "sweep.c").write_text("int f(void) { return 2; }\n")
    assert source_version("s-1", "fakekernel") != v1
    sys.modules.pop("fakekernel", None)


def test_run_stage_hit_never_computes(tmp_path):
    calls = []

    def compute(tmp):
        calls.append(1)
        (tmp / "out.txt").write_text("x")
        return {"status": "ok", "metrics": {"n": 1}}

    cache = Cache(tmp_path)
    a = run_stage(cache, "demo", "v1", {"a": 1}, [], compute)
    b = run_stage(cache, "demo", "v1", {"a": 1}, [], compute)
    c = run_stage(cache, "demo", "v2", {"a": 1}, [], compute)
    assert (a.cached, b.cached, c.cached) == (False, True, False) and len(calls) == 2
    assert b.metrics == {"n": 1} and a.key == b.key != c.key and a.reason == "no cache entry"


def test_json_line_is_strict_json():
    import json

    from raico.pipeline.engine.runner import Outcome

    o = Outcome("plan", "k", "p", False, "diverged", {"final_cost": float("nan"), "e": {"a": float("inf")}})
    text = json.dumps(o.json_line(), allow_nan=False)
    assert json.loads(text)["metrics"] == {"final_cost": None, "e": {"a": None}}


def test_source_version_follows_the_shipped_problem_files(tmp_path, monkeypatch):
    """A built-in task is a problem file (raico/problems/*.toml): editing one invalidates the plans, as editing code does
    (a ``files:GLOB`` source entry, under the repository root)."""
    from raico.pipeline.engine import keys

    (tmp_path / "problems").mkdir()
    task = tmp_path / "problems" / "pendulum_swing-up.toml"
    task.write_text("T = 750\n")
    monkeypatch.setattr(keys, "REPO", tmp_path)
    v1 = source_version("plan", "files:problems/*.toml")
    assert v1 == source_version("plan", "files:problems/*.toml")
    task.write_text("T = 1000\n")
    assert source_version("plan", "files:problems/*.toml") != v1
    # the plan stage hashes the shipped problem files
    from raico.stages.plan.stage import STAGE

    assert "files:problems/*.toml" in STAGE.sources
