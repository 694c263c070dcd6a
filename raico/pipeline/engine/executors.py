"""Where the runs of ``raico reproduce``, ``exp run`` and ``bench suite`` execute, and what keeps the workers busy.

An :class:`Executor` runs picklable job functions ``fn(arg)`` (module-level functions, so a
spawned process or a Ray worker imports them by name): ``submit`` returns a
``concurrent.futures.Future``, ``wait`` blocks until some are done, ``result`` gives a done
future's value (or raises its error as raico's own), ``shutdown(cancel=True)`` stops everything
at once. Three of them (``make_executor``):

- ``serial``: in this process, one job at a time (in the main thread, so Ctrl-C interrupts it);
- ``process``: one pool of spawned worker processes for the executor's whole life (the default;
  started on the first submit, so nothing starts when every run is cached). Workers die with the
  parent, ignore SIGINT (Ctrl-C is the parent's), end on SIGTERM, and keep their per-process
  caches (compiled dynamics, shared robots) from one job to the next;
- ``ray``: Ray tasks on a local instance with ``--jobs`` CPUs, or on the cluster at ``address``.

:func:`stream` runs many independent runs on one executor (``raico exp run``, ``raico bench suite``):
consumed lazily from any iterable, cached runs looked up first, short runs batched into tasks of about a
second, a task whose worker died submitted again, each worker's code version checked.

:class:`Scheduler` runs *flows* on one executor: a flow is a generator that yields a
:class:`Batch` of jobs and receives their results (in the batch's order), so a figure is written
as plain sequential code (plans, then the executions that depend on them) while many figures share
the workers. Jobs wait in a priority queue in this process (lower priority value first, then in the
order they were yielded); at most ``executor.slots`` are handed to the executor, so work that
becomes ready late (a figure's executions) still goes ahead of lower-priority work. A job's
``lookup`` (a cached run) is answered here and never submitted; identical jobs run once.
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import multiprocessing as mp
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as wait_futures
from dataclasses import dataclass
from typing import Any

from raico.pipeline.errors import BadInput, RaicoError
from raico.pipeline.lifecycle import Interrupted

EXECUTORS = ("serial", "process", "ray")
WORKER_DIED = "a worker process died (killed, or out of memory); the runs that finished are cached"


class WorkerLost(RaicoError):
    """A job's worker (a pool process, a Ray worker or its whole node) died while it ran the job: the
    job did not fail, it can run again elsewhere (:func:`stream` resubmits it; a flow stops)."""


def timed(call: tuple[Callable[[Any], Any], Any]) -> tuple[float, Any]:
    """``(wall seconds, fn(arg))`` of ``call = (fn, arg)``: what the scheduler submits."""
    fn, arg = call
    t0 = time.perf_counter()
    value = fn(arg)
    return time.perf_counter() - t0, value


class Executor:
    """Runs ``fn(arg)`` somewhere; a context manager (an exception on the way out cancels everything)."""

    name = "executor"
    _workers = 1   # jobs that run at once (set by a subclass; a Ray cluster counts its CPUs)

    @property
    def slots(self) -> int:
        """Jobs that run at once."""
        return self._workers
    # jobs queued beyond the running ones (per slot): workers that run apart from this process start the next
    # job at once while this process is busy (a figure's report is written here between waits)
    queued_per_slot = 0

    def submit(self, fn: Callable[[Any], Any], arg: Any) -> Future:
        raise NotImplementedError

    def wait(self, futures: list[Future]) -> set[Future]:
        """Block until at least one of ``futures`` is done; the done ones."""
        return wait_futures(futures, return_when=FIRST_COMPLETED).done

    def result(self, future: Future) -> Any:
        """The value of a done future; its job's exception is raised as the job raised it."""
        return future.result()

    def shutdown(self, cancel: bool = False) -> None:
        """Release the workers: after the running jobs, or (``cancel``) at once, killing them."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.shutdown(cancel=exc_type is not None)


class SerialExecutor(Executor):
    """In this process: a submitted job runs when :meth:`wait` is called, in submission order."""

    name = "serial"

    def __init__(self) -> None:
        self._queue: deque[tuple[Future, Callable, Any]] = deque()

    def submit(self, fn, arg) -> Future:
        future: Future = Future()
        self._queue.append((future, fn, arg))
        return future

    def wait(self, futures: list[Future]) -> set[Future]:
        wanted = set(futures)
        done = {f for f in wanted if f.done()}
        while not done and self._queue:
            future, fn, arg = self._queue.popleft()
            if future.set_running_or_notify_cancel():
                try:
                    future.set_result(fn(arg))
                except Exception as e:  # noqa: BLE001  (an interrupt is not an Exception: it propagates)
                    future.set_exception(e)
            if future in wanted:
                done.add(future)
        return done

    def shutdown(self, cancel: bool = False) -> None:
        while self._queue:
            self._queue.popleft()[0].cancel()


# ----------------------------------------------------------------------------- process pool
def _worker_init(parent_pid: int, threads: int = 1) -> None:
    """Pool worker set-up: die with the parent (also on SIGKILL); Ctrl-C is the parent's to handle
    (the terminal sends it to the whole process group), SIGTERM from the parent ends the worker;
    ``threads``: the worker's share of the CPUs for per-output GP work (``RAICO_THREADS``)."""
    import os
    import signal

    os.environ["RAICO_THREADS"] = str(max(1, int(threads)))

    from raico.pipeline.lifecycle import die_with_parent

    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


