"""The views of the cache: ``raico ls``, ``show``, ``plot`` and ``compare`` (and the Rerun viewer they open)."""

from __future__ import annotations

import json
import os
import sys
import typing
from pathlib import Path
from typing import Annotated

import typer

from raico.pipeline.errors import BadInput, MissingArtifact, RaicoError, StorageError, check_folder, os_error_text
from raico.pipeline.interface.cli.common import Artifacts, Json, Quiet, handles_errors, open_cache

if typing.TYPE_CHECKING:
    from raico.pipeline.engine.cache import Cache


def register(app: typer.Typer) -> None:
    """Add ``plot``, ``compare``, ``ls`` and ``show`` to the ``raico`` group ``app``."""
    app.command("plot")(plot)
    app.command("compare")(compare)
    app.command("ls")(ls)
    app.command()(show)


@handles_errors
def plot(
    experiment: Annotated[str, typer.Argument(help="An experiment's name or its file.")],
    kind: Annotated[str, typer.Option("--kind", help="line: a metric against --x with bands over seeds (points "
                                      "and error bars on a categorical option); curve: cost per iteration per "
                                      "group (log axis); wall: cost against wall time per group; box: a box and "
                                      "the runs per group.")] = "line",
    x: Annotated[str | None, typer.Option("--x", help="The swept option on the x axis (--kind line).")] = None,
    metric: Annotated[str, typer.Option("--metric", "-m", help="The runs table's column plotted (line, box).")]
    = "plan.final_cost",
    group: Annotated[list[str] | None, typer.Option("--group", help="Group the runs by these options (repeatable; "
                                                    "default: every swept option that varies, but --x).")] = None,
    where: Annotated[str | None, typer.Option("--where", help="Keep rows matching a condition, as in exp show.")]
    = None,
    yscale: Annotated[str, typer.Option("--yscale", help="auto (log when the values span two decades; curve: "
                                        "log), linear or log.")] = "auto",
    ylim: Annotated[str | None, typer.Option("--ylim", help="LO,HI: the value axis's range (default: the data's; "
                                             "curve and wall: the finite values that do not explode).")] = None,
    out: Annotated[Path | None, typer.Option("--out", "-o", help="The PNG to write (default: artifacts/exp/NAME/"
                                             "KIND-METRIC.png).")] = None,
    artifacts: Artifacts = None, quiet: Quiet = False,
):
    """Plot an experiment's runs table: a metric against a swept option (median line, interquartile band over
    seeds), the cost per iteration per group, or a box per group. Legends name the options that differ."""
    from raico.pipeline.engine.ui import Reporter
    from raico.pipeline.experiments import plots

    if out is not None and out.suffix.lower() != ".png":
        raise BadInput(f"--out {out}: a .png file")
    cache = open_cache(artifacts)
    drawn = plots.plot_experiment(cache, experiment, kind, x, metric, group, where, yscale, ylim, out)
    Reporter(quiet).say(drawn.line)


@handles_errors
def compare(
    keys: Annotated[list[str] | None, typer.Argument(help="Runs to compare: plan or execute keys, key prefixes or "
                                                     "STAGE/KEY (at most 9).")] = None,
    exp: Annotated[str | None, typer.Option("--exp", help="Compare runs of this experiment (its name or file) "
                                            "instead: those --where keeps.")] = None,
    where: Annotated[str | None, typer.Option("--where", help="With --exp: the runs to compare, a condition on "
                                              "the runs table as in exp show, e.g. \"seed == 0\".")] = None,
    stage: Annotated[str | None, typer.Option("--stage", help="With --exp: plan or execute (default: the "
                                              "experiment's first stage).")] = None,
    out: Annotated[Path | None, typer.Option("--out", "-o", help="The recording to write (default: "
                                             "artifacts/compare/HASH.rrd).")] = None,
    open_: Annotated[bool, typer.Option("--open", help="Open the recording in the Rerun viewer.")] = False,
    artifacts: Artifacts = None, quiet: Quiet = False, json_: Json = False,
):
    """Put up to 9 runs into one Rerun recording on one timeline, each under its own entity path named by
    the options that differ, with a generated layout: a 3D view per run beside overlaid joint angles (and
    each run's log10 cost per iteration on the iteration timeline)."""
    from raico.pipeline.engine.ui import Reporter
    from raico.pipeline.experiments import compare as cmp

    if out is not None and out.suffix != ".rrd":
        raise BadInput(f"--out {out}: a .rrd file")
    cache = open_cache(artifacts)
    path, runs = cmp.compare(cache, list(keys or []), exp, where, stage, out)
    reporter = Reporter(quiet)
    reporter.say(f"compare: {len(runs)} runs -> {path}")
    for r in runs:
        reporter.say(f"  {r.label}: {r.ref}")
    if json_:
        typer.echo(json.dumps({"recording": str(path), "runs": {r.label: r.ref for r in runs}}))
    if open_:
        open_viewer(str(path))


