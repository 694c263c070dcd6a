"""mkdocs hook (``hooks:`` in mkdocs.yml): the reference tables generated from the code's own schema.

A page asks for a table with a marker on a line of its own, replaced when the site is built:

- ``<!-- schema: options STAGE -->``: the options of ``raico STAGE`` (the stage's config dataclass:
  field, type, default, help text), which are also the keys an experiment file's ``[base]`` takes;
- ``<!-- schema: problem-file -->``: the keys of a problem file, by table, and the cost-term types
  with their keys (the sets the loader refuses unknown keys against);
- ``<!-- schema: experiment-file -->``: the top-level keys of an experiment file, a point's own keys and
  the stage chains it may run;
- ``<!-- schema: commands -->``: every command with the page its ``--help`` ends with.

An unknown marker stops the build (``mkdocs build --strict`` is run by ``make docs``). The modules read
here are named in ``SCHEMA_MODULES`` (the one place to edit when a module moves).
"""

from __future__ import annotations

import dataclasses
import importlib
import re
import typing
from typing import Any

# where the schema lives: the stage registry, the problem-file loader, the experiment-file loader, the CLI
SCHEMA_MODULES = {
    "registry": "raico.stages.registry",
    "problem_file": "raico.planning.problem_file",
    "term_kinds": "raico.planning.term_kinds",
    "expfile": "raico.pipeline.experiments.expfile",
    "cli": "raico.pipeline.interface.cli.common",
}

MARKER = re.compile(r"^<!-- schema: ([\w-]+)(?: ([\w-]+))? -->$", re.M)


def _mod(name: str) -> Any:
    return importlib.import_module(SCHEMA_MODULES[name])


def _cell(text: Any) -> str:
    """A markdown table cell: pipes escaped, one line."""
    return " ".join(str(text).split()).replace("|", "\\|")


def _code(text: Any) -> str:
    """A table cell's code span: one line (a pipe inside a code span does not split the cell)."""
    return " ".join(str(text).split()).replace("`", "'")


def _type_name(hint: Any) -> str:
    text = getattr(hint, "__name__", None) if not typing.get_args(hint) else None
    return text or str(hint).replace("typing.", "")


def options_table(stage_name: str) -> str:
    """The options of ``raico STAGE`` from its config dataclass (defaults and help from the class)."""
    stage = _mod("registry").get_stage(stage_name)
    cls = stage.config_cls
    hints = typing.get_type_hints(cls)
    helps = {"seed": "Random seed.", **getattr(cls, "HELP", {})}
    inputs = set(getattr(cls, "INPUTS", ()))
    rows = ["| option | type | default | meaning |", "|---|---|---|---|"]
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            default = "unset" if f.default == "" else repr(f.default)
        elif f.default_factory is not dataclasses.MISSING:
            default = repr(f.default_factory())
        else:
            default = "required"
        what = helps.get(f.name, "")
        if f.name in inputs:
            what = f"(an input artifact: a key, key prefix or STAGE/KEY) {what}"
        rows.append(f"| `--{f.name.replace('_', '-')}` | `{_code(_type_name(hints[f.name]))}` | `{_code(default)}` | "
                    f"{_cell(what)} |")
    return (f"`raico {stage_name} --help` lists the same (generated from `{cls.__module__}.{cls.__name__}`); in an "
            f"experiment file the key is the field name (`{dataclasses.fields(cls)[0].name}`), not the flag.\n\n"
            + "\n".join(rows))


def _keys(keys: Any) -> str:
    return ", ".join(f"`{k}`" for k in sorted(keys, key=str.lower))


def problem_file_table() -> str:
    """The keys a problem file may hold, by table, and the cost terms' types with their keys."""
    pf = _mod("problem_file")
    rows = ["| table | keys |", "|---|---|",
            f"| top level | {_keys(pf.TOP_KEYS)} |",
            f"| `[robot]` | {_keys(pf.ROBOT_KEYS)} |",
            f"| `[robot.true]` | {_keys(pf.TRUE_KEYS)} |",
            f"| `[robot.true] payload` | {_keys(pf.PAYLOAD_KEYS)} |",
            f"| `[achieved]` | {_keys(pf.ACHIEVED_KEYS)} |",
            f"| `[horizon]` | {_keys(pf.HORIZON_KEYS)} |",
            f"| `[dynamics]` | {_keys(pf.DYNAMICS_KEYS)} |"]
    rows += [f"| `[[scene]]` `type = \"{kind}\"` | {_keys(keys)} |" for kind, keys in pf.SCENE_KEYS.items()]
    integ = ["| `model` | `integrator` (the first is the default) |", "|---|---|"]
    integ += [f"| `{m}` | {', '.join(f'`{i}`' for i in ints)} |" for m, ints in pf.INTEGRATORS.items()]
    terms = ["| `type` | keys |", "|---|---|"]
    terms += [f"| `{row.type}` | {_keys(row.keys)} |" for row in _mod("term_kinds").COST_KINDS]
    return ("Generated from the key sets of `" + SCHEMA_MODULES["problem_file"] + "` and the cost kinds of `"
            + SCHEMA_MODULES["term_kinds"] + "` (a key outside them is refused "
            "with the valid ones listed).\n\n" + "\n".join(rows) + "\n\nDynamics models and their integrators:\n\n"
            + "\n".join(integ) + "\n\nCost terms (`[costs.NAME]`; `[costs] convention` is `raico` or `crocoddyl`):\n\n"
            + "\n".join(terms))


def experiment_file_table() -> str:
    """The top-level keys of an experiment file, a point's own keys and the stage chains."""
    ef = _mod("expfile")
    chains = ", ".join("`" + ", ".join(c) + "`" for c in sorted(ef.CHAINS))
    return ("Generated from `" + SCHEMA_MODULES["expfile"] + "` (a key outside these is refused with the valid ones "
            "listed; every option key is checked by the stage's config class before anything runs).\n\n"
            "| where | keys |\n|---|---|\n"
            f"| top level | {', '.join(f'`{k}`' for k in ef.TOP_KEYS)} |\n"
            f"| a `[[point]]`, besides stage options | {', '.join(f'`{k}`' for k in ef.POINT_KEYS)} |\n"
            f"| `stages` | {chains} |")


def commands_table() -> str:
    """Every command of ``raico`` and the page its ``--help`` ends with."""
    cli = _mod("cli")
    rows = ["| command | page |", "|---|---|"]
    rows += [f"| `raico {cmd}`".rstrip() + f" | [{page}]({page}) |" for cmd, page in cli.DOCS_PAGES.items()]
    return "\n".join(rows)


def render(kind: str, arg: str | None) -> str:
    if kind == "options" and arg:
        return options_table(arg)
    if kind == "problem-file":
        return problem_file_table()
    if kind == "experiment-file":
        return experiment_file_table()
    if kind == "commands":
        return commands_table()
    raise ValueError(f"unknown schema marker: {kind} {arg or ''}")


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    """mkdocs: replace the page's schema markers by their tables."""
    return MARKER.sub(lambda m: render(m.group(1), m.group(2)), markdown)
