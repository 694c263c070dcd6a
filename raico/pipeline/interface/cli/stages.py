"""The stage commands (babble, fit, plan, execute, evaluate, learn), generated from the stages' configs.

:func:`config_command` makes one option per field of a stage's config class (defaults and help from
the class) plus the shared ``--artifacts``, ``--no-record``, ``--quiet`` and ``--json``; with
``--json`` a command prints one JSON line ``{"stage", "key", "path", "cached", "status",
"metrics"}`` on stdout. :class:`LazyStageGroup` builds a stage's command on first use, so help,
``--version`` and usage errors import no stage.
"""

from __future__ import annotations

import dataclasses
import inspect
import typing
from typing import Annotated, Any

import typer
from typer.core import TyperGroup

from raico.pipeline.errors import BadInput
from raico.pipeline.interface.cli.common import (
    DOCS_PAGES,
    Artifacts,
    Json,
    NoRecord,
    Quiet,
    docs_line,
    handles_errors,
    open_cache,
    report,
)

SHARED_HELP = {"seed": "Random seed."}


def _option(name: str, hint: Any, default: Any, help_text: str) -> inspect.Parameter:
    """A Typer option parameter for config field ``name`` (``--kebab-name``)."""
    origin = typing.get_origin(hint)
    if origin is tuple:  # repeatable input: --data A --data B
        hint, default = list[str] | None, None
    required = default is inspect.Parameter.empty
    opt = typer.Option(f"--{name.replace('_', '-')}", help=help_text, show_default=not required)
    if hint is bool:
        opt = typer.Option(f"--{name.replace('_', '-')}/--no-{name.replace('_', '-')}", help=help_text)
    return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default,
                             annotation=Annotated[hint, opt])


def config_command(name: str, cls: type, description: str, action, target: typer.Typer) -> None:
    """Register ``raico NAME``: one option per field of the config class ``cls`` (defaults and help
    from the class), plus the shared ``--artifacts``, ``--no-record``, ``--quiet`` and ``--json``.
    ``action(cache, config, record, reporter) -> Outcome`` does the work."""
    hints = typing.get_type_hints(cls)
    helps = {**SHARED_HELP, **getattr(cls, "HELP", {})}
    params = []
    unset = set()   # fields whose default "" means "the task's" (left out); a typed "" is refused
    for f in dataclasses.fields(cls):
        default = inspect.Parameter.empty if f.default is dataclasses.MISSING else f.default
        hint = hints[f.name]
        if default == "" and hint is str:
            unset.add(f.name)
            hint, default = str | None, None
        params.append(_option(f.name, hint, default, helps.get(f.name, "")))
    shared = {"artifacts": (Artifacts, None), "no_record": (NoRecord, False), "quiet": (Quiet, False),
              "json_": (Json, False)}
    params += [inspect.Parameter(k, inspect.Parameter.KEYWORD_ONLY, default=d, annotation=a)
               for k, (a, d) in shared.items()]

    def command(**kw):
        from raico.pipeline.engine.ui import Reporter

        artifacts, no_record, quiet, as_json = (kw.pop(k) for k in ("artifacts", "no_record", "quiet", "json_"))
        for k in unset:
            if kw[k] is None:
                del kw[k]
            elif not kw[k].strip():
                raise BadInput(f"--{k.replace('_', '-')}: an empty value (leave the option out for its default)")
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in kw.items()}
        try:
            cfg = cls(**values)
            cfg.validate()
        except (TypeError, ValueError) as e:
            raise BadInput(str(e)) from None
        reporter = Reporter(quiet)
        for field_name, why in (cfg.ignored() if hasattr(cfg, "ignored") else {}).items():
            reporter.say(f"raico: note: --{field_name.replace('_', '-')} {getattr(cfg, field_name)} is ignored: "
                         f"it is {why} (not part of the cache key)")
        cache = open_cache(artifacts)
        cache.notify = reporter.say  # repairs it makes on its own (a damaged recording written again)
        outcome = action(cache, cfg, not no_record, reporter)
        report(outcome, as_json, reporter)

    typing.cast(Any, command).__signature__ = inspect.Signature(params)   # what Typer reads the options from
    command.__annotations__ = {p.name: p.annotation for p in params}
    command.__name__ = name
    command.__doc__ = description
    target.command(name, help=description)(handles_errors(command))


def stage_command(name: str, target: typer.Typer) -> None:
    """``raico NAME`` for a registered stage: its config's fields, run through the cache."""
    from raico.pipeline.engine import runner
    from raico.stages.registry import get_stage

    stage = get_stage(name)
    config_command(name, stage.config_cls, stage.description,
                   lambda cache, cfg, record, reporter: runner.run(cache, stage, cfg, record=record,
                                                                  reporter=reporter), target)


def _stage_click_command(name: str):
    """The click command of stage ``name`` (built when the group first needs it)."""
    one = typer.Typer(add_completion=False, pretty_exceptions_enable=False, rich_markup_mode=None)
    stage_command(name, one)
    return typer.main.get_command(one)


class LazyStageGroup(TyperGroup):
    """The ``raico`` group with the stage commands built on first use: ``raico --help`` lists them from
    the registry's names and one-line descriptions, so help, ``--version`` and usage errors start without
    importing a stage (Drake, crocoddyl, scipy); ``raico plan ...`` imports the plan stage only."""

    def parse_args(self, ctx, args: list[str]) -> list[str]:
        if not args and self.no_args_is_help and not ctx.resilient_parsing:  # plain `raico`: the help, exit 0
            typer.echo(ctx.get_help())
            ctx.exit(0)
        return super().parse_args(ctx, args)

    def list_commands(self, ctx) -> list[str]:
        from raico.stages.registry import stage_names

        return [*stage_names(), *(c for c in super().list_commands(ctx) if c not in stage_names())]

    def get_command(self, ctx, name: str):
        from raico.stages.registry import stage_names

        if name in stage_names() and name not in self.commands:
            self.commands[name] = _stage_click_command(name)
        return with_docs(super().get_command(ctx, name), name)

    def format_commands(self, ctx, formatter) -> None:
        from raico.stages.registry import DESCRIPTIONS

        names = self.list_commands(ctx)
        limit = formatter.width - 6 - max(map(len, names))   # as click's own listing
        rows = []
        for name in names:
            cmd = self.commands.get(name)
            text = short_help(DESCRIPTIONS[name], limit) if name in DESCRIPTIONS else cmd.get_short_help_str(limit)
            rows.append((name, text))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


def with_docs(cmd, path: str):
    """``cmd`` (and its subcommands) with the docs line as the epilog of its help."""
    if cmd is not None and path in DOCS_PAGES:
        cmd.epilog = docs_line(path)
        for name, sub in getattr(cmd, "commands", {}).items():
            with_docs(sub, f"{path} {name}")
    return cmd


def short_help(text: str, limit: int = 70) -> str:
    """Click's short help: the first sentence, cut at ``limit`` characters."""
    first = text.split(". ")[0].split("; ")[0]
    return first if len(first) <= limit else first[: limit - 3].rsplit(" ", 1)[0] + "..."