@contextlib.contextmanager
def _sigint_blocked():
    """SIGINT blocked in this thread while workers are spawned, so they start with it blocked
    (a Ctrl-C during their imports is not theirs); a pending one is delivered afterwards."""
    import signal
    import threading

    if not hasattr(signal, "pthread_sigmask") or threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


TRACKER_WARNING = "ignore:resource_tracker:UserWarning"


def _quiet_resource_tracker() -> None:
    """multiprocessing's resource tracker (a helper process started with the first pool) warns about
    "leaked semaphores" on stderr when this process was SIGKILLed; it gets this process's ``-W``
    options, so the warning is filtered there (it unlinks them all the same)."""
    import sys

    if TRACKER_WARNING not in sys.warnoptions:
        sys.warnoptions.append(TRACKER_WARNING)


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Stop at once: runs not started are cancelled, the workers get SIGTERM (SIGKILL after 1 s)
    and are reaped, the pool's manager thread is joined."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    # the pool's own thread cancels what has not started (cancelling futures here races with it
    # marking them broken once the workers are gone: InvalidStateError in that thread)
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + 1.0
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
    for p in procs:
        if p.is_alive():
            p.kill()
            p.join(5.0)
    if manager is not None:
        manager.join(10.0)


class ProcessExecutor(Executor):
    """One pool of ``workers`` spawned processes, started on the first submit (a worker is spawned
    per submit until there are ``workers``) and kept until :meth:`shutdown`."""

    name = "process"
    queued_per_slot = 1

    def __init__(self, workers: int) -> None:
        self._workers = workers
        self._pool: ProcessPoolExecutor | None = None

    def submit(self, fn, arg) -> Future:
        import os

        if self._pool is not None and getattr(self._pool, "_broken", False):  # a worker died: a new pool
            _stop_pool(self._pool)
            self._pool = None
        if self._pool is None:
            _quiet_resource_tracker()
            self._pool = ProcessPoolExecutor(max_workers=self.slots, mp_context=mp.get_context("spawn"),
                                             initializer=_worker_init,
                                             initargs=(os.getpid(), _share(self.slots)))
        with _sigint_blocked():  # workers are spawned here
            return self._pool.submit(fn, arg)

    def result(self, future: Future) -> Any:
        from concurrent.futures.process import BrokenProcessPool

        try:
            return future.result()
        except BrokenProcessPool:
            raise WorkerLost(WORKER_DIED) from None

    def shutdown(self, cancel: bool = False) -> None:
        pool, self._pool = self._pool, None
        if pool is None:
            return
        if cancel:
            _stop_pool(pool)
        else:
            pool.shutdown(wait=True)


# ----------------------------------------------------------------------------- ray
def _share(workers: int) -> int:
    """Per-output GP threads of one of ``workers`` pool workers: this process's CPUs over the workers
    (at least 1)."""
    from raico.plants.threads import output_threads

    return max(1, output_threads() // max(1, workers))


def _ray_call(fn, arg):
    """The one Ray task: ``fn(arg)`` in a Ray worker (one CPU: one thread for per-output GP work)."""
    import os

    os.environ["RAICO_THREADS"] = "1"
    return fn(arg)


def _call0(fn):
    """``fn()``: a job of no argument, as ``fn(arg)``."""
    return fn()


class RayExecutor(Executor):
    """Ray tasks (one CPU each, no retries): on the Ray instance this process is already connected
    to, else on the cluster at ``address``, else on a local instance with ``workers`` CPUs; connected
    on the first submit. ``shutdown`` disconnects (stopping a local instance) only if it connected."""

    name = "ray"
    queued_per_slot = 1

    def __init__(self, workers: int, address: str | None = None) -> None:
        self.workers, self.address = workers, address
        self._remote: Any = None   # ray.remote of _ray_call, on connecting
        self._slots: int | None = None
        self._connected_here = False
        self._refs: dict[Future, Any] = {}
        self._reaper = None  # of a local instance (see start_reaper)

    @property
    def slots(self) -> int:  # the cluster's CPUs
        self._connect()
        return self._slots or self.workers

    def _connect(self) -> None:
        if self._remote is not None:
            return
        import logging
        import os
        import signal
        import threading

        import ray

        if not ray.is_initialized():
            main = threading.current_thread() is threading.main_thread()
            handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)} if main else {}
            # log_to_driver off: the Ray processes' own lines (a metrics agent that retries under load, a
            # worker's stdout) stay in Ray's log files; raico says a failed run in its row and one line
            kwargs: dict[str, Any] = {"logging_level": logging.ERROR, "log_to_driver": False}
            # RAY_BACKEND_LOG_LEVEL is left to the user: Ray's C++ side logs to its files unless it is set, and
            # setting it prints "Set ray log level from environment variable ..." on stderr from every process
            mark = None
            if self.address is None:
                kwargs.update(num_cpus=self.workers, include_dashboard=False)
                mark, self._reaper = start_reaper()
            else:
                check_reachable(self.address)
                _token_auth_like_ray_start()
            try:
                if mark is not None:
                    os.environ[RAY_OWNER] = mark.split("=", 1)[1]  # inherited by every process of the instance
                ray.init(address=self.address or "local", **kwargs)  # "local": a new instance, even if
                # `ray start` left its address behind (plain ray.init() would connect to that cluster)
            except BaseException as e:
                _stop_reaper(self._reaper)
                self._reaper = None
                if isinstance(e, SystemExit):  # ray.init's own SIGTERM handler (in place while it starts)
                    raise Interrupted(signal.SIGTERM) from None
                if not isinstance(e, (ConnectionError, RuntimeError, ValueError)):
                    raise
                where = f"the Ray cluster at {self.address}" if self.address else "a local Ray instance"
                hint = ("" if self.address is None or os.environ.get("RAY_AUTH_MODE") else
                        " (a cluster with token authentication needs RAY_AUTH_MODE=token and its token here)")
                raise RaicoError(f"cannot start or reach {where}: {e}{hint}") from None
            finally:
                os.environ.pop(RAY_OWNER, None)
                for s, h in handlers.items():  # ray.init replaces the SIGTERM handler with sys.exit
                    signal.signal(s, h)
            self._connected_here = True
        self._remote = ray.remote(num_cpus=1, max_retries=0)(_ray_call)
        self._slots = max(1, int(ray.cluster_resources().get("CPU", self.workers)))

    def submit(self, fn, arg) -> Future:
        self._connect()
        ref = self._remote.remote(fn, arg)
        future = ref.future()
        self._refs[future] = ref
        return future

    def result(self, future: Future) -> Any:
        import ray.exceptions as rex

        self._refs.pop(future, None)
        try:
            return future.result()
        except rex.RayTaskError as e:  # the job's own exception, as it raised it
            cause = getattr(e, "cause", None)
            if isinstance(cause, BaseException):
                raise cause from None
            raise RaicoError(f"a Ray task failed: {str(e).splitlines()[-1] if str(e) else type(e).__name__}") from None
        except (rex.WorkerCrashedError, rex.NodeDiedError, rex.OutOfMemoryError, rex.ObjectLostError):
            raise WorkerLost(WORKER_DIED) from None

    def probe_nodes(self, fn: Callable[[], Any]) -> list[Any]:
        """``fn()`` run once on every alive node of the cluster that has CPUs (pinned to it), in node order."""
        import ray
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        self._connect()
        probe = ray.remote(num_cpus=0, max_retries=0)(_ray_call)
        nodes = [n["NodeID"] for n in ray.nodes() if n.get("Alive") and n.get("Resources", {}).get("CPU")]
        refs = [probe.options(scheduling_strategy=NodeAffinitySchedulingStrategy(node, soft=False)).remote(_call0, fn)
                for node in nodes]
        out = []
        for node, ref in zip(nodes, refs):
            try:
                out.append(ray.get(ref, timeout=120))
            except Exception as e:  # noqa: BLE001 - a node that cannot answer (raico missing there, ...): its name
                last = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
                raise RaicoError(f"the Ray node {node[:12]} cannot run raico's check of its code: {last}") from None
        return out

    def shutdown(self, cancel: bool = False) -> None:
        if self._remote is None:
            return
        import ray

        refs = list(self._refs.values())
        self._refs.clear()
        if cancel and refs:
            for ref in refs:
                with contextlib.suppress(Exception):
                    ray.cancel(ref, force=True)  # kills the worker that runs it
            with contextlib.suppress(Exception):  # until the killed workers are gone
                ray.wait(refs, num_returns=len(refs), timeout=10.0)
        self._remote = None
        if self._connected_here:
            self._connected_here = False
            try:
                ray.shutdown()
            finally:
                _stop_reaper(self._reaper)
                self._reaper = None


