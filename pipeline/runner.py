"""Run a stage through the artifact cache: key, hit or compute, outcome (SPEC §9).

A stage run is ``(stage name, code version, declared config, input keys)``. On a hit the
stage function is never called; otherwise the stage's ``run`` does the work and its files
are written into a temporary folder that the cache publishes atomically. A recording is
derived from the stored data afterwards (``pipeline/recorders.py``), so ``--no-record``
never changes the key and a later call with recording writes it without recomputing. The
outcome is what the CLI prints: ``{"stage", "key", "path", "cached", "status", "metrics",
"recording"}``.
"""

from __future__ import annotations

import functools
import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from pipeline.cache import Cache, Entry, stage_key
from pipeline.errors import BadInput, CorruptArtifact, Interrupted, MissingArtifact

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
    recording: str | None = None
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
    """``name`` plus a hash of the source (``*.py``, ``*.c``: the compiled kernels) and model files
    (``*.urdf``) of ``packages``.

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
            files = sorted(p for pat in ("*.py", "*.c", "*.urdf") for p in root.rglob(pat)
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


# ----------------------------------------------------------------------------- stages
def find_entry(cache: Cache, ref: str, stage: str | tuple[str, ...] | None = None) -> Entry:
    """A valid entry from ``STAGE/KEY`` or a bare ``KEY`` or key prefix (searched in ``stage``,
    in each of a tuple of stages, or everywhere). An empty reference, an unknown one, one of
    another stage or an ambiguous prefix is an error."""
    ref = (ref or "").strip()
    if not ref:
        raise BadInput("an empty artifact key")
    stages = (stage,) if isinstance(stage, str) else stage
    if "/" in ref:
        st, key = ref.split("/", 1)
        if stages is not None and st not in stages:
            raise BadInput(f"{ref} is a {st} artifact, not a {' or '.join(stages)} artifact")
        return cache.require(st, key)
    rows = [r for s in stages for r in cache.list(s)] if stages is not None else cache.list()
    matches = [r for r in rows if r.key.startswith(ref)]
    valid = [r for r in matches if r.valid]
    if not valid:
        if matches:
            return cache.require(matches[0].stage, matches[0].key)  # raises with the reason
        where = " or ".join(f"stage '{s}'" for s in stages) if stages else "any stage"
        raise MissingArtifact(f"no artifact with key '{ref}' in {where} under {cache.root}")
    if len({(r.stage, r.key) for r in valid}) > 1:
        raise BadInput(f"key prefix '{ref}' is ambiguous: give more characters or STAGE/KEY")
    return cache.require(valid[0].stage, valid[0].key)


def as_artifact(entry: Entry):
    """The stage-side view of a cache entry (``stages.base.Artifact``)."""
    from stages.base import Artifact

    m = entry.meta
    return Artifact(stage=entry.stage, key=entry.key, path=entry.path, config=m.get("config", {}),
                    status=m.get("status", "ok"), metrics=m.get("metrics", {}), inputs=tuple(m.get("inputs", ())))


@functools.cache
def _code_version(name: str, sources: tuple[str, ...]) -> str:
    return source_version(name, *sources)


def code_version(stage) -> str:
    """The stage's name plus a hash of its source files (see :func:`source_version`), once per process."""
    return _code_version(stage.name, tuple(stage.sources))


def resolve_inputs(cache: Cache, stage, config) -> dict[str, Any]:
    """Role -> Artifact (a tuple of them for a repeatable input) of the inputs ``config`` names."""
    out: dict[str, Any] = {}
    for ref in stage.inputs(config):
        art = as_artifact(find_entry(cache, ref.ref, stage=ref.stage))
        if isinstance(getattr(config, ref.role), tuple):
            out[ref.role] = (*out.get(ref.role, ()), art)
        else:
            out[ref.role] = art
    return out


def _input_keys(inputs: dict[str, Any]) -> list[str]:
    keys = []
    for v in inputs.values():
        keys += [a.ref for a in (v if isinstance(v, tuple) else (v,))]
    return keys


