"""Experiments a user writes: a TOML file of variants over seeds, run through the cache, one runs table.

An experiment file (read with ``tomllib``; every key: docs/experiment-files.md)::

    name = "alpha-on-the-arm"              # the table's folder: artifacts/exp/<name>/
    stages = ["plan", "execute"]           # plan | plan, execute | plan, evaluate | ... | learn | babble
    seeds = "range(10)"                    # or a list: the initial states, shared by every point
    [base]                                 # options of the first stage (raico <stage> --help)
    plant = "arm5"                         # or problem = "my_robot_reach.toml"
    task = "reach-roll"
    [execute]                              # options of a later stage
    clip_torques = true
    [grid]                                 # the cartesian product of these lists ...
    alpha = [0.1, 1.0, 10.0]
    [zip]                                  # ... times these lists taken side by side (equal lengths)
    [[point]]                              # and hand-listed variants, each on top of [base]
    label = "ilqg"
    solver = "ilqg"

Every variant runs at every seed (a point's own ``seeds`` at those only), so comparisons pair by
seed; every key and value is checked by the stage's own config class before anything runs. The
thesis's files add ``claims``, a ``[quick]`` profile, ``needs`` and ``[reproduce]``.

Each run is an ordinary cached stage run: a second ``run`` computes nothing, a failed run is a row
with its error. The grid is generated as it is consumed and runs on any executor
(:func:`raico.pipeline.engine.executors.stream`). The runs table (one row per seed and variant) is written
as runs finish, ``runs.parquet`` under ``artifacts/exp/<name>/`` (with ``runs.csv`` and
``runs.json`` beside it); :func:`summarize` groups it over seeds.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import itertools
import json
import math
import os
import re
import tomllib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from raico.pipeline.errors import BadInput

if TYPE_CHECKING:
    from raico.pipeline.engine.executors import Executor

CHAINS = {("plan",), ("plan", "execute"), ("plan", "evaluate"), ("plan", "execute", "evaluate"), ("learn",),
          ("babble",)}
TOP_KEYS = ("name", "description", "stages", "seeds", "base", "grid", "zip", "point", "execute", "evaluate", "claims",
            "quick", "reproduce")
POINT_KEYS = ("label", "seeds", "quick", "needs")   # a point's keys that are not options
# what a point or a claim may need: the crocoddyl baseline (the extra raico[baseline]); the thesis's set-ups beside
# raico's, run where THESIS_SETUPS is "1" in the environment (`raico reproduce --thesis-setups`)
NEEDS = ("crocoddyl", "thesis-setups")
THESIS_SETUPS = "RAICO_THESIS_SETUPS"
CURVE_TOL = 0.01   # iterations to come within 1 % of the run's lowest cost
# a run counted as failed in the summaries: a stage raised, a solver diverged, the robot fell
FAILED_STATUSES = ("error", "diverged", "fell")
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


@dataclass(frozen=True)
class Variant:
    """One point of the experiment: its label and options per stage (first stage's under its name)."""

    label: str
    options: dict[str, dict[str, Any]]   # stage -> {option: value}
    swept: dict[str, Any]                # the options that vary across the experiment (``stage.option`` for later stages)
    seeds: tuple[int, ...] = ()          # a point's own seeds (empty: the experiment's)


@dataclass(frozen=True)
class Run:
    variant: Variant
    seed: int


@dataclass
class Experiment:
    name: str
    description: str
    stages: tuple[str, ...]
    seeds: tuple[int, ...]
    base: dict[str, dict[str, Any]]
    grid: dict[str, list]
    zipped: dict[str, list]
    points: list[dict[str, Any]]
    path: Path | None = None
    claims: tuple[str, ...] = ()            # named claims (Python functions of raico.thesis.claims)
    reproduce: dict[str, Any] = field(default_factory=dict)   # raico reproduce's own settings, unread here
    quick: bool = False                     # loaded with its [quick] profile
    left_out: tuple[str, ...] = ()          # points left out: what they need is not installed
    notes: tuple[str, ...] = ()             # what the -S overrides did where a user may expect otherwise

    @functools.cached_property
    def variants(self) -> list[Variant]:
        """Every variant, as a list (:func:`iter_variants` generates them one at a time)."""
        return list(iter_variants(self))

    @property
    def runs(self) -> list[Run]:
        """Every run, as a list (:func:`iter_runs` generates them one at a time)."""
        return list(iter_runs(self))

    def variant(self, label: str) -> Variant:
        """The variant labelled ``label``; :class:`BadInput` listing the labels if there is none."""
        for v in self.variants:
            if v.label == label:
                return v
        raise BadInput(f"{self.name}: no variant '{label}': variants are "
                       + ", ".join(repr(v.label) for v in self.variants))


# ----------------------------------------------------------------------------- reading
def _seeds(value: Any) -> tuple[int, ...]:
    if isinstance(value, str):
        m = re.fullmatch(r"\s*range\(\s*(\d+)\s*(?:,\s*(\d+)\s*)?\)\s*", value)
        if not m:
            raise BadInput(f"seeds: '{value}' is neither a list of integers nor range(N) / range(A, B)")
        a, b = (0, int(m.group(1))) if m.group(2) is None else (int(m.group(1)), int(m.group(2)))
        value = list(range(a, b))
    if not isinstance(value, list) or not value or not all(isinstance(s, int) and s >= 0 for s in value):
        raise BadInput("seeds: a non-empty list of integers >= 0, or range(N)")
    if len(set(value)) != len(value):
        raise BadInput("seeds: a seed is listed twice")
    return tuple(value)


def parse_override(text: str) -> tuple[str, list]:
    """``-S key=a,b`` / ``-S key=range(3)``: a grid axis (values parsed as TOML scalars)."""
    if "=" not in text:
        raise BadInput(f"-S {text}: expected KEY=VALUE[,VALUE...]")
    key, raw = (p.strip() for p in text.split("=", 1))
    m = re.fullmatch(r"range\(\s*(\d+)\s*(?:,\s*(\d+)\s*)?\)", raw)
    if m:
        a, b = (0, int(m.group(1))) if m.group(2) is None else (int(m.group(1)), int(m.group(2)))
        return key, list(range(a, b))
    values = []
    for item in raw.split(","):
        item = item.strip()
        try:
            values.append(tomllib.loads(f"v = {item}")["v"])
        except tomllib.TOMLDecodeError:
            values.append(item)   # a bare word: a string
    if not key or not values or any(v == "" for v in values):
        raise BadInput(f"-S {text}: expected KEY=VALUE[,VALUE...]")
    return key, values


@functools.cache
def available(need: str) -> bool:
    """Whether what a point or claim ``needs`` is installed (:data:`NEEDS`)."""
    if need == "crocoddyl":
        from raico.planning.crocoddyl import AVAILABLE

        return bool(AVAILABLE)
    if need == "thesis-setups":
        return os.environ.get(THESIS_SETUPS) == "1"
    raise BadInput(f"needs = '{need}': one of {', '.join(NEEDS)}")


def _claims(path: Path, value: Any) -> tuple[str, ...]:
    """``claims``: names, or ``{name, needs}`` tables (left out where the need is not installed)."""
    if not isinstance(value, list):
        raise BadInput(f"{path}: claims must be a list of names or {{name = ..., needs = ...}} tables")
    out = []
    for c in value:
        if isinstance(c, dict) and set(c) <= {"name", "needs"} and isinstance(c.get("name"), str):
            if "needs" not in c or available(str(c["needs"])):
                out.append(c["name"])
        elif isinstance(c, str) and c:
            out.append(c)
        else:
            raise BadInput(f"{path}: claim {c!r} is neither a name nor a {{name = ..., needs = ...}} table")
    return tuple(out)


def _point_seeds(path: Path, point: dict, seeds: tuple[int, ...], quick: bool) -> tuple[int, ...]:
    """A point's own seeds (those of the experiment it runs at), () for the experiment's."""
    if "seeds" not in point:
        return ()
    try:
        own = _seeds(point["seeds"])
    except BadInput as e:
        raise BadInput(f"{path}: point '{point.get('label')}': {e}") from None
    missing = [s for s in own if s not in seeds]
    if missing and not quick:
        raise BadInput(f"{path}: point '{point.get('label')}': seed {missing[0]} is not among the experiment's seeds")
    return tuple(s for s in seeds if s in own)


def read_toml(path: Path, what: str) -> dict:
    """The TOML document of ``path``; a missing, unreadable or invalid file is one :class:`BadInput` line
    naming it as ``what`` (e.g. "experiment file")."""
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise BadInput(f"no {what} {path}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise BadInput(f"cannot read the {what} {path}: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise BadInput(f"{path}: not valid TOML ({e})") from None


def load(path: str | Path, overrides: Sequence[str] = (), quick: bool = False) -> Experiment:
    """The experiment of ``path`` with ``-S`` overrides (``seeds=...``; values added to a grid axis; one value
    of another option: ``[base]``'s, :func:`_set_base`; several: a new axis), what they do said in
    :attr:`Experiment.notes`, checked
    (:class:`BadInput` with one line on any problem) but not yet validated against the stages.
    ``quick``: its ``[quick]`` profile (seeds, options over ``[base]`` and the points', points kept)."""
    path = Path(path)
    doc = read_toml(path, "experiment file")
    unknown = [k for k in doc if k not in TOP_KEYS]
    if unknown:
        raise BadInput(f"{path}: unknown key '{unknown[0]}': valid keys are {', '.join(TOP_KEYS)}")
    name = doc.get("name") or path.stem
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise BadInput(f"{path}: name '{name}' must be letters, digits, '.', '_' or '-' (at most 64)")
    stages = doc.get("stages", ["plan"])
    stages = tuple([stages] if isinstance(stages, str) else stages)
    if stages not in CHAINS:
        raise BadInput(f"{path}: stages {list(stages)} is not one of "
                       + "; ".join(", ".join(c) for c in sorted(CHAINS)))
    grid, zipped = dict(doc.get("grid", {})), dict(doc.get("zip", {}))
    seeds = _seeds(doc.get("seeds", [0]))
    profile = doc.get("quick", {})
    if not isinstance(profile, dict):
        raise BadInput(f"{path}: [quick] must be a table")
    if quick:
        seeds = _seeds(profile["seeds"]) if "seeds" in profile else seeds[:2]
    base_sets: dict[str, Any] = {}   # -S KEY=VALUE on an option that is no axis: [base]'s value, every variant's
    for text in overrides:
        key, values = parse_override(text)
        if key == "seeds":
            seeds = _seeds(values)
        elif isinstance(grid.get(key), list):   # a grid axis of the file: its values and these
            grid[key] = [*grid[key], *(v for v in values if v not in grid[key])]
        elif len(values) == 1 and key not in zipped:
            base_sets[key] = values[0]
            grid.pop(key, None)
        else:   # a new axis (over [base]'s value or a [zip] list's)
            zipped.pop(key, None)
            base_sets.pop(key, None)
            grid[key] = values
    for table, what in ((grid, "grid"), (zipped, "zip")):
        for k, v in table.items():
            if not isinstance(v, list) or not v:
                raise BadInput(f"{path}: [{what}] {k} must be a non-empty list of values")
    if len({len(v) for v in zipped.values()}) > 1:
        raise BadInput(f"{path}: the [zip] lists must have equal lengths, got "
                       + ", ".join(f"{k} {len(v)}" for k, v in zipped.items()))
    points = doc.get("point", [])
    if not isinstance(points, list) or not all(isinstance(p, dict) for p in points):
        raise BadInput(f"{path}: [[point]] entries must be tables")
    labels = [p.get("label") for p in points]
    if any(not isinstance(lb, str) or not lb for lb in labels) or len(set(labels)) != len(labels):
        raise BadInput(f"{path}: every [[point]] needs a unique label")
    in_quick = profile.get("points", labels)
    unknown = [lb for lb in in_quick if lb not in labels] if isinstance(in_quick, list) else [in_quick]
    if unknown:
        raise BadInput(f"{path}: [quick] points: no point '{unknown[0]}'")
    kept = in_quick if quick else labels
    left_out, chosen = [], []
    for p in points:
        if not isinstance(p.get("quick", {}), dict) or not isinstance(p.get("needs", ""), str):
            raise BadInput(f"{path}: point '{p['label']}': quick must be a table of options, needs a name")
        if "needs" in p and not available(p["needs"]):
            left_out.append(p["label"])
            continue
        if p["label"] not in kept:
            continue
        opts = {k: v for k, v in p.items() if k not in POINT_KEYS}
        if quick:
            opts.update(p.get("quick", {}))
        own = _point_seeds(path, p, seeds, quick)
        if "seeds" in p and not own:   # the profile's seeds are none of the point's own: it does not run
            continue
        chosen.append({"label": p["label"], **opts, "seeds": own})
    points = chosen
    claims = _claims(path, doc.get("claims", []))
    reproduce = doc.get("reproduce", {})
    if not isinstance(reproduce, dict):
        raise BadInput(f"{path}: [reproduce] must be a table")
    base = {stages[0]: _resolve_problem(dict(doc.get("base", {})), path)}
    points = [_resolve_problem(p, path) for p in points]
    for table in (grid, zipped):   # problem files as a grid or zip axis: each relative to this file
        if isinstance(table.get("problem"), list):
            table["problem"] = [_resolve_problem({"problem": p}, path)["problem"] for p in table["problem"]]
    if quick:
        base[stages[0]].update({k: v for k, v in profile.items() if k not in ("seeds", "points")})
    for later in stages[1:]:
        base[later] = dict(doc.get(later, {}))
    notes = _set_base(path, stages, base, base_sets, points) + _axis_notes(grid, overrides, points, base, stages)
    for stage in ("execute", "evaluate"):
        if stage in doc and stage not in stages[1:]:
            raise BadInput(f"{path}: [{stage}] options, but {stage} is not among the stages {list(stages)}")
    return Experiment(name, str(doc.get("description", "")), stages, seeds, base, grid, zipped, points, path,
                      claims, reproduce, quick, tuple(left_out), tuple(notes))


def _stage_option(path: Path, stages: tuple[str, ...], key: str) -> tuple[str, str]:
    """``stage.option`` (a later stage's) or ``option`` (the first stage's) -> (stage, option)."""
    if "." in key:
        stage, option = key.split(".", 1)
        if stage not in stages[1:]:
            raise BadInput(f"{path}: -S {key}: {stage} is not a later stage of this experiment ({', '.join(stages)})")
        return stage, option
    return stages[0], key


def _keeping(points: list[dict[str, Any]], key: str) -> list[str]:
    """``'label' (key=value)`` of the points that set ``key`` themselves."""
    return [f"'{p['label']}' ({key}={p[key]!r})" for p in points if key in p]


def _set_base(path: Path, stages: tuple[str, ...], base: dict[str, dict[str, Any]], sets: Mapping[str, Any],
              points: list[dict[str, Any]]) -> list[str]:
    """Apply ``-S KEY=VALUE`` on an option that is no grid or zip axis to ``[base]`` (in place): every
    variant runs with it, a ``[[point]]`` that sets the key itself keeps its own value. One line each
    saying so (the dry run and the run print them)."""
    out = []
    for key, value in sets.items():
        stage, option = _stage_option(path, stages, key)
        before = base[stage].get(option)
        base[stage][option] = _resolve_problem({option: value}, path)[option]   # a file: as [base]'s, from here
        was = f"[base]'s {before!r}" if before is not None else "the stage's default"
        keep = _keeping(points, key)
        out.append(f"-S {key}={value!r}: in place of {was} for every variant"
                   + (f"; the points that set {key} keep their own: {', '.join(keep)}" if keep else ""))
    return out


def _axis_notes(grid: Mapping[str, list], overrides: Sequence[str], points: list[dict[str, Any]],
                base: dict[str, dict[str, Any]], stages: tuple[str, ...]) -> list[str]:
    """A line per ``-S`` grid axis that the ``[[point]]`` variants do not run along: they are listed
    beside the grid, each at its own value or ``[base]``'s."""
    if not points:
        return []
    out = []
    for text in overrides:
        key = text.split("=", 1)[0].strip()
        if key == "seeds" or key not in grid:
            continue
        stage, option = (key.split(".", 1) if "." in key else (stages[0], key))
        own = _keeping(points, key)
        rest = [f"'{p['label']}'" for p in points if key not in p]
        at = base.get(stage, {}).get(option)
        where = "the stage's default" if at is None else f"[base]'s {at!r}"
        parts = ([f"{', '.join(rest)} at {where}"] if rest else []) + ([f"{', '.join(own)} at their own"] if own else [])
        out.append(f"-S {text.strip()}: a grid axis; the points do not run along it: {'; '.join(parts)}")
    return out


def _resolve_problem(options: dict, path: Path) -> dict:
    """A ``problem`` file named relative to the experiment file, made absolute (a run reads it from
    wherever it is started)."""
    problem = options.get("problem")
    if isinstance(problem, str) and not Path(problem).is_absolute():
        options = {**options, "problem": str((Path(path).resolve().parent / problem).resolve())}
    return options


# ----------------------------------------------------------------------------- variants and configs
def _split(exp: Experiment, key: str) -> tuple[str, str]:
    """``stage.option`` or ``option`` (the first stage's) -> (stage, option)."""
    if "." in key:
        stage, option = key.split(".", 1)
        if stage not in exp.stages[1:]:
            raise BadInput(f"'{key}': {stage} is not a later stage of this experiment ({', '.join(exp.stages)})")
        return stage, option
    return exp.stages[0], key


def _settings(exp: Experiment, grid_only: bool = False) -> Iterator[tuple[Any, dict[str, Any], Any]]:
    """``(label or None, {key: value}, own seeds)`` of every variant, generated as it is consumed: the
    grid's combinations (times the [zip] lists), then the points."""
    axes = list(exp.grid.items())
    names = [k for k, _ in axes]
    n_zip = len(next(iter(exp.zipped.values()))) if exp.zipped else 0
    if axes or exp.zipped or not exp.points:
        for values in itertools.product(*[v for _, v in axes]):
            combo = dict(zip(names, values))
            for i in range(n_zip or 1):
                yield None, {**combo, **{k: v[i] for k, v in exp.zipped.items()}}, ()
    if not grid_only:
        for p in exp.points:
            yield p["label"], {k: v for k, v in p.items() if k not in ("label", "seeds")}, p.get("seeds", ())


def _grid_count(exp: Experiment) -> int:
    if not (exp.grid or exp.zipped or not exp.points):
        return 0
    n_zip = len(next(iter(exp.zipped.values()))) if exp.zipped else 1
    return math.prod(len(v) for v in exp.grid.values()) * n_zip


def swept_keys(exp: Experiment) -> list[str]:
    """The options that vary across the experiment: its grid and zip axes and every point's options (a
    table's option columns); for variants given as a list, the keys of their ``swept``."""
    if "variants" in exp.__dict__:
        return sorted({k for v in exp.variants for k in v.swept})
    keys = set(exp.grid) | set(exp.zipped) if _grid_count(exp) else set()
    return sorted(keys | {k for p in exp.points for k in p if k not in ("label", "seeds")})


def variant_count(exp: Experiment) -> int:
    """How many variants, without generating them."""
    if "variants" in exp.__dict__:
        return len(exp.variants)
    return _grid_count(exp) + len(exp.points)


def run_count(exp: Experiment) -> int:
    """How many runs, without generating them."""
    if "variants" in exp.__dict__:
        return sum(len(v.seeds or exp.seeds) for v in exp.variants)
    return _grid_count(exp) * len(exp.seeds) + sum(len(p.get("seeds") or exp.seeds) for p in exp.points)


def _variant(exp: Experiment, label: Any, setting: dict[str, Any], seeds: Any, keys: list[str]) -> Variant:
    options = {st: dict(opts) for st, opts in exp.base.items()}
    for key, value in setting.items():
        stage, option = _split(exp, key)
        options[stage][option] = value
    swept = {k: _used_value(exp, options, k) for k in keys}
    label = label or ", ".join(f"{k}={v}" for k, v in setting.items()) or "base"
    return Variant(label, options, swept, tuple(seeds))


def iter_variants(exp: Experiment) -> Iterator[Variant]:
    """The variants one at a time, in the table's order (a grid of any size starts at once, in bounded
    memory); those of an experiment whose variants were given as a list, from it."""
    if "variants" in exp.__dict__:
        yield from exp.variants
        return
    keys = swept_keys(exp)
    for label, setting, seeds in _settings(exp):
        yield _variant(exp, label, setting, seeds, keys)


def iter_runs(exp: Experiment) -> Iterator[Run]:
    """The runs one at a time: each variant at each of its seeds, in the table's order."""
    for v in iter_variants(exp):
        for seed in v.seeds or exp.seeds:
            yield Run(v, seed)


CHECK_ALL_BELOW = 1000   # variants: a larger grid is checked axis value by axis value, not combination by combination


def checked_variants(exp: Experiment) -> Iterator[Variant]:
    """The variants checked before anything runs: all of them up to :data:`CHECK_ALL_BELOW`; of a larger
    grid its first combination, one combination per value of each axis (the first with that value) and
    per [zip] position, and every point (a bad value is found before the runs; a combination that no
    single value explains is its runs' error in the table)."""
    if "variants" in exp.__dict__ or variant_count(exp) <= CHECK_ALL_BELOW:
        yield from iter_variants(exp)
        return
    keys = swept_keys(exp)
    first = {k: v[0] for k, v in exp.grid.items()}
    zip0 = {k: v[0] for k, v in exp.zipped.items()}
    seen: set[str] = set()
    settings = [{**first, **zip0}]
    settings += [{**first, k: x, **zip0} for k, values in exp.grid.items() for x in values]
    n_zip = len(next(iter(exp.zipped.values()))) if exp.zipped else 0
    settings += [{**first, **{k: v[i] for k, v in exp.zipped.items()}} for i in range(n_zip)]
    for setting in settings:
        v = _variant(exp, None, setting, (), keys)
        if v.label not in seen:
            seen.add(v.label)
            yield v
    for label, setting, seeds in ((p["label"], {k: x for k, x in p.items() if k not in ("label", "seeds")},
                                   p.get("seeds", ())) for p in exp.points):
        yield _variant(exp, label, setting, seeds, keys)


def _used_value(exp: Experiment, options: dict, key: str) -> Any:
    """The value a variant's run uses for option ``key``: as given, else the stage's default, as the
    config normalizes it (plain AICO's and iLQG's alpha is 0: they have none); None where the options
    do not make a config (``validate`` then says why)."""
    from raico.stages.registry import get_stage

    stage, option = _split(exp, key)
    cls = get_stage(stage).config_cls
    if stage != exp.stages[0]:
        return options[stage].get(option, cls.defaults().get(option))
    try:
        cfg = cls(**{k.replace("-", "_"): v for k, v in options[stage].items()})
        cfg = cfg.normalized() if hasattr(cfg, "normalized") else cfg
    except (TypeError, ValueError):
        return options[stage].get(option)
    return getattr(cfg, option.replace("-", "_"), options[stage].get(option))


def stage_config(stage: str, options: Mapping[str, Any], **inputs: Any):
    """The stage's config from ``options`` (plus input references), validated: :class:`BadInput`
    naming the option and listing the valid ones."""
    from raico.stages.registry import get_stage

    cls = get_stage(stage).config_cls
    fields = {f.name for f in dataclasses.fields(cls)}
    values = {k.replace("-", "_"): tuple(v) if isinstance(v, list) else v for k, v in options.items()}
    unknown = [k for k in values if k not in fields or k in cls.INPUTS]
    if unknown:
        valid = sorted(fields - set(cls.INPUTS) - {"seed"})
        raise BadInput(f"{stage}: unknown option '{unknown[0]}': valid are {', '.join(valid)}")
    try:
        cfg = cls(**values, **inputs)
        cfg.validate()
    except (TypeError, ValueError) as e:
        raise BadInput(f"{stage}: {e}") from None
    return cfg


def first_config(exp: Experiment, run: Run):
    """The first stage's config of ``run`` (its seed set)."""
    return stage_config(exp.stages[0], {**run.variant.options[exp.stages[0]], "seed": run.seed})


def validate(exp: Experiment) -> None:
    """Build every run's first-stage config and every later stage's options (with a stand-in input)
    before anything runs: the first bad key or value is one :class:`BadInput` naming the variant."""
    if not run_count(exp):
        raise BadInput(f"{exp.name}: no runs (an empty grid and no [[point]])")
    for v in checked_variants(exp):
        try:
            first_config(exp, Run(v, (v.seeds or exp.seeds)[0]))
            for stage in exp.stages[1:]:
                stage_config(stage, v.options[stage], **{"plan": "0" * 16})
        except BadInput as e:
            raise BadInput(f"variant '{v.label}': {e}") from None
        if "seed" in v.options[exp.stages[0]]:
            raise BadInput(f"variant '{v.label}': set the seeds with seeds = [...], not an option 'seed'")


def identical_seeds(exp: Experiment) -> str | None:
    """One line when some variant runs at several seeds that cannot differ, else None: a plan's seed
    only draws its initial state ``q0 = default + N(0, q0_std^2)`` (``q0_std_prismatic`` on a
    prismatic joint), and a problem file's ``q0_std`` defaults to 0; an execution's seed only draws its noise (``x0_noise``, ``process_noise``)."""
    if exp.stages[0] != "plan":
        return None
    from raico.stages.registry import get_stage

    ex_defaults = get_stage("execute").config_cls.defaults() if "execute" in exp.stages else {}
    same = []
    checked = list(checked_variants(exp))
    for v in checked:
        seeds = v.seeds or exp.seeds
        if len(seeds) < 2:
            continue
        try:
            cfg = first_config(exp, Run(v, seeds[0])).normalized()
        except (BadInput, ValueError):
            continue  # validate() says what is wrong
        ex = {**ex_defaults, **v.options.get("execute", {})}
        # a prismatic joint's own std draws q0 too (on a robot without one the seeds stay alike, unsaid)
        drawn = cfg.q0_std or getattr(cfg, "q0_std_prismatic", 0.0)
        if not drawn and not ex.get("x0_noise") and not ex.get("process_noise"):
            same.append(v.label)
    if not same:
        return None
    n = len(exp.seeds)
    which = "every variant" if len(same) == len(checked) else ", ".join(same[:3]) + (
        f" and {len(same) - 3} more" if len(same) > 3 else "")
    return (f"exp {exp.name}: note: q0_std = 0 (a problem file's default), so the seeds of {which} are identical "
            f"runs ({n} seeds, one result); for initial states that differ set q0_std in [base] "
            "(e.g. q0_std = 0.05, rad) or -S q0_std=0.05")


# ----------------------------------------------------------------------------- running
SEEDED = ("plan", "execute", "learn", "babble")   # stages whose ``seed`` is the run's seed


def _chain_config(stage: str, options: Mapping[str, dict], seed: int, refs: Mapping[str, str]):
    """A stage's config in a run's chain: its options, the run's seed, and the earlier stages' artifacts
    as its inputs (execute and evaluate read the plan; evaluate also the execution)."""
    inputs = {}
    if stage in ("execute", "evaluate"):
        inputs["plan"] = refs["plan"]
    if stage == "evaluate" and "execute" in refs:
        inputs["rollout"] = refs["execute"]
    opts = {**options[stage], **({"seed": seed} if stage in SEEDED else {})}
    return stage_config(stage, opts, **inputs)


def _run_chain(args) -> dict:
    """One run's stages in a worker: ``(root, stages, options, seed, record, notes_said)`` -> each stage's outcome
    fields, or the error that stopped it (the run's row says it; the experiment goes on)."""
    root, stages, options, seed, record, notes_said = args
    from raico.pipeline.engine import runner
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.errors import RaicoError
    from raico.stages.plan.stage import load_notes_said

    cache = Cache(root)
    out: dict[str, Any] = {}
    refs: dict[str, Any] = {}
    # the experiment said the model file's load report once (run_reported), and the plan's notes where it could
    with load_notes_said(plan_notes=not notes_said):
        for stage in stages:
            try:
                outcome = runner.run(cache, stage, _chain_config(stage, options, seed, refs), record=record)
            except (RaicoError, ValueError, ArithmeticError) as e:
                out[stage] = {"error": " ".join(str(e).split()) or type(e).__name__}
                break
            out[stage] = dataclasses.asdict(outcome)
            refs[stage] = f"{stage}/{outcome.key}"
    return out


def model_notes(exp: Experiment) -> tuple[list[str], frozenset[str]]:
    """What loading the experiment's model-file robots changed and what the plan stage says before planning
    (a target beyond reach, a start outside the limits: :func:`raico.stages.plan.stage.plan_notes`, at each variant's
    first seed), each line once (the first stage a plan); and the labels of the variants whose plan notes these
    are (their runs do not repeat them; a variant whose problem does not build here, e.g. on a learned model,
    says them in its runs)."""
    if exp.stages[0] != "plan":
        return [], frozenset()
    from raico.stages.plan.stage import build_problem, load_notes, plan_notes, robot_and_task

    lines: list[str] = []
    said = set()
    for v in checked_variants(exp):
        cfg = first_config(exp, Run(v, (v.seeds or exp.seeds)[0]))
        try:
            if getattr(cfg, "problem", None) is not None:
                robot, _ = robot_and_task(cfg)
                lines += [ln for ln in load_notes(robot) if ln not in lines]
            if cfg.dynamics == "learned" or cfg.model:
                continue   # the plan needs its model's artifact: its runs say the notes
            cfg = cfg.normalized()
            robot, _, problem, _, _ = build_problem(cfg)
            notes = plan_notes(cfg, robot, problem)
        except ValueError:   # the run says why, in its row
            continue
        lines += [ln for ln in notes if ln not in lines]
        said.add(v.label)
    return lines, frozenset(said)


def _lookup(cache, exp: Experiment, run: Run, record: bool) -> dict | None:
    """The run's outcomes when every stage is cached (nothing to submit), else None."""
    from raico.pipeline.engine import runner

    out: dict[str, Any] = {}
    refs: dict[str, Any] = {}
    for stage in exp.stages:
        try:
            hit = runner.lookup(cache, stage, _chain_config(stage, run.variant.options, run.seed, refs),
                                record=record)
        except Exception:  # noqa: BLE001 - anything unusual: let the worker run it and say what happened
            return None
        if hit is None:
            return None
        out[stage] = dataclasses.asdict(hit)
        refs[stage] = f"{stage}/{hit.key}"
    return out


@dataclass
class Plan:
    """What ``run`` would do: the runs and how many are cached."""

    runs: list[Run]
    cached: list[bool] = field(default_factory=list)

    @property
    def to_compute(self) -> int:
        return sum(not c for c in self.cached)


def dry_run(cache, exp: Experiment) -> Plan:
    return Plan(exp.runs, [_lookup(cache, exp, r, record=False) is not None for r in exp.runs])


@dataclass(frozen=True)
class _Head:
    """What a run's row needs of its experiment (sent to workers with each run, not the whole grid)."""

    name: str
    stages: tuple[str, ...]


@dataclass
class Progress:
    """Where an experiment is: runs ``done`` of ``total`` (``cached`` and ``failed`` among them), the
    estimated seconds left (None until a run was computed), the run that just finished."""

    done: int
    total: int
    cached: int = 0
    failed: int = 0
    eta_s: float | None = None
    label: str | None = None
    run_s: float = 0.0   # the computed runs' own wall seconds, summed (in their workers)

    def line(self, name: str) -> str:
        eta = "" if self.eta_s is None else f", ~{_duration(self.eta_s)} left"
        return (f"exp {name}: {self.done}/{self.total} runs done ({self.cached} cached, {self.failed} failed{eta})"
                + (f" ({self.label})" if self.label else ""))


def _duration(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}h{s // 60 % 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s" if s >= 60 else f"{s}s"


@functools.cache
def _raico_version() -> str:
    from raico.pipeline.engine.keys import source_version

    return source_version("raico", "raico.pipeline", "raico.stages", "raico.planning", "raico.plants")


def worker_identity() -> tuple[str, str]:
    """``(node, code version)`` of the process it runs in: the node is the Ray node (its address and id)
    in a Ray worker, else the host; the version hashes raico's code (every stage's key holds its part)."""
    import socket
    import sys

    node = socket.gethostname()
    ray = sys.modules.get("ray")
    if ray is not None and ray.is_initialized():
        worker = getattr(getattr(ray, "_private", None), "worker", None)
        try:   # the address the node was started with (ray start --node-ip-address)
            ip = worker.global_worker.node_ip_address
        except AttributeError:
            ip = ray.util.get_node_ip_address()
        node = f"{ip} (Ray node {ray.get_runtime_context().get_node_id()[:12]})"
    return node, _raico_version()


def _job(args) -> dict:
    """One run in a worker: ``(root, head, run, record, notes_said)`` -> its row of the runs table."""
    from raico.pipeline.engine.cache import Cache

    root, head, run_, record, notes_said = args
    result = _run_chain((root, head.stages, run_.variant.options, run_.seed, record, notes_said))
    return table_row(Cache(root), head, run_, result)


def _cached_row(cache, exp: Experiment, head: _Head, run_: Run, record: bool) -> dict | None:
    """The run's row where every stage is cached (then nothing is submitted), else None."""
    result = _lookup(cache, exp, run_, record)
    return None if result is None else table_row(cache, head, run_, result)


def run(cache, exp: Experiment, executor: Executor, record: bool = False,
        progress: Callable[[Progress], None] | None = None, notify: Callable[[str], None] | None = None,
        notes_said: frozenset[str] = frozenset()) -> Rows:
    """Every run of ``exp`` on ``executor``, the grid generated as it is consumed; cached runs are looked
    up here before anything is submitted, short runs go in batches (:func:`raico.pipeline.engine.executors.stream`).
    The runs table is written as runs finish (:class:`TableWriter`) and whole at the end; returns its rows.
    An interrupt stops the workers; the rows written so far stay (``exp show`` reads them), and a second
    call recomputes none of the finished runs (they are cached). ``notify`` hears a line when a worker
    died and its runs in flight run again. ``notes_said``: the variants whose plan notes the caller said
    (:func:`model_notes`): their runs do not say them again."""
    import time

    from raico.pipeline.engine.executors import Item, stream
    from raico.pipeline.lifecycle import Interrupted

    head, root, total = _Head(exp.name, exp.stages), str(cache.root), run_count(exp)
    writer = TableWriter(cache, exp)
    state = Progress(0, total)

    def items() -> Iterator[Item]:
        for i, r in enumerate(iter_runs(exp)):
            yield Item(_job, (root, head, r, record, r.variant.label in notes_said), f"{r.variant.label} seed {r.seed}",
                       lookup=functools.partial(_cached_row, cache, exp, head, r, record), tag=(i, r))

    t0 = time.perf_counter()
    try:
        with executor:
            said = (lambda line: notify(f"exp {exp.name}: {line}")) if notify else None
            for done in stream(executor, items(), total=total, probe=worker_identity, notify=said):
                i, r = done.item.tag
                row = done.value if done.error is None else \
                    table_row(cache, head, r, {exp.stages[0]: {"error": done.error}})
                writer.add(i, row)
                state.done += 1
                state.cached += done.cached
                state.failed += bool(row["failed"])
                state.run_s += done.seconds
                elapsed, computing = time.perf_counter() - t0, state.done - state.cached
                state.eta_s = elapsed / computing * (total - state.done) if computing else None
                state.label = done.item.label
                if progress is not None:
                    progress(state)
    except Interrupted as e:  # says how many runs are kept (not what one of them kept)
        writer.flush()
        _WRITING.discard(writer.prefix)   # its parts stay for exp show; the next call removes them
        cache.cleanup_stale()   # the killed workers' temporary folders
        e.finished, e.scheduled, e.note = state.done, total, None
        raise
    except BaseException:
        writer.flush()
        _WRITING.discard(writer.prefix)
        cache.cleanup_stale()
        raise
    return writer.finish()


def run_reported(cache, exp: Experiment, executor: Executor, record: bool, reporter) -> Rows:
    """:func:`run` with its progress on ``reporter`` (a bar on a terminal, a line per run otherwise) and
    its outcome said: runs, cached, failed, errors (the first five with their reason) and the table. What
    loading a model file changed is said once, before the runs (not by each run)."""
    lines, notes_said = model_notes(exp)
    for line in lines:
        reporter.say(line)
    with reporter.board() as board:
        def progress(p: Progress) -> None:
            board.update(exp.name, f"exp {exp.name} ({p.cached} cached, {p.failed} failed)", p.done, p.total,
                         p.line(exp.name) if p.label else None)

        rows = run(cache, exp, executor, record=record, progress=progress, notify=reporter.say,
                   notes_said=notes_said)
    cached = sum(all(r.get(f"{s}.cached") is True for s in exp.stages) for r in rows)
    errors = [r for r in rows if r["status"] == "error"]     # a stage raised: the run has no result
    failed = [r for r in rows if r["failed"]]                 # ... or a solver diverged, the robot fell
    reporter.say(f"exp {exp.name}: {len(rows)} runs ({cached} cached; {len(failed)} failed, of them "
                 f"{len(errors)} with an error) -> {table_dir(cache, exp.name) / TABLE}")
    for r in errors[:5]:
        reporter.say(f"  error: {r['variant']} seed {r['seed']}: {r['error']}")
    return rows


# ----------------------------------------------------------------------------- the runs table
def _flat(prefix: str, value: Any, out: dict[str, Any]) -> None:
    """Scalar metrics as columns: numbers, booleans and short strings; dicts of them as ``prefix.key``."""
    if isinstance(value, bool) or isinstance(value, (int, float)) and not isinstance(value, bool):
        out[prefix] = value
    elif isinstance(value, str) and len(value) <= 80:
        out[prefix] = value
    elif isinstance(value, dict):
        for k, v in value.items():
            _flat(f"{prefix}.{k}", v, out)


def _curve(cache, ref: str) -> dict[str, Any]:
    """First, last and lowest cost of a plan's iterations and the iterations to within 1 % of the lowest;
    all None where it has no finite cost, or where its ``plan.npz`` cannot be read (said in one line on
    stderr: the row keeps its other columns)."""
    import numpy as np

    from raico.pipeline.engine.artifacts import LOAD_ERRORS

    empty = {"cost.first": None, "cost.last": None, "cost.min": None, "cost.iterations_to_1pct": None}
    try:
        with np.load(cache.root / ref / "plan.npz", allow_pickle=False) as f:
            costs = np.asarray(f["costs"], float)
    except (OSError, *LOAD_ERRORS) as e:
        _unreadable(f"{ref}/plan.npz", e, "its cost columns stay empty")
        return empty
    finite = costs[np.isfinite(costs)]
    if not finite.size:
        return empty
    low = float(finite.min())
    within = np.nonzero(np.isfinite(costs) & (costs <= low + CURVE_TOL * abs(low)))[0]
    return {"cost.first": float(costs[0]) if np.isfinite(costs[0]) else None, "cost.last": float(costs[-1])
            if np.isfinite(costs[-1]) else None, "cost.min": low,
            "cost.iterations_to_1pct": int(within[0]) + 1 if within.size else None}


def table_row(cache, exp: Experiment | _Head, run: Run, result: Mapping[str, Any]) -> dict[str, Any]:
    """The runs table's row of one run: variant, swept options, seed, per stage key / status / metrics."""
    row: dict[str, Any] = {"experiment": exp.name, "variant": run.variant.label, **run.variant.swept,
                           "seed": run.seed}
    status, error = "ok", ""
    for stage in exp.stages:
        res = result.get(stage)
        if res is None:
            row[f"{stage}.status"] = "not run"
            continue
        if "error" in res:
            row[f"{stage}.status"], error, status = "error", f"{stage}: {res['error']}", "error"
            continue
        row[f"{stage}.key"], row[f"{stage}.status"] = res["key"], res["status"]
        status = res["status"]
        row[f"{stage}.cached"] = res["cached"]
        metrics: dict[str, Any] = {}
        for k, v in (res.get("metrics") or {}).items():
            if k != "status":
                _flat(f"{stage}.{k}", v, metrics)
        row.update(metrics)
        meta = entry_meta(cache, stage, res["key"])
        row[f"{stage}.compute_s"] = (meta.get("timings") or {}).get("compute_s")
        row[f"{stage}.code_version"] = meta.get("code_version")
        if stage == "plan":
            row.update({f"plan.{k}": v for k, v in _curve(cache, f"plan/{res['key']}").items()})
    stage_status = [row.get(f"{s}.status") for s in exp.stages]
    row["status"], row["error"] = status, error
    row["failed"] = status == "error" or any(s in FAILED_STATUSES for s in stage_status)
    row["achieved"] = achieved(result, exp.stages) if status != "error" else False
    return row


def achieved(result: Mapping[str, Any], stages: Sequence[str]) -> bool | None:
    """Whether a run achieved its task: its last stage that judges one (execute, else plan) has every
    via-point within its tolerance (``raico.planning.achieved.task_errors``), an execution with status ok, a plan
    not diverged; None where no stage judges a task (no via-point, or a stage without the verdict)."""
    for stage, good in (("execute", lambda st: st == "ok"), ("plan", lambda st: st != "diverged")):
        if stage not in stages:
            continue
        res = result.get(stage) or {}
        task = (res.get("metrics") or {}).get("task")
        if isinstance(task, dict):
            return bool(task.get("achieved")) and good(res.get("status"))
        return None
    return None


def entry_meta(cache, stage: str, key: str) -> dict:
    """The entry's ``meta.json``; ``{}`` where it cannot be read (said in one line on stderr: the row's
    compute time and code version stay empty)."""
    try:
        meta = json.loads((cache.root / stage / key / "meta.json").read_text())
        if not isinstance(meta, dict):
            raise ValueError(f"a JSON {type(meta).__name__}, not an object")
    except (OSError, ValueError) as e:
        _unreadable(f"{stage}/{key}/meta.json", e, f"the row's {stage}.compute_s and {stage}.code_version stay empty")
        return {}
    return meta


def _unreadable(what: str, e: BaseException, instead: str) -> None:
    """One line on stderr: a file of the runs table's rows could not be read, and what the table does instead."""
    import sys

    from raico.pipeline.engine.artifacts import clean_error

    print(f"raico: warning: runs table: {what} cannot be read ({clean_error(e)}): {instead}", file=sys.stderr,
          flush=True)


def table_dir(cache, name: str) -> Path:
    return cache.root / "exp" / name


TABLE = "runs.parquet"   # the runs table, columnar (the views read it); runs.csv and runs.json beside it
PARTS = "runs.parts"     # the rows of a run in progress, a Parquet file per flush, gone when the table is whole
INDEX = "_run"           # a part's column: the run's place in the experiment's order


def _arrow_table(rows: list[dict], columns: list[str] | None = None):
    """``rows`` as a pyarrow Table (a column of mixed kinds, a number and a word, is written as text)."""
    import pyarrow as pa

    columns = columns or list(dict.fromkeys(k for r in rows for k in r))
    arrays = {}
    for c in columns:
        values = [r.get(c) for r in rows]
        try:
            arrays[c] = pa.array(values)
        except (pa.ArrowInvalid, pa.ArrowTypeError):
            arrays[c] = pa.array([None if v is None else str(v) for v in values], pa.string())
    return pa.table(arrays)


def _concat(tables: list):
    """One table of ``tables`` (their columns united; a column of different kinds across them as text)."""
    import pyarrow as pa

    try:
        return pa.concat_tables(tables, promote_options="permissive")
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        kinds: dict[str, set] = {}
        for t in tables:
            for f in t.schema:
                if not pa.types.is_null(f.type):
                    kinds.setdefault(f.name, set()).add(f.type)
        mixed = {c for c, k in kinds.items() if len(k) > 1}
        fixed = []
        for t in tables:
            for c in mixed & set(t.column_names):
                i = t.column_names.index(c)
                t = t.set_column(i, c, pa.array([None if v is None else str(v) for v in t.column(c).to_pylist()],
                                                pa.string()))
            fixed.append(t)
        return pa.concat_tables(fixed, promote_options="permissive")


def _metadata(exp: Experiment) -> dict[str, Any]:
    return {"experiment": exp.name, "description": exp.description, "stages": list(exp.stages),
            "file": str(exp.path) if exp.path else None, "swept": swept_keys(exp)}


class TableWriter:
    """The runs table of one call of :func:`run`, written as runs finish: rows are buffered and flushed
    every :attr:`FLUSH_ROWS` rows or :attr:`FLUSH_S` seconds as a Parquet file of ``runs.parts/`` (named by
    host, process and a counter: two calls on one experiment, or on two machines, do not collide);
    :meth:`finish` puts them together in the experiment's order as ``runs.parquet`` (with ``runs.csv`` and
    ``runs.json``) and removes them (and those an interrupted or killed call of this host left). Memory while
    the runs go: one buffer of rows and the columns' order, not the table."""

    FLUSH_ROWS = 500
    FLUSH_S = 2.0

    def __init__(self, cache, exp: Experiment) -> None:
        import os
        import secrets
        import socket
        import time

        self.cache, self.exp = cache, exp
        self.parts = table_dir(cache, exp.name) / PARTS
        self.prefix = f"{socket.gethostname()}-{os.getpid()}-{secrets.token_hex(3)}"
        _WRITING.add(self.prefix)
        self.buffer: list[dict] = []
        self.written: list[Path] = []
        self.order: dict[str, tuple[int, int]] = {}   # column -> (first run with it, its place in that row)
        self.flushed_at = time.monotonic()
        self.started = time.time()

    def add(self, index: int, row: dict) -> None:
        import time

        for pos, k in enumerate(row):
            if k not in self.order or (index, pos) < self.order[k]:
                self.order[k] = (index, pos)
        self.buffer.append({INDEX: index, **row})
        if len(self.buffer) >= self.FLUSH_ROWS or time.monotonic() - self.flushed_at >= self.FLUSH_S:
            self.flush()

    def flush(self) -> None:
        """Write the buffered rows as one part (atomically)."""
        import os
        import time

        import pyarrow.parquet as pq

        self.flushed_at = time.monotonic()
        if not self.buffer:
            return
        path = self.parts / f"{self.prefix}-{len(self.written):06d}.parquet"
        tmp = path.with_suffix(".tmp")
        table = _arrow_table(self.buffer).replace_schema_metadata({"raico": json.dumps(_metadata(self.exp), default=str)})
        for attempt in range(3):   # another call that finished may remove the empty folder in between
            self.parts.mkdir(parents=True, exist_ok=True)
            try:
                pq.write_table(table, tmp)
                os.replace(tmp, path)
                break
            except FileNotFoundError:
                if attempt == 2:
                    raise
        self.written.append(path)
        self.buffer = []

    def finish(self) -> Rows:
        """The whole table: written (``runs.parquet``, ``runs.csv``, ``runs.json``), its parts removed; its rows
        (columnar in memory, a dict per row as they are read)."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        self.flush()
        columns = sorted(self.order, key=self.order.__getitem__)
        table = _concat([pq.read_table(p) for p in self.written]).sort_by(INDEX).drop_columns([INDEX]) \
            if self.written else pa.table({})
        newer = self._newer(table)
        if newer is not None:
            table = _concat([table, newer]) if table.num_columns else newer
            columns += [c for c in newer.column_names if c not in columns]
        table = table.select([c for c in columns if c in table.column_names])
        _write_arrow(self.cache, self.exp, table)
        for p in self.written:
            p.unlink(missing_ok=True)
        self.close()
        return Rows(table)

    def close(self) -> None:
        """This call writes no more parts: the next call removes those it left (an interrupted call's)."""
        _WRITING.discard(self.prefix)
        _remove_left_parts(self.parts)

    def _newer(self, ours):
        """The rows of a table another call of the same experiment wrote while this one ran (a second `exp
        run` that added a grid value) that ``ours`` (a pyarrow Table) has not, as a Table; None if there are
        none: the queue grew, the table keeps them."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        path = table_dir(self.cache, self.exp.name) / TABLE
        try:
            if path.stat().st_mtime < self.started:
                return None
            other = pq.read_table(path)
        except (OSError, pa.ArrowInvalid):
            return None
        if "variant" not in other.column_names or "seed" not in other.column_names:
            return None
        have = set(zip(*(ours.column(c).to_pylist() for c in ("variant", "seed")))) if ours.num_rows else set()
        keep = [i for i, key in enumerate(zip(other.column("variant").to_pylist(), other.column("seed").to_pylist()))
                if key not in have]
        return other.take(keep).replace_schema_metadata(None) if keep else None


class Rows(Sequence):
    """The rows of a runs table held as its columns (a pyarrow Table): a dict per row as it is read."""

    CHUNK = 2000

    def __init__(self, table) -> None:
        self.table = table

    def __len__(self) -> int:
        return self.table.num_rows

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(len(self))[i]]
        return self.table.slice(range(len(self))[i], 1).to_pylist()[0]

    def __iter__(self) -> Iterator[dict]:
        for batch in self.table.to_batches(max_chunksize=self.CHUNK):
            yield from batch.to_pylist()


_WRITING: set[str] = set()   # the parts' prefixes of this process's writers that still write


def _remove_left_parts(parts: Path) -> None:
    """Remove the parts that no writer will use any more (their runs are cached, so a whole table written
    since holds them): of this host, those of a dead process or of a writer of this process that was closed
    (an interrupted call); the folder if it is empty. A call still running, here or on another host, keeps
    its parts."""
    import contextlib
    import os
    import socket

    host, me = socket.gethostname(), str(os.getpid())
    for p in parts.glob(f"{host}-*.parquet") if parts.is_dir() else ():
        pid, _, rest = p.name[len(host) + 1:].partition("-")
        prefix = f"{host}-{pid}-{rest.split('-', 1)[0]}"
        if pid.isdigit() and (not Path(f"/proc/{pid}").exists() if pid != me else prefix not in _WRITING):
            with contextlib.suppress(OSError):
                p.unlink()
    with contextlib.suppress(OSError):
        parts.rmdir()


def write_table(cache, exp: Experiment, rows: list[dict]) -> Path:
    """``runs.parquet``, ``runs.csv`` and ``runs.json`` of the experiment from ``rows`` (see :func:`_write_arrow`)."""
    columns = list(dict.fromkeys(k for row in rows for k in row))
    return _write_arrow(cache, exp, _arrow_table(rows, columns))


def _write_arrow(cache, exp: Experiment, table) -> Path:
    """``runs.parquet``, ``runs.csv`` and ``runs.json`` of the experiment from ``table`` (a pyarrow Table),
    each written atomically; CSV and JSON a chunk of rows at a time (memory: the table's columns)."""
    import pyarrow.parquet as pq

    from raico.pipeline.engine.atomic import atomic_path
    from raico.pipeline.engine.runner import finite_json  # inf and NaN (a diverged run's cost) as null: strict JSON

    out = table_dir(cache, exp.name)
    out.mkdir(parents=True, exist_ok=True)
    meta = _metadata(exp)
    with atomic_path(out / TABLE) as tmp:
        pq.write_table(table.replace_schema_metadata({"raico": json.dumps(meta, default=str)}), tmp)
    columns, rows = table.column_names, Rows(table)
    with atomic_path(out / "runs.csv") as tmp, open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns, lineterminator="\n")
        w.writeheader()
        for row in rows:
            w.writerow({k: ("" if row.get(k) is None else row.get(k)) for k in columns})
    head = {**{k: v for k, v in meta.items() if k != "swept"},
            "file_text": exp.path.read_text() if exp.path and exp.path.exists() else None, "swept": meta["swept"]}
    with atomic_path(out / "runs.json") as tmp, open(tmp, "w") as f:
        f.write(json.dumps(finite_json(head), indent=1, default=_json_default, allow_nan=False)[:-2])
        f.write(',\n "rows": [')
        for i, row in enumerate(rows):
            f.write(("," if i else "") + "\n  " + json.dumps(finite_json(row), default=_json_default, allow_nan=False))
        f.write("\n ]\n}")
    return out


def _json_default(x: Any) -> Any:
    return str(x)


# ----------------------------------------------------------------------------- reading the table
def read_table(cache, name_or_file: str):
    """The runs table (a pandas ``DataFrame``) of an experiment by name or by its file, and the swept
    option columns: ``runs.parquet``, with the rows of a run in progress (``runs.parts/``) over it (an
    experiment of an older raico: its ``runs.json``); :class:`BadInput` if it has not run."""
    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq

    name = name_or_file
    p = Path(name_or_file)
    if p.suffix == ".toml" and p.exists():
        name = load(p).name
    folder = table_dir(cache, name)
    parts = sorted((folder / PARTS).glob("*.parquet")) if (folder / PARTS).is_dir() else []
    df, swept = None, None
    try:
        table = pq.read_table(folder / TABLE)
        swept = json.loads((table.schema.metadata or {}).get(b"raico", b"{}")).get("swept")
        df = table.to_pandas()
    except FileNotFoundError:
        with _suppress_missing():
            doc = json.loads((folder / "runs.json").read_text())
            df, swept = pd.DataFrame(doc["rows"]), doc.get("swept", [])
    except (OSError, pa.ArrowInvalid) as e:
        raise BadInput(f"the runs table {folder / TABLE} cannot be read: {e}") from None
    live = []
    for part in parts:
        try:
            t = pq.read_table(part)
        except (OSError, pa.ArrowInvalid):   # a part being replaced as it is read: the next look has it
            continue
        swept = swept if swept is not None else json.loads((t.schema.metadata or {}).get(b"raico", b"{}")).get("swept")
        live.append(t)
    if live:
        new = _concat(live).sort_by(INDEX).drop_columns([INDEX]).to_pandas()
        df = new if df is None else pd.concat([df, new], ignore_index=True).drop_duplicates(
            ["variant", "seed"], keep="last").reset_index(drop=True)
    if df is None:
        raise BadInput(f"no runs table of experiment '{name}' under {cache.root / 'exp'}: "
                       "`raico exp run FILE` makes it")
    return df, list(swept or [])


def _suppress_missing():
    import contextlib

    return contextlib.suppress(FileNotFoundError)


def query(df, where: str | None):
    """The rows of ``df`` matching ``where`` (pandas query syntax: comparisons, and/or, in; names with dots
    in backticks); :class:`BadInput` with the table's columns if it does not parse or names no column."""
    if not where:
        return df
    try:
        return df.query(where, engine="python")
    except Exception as e:  # noqa: BLE001 - pandas raises many kinds for a bad expression
        names = ", ".join(map(str, df.columns))
        raise BadInput(f"--where '{where}': {type(e).__name__}: {e} (columns: {names})") from None


def metric_columns(df) -> list[str]:
    """The table's numeric metric columns (``stage.metric``; keys, cache flags and code versions left out)."""
    import pandas as pd

    return [c for c in df.columns if "." in str(c) and not str(c).endswith((".key", ".cached", ".code_version"))
            and (pd.api.types.is_numeric_dtype(df[c]) and not pd.api.types.is_bool_dtype(df[c]))]


DEFAULT_METRICS = ("plan.final_cost", "plan.iterations", "plan.wall_time_s", "plan.cost.iterations_to_1pct",
                   "execute.rmse_planned_executed", "learn.episodes")


def summarize(df, swept: list[str], metrics: list[str] | None = None, stat: str = "median",
              group: bool = True, where: str | None = None, sort: str | None = None,
              only_changed: bool = False):
    """The table a user reads: rows filtered by ``where`` (pandas query syntax), grouped over seeds by
    variant (``stat``: median with interquartile range, or mean with a 95 % t-interval; n; failures
    k/n), sorted by a column. Returns a ``DataFrame`` of strings and numbers."""
    import numpy as np
    import pandas as pd

    df = query(df, where)
    metrics = [m for m in (metrics or DEFAULT_METRICS) if m in df.columns]
    keys = ["variant", *[s for s in swept if s in df.columns]]
    if only_changed:
        keys = ["variant", *[k for k in keys[1:] if df[k].astype(str).nunique() > 1]]
    if not group:
        cols = [*keys, "seed", "status", "achieved", "error", *metrics]
        out = df[[c for c in cols if c in df.columns]]
        return out.sort_values(sort) if sort else out
    # one pass per column over a group index (groups in order of appearance), not a loop over the groups:
    # 10,000 runs in 1,000 variants take milliseconds
    codes = df.groupby(keys, sort=False, dropna=False).ngroup().to_numpy()
    count = int(codes.max()) + 1 if codes.size else 0
    first = np.unique(codes, return_index=True)[1] if codes.size else np.array([], int)
    out = df[keys].iloc[first].reset_index(drop=True)
    n = np.bincount(codes, minlength=count)
    out["n"] = n
    failed = np.bincount(codes, weights=df["failed"].astype(bool).to_numpy(), minlength=count).astype(int) \
        if "failed" in df else np.zeros(count, int)
    out["failed"] = [f"{k}/{m}" for k, m in zip(failed, n)]
    if "achieved" in df and df["achieved"].notna().any():   # runs that judged a task, and how many achieved it
        judged = df["achieved"].notna().to_numpy()
        j = np.bincount(codes[judged], minlength=count)
        yes = np.bincount(codes[judged], weights=df["achieved"][judged].astype(bool).to_numpy(), minlength=count)
        out["achieved"] = [f"{int(y)}/{k}" if k else None for y, k in zip(yes, j)]
    if "status" in df:   # per group "status count", most frequent first (ties: the first seen first)
        tally = pd.Series(codes).groupby([codes, df["status"].astype(str).to_numpy()], sort=False).size()
        per: list[list[tuple[str, int]]] = [[] for _ in range(count)]
        for (c, st), k in tally.items():
            per[c].append((st, int(k)))
        out["statuses"] = [", ".join(f"{st} {k}" for st, k in sorted(g, key=lambda t: -t[1])) for g in per]
    for m in metrics:
        x = pd.Series(pd.to_numeric(df[m], errors="coerce").to_numpy(float))
        g = x.groupby(codes)
        if stat == "mean":
            k = g.count().reindex(range(count)).to_numpy()
            mean, sd = g.mean().reindex(range(count)).to_numpy(), g.std(ddof=1).reindex(range(count)).to_numpy()
            out[m] = mean
            out[f"{m} ±95%"] = _t_half_widths(sd, k)
        else:
            out[m] = g.median().reindex(range(count)).to_numpy()
            out[f"{m} IQR"] = (g.quantile(0.75) - g.quantile(0.25)).reindex(range(count)).to_numpy()
    if sort:
        if sort not in out.columns:
            raise BadInput(f"--sort {sort}: no such column (columns: {', '.join(map(str, out.columns))})")
        out = out.sort_values(sort)
    return out


def _t_half_widths(sd, k):
    """Half-widths of the 95 % t-intervals of means of ``k`` values of standard deviation ``sd`` (arrays);
    NaN below 2 values."""
    import numpy as np
    from scipy import special  # stdtrit is what scipy.stats.t.ppf computes, without importing scipy.stats (~1 s)

    k = np.asarray(k, float)
    ok = k >= 2
    out = np.full(k.shape, np.nan)
    out[ok] = special.stdtrit(k[ok] - 1, 0.975) * np.asarray(sd, float)[ok] / np.sqrt(k[ok])
    return out


def _t_half_width(x) -> float | None:
    """Half-width of the 95 % t-interval of the mean of ``x`` (None below 2 values)."""
    if len(x) < 2:
        return None
    from scipy import special

    return float(special.stdtrit(len(x) - 1, 0.975) * x.std(ddof=1) / math.sqrt(len(x)))


SPREADS = (" IQR", " ±95%")


def render(df, fmt: str) -> str:
    """``table`` (aligned text), ``md``, ``csv`` or ``json``; in a table a metric's spread is written
    beside it in its cell: ``median (IQR x)`` or ``mean ± half-width``."""
    if fmt == "json":
        return df.to_json(orient="records")
    if fmt == "csv":
        return df.to_csv(index=False)
    head: list[str] = []
    cells: list[list[str]] = [[] for _ in range(len(df))]
    cols = list(df.columns)
    for c in cols:
        if any(str(c).endswith(s) for s in SPREADS):
            continue
        spread = next((f"{c}{s}" for s in SPREADS if f"{c}{s}" in cols), None)
        head.append(str(c) + ("" if spread is None else " (IQR)" if spread.endswith("IQR") else " (±95%)"))
        for i, (v, w) in enumerate(zip(df[c], df[spread] if spread else [None] * len(df))):
            cells[i].append(_cell(v) if spread is None or _cell(w) == "-" else
                            f"{_cell(v)} ({_cell(w)})" if spread.endswith("IQR") else f"{_cell(v)} ± {_cell(w)}")
    if fmt == "md":
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in cells])
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(head)]
    fmt_row = "  ".join(f"{{:<{w}}}" for w in widths)
    return "\n".join([fmt_row.format(*head), *(fmt_row.format(*r) for r in cells)])


def _cell(v: Any) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)