def describe_entry(cache: Cache, info) -> dict:
    """What a listing shows of an entry: plant, task, solver (or dynamics), status and headline
    metric. An execution or evaluation takes plant, task and solver from its plan."""
    meta = info.entry.meta if info.entry is not None else {}
    cfg = dict(meta.get("config") or {})
    for ref in meta.get("inputs") or []:
        if "plant" in cfg or not ref.startswith("plan/"):
            continue
        try:
            cfg = {**json.loads((cache.root / ref / "meta.json").read_text()).get("config", {}), **cfg}
        except (OSError, ValueError):
            pass
    m = meta.get("metrics") or {}
    headline = {"plan": ("final_cost", m.get("final_cost")), "evaluate": ("final_cost", m.get("final_cost")),
                "execute": ("rmse", m.get("rmse_planned_executed")),
                "fit": ("heldout_rmse", m.get("heldout_rmse_overall")),
                "babble": ("samples", m.get("samples")),
                "learn": ("gp_error_last", (m.get("gp_error") or [None])[-1])}.get(info.stage, ("", None))
    return {"plant": cfg.get("plant"), "task": cfg.get("task"),
            "solver": cfg.get("solver") or cfg.get("schedule"), "dynamics": cfg.get("dynamics"),
            "status": meta.get("status"), "metric": headline[0], "value": headline[1]}


@handles_errors
def ls(
    stage: Annotated[str | None, typer.Argument(help="Only this stage (babble, fit, plan, execute, evaluate, learn).")]
    = None,
    artifacts: Artifacts = None,
    plant: Annotated[str | None, typer.Option(help="Only entries of this plant.")] = None,
    task: Annotated[str | None, typer.Option(help="Only entries of this task.")] = None,
    solver: Annotated[str | None, typer.Option(help="Only entries of this solver (aico, raico, ilqg, ...).")] = None,
    status: Annotated[str | None, typer.Option(help="Only entries with this status (ok, converged, diverged, ...).")]
    = None,
    all_: Annotated[bool, typer.Option("--all", help="Also list invalid entries.")] = False,
    verify: Annotated[bool, typer.Option("--verify", help="Deep check: re-hash every file of every entry.")] = False,
    json_: Json = False,
):
    """List cached artifacts with plant, task, solver, status and headline metric, filtered by them
    (valid ones; --all also shows invalid or partial entries).

    A plain listing checks each entry's own record and file sizes; --verify re-hashes every file."""
    from raico.pipeline.engine.runner import finite_json
    from raico.stages.registry import stage_names

    cache = open_cache(artifacts)
    known = stage_names()
    if stage is not None and stage not in known:
        raise BadInput(f"unknown stage '{stage}': choose one of {', '.join(known)}")
    for name, value in (("plant", plant), ("task", task), ("solver", solver), ("status", status)):
        if value is not None and not value.strip():
            raise BadInput(f"--{name}: an empty value")
    if not cache.root.is_dir():
        raise MissingArtifact(f"no artifacts folder {cache.root}")
    wanted = {"plant": plant, "task": task, "solver": solver, "status": status}
    for r in cache.list(stage, deep=verify):
        if not (r.valid or all_):
            continue
        d = describe_entry(cache, r)
        if any(v is not None and d[k] != v for k, v in wanted.items()):
            continue
        if json_:
            typer.echo(json.dumps(finite_json({"stage": r.stage, "key": r.key, "path": str(r.path),
                                               "valid": r.valid, "reason": r.reason, "created": r.created,
                                               "size": r.size, **d})))
        else:
            flag = f"  INVALID: {r.reason}" if not r.valid else "" if r.reason == "cached" else f"  STALE: {r.reason}"
            what = " ".join(str(d[k]) for k in ("plant", "task", "solver", "dynamics") if d[k]) or "-"
            val = d["value"]
            metric = f"{d['metric']}={val:.4g}" if isinstance(val, (int, float)) else "-"
            typer.echo(f"{r.stage:9s} {r.key}  {what:40s} {str(d['status'] or '-'):15s} {metric:24s} "
                       f"{r.created or '-':20s} {r.size / 1e6:8.2f} MB  {r.path}{flag}")