# A local Ray instance's own processes (GCS, raylet, dashboard, monitors) are started by ray.init with
# PR_SET_PDEATHSIG: they die with this process. The raylet's children (its agents, the workers) only
# notice the raylet is gone after seconds, the agents (killed while the instance starts) after half a
# minute. So a reaper -- a small process of its own, its output nowhere, immune to the terminal's
# Ctrl-C -- watches the instance: it learns the processes below this process's children that carry
# a mark in their environment (set while ray.init starts the instance), twice a second, and waits for
# EOF on its stdin, the pipe from this process that the kernel closes however this process ends,
# SIGKILL included. Then it SIGKILLs every process it learnt (unless its pid now names another process)
# and every process with the mark (workers started since it last looked).
RAY_OWNER = "RAICO_RAY_OWNER"
REAPER = r"""
import os, select, signal, sys, time
owner, mark, me = sys.argv[1], sys.argv[2].encode(), str(os.getpid())

def read(path):
    try:
        with open(path, "rb") as f:
            return f.read()
    except OSError:
        return b""

def started(pid):
    st = read("/proc/%s/stat" % pid)
    return st[st.rfind(b")") + 2:].split()[19] if st else b""

def children(pid):
    try:
        tasks = os.listdir("/proc/%s/task" % pid)
    except OSError:
        return []
    return [c.decode() for t in tasks for c in read("/proc/%s/task/%s/children" % (pid, t)).split()]

def marked(pid):
    return mark in read("/proc/%s/environ" % pid).split(b"\0")

known = {}

def learn(roots):
    todo = list(roots)
    while todo:
        p = todo.pop()
        if p == me:
            continue
        if p not in known:
            t = started(p)
            if not t:
                continue
            known[p] = t
        todo += children(p)

def kill(pid):
    try:
        os.kill(int(pid), signal.SIGKILL)
    except OSError:
        pass

while True:
    if select.select([0], [], [], 0.5)[0]:
        if not os.read(0, 4096):
            break
    else:
        learn(c for c in children(owner) if c in known or marked(c))
learn(list(known))
for _ in range(3):
    for p, t in list(known.items()):
        if started(p) == t:
            kill(p)
    for p in os.listdir("/proc"):
        if p.isdigit() and p != me and marked(p):
            kill(p)
    time.sleep(0.2)
"""