# ----------------------------------------------------------------------------- two variants, paired by seed
MIN_PAIRS_FOR_TEST = 6   # below this many seeds the signed-rank test cannot reach p < 0.05 (two-sided): none


@dataclass
class Paired:
    """``metric`` of variant ``b`` minus variant ``a``, seed by seed."""

    metric: str
    a: str
    b: str
    seeds: list[int]
    differences: list[float]
    median: float | None
    interval: tuple[float, float] | None      # 95 % t-interval of the mean difference
    p_value: float | None                     # Wilcoxon signed-rank, two-sided; None below MIN_PAIRS_FOR_TEST
    note: str


def paired(df, a: str, b: str, metric: str) -> Paired:
    """Variant ``b`` against variant ``a`` on ``metric``, paired by seed (seeds where both have a finite
    value). :class:`BadInput` if a variant or the metric is not in the table."""
    import numpy as np
    import pandas as pd

    labels = list(dict.fromkeys(df["variant"]))
    for v in (a, b):
        if v not in labels:
            raise BadInput(f"no variant '{v}' in the table: variants are {', '.join(map(repr, labels))}")
    if metric not in df.columns:
        raise BadInput(f"no column '{metric}': metrics are " + ", ".join(c for c in df.columns if "." in c))
    va = df[df["variant"] == a].set_index("seed")[metric].apply(pd.to_numeric, errors="coerce")
    vb = df[df["variant"] == b].set_index("seed")[metric].apply(pd.to_numeric, errors="coerce")
    both = sorted(s for s in set(va.index) & set(vb.index) if np.isfinite(va[s]) and np.isfinite(vb[s]))
    d = np.array([vb[s] - va[s] for s in both], float)
    if not d.size:
        return Paired(metric, a, b, [], [], None, None, None, "no seed where both variants have a value")
    half = _t_half_width(d)
    interval = None if half is None else (float(d.mean() - half), float(d.mean() + half))
    p, note = None, f"{d.size} seeds paired"
    if d.size < MIN_PAIRS_FOR_TEST:
        note += f"; not enough seeds for a signed-rank test (at least {MIN_PAIRS_FOR_TEST})"
    elif np.all(d == 0):
        p, note = 1.0, note + "; every difference is 0"
    else:
        p = signed_rank_p(d)
    return Paired(metric, a, b, both, d.tolist(), float(np.median(d)), interval, p, note)