def _write_outputs(tmp: Path, out) -> None:
    import numpy as np

    for name, arrays in out.arrays.items():
        with open(tmp / name, "wb") as f:
            np.savez_compressed(f, **arrays)
    for name, doc in out.documents.items():
        (tmp / name).write_text(json.dumps(finite_json(doc), indent=2, default=float) + "\n", encoding="utf-8")
    for name, writer in out.figures.items():
        writer(tmp / name)


def _prepare(cache: Cache, stage, config):
    """(stage, config, inputs, input keys, key config, code version, key) of a run."""
    from stages.registry import get_stage

    stage = get_stage(stage) if isinstance(stage, str) else stage
    if hasattr(config, "normalized"):
        config = config.normalized()
    try:
        config.validate()
    except ValueError as e:
        raise BadInput(str(e)) from None
    inputs = resolve_inputs(cache, stage, config)
    input_keys = _input_keys(inputs)
    version = code_version(stage)
    key_config = config.key_dict()
    return stage, config, inputs, input_keys, key_config, version, stage_key(stage.name, version, key_config,
                                                                              input_keys)


def lookup(cache: Cache, stage, config, *, record: bool = True) -> Outcome | None:
    """The outcome of a cached run (with its recording, if ``record``), or None if it must run.

    Cheap (no stage code runs): lets a sweep skip worker processes for what is cached."""
    from pipeline.recorders import RECORDERS, RECORDING

    stage, config, _, _, _, _, key = _prepare(cache, stage, config)
    entry = cache.lookup(stage.name, key)
    if entry is None:
        return None
    recording = None
    if record and stage.name in RECORDERS:
        if RECORDING not in cache.derived(entry):
            return None
        recording = str(entry.path / RECORDING)
    m = entry.meta
    return Outcome(stage=stage.name, key=key, path=str(entry.path), cached=True, status=m.get("status", "ok"),
                   metrics=m.get("metrics", {}), recording=recording, reason="cached")


def run(cache: Cache, stage, config, *, record: bool = True, reporter=None, payload: dict | None = None
        ) -> Outcome:
    """Run ``stage`` (a ``Stage`` or its name) with ``config`` through ``cache``.

    On a hit the stage is not called. With ``record``, the stage's recording is written
    from the stored data when the entry lacks one (fresh or cached). ``payload``, if given,
    receives the stage's in-memory output under ``"output"`` when it ran.
    """
    from pipeline.ui import Reporter

    reporter = reporter or Reporter(quiet=True)
    stage, config, inputs, input_keys, key_config, version, _ = _prepare(cache, stage, config)

    def compute(tmp: Path) -> dict[str, Any]:
        with reporter.progress(f"{stage.name} {_label(key_config)}", stage.progress_total(config)) as update:
            out = stage.run(config, inputs, progress=update)
        _write_outputs(tmp, out)
        if payload is not None:
            payload["output"] = out
        return {"status": str(out.status), "metrics": out.metrics}

    outcome = run_stage(cache, stage.name, version, key_config, input_keys, compute)
    if record:
        try:
            outcome.recording = ensure_recording(cache, cache.require(stage.name, outcome.key))
        except Interrupted as e:
            e.note = e.note or (f"{stage.name} {outcome.key} is cached, its recording was not written "
                                f"(the next call writes it)")
            raise
    return outcome


def _label(cfg: dict) -> str:
    return " ".join(str(cfg[k]) for k in ("plant", "task", "solver") if cfg.get(k))


def ensure_recording(cache: Cache, entry: Entry) -> str | None:
    """Path of the entry's recording, written from its stored data if missing or damaged;
    None for a stage that does not record."""
    from pipeline.recorders import RECORDERS, RECORDING

    recorder = RECORDERS.get(entry.stage)
    if recorder is None:
        return None
    if RECORDING not in cache.derived(entry):
        inputs = [as_artifact(cache.require(*ref.split("/", 1))) for ref in entry.meta.get("inputs", [])]
        try:
            cache.write_derived(entry, lambda tmp: recorder(tmp, as_artifact(entry), inputs))
        except (OSError, ValueError) as e:
            raise CorruptArtifact(f"cannot write the recording of {entry.stage}/{entry.key}: {e}") from None
    return str(entry.path / RECORDING)