def start_reaper():
    """(the mark ``NAME=VALUE`` for the instance's environment, the reaper) on Linux, else (None, None)."""
    import os
    import secrets
    import subprocess
    import sys

    if not sys.platform.startswith("linux"):
        return None, None
    mark = f"{RAY_OWNER}={os.getpid()}-{secrets.token_hex(4)}"
    env = {k: v for k, v in os.environ.items() if k != RAY_OWNER}
    reaper = subprocess.Popen([sys.executable, "-I", "-S", "-c", REAPER, str(os.getpid()), mark],
                              stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
                              start_new_session=True)
    return mark, reaper


def _stop_reaper(reaper) -> None:
    """Close the reaper's pipe (it kills what the instance left, if anything) and reap it."""
    import subprocess

    if reaper is None:
        return
    with contextlib.suppress(OSError):
        reaper.stdin.close()
    try:
        reaper.wait(5.0)
    except subprocess.TimeoutExpired:
        reaper.kill()
        reaper.wait()


def check_reachable(address: str, timeout: float = 5.0) -> None:
    """A ``HOST:PORT`` Ray address must accept a connection: ``ray.init`` would retry an unreachable
    one for minutes, deaf to signals while it waits in Ray's C++ client. ``auto`` and ``ray://``
    addresses are Ray's to resolve."""
    import socket

    if address == "auto" or "://" in address:
        return
    host, _, port = address.rpartition(":")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as e:
        raise RaicoError(f"cannot reach the Ray cluster at {address}: {e.strerror or e}") from None


