"""The environment is the one pyproject.toml describes: ``pip check`` is clean (every
installed package's declared requirements hold, crocoddyl's example-robot-data included), and the
pinned dependencies and the crocoddyl baseline (the ``baseline`` extra, which ``make install``
installs) are installed at their pinned versions. CI (``make test``) fails on an inconsistent
environment."""

from __future__ import annotations

import importlib.metadata as md
import re
import subprocess
import sys
import tomllib
from pathlib import Path

PYPROJECT = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]


def _pins(reqs: list[str]) -> dict[str, str]:
    out = {}
    for r in reqs:
        m = re.fullmatch(r"\s*([A-Za-z0-9_.\-]+)\s*==\s*([^\s;]+)\s*", r)
        assert m, f"not an exact pin: {r!r}"
        out[m.group(1)] = m.group(2)
    return out


def test_pip_check_is_clean():
    p = subprocess.run([sys.executable, "-m", "pip", "check"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr


def test_pinned_versions_are_installed():
    extras = PYPROJECT["optional-dependencies"]
    pins = _pins(PYPROJECT["dependencies"]) | _pins(extras["baseline"]) | _pins(extras["docs"])
    wrong = {}
    for name, version in pins.items():
        try:
            have = md.version(name)
        except md.PackageNotFoundError:
            have = None
        if have != version:
            wrong[name] = (version, have)
    assert not wrong, f"pinned -> installed: {wrong} (make install: pip install -e '.[test,ray,baseline,docs]')"


def test_the_baseline_imports():
    from raico.planning.crocoddyl import AVAILABLE, UNAVAILABLE_REASON

    assert AVAILABLE, UNAVAILABLE_REASON