@handles_errors
def show(
    ref: Annotated[str, typer.Argument(help="STAGE/KEY or KEY of a cached artifact.")],
    artifacts: Artifacts = None,
    open_: Annotated[bool, typer.Option("--open", help="Open the recording in the Rerun viewer.")] = False,
    png: Annotated[Path | None, typer.Option("--png", help="Render the recording headless, as the viewer opens "
                                             "it, to this PNG (1920 x 1080; needs a Vulkan driver).")] = None,
    at: Annotated[float | None, typer.Option("--time", help="With --png: the time cursor at T s of sim_time.")]
    = None,
):
    """Print an artifact's meta.json and recording path, open its recording in Rerun, or render it to a PNG."""
    from raico.pipeline.engine import runner
    from raico.pipeline.engine.ui import Reporter
    if open_ and png is not None:
        raise BadInput("give --open or --png, not both")
    if at is not None and png is None:
        raise BadInput("--time goes with --png")
    if png is not None and png.suffix.lower() != ".png":
        raise BadInput(f"--png {png}: a .png file")
    if at is not None and not (at >= 0 and at < float("inf")):
        raise BadInput(f"--time {at}: a time in s, at least 0")
    cache = open_cache(artifacts)
    cache.notify = Reporter().say
    entry = runner.find_entry(cache, ref)
    rrd = entry.path / "recording.rrd"
    if open_ or png is not None:
        rec = runner.ensure_recording(cache, entry)
        if rec is None:
            raise BadInput(f"{ref} is {runner.with_article(entry.stage)} artifact, which has no recording")
        if png is not None:
            from raico.pipeline.recordings.screenshots import render_png

            check_folder(png.parent, "output folder")
            Reporter().say(f"show {entry.stage}/{entry.key}: {render_png(rec, png, at)}")
            return
        open_viewer(rec)
        return
    config = dict(entry.meta.get("config") or {})
    if isinstance(config.get("problem"), str):  # a problem file's content, stored as canonical JSON text
        try:
            config["problem"] = json.loads(config["problem"])
        except ValueError:
            pass
    typer.echo(json.dumps({"path": str(entry.path), "recording": str(rrd) if rrd.exists() else None,
                           **{k: entry.meta.get(k) for k in ("stage", "key", "config", "inputs",
                                                             "status", "metrics", "timings")},
                           "config": config},
                          indent=2, default=str))


def open_viewer(rec: str) -> None:
    """Run the Rerun viewer on ``rec`` until it is closed; an error if it cannot start (no display,
    no viewer binary, the viewer failing), with the viewer's own error line."""
    import subprocess
    import tempfile

    if sys.platform.startswith("linux") and not any(
            os.environ.get(v) for v in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")):
        raise RaicoError(f"cannot open the Rerun viewer: no display (DISPLAY and WAYLAND_DISPLAY are unset); "
                         f"copy the recording and run `rerun {rec}` where there is one")
    exe = Path(sys.executable).with_name("rerun")
    with tempfile.TemporaryFile("w+") as log:
        try:
            res = subprocess.run([str(exe), rec], stdout=subprocess.DEVNULL, stderr=log, check=False)
        except OSError as e:
            raise StorageError(f"cannot start the Rerun viewer: {os_error_text(e, exe)}") from None
        log.seek(0)
        lines = [ln.strip() for ln in log.read().splitlines() if ln.strip()]
    if res.returncode != 0:
        why = next((ln for ln in reversed(lines) if "error" in ln.lower()), lines[-1] if lines else "")
        raise RaicoError(f"the Rerun viewer could not open {rec} (exit {res.returncode}){': ' + why if why else ''}")