def _token_auth_like_ray_start() -> None:
    """Use token authentication if a Ray token is configured here and ``RAY_AUTH_MODE`` is unset,
    as ``ray start`` does (Ray 2.60's own check; a head started with a token requires it)."""
    try:
        from ray._private.authentication.authentication_token_setup import (
            maybe_enable_token_auth_if_token_available,
        )
    except ImportError:  # another Ray version: RAY_AUTH_MODE decides
        return
    maybe_enable_token_auth_if_token_available(warn_if_disabled=False)


def make_executor(name: str, jobs: int, address: str | None = None) -> Executor:
    """``serial``, ``process`` (``jobs`` workers; ``jobs == 1`` runs in this process) or ``ray``."""
    if name not in EXECUTORS:
        raise BadInput(f"unknown executor '{name}': choose one of {', '.join(EXECUTORS)}")
    if address is not None and name != "ray":
        raise BadInput("--address goes with --executor ray")
    if name == "ray":
        import importlib.util

        if address is not None and not address.strip():
            raise BadInput("--address: an empty address")
        host, _, port = (address or "").rpartition(":")
        if address is not None and address != "auto" and "://" not in address and not (host and port.isdigit()):
            raise BadInput(f"--address {address}: give HOST:PORT of the Ray head (its GCS port, 6379 by default), "
                           f"or auto")
        if importlib.util.find_spec("ray") is None:
            raise BadInput("--executor ray needs Ray: pip install -e '.[ray]'")
        return RayExecutor(jobs, address)
    if name == "serial" or jobs <= 1:
        return SerialExecutor()
    return ProcessExecutor(jobs)


# ----------------------------------------------------------------------------- scheduler
@dataclass
class Job:
    """One run: ``fn(arg)`` in a worker, unless ``lookup()`` (here) finds its result cached."""

    fn: Callable[[Any], Any]
    arg: Any
    label: str = ""
    lookup: Callable[[], Any] | None = None


@dataclass
class Batch:
    """What a flow yields: jobs of one kind (``plan``, ``execute``, ...); it receives their results."""

    kind: str
    jobs: list[Job]


