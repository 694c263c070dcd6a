"""Screenshots of recordings as the Rerun viewer shows them, rendered headless.

:func:`render_screenshot` opens one ``.rrd`` in a headless native viewer (``rerun``, rendering
with a Vulkan driver: Mesa's software ``lavapipe`` is enough, ``apt-get install
mesa-vulkan-drivers``) with the recording's default blueprint, waits until the data has loaded
and is drawn, and saves the whole window (1920 x 1080) as a PNG, and, on request, single views
by name. "Drawn" means: the view named ``robot`` (every recording's 3D view) shows coloured or
light pixels; a screenshot taken before shows an empty scene, so it retries for a while.

:func:`report_screenshots` renders the most recent plan recording of each plant in a cache (and the
most recent learn recording of each learning plant), for the report; it returns ``[]`` (and raises nothing) where no renderer is available.
"""

from __future__ import annotations

import glob
import io
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["content_mask", "read_png", "render_png", "render_screenshot", "renderer_unavailable", "report_screenshots",
           "robot_mask"]

ROBOT_VIEW = "robot"  # name of the 3D view in every recording's blueprint (raico.pipeline.recordings.rerun_io)
VULKAN_ICDS = "/usr/share/vulkan/icd.d/*.json"
TOAST_S = 8.0  # a new viewer shows a notification ("Listening for gRPC connections") for 3 s, longer on a busy machine
ROBOT_PIXELS = 3e-4  # share of a 3D view's pixels showing bodies once drawn (an empty view: 0; the pendulum: 1e-3)


def _rerun_executable() -> str | None:
    """The viewer's own executable: the binary of the ``rerun_cli`` package (the ``rerun`` command
    of a pip install is a Python launcher that runs that binary as its child: killing the launcher
    would leave the viewer running), else ``rerun`` beside this Python or on the PATH."""
    override = os.environ.get("RERUN_CLI_PATH")  # what the launcher honours, too
    if override:
        return override
    try:
        import rerun_cli
    except ImportError:
        pass
    else:
        binary = Path(rerun_cli.__file__).with_name("rerun")
        if binary.is_file():
            return str(binary)
    venv = Path(sys.executable).with_name("rerun")
    return str(venv) if venv.exists() else shutil.which("rerun")


def renderer_unavailable() -> str | None:
    """Why recordings cannot be rendered here, or None if they can (a ``rerun`` executable and a
    Vulkan driver are installed)."""
    if _rerun_executable() is None:
        return "the rerun executable is not installed"
    if not glob.glob(VULKAN_ICDS) and not os.environ.get("VK_ICD_FILENAMES"):
        return "no Vulkan driver (apt-get install mesa-vulkan-drivers)"
    return None


def read_png(png: bytes | str | Path) -> np.ndarray:
    """RGB floats in [0, 1], ``(H, W, 3)``."""
    from PIL import Image

    src = io.BytesIO(png) if isinstance(png, bytes) else png
    with Image.open(src) as im:
        return np.asarray(im.convert("RGB"), dtype=float) / 255.0


def robot_mask(img: np.ndarray) -> np.ndarray:
    """Pixels of a 3D view's screenshot ``(H, W, 3)`` that show a body: coloured or light (the
    grid and the background are dim grey on black)."""
    bright = img.max(axis=2)
    sat = bright - img.min(axis=2)
    return (sat > 0.25) | (bright > 0.55)


def content_mask(img: np.ndarray) -> np.ndarray:
    """Pixels of a plot view's screenshot ``(H, W, 3)`` drawn in colour (lines, bars, markers):
    the axes, the grid and the text are grey."""
    return (img.max(axis=2) - img.min(axis=2)) > 0.2


@dataclass
class _Viewer:
    client: Any  # rerun.experimental.ViewerClient
    started: float  # time.monotonic() at its start


START_TIMEOUT_S = 60.0  # the viewer listening on its port (it starts in about 1 s; a loaded machine is slower)


@contextmanager
def _viewer() -> Iterator[_Viewer]:
    """A headless viewer on a free local port, stopped on exit.

    Started here rather than by ``ViewerClient.spawn`` (which starts the pip launcher, whose child
    the viewer is, inheriting this process's stdout and stderr): the binary itself, as a direct
    child that the kernel kills with this process, SIGKILL included (``PR_SET_PDEATHSIG``), with
    its output in a temporary file, never in the caller's pipes. Raises ``RuntimeError`` with the
    viewer's last line if it does not start."""
    if not os.environ.get("XDG_RUNTIME_DIR"):  # else the viewer's window layer complains on stderr
        os.environ["XDG_RUNTIME_DIR"] = tempfile.mkdtemp(prefix="raico-xdg-")
    os.environ.setdefault("WGPU_BACKEND", "vulkan")
    from rerun.experimental import ViewerClient

    from raico.pipeline.lifecycle import dies_with_this_process

    exe = _rerun_executable()
    if exe is None:
        raise RuntimeError("the rerun executable is not installed")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    # the arguments ViewerClient.spawn(headless=True, hide_welcome_screen=True) gives the viewer
    cmd = [exe, f"--port={port}", "--memory-limit=75%", "--server-memory-limit=1GiB", "--expect-data-soon",
           "--hide-welcome-screen", "--headless"]
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                                env={"RUST_LOG": "off", **os.environ, "RERUN_APP_ONLY": "true"}, preexec_fn=dies_with_this_process())
        try:
            _wait_listening(proc, port, log)
            yield _Viewer(ViewerClient(f"rerun+http://127.0.0.1:{port}/proxy"), time.monotonic())
        finally:
            _stop(proc)


