"""Run a stage through the artifact cache: key, hit or compute, outcome (SPEC §9).

A stage run is ``(stage name, code version, declared config, input keys)``. On a hit the
stage function is never called; otherwise ``compute(tmp_dir)`` does the work and writes its
files into a temporary folder that the cache publishes atomically. The outcome is what the
CLI prints: ``{"stage", "key", "path", "cached", "status", "metrics"}``.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from pipeline.cache import Cache, stage_key

DEFAULT_ARTIFACTS = "artifacts"


def artifacts_root(path: str | Path | None = None) -> Path:
    """``--artifacts`` if given, else ``$RAICO_ARTIFACTS``, else ``./artifacts``."""
    return Path(path or os.environ.get("RAICO_ARTIFACTS") or DEFAULT_ARTIFACTS)


@dataclass
class Outcome:
    stage: str
    key: str
    path: str
    cached: bool
    status: str
    metrics: dict[str, Any] = field(default_factory=dict)
    reason: str = ""

    def json_line(self) -> dict[str, Any]:
        """The ``--json`` line; non-finite numbers become ``null`` (strict JSON)."""
        d = asdict(self)
        d.pop("reason")
        return finite_json(d)


def finite_json(obj: Any) -> Any:
    """``obj`` with non-finite floats replaced by None, recursively."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    return obj


def source_version(name: str, *packages: str) -> str:
    """``name`` plus a hash of the source (``*.py``) and model files (``*.urdf``) of ``packages``.

    The cache key includes it, so editing a solver or a model file invalidates the stages
    that depend on it (and only those).
    """
    import hashlib
    import importlib

    h = hashlib.sha256()
    for pkg in packages:
        src = Path(importlib.import_module(pkg).__file__)
        root = src.parent
        if src.name != "__init__.py":  # a module: just its file
            files = [src]
        else:
            files = sorted(p for pat in ("*.py", "*.urdf") for p in root.rglob(pat)
                           if "__pycache__" not in p.parts)
        for f in files:
            h.update(str(f.relative_to(root)).encode())
            h.update(f.read_bytes())
    return f"{name}+{h.hexdigest()[:12]}"


def run_stage(
    cache: Cache,
    stage: str,
    code_version: str,
    config: dict[str, Any],
    inputs: list[str],
    compute: Callable[[Path], dict[str, Any]],
) -> Outcome:
    """Look ``stage`` up in ``cache``; on a miss call ``compute(tmp_dir) -> {"status", "metrics"}``.

    ``inputs`` are ``"stage/key"`` strings of the input artifacts (part of the key).
    """
    key = stage_key(stage, code_version, config, inputs)

    def writer(tmp: Path) -> dict[str, Any]:
        t0 = time.perf_counter()
        result = compute(tmp)
        return {"status": result.get("status", "ok"), "metrics": result.get("metrics", {}),
                "timings": {"compute_s": time.perf_counter() - t0}}

    meta = {"config": config, "inputs": inputs, "code_version": code_version}
    res = cache.run(stage, key, writer, meta)
    m = res.entry.meta
    return Outcome(stage=stage, key=key, path=str(res.entry.path), cached=res.cached,
                   status=m.get("status", "ok"), metrics=m.get("metrics", {}), reason=res.reason)