@dataclass
class Event:
    """Progress of a flow's batch: ``done`` of ``total``; ``label`` and ``seconds`` of the run that
    just finished (None when the batch starts, its cached runs counted)."""

    flow: str
    kind: str
    done: int
    total: int
    label: str | None = None
    seconds: float | None = None


class _Flow:
    def __init__(self, name: str, gen, priority: float):
        self.name, self.gen, self.priority = name, gen, priority
        self.batch: Batch | None = None
        self.results: list = []
        self.done = 0
        self.added = time.perf_counter()
        self.started: float | None = None  # when its first job was handed to the executor


class Scheduler:
    """Runs flows on one executor; see the module's docstring. A context manager: an exception
    inside (an interrupt, a failed run) cancels the executor's work at once, then ``on_abort()``
    (removing the killed workers' temporary folders)."""

    def __init__(self, executor: Executor, progress: Callable[[Event], None] | None = None,
                 on_abort: Callable[[], Any] | None = None) -> None:
        self.executor, self.progress, self.on_abort = executor, progress, on_abort
        self.finished = 0  # runs finished in this call, cached ones included
        self._seq = itertools.count()
        self._ready: list = []  # heap of (priority, seq, key, job)
        self._waiting: dict[Any, list[tuple[_Flow, int]]] = {}  # job key -> the batch slots it fills
        self._inflight: dict[Future, tuple[int, Any, Job]] = {}
        self._flows: dict[str, _Flow] = {}
        self._open = 0
        self._completed: deque[tuple[str, Any]] = deque()

    def __enter__(self) -> Scheduler:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.abort()

    def abort(self) -> None:
        """Stop at once: nothing more is submitted, the executor's jobs are cancelled and killed."""
        self._ready.clear()
        self._inflight.clear()
        self.executor.shutdown(cancel=True)
        if self.on_abort is not None:
            self.on_abort()

    def add(self, name: str, flow, priority: float = 0) -> None:
        """Start ``flow`` (a generator of batches): its first batch's lookups run now."""
        if name in self._flows:
            raise ValueError(f"flow {name} was added twice")
        f = self._flows[name] = _Flow(name, flow, priority)
        self._open += 1
        self._step(f, None)

    def started(self, name: str) -> float:
        """``time.perf_counter()`` when the flow's first job was submitted (if all were cached: when
        the flow was added)."""
        flow = self._flows[name]
        return flow.started if flow.started is not None else flow.added

    def run(self) -> Iterator[tuple[str, Any]]:
        """``(name, value)`` of each flow as it returns, until all have."""
        while True:
            self._dispatch()  # before the caller works on a completed flow (workers stay busy meanwhile)
            while self._completed:
                yield self._completed.popleft()
            if not self._open:
                return
            self._dispatch()
            if not self._inflight:
                raise RuntimeError("scheduler: flows wait but no job is ready")  # a flow bug
            done = self.executor.wait(list(self._inflight))
            for future in sorted(done, key=lambda f: self._inflight[f][0]):
                _, key, job = self._inflight.pop(future)
                seconds, value = self.executor.result(future)
                self._finish(key, job, value, seconds)

    # -- internals
    def _step(self, flow: _Flow, value) -> None:
        """Send ``value`` (the last batch's results) into ``flow``; queue its next batch."""
        try:
            batch = flow.gen.send(value)
        except StopIteration as stop:
            self._open -= 1
            self._completed.append((flow.name, stop.value))
            return
        flow.batch, flow.results, flow.done = batch, [None] * len(batch.jobs), 0
        for i, job in enumerate(batch.jobs):
            cached = job.lookup() if job.lookup is not None else None
            if cached is not None:
                flow.results[i] = cached
                flow.done += 1
                self.finished += 1
                continue
            key = _job_key(job)
            if key in self._waiting:  # the same run is already queued or running: it fills both
                self._waiting[key].append((flow, i))
                continue
            self._waiting[key] = [(flow, i)]
            heapq.heappush(self._ready, (flow.priority, next(self._seq), key, job))
        if self.progress:
            self.progress(Event(flow.name, batch.kind, flow.done, len(batch.jobs)))
        if flow.done == len(batch.jobs):
            self._step(flow, flow.results)

    def _dispatch(self) -> None:
        depth = self.executor.slots * (1 + self.executor.queued_per_slot)
        while self._ready and len(self._inflight) < depth:
            _, seq, key, job = heapq.heappop(self._ready)
            now = time.perf_counter()
            for flow, _ in self._waiting[key]:
                flow.started = flow.started or now
            self._inflight[self.executor.submit(timed, (job.fn, job.arg))] = (seq, key, job)

    def _finish(self, key, job: Job, value, seconds: float) -> None:
        complete = []
        for flow, i in self._waiting.pop(key):
            flow.results[i] = value
            flow.done += 1
            self.finished += 1
            if self.progress:
                self.progress(Event(flow.name, flow.batch.kind, flow.done, len(flow.results), job.label, seconds))
            if flow.done == len(flow.results) and flow not in complete:
                complete.append(flow)
        for flow in complete:
            self._step(flow, flow.results)


