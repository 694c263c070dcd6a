"""The process's life: signals, interrupts and child processes.

SIGINT and SIGTERM become :class:`Interrupted` in the main thread (so ``finally`` blocks clean up and
the CLI exits ``128 + signum``); worker processes die with their parent; the resource tracker
that multiprocessing starts is stopped and reaped on the way out. The error types the CLI reports
are in :mod:`raico.pipeline.errors`.
"""

from __future__ import annotations


class Interrupted(BaseException):  # noqa: N818  (like KeyboardInterrupt: not an Exception)
    """SIGINT or SIGTERM arrived. Raised in the main thread by :func:`install_signal_handlers`'s
    handler, so ``finally`` blocks remove temporary folders and stop worker processes on the
    way out; the CLI prints one line and exits ``128 + signum`` (130, 143).

    It is not an ``Exception`` (nothing catches it by accident) and not a
    ``KeyboardInterrupt`` (click would print a blank line for those). ``finished`` counts the
    runs that finished (and are cached) before the interrupt, where a sweep knows it."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum
        self.finished: int | None = None
        self.scheduled: int | None = None
        self.note: str | None = None  # what the interrupted run did keep, where that is known

    @property
    def exit_code(self) -> int:
        return 128 + self.signum

    @property
    def signame(self) -> str:
        import signal

        try:
            return signal.Signals(self.signum).name
        except ValueError:
            return f"signal {self.signum}"

    def message(self) -> str:
        """The one line the CLI prints."""
        text = f"interrupted by {self.signame}"
        if self.note is not None:
            return f"{text}; {self.note}"
        if self.finished is None:
            return f"{text}; the interrupted run left no partial artifact"
        of = f" of {self.scheduled}" if self.scheduled is not None else ""
        return (f"{text}; {self.finished}{of} runs had finished and are cached (the next call reuses them); "
                f"the interrupted runs left no partial artifact")

    def __str__(self) -> str:
        return self.message()


def interrupt_in(error: BaseException) -> Interrupted | None:
    """The :class:`Interrupted` behind ``error``, if a signal caused it: a SIGTERM that lands while an
    extension module is being imported (Drake, scipy: imported when first used) surfaces as that
    module's ``ImportError("initialization failed")``, the interrupt in its context."""
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, Interrupted):
            return error
        seen.add(id(error))
        error = error.__cause__ or (None if error.__suppress_context__ else error.__context__)
    return None


# Extension modules whose initialization catches an exception raised inside it and logs it with a stack
# trace from C++ (Drake's spdlog) before re-raising: an interrupt is held back until they are loaded.
HOLD_SIGNALS_DURING = ("pydrake.common",)


class _HeldSignals:
    """A meta-path finder that loads the modules of :data:`HOLD_SIGNALS_DURING` with the interrupt held:
    the handler records a signal that lands meanwhile, and it is raised once the module is loaded."""

    def __init__(self, state: dict[str, int], raise_held) -> None:
        self.state, self.raise_held = state, raise_held

    def find_spec(self, name, path, target=None):
        import importlib.util
        import sys

        if name not in HOLD_SIGNALS_DURING:
            return None
        sys.meta_path.remove(self)
        try:
            spec = importlib.util.find_spec(name)
        finally:
            sys.meta_path.insert(0, self)
        if spec is not None and spec.loader is not None:
            spec.loader = _HeldLoader(spec.loader, self)
        return spec


class _HeldLoader:
    """A loader that runs another one's ``create_module`` and ``exec_module`` with the interrupt held."""

    def __init__(self, loader, finder: _HeldSignals) -> None:
        self.loader, self.finder = loader, finder

    def _held(self, call, arg):
        state = self.finder.state
        state["holding"] = state.get("holding", 0) + 1
        try:
            return call(arg)
        finally:
            state["holding"] -= 1
            if not state["holding"] and "held" in state:
                self.finder.raise_held(state.pop("held"))

    def create_module(self, spec):
        return self._held(self.loader.create_module, spec)

    def exec_module(self, module):
        return self._held(self.loader.exec_module, module)


def install_signal_handlers() -> None:
    """SIGINT and SIGTERM raise :class:`Interrupted` in the main thread; a second signal while
    the first unwinds exits at once (``128 + signum``) with one line on stderr. A signal that lands
    while an extension of :data:`HOLD_SIGNALS_DURING` initializes is raised once it is loaded."""
    import os
    import signal
    import sys

    state: dict[str, int] = {}

    def raise_interrupt(signum: int):
        state["first"] = signum
        raise Interrupted(signum)

    def handler(signum, frame):
        if "first" in state:
            os.write(2, f"raico: error: interrupted by {signal.Signals(signum).name} again; "
                        f"stopped without cleaning up\n".encode())
            os._exit(128 + signum)
        if state.get("holding"):
            state.setdefault("held", signum)
            return
        raise_interrupt(signum)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, handler)
    sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, _HeldSignals)]
    sys.meta_path.insert(0, _HeldSignals(state, raise_interrupt))


def die_with_parent(parent_pid: int | str | None) -> None:
    """Make this worker process die with its parent ``parent_pid``, also when the parent is
    SIGKILLed: Linux's ``PR_SET_PDEATHSIG`` (SIGKILL when the parent exits), elsewhere a daemon
    thread polling the parent's pid. Exits at once if the parent is already gone."""
    import os
    import signal
    import sys
    import threading
    import time

    try:
        ppid = int(parent_pid)
    except (TypeError, ValueError):
        return
    if sys.platform.startswith("linux"):
        import ctypes

        pr_set_pdeathsig = 1
        try:
            ok = ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, int(signal.SIGKILL), 0, 0, 0) == 0
        except (OSError, AttributeError):
            ok = False
        if os.getppid() != ppid:  # the parent died before we asked
            os._exit(1)
        if ok:
            return

    def watch() -> None:
        while os.getppid() == ppid:
            time.sleep(0.25)
        os._exit(1)

    threading.Thread(target=watch, name="raico-parent-watch", daemon=True).start()


def dies_with_this_process():
    """A ``preexec_fn`` for :class:`subprocess.Popen`: the child is SIGKILLed by the kernel when the
    thread that starts it ends, this process's SIGKILL included (Linux ``PR_SET_PDEATHSIG``; the
    function is looked up here, so the forked child only calls it), and exits at once if this
    process is already gone. None where there is no ``prctl``."""
    import os
    import signal
    import sys

    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    parent = os.getpid()
    pr_set_pdeathsig, sigkill = 1, int(signal.SIGKILL)

    def preexec() -> None:
        prctl(pr_set_pdeathsig, sigkill, 0, 0, 0)
        if os.getppid() != parent:  # the parent died before we asked
            os._exit(1)

    return preexec


def stop_resource_tracker() -> None:
    """Close multiprocessing's resource tracker (a child started with the first worker pool) and
    reap it, so no child of this process outlives it, not even as a zombie."""
    import gc
    import sys

    rt = sys.modules.get("multiprocessing.resource_tracker")
    tracker = getattr(rt, "_resource_tracker", None)
    if tracker is None or getattr(tracker, "_pid", None) is None:
        return
    gc.collect()  # the pools' queues: their semaphores are unregistered before the tracker stops
    try:
        tracker._stop()
    except Exception:  # noqa: BLE001  (private API; at worst the tracker exits with this process)
        pass
