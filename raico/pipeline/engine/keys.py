"""Cache keys: a stage run's key from the canonical JSON of all it depends on, and its provenance.

A stage's key hashes its name, code version (:func:`code_version`: a hash of its source files,
:func:`source_version`), declared config and input keys (:func:`stage_key`) as canonical JSON
(sorted keys, floats normalized: ``1.0`` and ``1`` are one key). An entry's
record carries its own checksum (:func:`meta_checksum`), the versions of the packages its numbers
depend on (:func:`package_versions`, compared by :func:`version_drift`) and the git commit.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import hashlib
import importlib
import json
import math
import os
import re
import subprocess
from collections.abc import Mapping
from functools import lru_cache
from importlib import metadata
from pathlib import Path, PurePath
from typing import Any

import numpy as np

__all__ = ["FORMAT", "KEY_LENGTH", "META_SUM", "NUMERIC_PACKAGES", "PACKAGES", "canonical_json", "code_version",
           "git_commit", "meta_checksum", "package_versions", "source_version", "stage_key", "version_drift"]

META_SUM = "meta_sha256"  # the record's field holding its own checksum
FORMAT = 2  # bump to invalidate every key (part of the hashed payload)
KEY_LENGTH = 16  # hex digits of a stage run's key (stage_key)
# Packages whose versions a stage's numbers depend on: an entry made with other installed
# versions of these is computed again by the next run, which says which versions differ (``raico ls --verify``
# flags it). rerun-sdk governs the recordings only: a recording written by another version is written again.
NUMERIC_PACKAGES = ("drake", "numpy", "scipy", "scikit-learn", "crocoddyl", "pin")
PACKAGES = (*NUMERIC_PACKAGES, "rerun-sdk", "mcap", "typer")


def _canon(obj: Any) -> Any:
    """Convert ``obj`` to plain JSON values; integral floats become ints (1.0 -> 1)."""
    if obj is None or isinstance(obj, (bool, np.bool_)):
        return None if obj is None else bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        x = float(obj)
        if math.isnan(x):
            return {"__float__": "nan"}
        if math.isinf(x):
            return {"__float__": "inf" if x > 0 else "-inf"}
        return int(x) if x.is_integer() else x  # also maps -0.0 to 0
    if isinstance(obj, str):
        return obj
    if isinstance(obj, enum.Enum):
        return _canon(obj.value)
    if isinstance(obj, PurePath):
        return obj.as_posix()
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in "biuf":
            raise TypeError(f"cannot hash a numpy array of dtype {obj.dtype}")
        return _canon(obj.tolist())  # nesting keeps the shape; dtype is ignored
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return _canon(dataclasses.asdict(obj))
    if isinstance(obj, Mapping):
        out: dict[str, Any] = {}
        for k, v in obj.items():
            ks = k if isinstance(k, str) else json.dumps(_canon(k), sort_keys=True)
            if ks in out:
                raise TypeError(f"config keys collide after conversion to text: {ks!r}")
            out[ks] = _canon(v)
        return out
    if isinstance(obj, (list, tuple)):
        return [_canon(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        items = [_canon(v) for v in obj]
        return sorted(items, key=lambda v: json.dumps(v, sort_keys=True))
    raise TypeError(f"cannot hash a config value of type {type(obj).__name__}")


def canonical_json(obj: Any) -> str:
    """Canonical JSON text of ``obj``: sorted keys, no spaces, floats normalized."""
    return json.dumps(
        _canon(obj), sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False
    )


def stage_key(
    stage: str, code_version: str, config: Mapping[str, Any], input_keys: list[str]
) -> str:
    """16-hex key of a stage run: sha256 of the canonical JSON of all it depends on.

    ``input_keys`` is ordered (the stage receives its inputs in that order).
    """
    payload = {
        "format": FORMAT,
        "stage": stage,
        "code_version": code_version,
        "config": config,
        "inputs": list(input_keys),
    }
    return hashlib.sha256(canonical_json(payload).encode("utf-8")).hexdigest()[:KEY_LENGTH]


def meta_checksum(meta: Mapping[str, Any]) -> str:
    """sha256 of the canonical JSON of ``meta`` without its own checksum field."""
    body = {k: v for k, v in meta.items() if k != META_SUM}
    return hashlib.sha256(canonical_json(body).encode("utf-8")).hexdigest()


# --------------------------------------------------------------------------- code versions


FILES = "files:"  # a source entry naming data files (a glob under the repository root), not a package
REPO = Path(__file__).resolve().parents[2]


def source_version(name: str, *packages: str) -> str:
    """``name`` plus a hash of the source (``*.py``, ``*.c``: the compiled kernels) and model files
    (``*.urdf``) of ``packages``, and of the data files an entry ``files:GLOB`` names (the shipped
    problem files).

    The cache key includes it, so editing a solver or a model file invalidates the stages
    that depend on it (and only those).
    """
    h = hashlib.sha256()
    for pkg in packages:
        if pkg.startswith(FILES):  # data files the stage reads (a glob under the repository root)
            for f in sorted(REPO.glob(pkg[len(FILES):])):
                h.update(str(f.relative_to(REPO)).encode())
                h.update(f.read_bytes())
            continue
        src = Path(importlib.import_module(pkg).__file__)
        root = src.parent
        if src.name != "__init__.py":  # a module: just its file
            files = [src]
        else:
            files = sorted(p for pat in ("*.py", "*.c", "*.urdf") for p in root.rglob(pat)
                           if "__pycache__" not in p.parts)
        for f in files:
            h.update(str(f.relative_to(root)).encode())
            h.update(f.read_bytes())
    return f"{name}+{h.hexdigest()[:12]}"


@functools.cache
def sources_version(name: str, sources: tuple[str, ...]) -> str:
    return source_version(name, *sources)


def code_version(stage) -> str:
    """The stage's name plus a hash of its source files (see :func:`source_version`), once per process;
    a composite stage's joined with its steps' (``+``), so editing a step's code invalidates it too."""
    from raico.stages.registry import get_stage

    own = sources_version(stage.name, tuple(stage.sources))
    return "+".join([own, *(code_version(get_stage(s)) for s in stage.step_stages)])


# --------------------------------------------------------------------------- provenance


@lru_cache(maxsize=1)
def package_versions() -> dict[str, str | None]:
    """Installed versions of the packages a result depends on (None if absent)."""
    out: dict[str, str | None] = {}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def version_drift(meta: Mapping[str, Any]) -> str:
    """"" if ``meta`` (an entry's record) was made with the installed versions of ``NUMERIC_PACKAGES``,
    else which differ: ``made with numpy 2.3.5 (installed 2.4.6)``. A package the record does not name
    (an entry older than the field) is not compared."""
    made, now = meta.get("packages") or {}, package_versions()
    diffs = [f"{p} {made[p]} (installed {now.get(p)})" for p in NUMERIC_PACKAGES
             if p in made and made[p] != now.get(p)]
    return f"made with {', '.join(diffs)}" if diffs else ""


@lru_cache(maxsize=8)
def git_commit(path: Path | None = None) -> str | None:
    """``git rev-parse HEAD`` of the tree holding ``path`` (default: this package), else None."""
    where = Path(path) if path is not None else Path(__file__).resolve().parent
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}
    try:
        res = subprocess.run(
            ["git", "-C", str(where), "rev-parse", "--verify", "-q", "HEAD"],
            capture_output=True, text=True, timeout=10, env=env, check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    sha = res.stdout.strip()
    return sha if res.returncode == 0 and re.fullmatch(r"[0-9a-f]{40,64}", sha) else None