def _job_key(job: Job) -> Any:
    """Identical jobs (same function, equal argument) share one run; unhashable ones never do."""
    try:
        key = (job.fn, job.arg)
        hash(key)
        return key
    except TypeError:
        return object()


def run_flow(executor: Executor, flow, progress: Callable[[Event], None] | None = None,
             on_abort: Callable[[], Any] | None = None, scheduled: int | None = None) -> Any:
    """Run one flow to its end on ``executor`` (shut down afterwards); an interrupt learns how
    many runs had finished (of ``scheduled``)."""
    with executor, Scheduler(executor, progress, on_abort) as sched:
        try:
            sched.add("flow", flow)
            return next(value for _, value in sched.run())
        except Interrupted as e:  # says how many runs are kept (not what one of them kept)
            e.finished, e.scheduled, e.note = sched.finished, scheduled, None
            raise


# ----------------------------------------------------------------------------- a stream of many runs
TASK_TARGET_S = 1.0   # runs shorter than this are batched into tasks of about this long
MAX_BATCH = 256       # runs in one task at most
RESUBMITS = 3         # times a task whose worker died is submitted again


@dataclass
class Item:
    """One run of a :func:`stream`: ``fn(arg)`` in a worker, unless ``lookup()`` (here, before anything
    is submitted) finds its result cached; ``label`` names it in progress lines."""

    fn: Callable[[Any], Any]
    arg: Any
    label: str = ""
    lookup: Callable[[], Any] | None = None
    tag: Any = None   # the caller's, carried to its Done (not sent to the worker)


@dataclass
class Done:
    """A finished run of a :func:`stream`: its value, or (``error``) the one line of what it raised; its
    wall seconds in the worker (0 for a cached one); where it ran (``node``, from the probe)."""

    item: Item
    value: Any = None
    seconds: float = 0.0
    cached: bool = False
    error: str | None = None
    node: Any = None


def _run_batch(payload: tuple[list[tuple[Callable[[Any], Any], Any]], Callable[[], Any] | None]) -> tuple[Any, list]:
    """The one task of a stream, in a worker: ``(probe(), [(seconds, error or None, value) per run])``.
    A run that raises is that run's error (one line); the batch's other runs go on."""
    calls, probe = payload
    out = []
    for fn, arg in calls:
        t0 = time.perf_counter()
        try:
            value, error = fn(arg), None
        except Exception as e:  # noqa: BLE001 - one run's failure, reported as its own; an interrupt propagates
            value, error = None, " ".join(str(e).split()) or type(e).__name__
            error = f"{type(e).__name__}: {error}" if not isinstance(e, RaicoError) else error
        out.append((time.perf_counter() - t0, error, value))
    return (probe() if probe is not None else None), out


class VersionMismatch(RaicoError):
    """A worker node runs other code than this process (the head's): its results are refused."""