def _wait_listening(proc: subprocess.Popen, port: int, log: Any) -> None:
    """Until the viewer accepts connections on ``port``; ``RuntimeError`` if it exits first or takes
    longer than :data:`START_TIMEOUT_S`."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        if proc.poll() is not None:
            log.seek(0)
            lines = [ln.strip() for ln in log.read().decode("utf-8", "replace").splitlines() if ln.strip()]
            raise RuntimeError(f"the Rerun viewer exited at start (code {proc.returncode})"
                               + (f": {lines[-1]}" if lines else ""))
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            return
        except OSError:
            pass
        if time.monotonic() > deadline:
            raise RuntimeError(f"the Rerun viewer did not start listening within {START_TIMEOUT_S:.0f} s")
        time.sleep(0.1)


def _stop(proc: subprocess.Popen) -> None:
    """SIGTERM, SIGKILL after 5 s; reaped either way."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _robot_drawn(viewer: Any, views: Mapping[str, str]) -> bool:
    if ROBOT_VIEW not in views:
        return True
    return robot_mask(read_png(viewer.take_screenshot(views[ROBOT_VIEW]))).mean() > ROBOT_PIXELS


def _shoot(v: _Viewer, rrd: Path, png: Path, views: Mapping[str, str | Path], timeline: str | None,
           time_value: float | int | None, ready: Callable[[Any, Mapping[str, str]], bool],
           timeout_s: float) -> Path:
    """Open ``rrd``, wait until ``ready`` (at most ``timeout_s``), save the window and the ``views``."""
    viewer = v.client
    viewer.open(str(rrd))
    try:
        # the file's own layout, not the one of an earlier recording of the same application
        viewer.run_command("recording.reset_blueprint_to_default")
        if timeline is not None:
            if isinstance(time_value, float):
                viewer.set_time(timeline, duration=time_value, play_state="paused")
            elif time_value is not None:
                viewer.set_time(timeline, sequence=int(time_value), play_state="paused")
            else:
                viewer.set_time(timeline, play_state="paused")
        deadline = time.monotonic() + timeout_s
        while True:
            state = viewer.get_state()
            ids = {v.name: v.view_id for v in state.views if v.name}
            if (not state.loading and ids and ready(viewer, ids)) or time.monotonic() > deadline:
                break
            time.sleep(0.5)
        time.sleep(0.3)  # one more frame: plots finish laying out their axes
        time.sleep(max(0.0, v.started + TOAST_S - time.monotonic()))  # the start notification gone
        png.parent.mkdir(parents=True, exist_ok=True)
        viewer.save_screenshot(str(png.resolve()))
        for name, out in views.items():
            if name in ids:
                Path(out).parent.mkdir(parents=True, exist_ok=True)
                try:
                    viewer.save_screenshot(str(Path(out).resolve()), view_id=ids[name])
                except ConnectionError:  # a view that is not on screen (a tab behind another): no file
                    continue
    finally:
        viewer.close("all")
    return png


def render_screenshot(
    rrd_path: str | Path,
    png_path: str | Path,
    *,
    views: Mapping[str, str | Path] | None = None,
    timeline: str | None = None,
    time: float | int | None = None,
    ready: Callable[[Any, Mapping[str, str]], bool] | None = None,
    timeout_s: float = 30.0,
) -> Path:
    """Render ``rrd_path`` in a headless Rerun viewer with its default blueprint and save the window
    as ``png_path`` (1920 x 1080); ``views`` ``{view name: png path}`` also saves single views.

    ``timeline`` (and ``time``: s on a duration timeline as a float, a sequence number as an int)
    moves the time cursor first; without it the viewer shows what a user sees on opening the file.
    ``ready(viewer, {view name: view id})`` says when the data is drawn (default: the ``robot`` view
    shows a body); after ``timeout_s`` the screenshot is taken anyway. Raises the viewer's error if
    it cannot start (see :func:`renderer_unavailable`). Takes about 5 s (the viewer's start).
    """
    with _viewer() as viewer:
        return _shoot(viewer, Path(rrd_path), Path(png_path), views or {}, timeline, time,
                      ready or _robot_drawn, timeout_s)