EXACT_UP_TO = 50   # pairs: scipy.stats.wilcoxon's exact null distribution up to here (without ties or zeros)


def signed_rank_p(d) -> float:
    """Two-sided p-value of Wilcoxon's signed-rank test of the differences ``d``, as ``scipy.stats.wilcoxon(d)``
    gives it. Without ties or zeros and up to :data:`EXACT_UP_TO` pairs (a table's seeds), from the exact null
    distribution here (the count of rank subsets per sum; ``scipy.stats`` takes about a second to import,
    more than ``exp diff``'s whole work); otherwise from ``scipy.stats.wilcoxon``."""
    import numpy as np

    d = np.asarray(d, float)
    a = np.abs(d)
    if d.size > EXACT_UP_TO or np.any(d == 0) or np.unique(a).size != a.size:
        from scipy import stats

        return float(stats.wilcoxon(d).pvalue)
    n = d.size
    ranks = np.empty(n, int)
    ranks[np.argsort(a)] = np.arange(1, n + 1)
    r_plus = int(ranks[d > 0].sum())
    counts = [1] + [0] * (n * (n + 1) // 2)   # subsets of the ranks 1..n by their sum (exact integers)
    for r in range(1, n + 1):
        for total in range(len(counts) - 1, r - 1, -1):
            counts[total] += counts[total - r]
    whole = 2 ** n
    cdf, sf = sum(counts[:r_plus + 1]), sum(counts[r_plus:])
    return min(1.0, 2 * min(cdf, sf) / whole)


def render_paired(r: Paired, fmt: str = "table") -> str:
    if fmt == "json":
        return json.dumps(dataclasses.asdict(r))
    lines = [f"{r.metric}: {r.b} - {r.a}, paired by seed ({r.note})"]
    lines += [f"  seed {s}: {_cell(x)}" for s, x in zip(r.seeds, r.differences)]
    if r.median is not None:
        ci = "-" if r.interval is None else f"[{_cell(r.interval[0])}, {_cell(r.interval[1])}]"
        p = "-" if r.p_value is None else f"{r.p_value:.3g}"
        lines += [f"  median difference {_cell(r.median)}; mean's 95 % interval {ci}; signed-rank p {p}"]
    return "\n".join(lines)


def _normalized(cfg):
    return cfg.normalized() if hasattr(cfg, "normalized") else cfg


def unused_in(stage: str, cfg: dict[str, Any], options: Sequence[str], others: dict[str, set]) -> set[str]:
    """Of ``options``, those a run of ``stage`` with config ``cfg`` (its ``meta.json`` config) does not use:
    setting one to any value ``others`` lists for it leaves the normalized config (so the cache key) as it
    is, as iLQG's alpha. Options of later stages (``stage.option``) and unknown ones count as used."""
    import dataclasses

    from raico.stages.registry import get_stage

    try:
        base = get_stage(stage).config_cls.from_dict(cfg)
        ref = dataclasses.asdict(_normalized(base))
    except (TypeError, ValueError, KeyError):  # an entry of another version (fields, values): nothing unused
        return set()
    out = set()
    for opt in options:
        values = [v for v in others.get(opt, ()) if v is not None and v != cfg.get(opt)]
        if "." in opt or opt not in cfg or not others.get(opt):
            continue
        try:
            if all(dataclasses.asdict(_normalized(dataclasses.replace(base, **{opt: v}))) == ref for v in values):
                out.add(opt)
        except (TypeError, ValueError):
            continue
    return out


# ----------------------------------------------------------------------------- two single runs
KEY_RE = re.compile(r"^[0-9a-f]{4,16}$")   # a cache key or a prefix of one (at least 4 hex digits)


def key_columns(df) -> list[str]:
    """The table's ``<stage>.key`` columns, in the stages' order."""
    return [c for c in df.columns if str(c).endswith(".key")]


def find_run(df, ref: str) -> int | None:
    """The row index of the run whose key (of any stage) is ``ref`` or starts with it; None if ``ref``
    is not a key prefix or no run has it; :class:`BadInput` if it names more than one run."""
    ref = ref.strip().lower()
    if "/" in ref:   # STAGE/KEY, as raico show and raico ls write it
        stage, ref = ref.split("/", 1)
        cols = [f"{stage}.key"] if f"{stage}.key" in df.columns else []
    else:
        cols = key_columns(df)
    if not KEY_RE.match(ref):
        return None
    hits = sorted({i for c in cols for i, k in df[c].items() if isinstance(k, str) and k.startswith(ref)})
    if len(hits) > 1:
        which = ", ".join(f"{df.at[i, 'variant']} seed {df.at[i, 'seed']}" for i in hits[:4])
        raise BadInput(f"key prefix '{ref}' names {len(hits)} runs ({which}{', ...' if len(hits) > 4 else ''}): "
                       "give more characters")
    return hits[0] if hits else None


@dataclass
class RunDiff:
    """Two single runs of an experiment side by side: who they are, the options that differ, every
    metric of either with ``b - a``."""

    a: dict[str, Any]                                  # {"variant", "seed", "keys": {stage: key}}
    b: dict[str, Any]
    options: list[tuple[str, Any, Any]]                # (option, a's value, b's value), only where they differ
    metrics: list[tuple[str, Any, Any, float | None]]  # (metric, a, b, b - a where both are numbers)
    unused: dict[str, list[str]] = field(default_factory=dict)   # "a"/"b" -> options of it its run does not use


def _who(df, i: int) -> dict[str, Any]:
    row = df.loc[i]
    return {"variant": row["variant"], "seed": _plain(row["seed"]),
            "keys": {c[:-4]: row[c] for c in key_columns(df) if isinstance(row[c], str)}}


def _plain(v: Any) -> Any:
    """numpy scalars and NaN as plain Python values (None for a missing one)."""
    if hasattr(v, "item"):
        v = v.item()
    if isinstance(v, float) and math.isnan(v):
        return None
    return v


def step_configs(cache, who: dict[str, Any], first: str) -> dict[str, Any]:
    """The options each stage of a run used (its ``meta.json`` config, input references left out),
    named as the table names them: the first stage's plain, later ones ``stage.option``."""
    from raico.stages.registry import get_stage

    out: dict[str, Any] = {}
    for stage, key in who["keys"].items():
        cfg = entry_meta(cache, stage, key).get("config") or {}
        try:
            inputs = set(get_stage(stage).config_cls.INPUTS)
        except ValueError:  # a stage this version does not know (get_stage's error): every field
            inputs = set()
        for k, v in cfg.items():
            if k not in inputs:
                out[k if stage == first else f"{stage}.{k}"] = v
    return out


def _same(x: Any, y: Any) -> bool:
    if isinstance(x, (int, float)) and isinstance(y, (int, float)) and not isinstance(x, bool) \
            and not isinstance(y, bool):
        return x == y or (math.isnan(x) and math.isnan(y))
    return x == y


def run_diff(df, swept: list[str], a: str, b: str, cache=None) -> RunDiff:
    """Runs ``a`` and ``b`` (cache keys or key prefixes of any stage of the table) side by side: the
    options that differ (every option of each stage's config where ``cache`` has the entries, else the
    swept ones) and every metric with its difference. :class:`BadInput` if a key names no run."""
    idx = []
    for ref in (a, b):
        i = find_run(df, ref)
        if i is None:
            cols = ", ".join(key_columns(df)) or "no key columns"
            raise BadInput(f"no run with key '{ref}' in the table ({cols}: `raico exp show NAME --no-group "
                           f"--metric plan.key` lists them) and no variant of that name")
        idx.append(i)
    ia, ib = idx
    who_a, who_b = _who(df, ia), _who(df, ib)
    first = key_columns(df)[0][:-4] if key_columns(df) else "plan"
    conf_a = step_configs(cache, who_a, first) if cache is not None else {}
    conf_b = step_configs(cache, who_b, first) if cache is not None else {}
    if not conf_a or not conf_b:   # no entries to read: the swept options and the seed, from the table
        conf_a = {k: _plain(df.at[ia, k]) for k in (*swept, "seed") if k in df.columns}
        conf_b = {k: _plain(df.at[ib, k]) for k in (*swept, "seed") if k in df.columns}
    names = list(dict.fromkeys([*conf_a, *conf_b]))
    options = [(k, conf_a.get(k), conf_b.get(k)) for k in names if not _same(conf_a.get(k), conf_b.get(k))]
    unused = {}
    if cache is not None:   # options a run does not use (iLQG's alpha): its normalized config is the same without
        differ = [k for k, _, _ in options]
        values = {k: {_hashable(x), _hashable(y)} for k, x, y in options}
        for side, conf in (("a", conf_a), ("b", conf_b)):
            unused[side] = sorted(unused_in(first, conf, differ, values))
    skip = {*swept, "experiment", "variant", "seed", "error", *key_columns(df)}
    metrics = []
    for c in df.columns:
        if c in skip or c.endswith((".cached", ".code_version")):
            continue
        va, vb = _plain(df.at[ia, c]), _plain(df.at[ib, c])
        if va is None and vb is None:
            continue
        num = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (va, vb))
        metrics.append((c, va, vb, float(vb - va) if num else None))
    return RunDiff(who_a, who_b, options, metrics, unused)