def stream(executor: Executor, items, *, total: int | None = None, probe: Callable[[], Any] | None = None,
           target_s: float = TASK_TARGET_S, batch: int | None = None,
           notify: Callable[[str], None] | None = None) -> Iterator[Done]:
    """Run ``items`` (any iterable, consumed as it goes: a lazy grid's first run starts before the grid is
    enumerated) on ``executor``; yield a :class:`Done` per run as it finishes (cached runs at once).

    Each item's ``lookup`` runs here before anything of it is submitted. Runs are sent as tasks of one
    or more (a task of about ``target_s`` seconds, from the mean time of the runs so far; at most a
    quarter of what is left per slot, so the last tasks still spread over every slot); at most the
    executor's slots (plus its queue) of tasks are out at once, so memory is bounded by that, not by
    the number of items. A task whose worker died (a killed process, a Ray node gone) is submitted again
    (up to :data:`RESUBMITS` times; its runs that finished are in the cache by then and are found, not
    recomputed). ``probe`` (a module-level function of no argument) is called in each worker with each
    task, and on every node of a Ray cluster first: a worker whose answer's ``version`` (its second value)
    differs from this process's is :class:`VersionMismatch`, naming the node (its first value). ``batch``
    fixes the runs per task (else adaptive; always 1 on the serial executor); ``notify`` hears a line when
    a task is submitted again."""
    mine = probe() if probe is not None else None
    if probe is not None and hasattr(executor, "probe_nodes") and getattr(executor, "address", None):
        for answer in executor.probe_nodes(probe):
            check_version(answer, mine)
    source = iter(items)
    exhausted = False
    inflight: dict[Future, tuple[list[Item], int]] = {}
    run_s, timed_runs, pulled = 0.0, 0, 0
    batching = not isinstance(executor, SerialExecutor)

    def batch_size() -> int:
        if batch is not None:
            return max(1, batch)
        if not batching or not timed_runs:
            return 1
        k = int(target_s / max(run_s / timed_runs, 1e-3))
        if total is not None:
            k = min(k, max(1, (total - pulled) // (4 * max(1, executor.slots))))
        return max(1, min(k, MAX_BATCH))

    def submit(sent: list[Item], attempt: int) -> None:
        future = executor.submit(_run_batch, ([(it.fn, it.arg) for it in sent], probe))
        inflight[future] = (sent, attempt)

    def room() -> bool:   # (a Ray executor connects when asked its slots: not before a run is to be submitted)
        return not inflight or len(inflight) < executor.slots * (1 + executor.queued_per_slot)

    while True:
        while not exhausted and room():
            runs: list[Item] = []
            k = batch_size()
            while len(runs) < k:
                try:
                    item = next(source)
                except StopIteration:
                    exhausted = True
                    break
                pulled += 1
                value = item.lookup() if item.lookup is not None else None
                if value is not None:
                    yield Done(item, value, cached=True)
                else:
                    runs.append(item)
            if runs:
                submit(runs, 0)
        if not inflight:
            return
        for future in executor.wait(list(inflight)):
            sent, attempt = inflight.pop(future)
            try:
                node, results = executor.result(future)
            except WorkerLost:
                if attempt >= RESUBMITS:
                    raise
                if notify is not None:
                    notify(f"a worker died with {len(sent)} run{'s' if len(sent) > 1 else ''} in flight: "
                           f"{'they run' if len(sent) > 1 else 'it runs'} again elsewhere")
                submit(sent, attempt + 1)
                continue
            if probe is not None:
                check_version(node, mine)
            for item, (seconds, error, value) in zip(sent, results):
                run_s += seconds
                timed_runs += 1
                yield Done(item, value, seconds, False, error, node)


def check_version(answer: Any, mine: Any) -> None:
    """``answer`` and ``mine`` are ``(node, version)``: a different version is :class:`VersionMismatch`."""
    if answer is None or mine is None or answer[1] == mine[1]:
        return
    raise VersionMismatch(f"node {answer[0]} runs code version {answer[1]}, this head {mine[1]}: its results are "
                          f"refused (install the same raico on every node)")