def render_png(rrd_path: str | Path, png_path: str | Path, time_s: float | None = None) -> Path:
    """``raico show KEY --png``: the recording as the viewer opens it (``time_s``: the time cursor at that
    many seconds of ``sim_time``), saved as ``png_path`` (1920 x 1080). Where it cannot render, a
    :class:`raico.pipeline.errors.RaicoError` whose one line names what is missing (no Vulkan driver, no
    ``rerun`` executable) or the viewer's own error; never a raw transport error."""
    from raico.pipeline.errors import RaicoError

    why = renderer_unavailable()
    if why is not None:
        raise RaicoError(f"cannot render {rrd_path}: {why}")
    try:
        return render_screenshot(rrd_path, png_path, timeline=None if time_s is None else "sim_time",
                                 time=None if time_s is None else float(time_s))
    except (RuntimeError, ConnectionError, TimeoutError) as e:  # the viewer did not start, or could not draw
        text = " ".join(str(e).split()) or type(e).__name__
        raise RaicoError(f"cannot render {rrd_path}: the Rerun viewer failed ({text}); a Vulkan driver that "
                         f"works is needed (apt-get install mesa-vulkan-drivers)") from None


def _latest_plans(cache: Any, stage: str = "plan") -> dict[str, Any]:
    """Plant -> the most recent valid ``stage`` entry (plan or learn) that has a recording (``EntryInfo``)."""
    from raico.pipeline.recordings import RECORDING

    latest: dict[str, Any] = {}
    for info in cache.list(stage):
        if not info.valid or info.entry is None or not (info.path / RECORDING).is_file():
            continue
        plant = (info.entry.meta.get("config") or {}).get("plant")
        if plant is None:
            continue
        best = latest.get(plant)
        if best is None or (info.created or "") > (best.created or ""):
            latest[plant] = info
    return latest


def report_screenshots(cache: Any, out_dir: str | Path,
                       say: Callable[[str], None] | None = None) -> list[tuple[str, Path]]:
    """One screenshot per plant and stage of the cache in ``out_dir`` (``plan-<plant>-<key>.png``, and
    for the learning plants ``learn-<plant>-<key>.png``): the recording of its most recent plan (learn
    loop) that has one, as the viewer opens it. A screenshot already there for that entry is reused (a
    recording is derived from its entry's data: the same key, the same picture), older ones of the
    plant are removed. Returns ``[(caption, path)]`` plans first, each sorted by plant; ``[]`` where no
    renderer is available (:func:`renderer_unavailable`, or the viewer does not start); a recording
    that fails to render is left out. Nothing raises: a cache that cannot be listed, a recording that
    fails to render and a viewer that does not start are one line each to ``say`` (e.g. a reporter's);
    no renderer installed is no screenshots, without a word (the report stands without them)."""
    out_dir = Path(out_dir)
    say = say or (lambda line: None)
    try:
        found = {stage: _latest_plans(cache, stage) for stage in ("plan", "learn")}
    except Exception as e:  # noqa: BLE001 - an unreadable cache: no screenshots, said
        say(f"raico: warning: no screenshots in the report: the cache cannot be listed ({_one_line(e)})")
        return []
    items = [(stage, plant, info) for stage in ("plan", "learn") for plant, info in sorted(found[stage].items())]
    if not items:
        return []
    from raico.pipeline.recordings import RECORDING

    def png_of(stage: str, plant: str, info: Any) -> Path:
        return out_dir / f"{stage}-{plant}-{info.key}.png"

    def caption(stage: str, plant: str, info: Any) -> str:
        cfg = info.entry.meta.get("config") or {}
        what = cfg.get("solver", "") if stage == "plan" else f"{cfg.get('episodes', '')} episodes"
        text = (f"{stage} {plant} {cfg.get('task', '')} {what} ({info.key}), "
                f"as the Rerun viewer opens its recording")
        return " ".join(text.split())

    todo = [it for it in items if not png_of(*it).is_file()]
    if todo and renderer_unavailable() is None:   # no renderer installed: no screenshots, as documented
        out_dir.mkdir(parents=True, exist_ok=True)
        try:
            with _viewer() as viewer:
                for stage, plant, info in todo:
                    for old in out_dir.glob(f"{stage}-{plant}-*.png"):
                        old.unlink(missing_ok=True)
                    try:
                        _shoot(viewer, info.path / RECORDING, png_of(stage, plant, info), {}, None, None,
                               _robot_drawn, 30.0)
                    except Exception as e:  # noqa: BLE001 - one recording the viewer cannot show: left out, said
                        say(f"raico: warning: screenshot of {stage}/{info.key} left out of the report: "
                            f"the viewer could not render it ({_one_line(e)})")
                        continue
        except Exception as e:  # noqa: BLE001 - the viewer did not start (no graphics adapter, ...): said
            say(f"raico: warning: screenshots left out of the report: the Rerun viewer did not start "
                f"({_one_line(e)})")
    return [(caption(*it), png_of(*it)) for it in items if png_of(*it).is_file()]


def _one_line(e: BaseException) -> str:
    """An exception as one line: its type and its first words."""
    text = " ".join(str(e).split())
    return f"{type(e).__name__}: {text}" if text else type(e).__name__