def _hashable(v: Any) -> Any:
    return tuple(v) if isinstance(v, list) else v


def _run_name(who: dict[str, Any]) -> str:
    keys = ", ".join(f"{s} {k}" for s, k in who["keys"].items())
    return f"{keys} ({who['variant']}, seed {who['seed']})"


def render_run_diff(r: RunDiff, fmt: str = "table") -> str:
    if fmt == "json":
        return json.dumps({"a": r.a, "b": r.b,
                           "options": [{"option": k, "a": x, "b": y,
                                        "unused_by": [s for s in ("a", "b") if k in r.unused.get(s, ())]}
                                       for k, x, y in r.options],
                           "metrics": [{"metric": k, "a": x, "b": y, "b_minus_a": d} for k, x, y, d in r.metrics]},
                          default=str, allow_nan=False)

    def table(head: list[str], rows: list[list[str]]) -> list[str]:
        widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(head)]
        line = "  ".join(f"{{:<{w}}}" for w in widths)
        return ["  " + line.format(*head).rstrip(), *("  " + line.format(*row).rstrip() for row in rows)]

    out = [f"A: {_run_name(r.a)}", f"B: {_run_name(r.b)}"]
    if r.options:
        def value(side: str, k: str, v: Any) -> str:
            return _cell(v) + (" (not used)" if k in r.unused.get(side, ()) else "")

        out += ["options that differ:", *table(["option", "A", "B"], [[k, value("a", k, x), value("b", k, y)]
                                                                      for k, x, y in r.options])]
    else:
        out += ["options that differ: none"]
    out += ["metrics:", *table(["metric", "A", "B", "B - A"],
                               [[k, _cell(x), _cell(y), _cell(d)] for k, x, y, d in r.metrics])]
    return "\n".join(out)
