"""The Stage contract: what every pipeline stage declares, stated once.

A stage is a plain object that knows nothing of the CLI or the cache:

- ``name``: its folder under the artifacts root and its CLI command;
- ``config_cls``: a frozen dataclass (subclass of :class:`StageConfig`) whose field defaults are
  the stage's defaults (the CLI reads them from there, never repeats them);
- ``sources``: the modules/packages whose source files make its code version;
- ``inputs(config)``: the input artifacts the config names, as :class:`InputRef`;
- ``run(config, inputs, progress) -> StageOutput``: the computation, on a config the runner has
  normalized (``config.normalized()``, if defined) and validated (``config.validate()``) once;
- ``data_files``: the data files ``run`` returns (``.npz`` arrays or JSON documents).

The pipeline (``raico/pipeline/engine/runner.py``) keys the run by ``(name, code version, config without
its input references, input keys)``, calls ``run`` on a miss and publishes the files atomically; a
stored entry is an :class:`Artifact`, the one record the cache returns and a stage reads. Recordings
are derived from the stored data (``raico/pipeline/recordings/``), never part of the data's key.

A composite stage (``raico learn``) runs a sequence of other stages' runs (its *steps*, named in
``step_stages``), each cached on its own so that a killed run resumes where it stopped: ``run`` gets
``steps=`` a :class:`Steps`, whose ``run(stage_name, config) -> Artifact`` runs one step through the
cache. Its code version includes its steps' code versions; the steps are not part of its key.

Adding a stage: one module under ``stages/`` defining a ``Stage`` and one line in
``raico/stages/registry.py``; a recorder, if it records, in ``raico/pipeline/recordings/``. docs/stages.md
says more.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

Progress = Callable[[int, int], None]


class StageConfig:
    """Mixin for a stage's frozen config dataclass.

    ``INPUTS`` names the fields that hold input-artifact references (a key, a key prefix
    or ``STAGE/KEY``; a tuple of them for a repeatable input); ``INPUT_STAGES`` the stage
    each must come from (or a tuple of stages it may come from, e.g. ``("babble",
    "execute")``). Input fields are not part of the hashed config: the resolved keys are.
    """

    INPUTS: ClassVar[tuple[str, ...]] = ()
    INPUT_STAGES: ClassVar[dict[str, str | tuple[str, ...]]] = {}
    __dataclass_fields__: ClassVar[dict[str, Any]]   # every subclass is a dataclass

    def validate(self) -> None:
        """Raise ``ValueError`` with one clear line on a bad value."""

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def key_dict(self) -> dict[str, Any]:
        """The config values that go into the cache key (input references left out)."""
        return {k: v for k, v in self.to_dict().items() if k not in self.INPUTS}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]):
        """From a stored config (``meta.json``): keys the class does not declare are ignored."""
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: _frozen(v) for k, v in d.items() if k in names})

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """Field name -> default value (fields without a default are left out)."""
        out = {}
        for f in dataclasses.fields(cls):
            if f.default is not dataclasses.MISSING:
                out[f.name] = f.default
        return out


def _frozen(v: Any) -> Any:
    """Lists from JSON back to tuples, so stored configs rebuild frozen dataclasses."""
    return tuple(_frozen(x) for x in v) if isinstance(v, list) else v


@dataclass(frozen=True)
class InputRef:
    """An input artifact named by a config: ``role`` (the config field), the stage it must
    come from (or a tuple of stages it may come from), and the user's reference (key, prefix
    or ``STAGE/KEY``)."""

    role: str
    stage: str | tuple[str, ...]
    ref: str


@dataclass(frozen=True)
class Artifact:
    """A stored entry: ``root/<stage>/<key>/`` (``path``) and its record ``meta`` (the entry's
    ``meta.json``: config, inputs, status, metrics, timings, the files and their hashes, provenance).

    The cache returns it for a valid, complete entry; a stage reads its inputs through it.
    ``cached``: for a step of a composite stage, whether the run was a cache hit."""

    stage: str
    key: str
    path: Path
    meta: dict[str, Any] = field(default_factory=dict)
    cached: bool = False

    @property
    def ref(self) -> str:
        return f"{self.stage}/{self.key}"

    @property
    def config(self) -> dict[str, Any]:
        """The stored config (what the run was keyed by, input references resolved)."""
        return self.meta.get("config", {})

    @property
    def status(self) -> str:
        return self.meta.get("status", "ok")

    @property
    def metrics(self) -> dict[str, Any]:
        return self.meta.get("metrics", {})

    @property
    def inputs(self) -> tuple[str, ...]:
        """The input entries' ``STAGE/KEY``, in the order the stage received them."""
        return tuple(self.meta.get("inputs", ()))

    @property
    def timings(self) -> dict[str, Any]:
        """The run's wall times (``compute_s``, ...)."""
        return self.meta.get("timings") or {}

    def arrays(self, name: str, keys: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
        """The arrays of data file ``name`` (``.npz``; no pickles); only ``keys`` if given."""
        with np.load(self.path / name, allow_pickle=False) as f:
            return {k: f[k] for k in f.files if keys is None or k in keys}

    def document(self, name: str) -> Any:
        """A JSON data file."""
        return json.loads((self.path / name).read_text(encoding="utf-8"))


@dataclass
class StageOutput:
    """What ``Stage.run`` returns: data files, a status and headline metrics.

    ``arrays``: file name -> arrays (written as uncompressed ``.npz``: zlib cost a fifth of a learning loop for 40 % less disk); ``documents``:
    file name -> JSON-able object; ``figures``: file name -> ``writer(path)`` for files
    such as PNGs; ``payload``: in-memory objects a caller may use (never stored).
    """

    status: str
    metrics: dict[str, Any]
    arrays: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    documents: dict[str, Any] = field(default_factory=dict)
    figures: dict[str, Callable[[Path], None]] = field(default_factory=dict)
    payload: Any = None


@dataclass(frozen=True)
class Steps:
    """What the runner gives a composite stage's ``run`` as ``steps`` (see the module docstring).

    ``run(stage_name, config) -> Artifact``: one step, a cached run of a stage named in the
    composite's ``step_stages`` (its ``cached`` field says whether it was a hit); ``say(line)``: one
    line to the user (the CLI's stderr; nothing when quiet)."""

    run: Callable[[str, Any], Artifact]
    say: Callable[[str], None] = lambda line: None


@dataclass(frozen=True)
class Stage:
    """A pipeline stage (see the module docstring)."""

    name: str
    config_cls: type[StageConfig]
    run: Callable[..., StageOutput]
    sources: tuple[str, ...]
    data_files: tuple[str, ...]
    description: str
    progress_total: Callable[[Any], int] = lambda cfg: 0
    step_stages: tuple[str, ...] = ()  # a composite stage: the stages its steps run (``run`` gets ``steps=``)

    def inputs(self, config: StageConfig) -> list[InputRef]:
        """The input artifacts ``config`` names (an empty reference is an error)."""
        refs: list[InputRef] = []
        for role in config.INPUTS:
            value = getattr(config, role)
            if value is None:
                continue
            for ref in (value if isinstance(value, tuple) else (value,)):
                if not isinstance(ref, str) or not ref.strip():
                    raise ValueError(f"{role.replace('_', '-')}: an empty artifact reference")
                refs.append(InputRef(role, config.INPUT_STAGES[role], ref.strip()))
        return refs
