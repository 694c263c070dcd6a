"""Run a stage through the artifact cache: key, hit or compute, outcome.

A stage run is ``(stage name, code version, declared config, input keys)``. On a hit the
stage function is never called; otherwise the stage's ``run`` does the work and its files
are written into a temporary folder that the cache publishes atomically. A recording is
derived from the stored data afterwards (``raico/pipeline/recordings/``), so ``--no-record``
never changes the key and a later call with recording writes it without recomputing. The
outcome is what the CLI prints: ``{"stage", "key", "path", "cached", "status", "metrics",
"recording"}``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from raico.pipeline.engine import keys
from raico.pipeline.engine.artifacts import as_artifact
from raico.pipeline.engine.cache import Cache
from raico.pipeline.engine.keys import KEY_LENGTH, stage_key
from raico.pipeline.errors import BadInput, CorruptArtifact, MissingArtifact, UnreadableArtifact
from raico.pipeline.lifecycle import Interrupted
from raico.stages.base import Artifact

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


# a plan whose final cost exceeds its first iteration's by more than this fraction is said to have risen
COST_ROSE = 1e-6


def outcome_notes(outcome: Outcome) -> list[str]:
    """What the status alone does not say: whether an execution achieved its task (status ok and its
    via-points reached, the report's tolerance) and whether a plan's cost rose over its iterations."""
    m = outcome.metrics if isinstance(outcome.metrics, dict) else {}
    notes = []
    if outcome.stage == "execute" and isinstance(m.get("task"), dict):   # each term in its unit, the worst named
        from raico.stages.evaluate.metrics import executed_task, task_note

        notes.append(task_note(executed_task(m["task"], str(outcome.status))))
    elif outcome.stage == "execute" and m.get("via_point_errors"):   # an entry from before the task verdict
        from raico.stages.evaluate.summary import EXECUTED_VIA_TOL, executed_achieved, largest_via_error

        err = largest_via_error(m)
        verdict = "achieved" if executed_achieved({**m, "status": outcome.status}) else "missed"
        rel = "<=" if err <= EXECUTED_VIA_TOL else ">"
        notes.append(f"task {verdict}: largest via-point error {err:.3g} {rel} {EXECUTED_VIA_TOL:g}"
                     + ("" if outcome.status == "ok" or verdict == "missed" else f", status {outcome.status}"))
    if outcome.stage == "execute" and isinstance(m.get("min_distance"), (int, float)):   # a scene: how close it came
        at = m.get("min_distance_time")
        notes.append(f"smallest distance {1e3 * m['min_distance']:.3g} mm ({m.get('min_distance_pair')}"
                     + (f" at t = {at:.3g} s" if isinstance(at, (int, float)) else "") + ")"
                     + ("; contact" if m.get("contact") else ""))
    achieved = m.get("achieved")
    if outcome.stage == "learn" and isinstance(achieved, list) and achieved:
        notes.append(f"task {'achieved' if achieved[-1] else 'missed'} in the last episode "
                     f"({sum(map(bool, achieved))}/{len(achieved)} episodes achieved it)")
    if outcome.stage == "plan" and outcome.status == "diverged" and m.get("message"):
        notes.append(f"reason: {m['message']}")   # why, here and not only in `raico show`
    if outcome.stage == "evaluate":
        notes += evaluation_notes(m)
    if outcome.stage == "plan" and isinstance(m.get("rejected_trials"), int):   # adaptive R-AICO
        notes.append(f"{m['rejected_trials']} of {m.get('iterations')} trials rejected (the previous iterate "
                     f"kept, the step shrunk); {m.get('repeats_per_iteration', 0):.0f} relinearization repeats per "
                     "iteration (median), which set its time")
    first, final = m.get("first_iteration_cost"), m.get("final_cost")
    if (outcome.stage == "plan" and isinstance(first, (int, float)) and isinstance(final, (int, float))
            and math.isfinite(first) and math.isfinite(final) and final > first * (1 + COST_ROSE) and first > 0):
        notes.append(f"warning: the cost rose over the iterations, from {first:.4g} after the first to "
                     f"{final:.4g} ({final / first:.3g}x)")
    return notes


def evaluation_notes(m: dict) -> list[str]:
    """An evaluation's headline: the plan's final cost and the task verdict of the plan (and of its
    execution: execute's judgement), the worst term named in its unit; an evaluation from before the
    verdicts: the worst via-point error."""
    from raico.stages.evaluate.metrics import task_note
    from raico.stages.evaluate.summary import largest_via_error

    notes = []
    if isinstance(m.get("final_cost"), (int, float)):
        notes.append(f"final cost {m['final_cost']:.4g}")
    for key, vkey, what in (("via_point_errors", "task", "planned"),
                            ("executed_via_point_errors", "executed_task", "executed")):
        if isinstance(m.get(vkey), dict):
            notes.append(f"{what} {task_note(m[vkey])}")
            continue
        errs = m.get(key) or {}
        err = largest_via_error({"via_point_errors": errs})
        name = next((k for k, v in errs.items() if not k.startswith("r_sole")
                     and (math.inf if v is None else v) == err), None)
        if name is not None:
            notes.append(f"worst {what} via-point error {err:.3g} ({name})")
    return notes


def outcome_line(outcome: Outcome) -> str:
    """One line per stage run: what ran (and why) or was cached, where, its status and notes."""
    what = "cached" if outcome.cached else f"ran ({outcome.reason})"
    rec = f"; recording {outcome.recording}" if outcome.recording else ""
    status = "; ".join([str(outcome.status), *outcome_notes(outcome)])
    return f"{outcome.stage} {outcome.key}: {what} -> {outcome.path} [{status}]{rec}"


def finite_json(obj: Any) -> Any:
    """``obj`` with non-finite floats replaced by None, recursively."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    return obj


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
# The command that makes an artifact of each stage (said when an input of that stage is missing).
PRODUCERS = {"babble": "raico babble", "fit": "raico fit --data BABBLE_KEY", "plan": "raico plan",
             "execute": "raico execute --plan PLAN_KEY", "evaluate": "raico evaluate --plan PLAN_KEY",
             "learn": "raico learn"}


def with_article(word: str) -> str:
    """``word`` with its indefinite article (an execute, a plan)."""
    return f"{'an' if word[:1] in 'aeiou' else 'a'} {word}"


def _producer_hint(stages: tuple[str, ...]) -> str:
    return "; " + " or ".join(f"`{PRODUCERS[s]}` makes {with_article(s)} artifact" for s in stages if s in PRODUCERS)


def find_entry(cache: Cache, ref: str, stage: str | tuple[str, ...] | None = None) -> Artifact:
    """A valid entry from ``STAGE/KEY`` or a bare ``KEY`` or key prefix (searched in ``stage``,
    in each of a tuple of stages, or everywhere). An empty reference, an unknown one, one of
    another stage or an ambiguous prefix is an error."""
    ref = (ref or "").strip()
    if not ref:
        raise BadInput("an empty artifact key")
    stages = (stage,) if isinstance(stage, str) else stage
    wanted = stages
    if "/" in ref:   # STAGE/KEY or STAGE/PREFIX
        st, ref = (p.strip() for p in ref.split("/", 1))
        if stages is not None and st not in stages:
            raise BadInput(f"{st}/{ref} is {with_article(st)} artifact, not {with_article(' or '.join(stages))} artifact"
                           f"{_producer_hint(stages)}")
        from raico.stages.registry import stage_names

        if st not in stage_names():
            raise BadInput(f"unknown stage '{st}' in '{st}/{ref}': choose one of {', '.join(stage_names())}")
        stages = (st,)
        if not ref:
            raise BadInput(f"an empty artifact key after '{st}/'")
        if len(ref) == KEY_LENGTH:   # a whole key (what the pipeline itself passes): its entry, no listing
            return cache.require(st, ref)
    rows = [r for s in stages for r in cache.list(s)] if stages is not None else cache.list()
    matches = [r for r in rows if r.key.startswith(ref)]
    valid = [r for r in matches if r.valid]
    if not valid:
        if matches:
            return cache.require(matches[0].stage, matches[0].key)  # raises with the reason
        elsewhere = [r for r in cache.list() if r.valid and r.key.startswith(ref)] if stages is not None else []
        if elsewhere:
            raise BadInput(f"'{ref}' is {with_article(elsewhere[0].stage)} artifact, not {with_article(' or '.join(stages))} artifact"
                           f"{_producer_hint(wanted) if wanted else ''}")
        where = " or ".join(f"stage '{s}'" for s in stages) if stages else "any stage"
        raise MissingArtifact(f"no artifact with key '{ref}' in {where} under {cache.root}"
                              f"{_producer_hint(wanted) if wanted else ''}")
    if len({(r.stage, r.key) for r in valid}) > 1:
        raise BadInput(f"key prefix '{ref}' is ambiguous: give more characters or STAGE/KEY")
    return cache.require(valid[0].stage, valid[0].key)


Repair = Callable[[CorruptArtifact], Artifact]


def resolve_inputs(cache: Cache, stage, config, repair: Repair | None = None) -> dict[str, Any]:
    """Role -> Artifact (a tuple of them for a repeatable input) of the inputs ``config`` names.

    A damaged input is :class:`CorruptArtifact`, or, with ``repair``, what ``repair(error)`` makes
    of it (:func:`rebuild`)."""
    out: dict[str, Any] = {}
    for ref in stage.inputs(config):
        try:
            entry = find_entry(cache, ref.ref, stage=ref.stage)
        except CorruptArtifact as e:
            if repair is None or e.ref is None:
                raise
            entry = repair(e)
        art = as_artifact(entry)
        if isinstance(getattr(config, ref.role), tuple):
            out[ref.role] = (*out.get(ref.role, ()), art)
        else:
            out[ref.role] = art
    return out


def _input_keys(inputs: dict[str, Any]) -> list[str]:
    refs = []
    for v in inputs.values():
        refs += [a.ref for a in (v if isinstance(v, tuple) else (v,))]
    return refs


def _write_outputs(tmp: Path, out) -> None:
    import numpy as np

    for name, arrays in out.arrays.items():
        with open(tmp / name, "wb") as f:  # stored, not deflated: zlib cost ~20 % of a learning loop
            np.savez(f, **arrays)
    for name, doc in out.documents.items():
        (tmp / name).write_text(json.dumps(finite_json(doc), indent=2, default=float) + "\n", encoding="utf-8")
    for name, writer in out.figures.items():
        writer(tmp / name)


def prepare(cache: Cache, stage, config, repair: Repair | None = None):
    """(stage, config, inputs, input keys, key config, code version, key) of a run."""
    from raico.stages.registry import get_stage

    stage = get_stage(stage) if isinstance(stage, str) else stage
    if hasattr(config, "normalized"):
        config = config.normalized()
    try:
        config.validate()
    except ValueError as e:
        raise BadInput(str(e)) from None
    inputs = resolve_inputs(cache, stage, config, repair)
    check = getattr(config, "check_inputs", None)
    if check is not None:  # options that only some inputs accept (a Nao controller for an arm's plan)
        try:
            check(inputs)
        except ValueError as e:
            raise BadInput(str(e)) from None
    input_keys = _input_keys(inputs)
    version = keys.code_version(stage)
    key_config = config.key_dict()
    return stage, config, inputs, input_keys, key_config, version, stage_key(stage.name, version, key_config,
                                                                              input_keys)


def run_key(cache: Cache, stage, config) -> str:
    """The key a run of ``config`` has (normalized, validated, its inputs resolved in ``cache``)."""
    return prepare(cache, stage, config)[-1]


def lookup(cache: Cache, stage, config, *, record: bool = True) -> Outcome | None:
    """The outcome of a cached run (with its recording, if ``record``), or None if it must run.

    Cheap (no stage code runs): lets a sweep skip worker processes for what is cached. A damaged
    entry, input or recording is left to the run (which recomputes, rebuilds or writes it again);
    ``cache.notify`` hears why."""
    try:
        stage, config, _, _, _, _, key = prepare(cache, stage, config)
    except CorruptArtifact as e:  # a damaged input: the run rebuilds it (or says why it cannot)
        if cache.notify is not None and e.ref is not None:
            cache.notify(f"{e.ref.replace('/', ' ')}: damaged ({e.reason or e}); the run that reads it rebuilds it")
        return None
    entry, why = cache.check(stage.name, key)
    if entry is None:
        if why != "no cache entry" and cache.notify is not None:
            cache.notify(f"{stage.name} {key}: {why}; computing it again")
        return None
    recording = None
    if record:   # the recorders (Rerun, Drake's geometry) are imported only when a recording is asked for
        from raico.pipeline.recordings import RECORDING
        from raico.pipeline.recordings.registry import RECORDERS
    if record and stage.name in RECORDERS:
        intact, damaged = cache.derived_check(entry)
        if RECORDING not in intact or damaged:  # the recorder writes the .rrd and the .mcap together
            if damaged and cache.notify is not None:
                cache.notify(f"{stage.name} {key}: recording damaged or out of date ({'; '.join(damaged.values())}); "
                             f"writing it again")
            return None
        recording = str(entry.path / RECORDING)
    m = entry.meta
    return Outcome(stage=stage.name, key=key, path=str(entry.path), cached=True, status=m.get("status", "ok"),
                   metrics=m.get("metrics", {}), recording=recording, reason="cached")


def run(cache: Cache, stage, config, *, record: bool = True, reporter=None, payload: dict | None = None,
        _rebuilt: set[str] | None = None) -> Outcome:
    """Run ``stage`` (a ``Stage`` or its name) with ``config`` through ``cache``.

    On a hit the stage is not called. With ``record``, the stage's recording is written
    from the stored data when the entry lacks one (fresh or cached). ``payload``, if given,
    receives the stage's in-memory output under ``"output"`` when it ran.

    A damaged input is rebuilt first where it can be (:func:`rebuild`; the reporter says so), else
    one :class:`CorruptArtifact` line; a cached entry of this run whose data turn out unreadable is
    computed again. Each entry is rebuilt at most once per call.
    """
    from raico.pipeline.engine.ui import Reporter

    reporter = reporter or Reporter(quiet=True)
    rebuilt: set[str] = set() if _rebuilt is None else _rebuilt
    name = stage.name if hasattr(stage, "name") else str(stage)

    def repair(err: CorruptArtifact) -> Artifact:
        return rebuild(cache, err, reporter, consumer=name, _rebuilt=rebuilt)

    own_damage: str | None = None
    while True:
        this: dict[str, str] = {}
        try:
            outcome = _run_once(cache, stage, config, record, reporter, payload, repair, this)
        except UnreadableArtifact as e:  # data that passed their check but do not load
            own = this.get("ref")
            if e.ref == own and own_damage is None:
                own_damage = e.reason or str(e)
                cache.remove(*own.split("/", 1))  # damaged: computed again below
                continue
            if e.ref is None or e.ref == own:
                raise
            repair(e)  # an input: rebuilt (at most once), then the run again
            continue
        if own_damage is not None and not outcome.cached:
            outcome.reason = own_damage
        return outcome


def _run_once(cache: Cache, stage, config, record: bool, reporter, payload: dict | None, repair: Repair,
              this: dict[str, str]) -> Outcome:
    """One attempt of :func:`run`; ``this["ref"]`` is the run's ``STAGE/KEY`` once it is known."""
    stage, config, inputs, input_keys, key_config, version, key = prepare(cache, stage, config, repair)
    this["ref"] = f"{stage.name}/{key}"

    steps = {"steps": composite_steps(cache, stage, reporter)} if stage.step_stages else {}

    def compute(tmp: Path) -> dict[str, Any]:
        with reporter.progress(f"{stage.name} {_label(key_config)}", stage.progress_total(config)) as update:
            out = stage.run(config, inputs, progress=update, **steps)
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


def composite_steps(cache: Cache, stage, reporter):
    """The :class:`raico.stages.base.Steps` of a composite stage: each step a cached run of one of its
    ``step_stages`` (quiet, without recording: the composite records itself), as its stored artifact."""
    from raico.stages.base import Steps

    def run_step(name: str, config) -> Artifact:
        if name not in stage.step_stages:
            raise ValueError(f"stage {stage.name} runs {', '.join(stage.step_stages)} as steps, not {name}")
        out = run(cache, name, config, record=False)
        return dataclasses.replace(as_artifact(cache.require(name, out.key)), cached=out.cached)

    return Steps(run=run_step, say=reporter.say)


def config_from_meta(stage, meta: dict[str, Any]):
    """The config that made an entry, from its ``meta.json``: the stored (key) config plus the input
    references, each given back to the one input field that accepts its stage; None if a reference
    fits no field or several, or the values no longer make a config."""
    cls = stage.config_cls
    values = dict(meta.get("config") or {})
    fields = {f.name: f for f in dataclasses.fields(cls)}
    refs: dict[str, list[str]] = {}
    for ref in meta.get("inputs") or []:
        st = str(ref).split("/", 1)[0]
        roles = [r for r in cls.INPUTS
                 if st in ((cls.INPUT_STAGES[r],) if isinstance(cls.INPUT_STAGES[r], str) else cls.INPUT_STAGES[r])]
        if len(roles) != 1:
            return None
        refs.setdefault(roles[0], []).append(str(ref))
    for role, rs in refs.items():
        if isinstance(fields[role].default, tuple):
            values[role] = tuple(rs)
        elif len(rs) == 1:
            values[role] = rs[0]
        else:
            return None
    try:
        return cls.from_dict(values)
    except (TypeError, ValueError):
        return None


def rebuild(cache: Cache, err: CorruptArtifact, reporter, consumer: str | None = None,
            _rebuilt: set[str] | None = None) -> Artifact:
    """Compute the damaged entry ``err.ref`` again from its stored config (and inputs, rebuilt in turn
    if need be), under the same key; the reporter says so in one line. Where that cannot be (its
    ``meta.json`` is damaged too, it is not a stage run, or this code would give it another key), or
    it was rebuilt already in this call, one :class:`CorruptArtifact` line saying why."""
    from raico.pipeline.engine.ui import Reporter
    from raico.stages.registry import get_stage, stage_names

    ref, why = err.ref, err.reason or str(err)
    rebuilt = set() if _rebuilt is None else _rebuilt
    if ref is None:
        raise err

    def refuse(cause: str):
        return CorruptArtifact(f"artifact {ref} is damaged ({why}) and cannot be rebuilt: {cause}; run the command "
                               f"that made it again", ref=ref, reason=why)

    if ref in rebuilt:
        raise refuse("it was rebuilt once in this call already and is still damaged")
    st_name, key = ref.split("/", 1)
    meta, _ = cache.stored_meta(st_name, key)
    if meta is None:
        raise refuse("its config is in its meta.json, which is damaged or missing")
    if st_name not in stage_names():
        raise refuse(f"raico rebuilds stage runs ({', '.join(stage_names())}), not a {st_name} entry")
    stage = get_stage(st_name)
    cfg = config_from_meta(stage, meta)
    if cfg is None:
        raise refuse(f"its {st_name} config is not one this version reads")
    rebuilt.add(ref)

    def repair(e: CorruptArtifact) -> Artifact:
        return rebuild(cache, e, reporter, consumer=st_name, _rebuilt=rebuilt)

    try:
        new_key = prepare(cache, stage, cfg, repair)[-1]
    except (BadInput, MissingArtifact) as e:
        raise refuse(str(e)) from None
    if new_key != key:
        raise refuse(f"it was made by another version of the {st_name} code (this one gives key {new_key})")
    cache.remove(st_name, key)
    run(cache, stage, cfg, record=False, reporter=Reporter(quiet=True), _rebuilt=rebuilt)
    of = f" (input of {consumer})" if consumer else ""
    reporter.say(f"{st_name} {key}{of}: damaged ({why}); rebuilt from its stored config")
    return cache.require(st_name, key)


def _label(cfg: dict) -> str:
    return " ".join(str(cfg[k]) for k in ("plant", "task", "solver") if cfg.get(k))


def ensure_recording(cache: Cache, entry: Artifact) -> str | None:
    """Path of the entry's recording, written from its stored data if missing or damaged;
    None for a stage that does not record."""
    from raico.pipeline.recordings import RECORDING
    from raico.pipeline.recordings.registry import RECORDERS

    recorder = RECORDERS.get(entry.stage)
    if recorder is None:
        return None
    intact, damaged = cache.derived_check(entry)
    if RECORDING not in intact or damaged:  # written again together (the cache says which was damaged)
        with cache.lock(entry.stage, entry.key):   # one writer; an identical call in flight waits, then reads
            intact, damaged = cache.derived_check(entry)
            if RECORDING in intact and not damaged:
                return str(entry.path / RECORDING)
            inputs = [as_artifact(cache.require(*ref.split("/", 1))) for ref in entry.meta.get("inputs", [])]

            def lookup(stage: str, key: str):  # another entry of this cache (a learn entry's episodes)
                return as_artifact(cache.require(stage, key))

            try:
                cache.write_derived(entry, lambda tmp: recorder(tmp, as_artifact(entry), inputs, lookup))
            except (OSError, ValueError) as e:
                raise CorruptArtifact(f"cannot write the recording of {entry.stage}/{entry.key}: {e}") from None
    return str(entry.path / RECORDING)
