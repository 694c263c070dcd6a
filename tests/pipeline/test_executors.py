"""Executors and the scheduler of ``raico reproduce`` (``raico/pipeline/engine/executors.py``): serial, process and
Ray give the same results; a failed job stops the rest; a real figure on a local Ray instance equals
the process pool's; one progress line per finished run in a log.

Module level imports stay light: pool and Ray workers import this module for its job functions."""

from __future__ import annotations

import json
import os
import re
import time
from pathlib import Path

import pytest

EXECUTORS = ["serial", "process", "ray"]


# ----------------------------------------------------------------------------- job functions (run in workers)
def _square(x: int) -> int:
    return x * x


def _add(args: tuple[int, int]) -> int:
    return args[0] + args[1]


def _never(x):
    raise AssertionError("a job answered by its lookup was submitted")


SLEEP_S = 120  # a sleeping job's length: far beyond any start-up of the executors, even on a loaded machine


def _fail_or_sleep(args: tuple[str, int, bool]) -> int:
    """Job 0 fails (once job 1 has started, if ``wait``); the others mark that they started, then sleep."""
    folder, i, wait = args
    if i == 0:
        deadline = time.monotonic() + 20
        while wait and not Path(folder, "started1").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        raise ValueError("job 0 failed")
    Path(folder, f"started{i}").write_text("")
    time.sleep(SLEEP_S)
    Path(folder, f"finished{i}").write_text("")
    return i


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def ray_instance():
    """One local Ray instance with 2 CPUs for this module (the executor uses it, and leaves it running)."""
    import signal

    ray = pytest.importorskip("ray")
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="ERROR")
    for s, h in handlers.items():
        signal.signal(s, h)
    yield ray
    ray.shutdown()


def executor(name: str, request):
    from raico.pipeline.engine.executors import make_executor

    if name == "ray":
        request.getfixturevalue("ray_instance")
    return make_executor(name, 2)


# ----------------------------------------------------------------------------- executors and scheduler
def _flow(n: int, cached: dict[int, int]):
    """Squares (some answered by a lookup), then sums of neighbours that depend on them."""
    from raico.pipeline.engine.executors import Batch, Job

    squares = yield Batch("square", [Job(_never, i, f"{i}^2", lambda i=i: cached[i]) if i in cached
                                     else Job(_square, i, f"{i}^2") for i in range(n)])
    sums = yield Batch("sum", [Job(_add, (a, b), f"{a}+{b}") for a, b in zip(squares, squares[1:])]
                       + [Job(_add, (squares[0], squares[1]), "again")])  # identical to the first: one run
    return squares, sums


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n == "ray" else n  # Ray: 5 s
                                  for n in EXECUTORS])
def test_executors_give_the_same_results(name, request):
    from raico.pipeline.engine.executors import Scheduler

    events = []
    with executor(name, request) as ex, Scheduler(ex, events.append) as sched:
        sched.add("a", _flow(6, {2: 4, 5: 25}), priority=1)
        sched.add("b", _flow(3, {}), priority=0)
        out = dict(sched.run())
        assert sched.finished == 6 + 6 + 3 + 3
    squares = [i * i for i in range(6)]
    assert out["a"] == (squares, [a + b for a, b in zip(squares, squares[1:])] + [1])
    assert out["b"] == ([0, 1, 4], [1, 5, 1])
    a_squares = [e for e in events if (e.flow, e.kind) == ("a", "square")]
    assert (a_squares[0].done, a_squares[0].label) == (2, None)  # the batch starts with its 2 cached runs
    assert sorted(e.done for e in a_squares[1:]) == [3, 4, 5, 6] and all(e.seconds >= 0 for e in a_squares[1:])
    a_sums = [e.label for e in events if (e.flow, e.kind) == ("a", "sum")]  # "again" ran once, as "0+1"
    assert a_sums[0] is None and sorted(a_sums[1:]) == ["0+1", "0+1", "1+4", "16+25", "4+9", "9+16"]


@pytest.mark.parametrize("name", EXECUTORS)
def test_a_failing_job_stops_the_rest(name, request, tmp_path):
    from raico.pipeline.engine.executors import Batch, Job, run_flow

    def flow():
        yield Batch("run", [Job(_fail_or_sleep, (str(tmp_path), i, name != "serial")) for i in range(6)])

    t0 = time.monotonic()
    with pytest.raises(ValueError, match="^job 0 failed$"):
        run_flow(executor(name, request), flow())
    assert time.monotonic() - t0 < SLEEP_S  # the failure did not wait for the sleeping jobs
    assert not list(tmp_path.glob("finished*"))  # they were stopped, not awaited
    started = sorted(p.name for p in tmp_path.glob("started*"))
    if name == "serial":
        assert started == []
    else:  # 2 slots and 2 queued: job 1 ran and was killed, job 2 (queued) may have started on the freed worker
        # before the abort and was killed too; jobs 3-5 never started
        assert started in (["started1"], ["started1", "started2"]), started


def test_bad_executor_values_are_one_line(tmp_path):
    from typer.testing import CliRunner

    from raico.pipeline.interface.cli import app

    for args, message in ((["--executor", "threads"], "unknown executor 'threads': choose one of serial, process, ray"),
                          (["--address", "head:6379"], "--address goes with --executor ray"),
                          (["--executor", "ray", "--address", " "], "--address: an empty address"),
                          (["--executor", "ray", "--address", "head"], "--address head: give HOST:PORT of the Ray "
                                                                       "head (its GCS port, 6379 by default), or auto")):
        res = CliRunner().invoke(app, ["reproduce", "--figure", "fig3.2a", *args, "--artifacts", str(tmp_path)])
        assert res.exit_code == 2 and res.stderr.strip() == f"raico: error: {message}", res.stderr
    assert not any(tmp_path.iterdir())


def test_unreachable_ray_address_is_one_error_at_once():
    from raico.pipeline.engine.executors import check_reachable
    from raico.pipeline.errors import RaicoError

    t0 = time.monotonic()
    with pytest.raises(RaicoError, match=r"^cannot reach the Ray cluster at 127\.0\.0\.1:1: "):
        check_reachable("127.0.0.1:1")  # ray.init would retry for minutes, deaf to Ctrl-C
    assert time.monotonic() - t0 < 10


def test_reproduce_help_lists_every_experiment_and_executor():
    from typer.testing import CliRunner

    from raico.pipeline.interface.cli import app
    from raico.thesis.reproduce import ALL_IDS

    text = " ".join(CliRunner().invoke(app, ["reproduce", "--help"]).output.split())
    assert all(i in text for i in ALL_IDS) and all(e in text for e in ("serial", "process", "ray", "--address"))


def test_work_order_is_longest_first():
    from raico.thesis.reproduce import ALL_IDS, work_order

    order = work_order(["fig3.2a", "fig4.1/4.2", "fig3.2c", "fig3.2a", "fig4.3"])
    assert order == ["fig4.3", "fig4.1/4.2", "fig3.2c", "fig3.2a"] and sorted(work_order(ALL_IDS)) == sorted(ALL_IDS)


# ----------------------------------------------------------------------------- a real figure on Ray
def _quick_runs() -> int:
    """fig3.2a's plan runs with --quick (two initial states per variant; the experiment says which)."""
    from raico.thesis.figures import EXPERIMENTS

    exp = EXPERIMENTS["fig3.2a"]
    return sum(v.seed_count(exp.seeds, True) for v in exp.variants)


N = _quick_runs()
PROGRESS = re.compile(rf"raico: fig3\.2a plan (\d+)/{N} done \((iLQG|AICO|R-AICO a=1|R-AICO a=10|R-AICO adaptive "
                      r"\(a0=1\)) seed [01], \d+\.\d s\)")


def _reproduce(root: Path, *args: str):
    from typer.testing import CliRunner

    from raico.pipeline.interface.cli import app

    res = CliRunner().invoke(app, ["reproduce", "--figure", "fig3.2a", "--quick", "--no-record", "--json",
                                   "--artifacts", str(root), *args])
    assert res.exit_code == 0, res.output
    return res


def _untimed(obj):
    """``obj`` without its wall times (``wall_time_s``, ``wall_time_median_s``: they differ run to run)."""
    if isinstance(obj, dict):
        return {k: _untimed(v) for k, v in obj.items() if not k.startswith("wall_time")}
    if isinstance(obj, list):
        return [_untimed(v) for v in obj]
    return obj


def _claims(root: Path) -> dict:
    """The figure's claims.json, its paths relative to ``root``."""
    return _untimed(json.loads((root / "report-quick" / "fig3.2a" / "claims.json").read_text()
                               .replace(str(root), "ROOT")))


def _call(root: Path) -> dict:
    """The whole reproduce call's timing (``timings.json``), checked against the report README's line."""
    from raico.thesis.reproduce import CALL, call_line

    call = json.loads((root / "report-quick" / "timings.json").read_text())[CALL]
    assert call_line(call) in (root / "report-quick" / "README.md").read_text()
    return call


def _plans(root: Path) -> dict[str, dict]:
    """Key -> (status, metrics) of every cached plan under ``root``."""
    out = {}
    for p in sorted((root / "plan").iterdir()):
        if not p.name.startswith("."):
            meta = json.loads((p / "meta.json").read_text())
            out[p.name] = {"status": meta["status"], "metrics": _untimed(meta["metrics"])}
    return out


@pytest.mark.slow  # starts a Ray instance: 5-9 s
def test_ray_reproduces_the_process_pool_with_one_progress_line_per_run(ray_instance, tmp_path):
    by_process = _reproduce(tmp_path / "process", "--executor", "process", "--jobs", "2")
    lines = [ln for ln in by_process.stderr.splitlines() if ln.strip()]
    progress = [ln for ln in lines if PROGRESS.fullmatch(ln)]
    assert sorted(int(PROGRESS.fullmatch(ln).group(1)) for ln in progress) == list(range(1, N + 1)), lines
    assert len(lines) == N + 2 and lines[-2].startswith(f"fig3.2a: {N} runs (0 cached) in ")  # and nothing else
    assert lines[-1] == f"raico: report: {tmp_path / 'process' / 'report-quick' / 'README.md'}"
    call = _call(tmp_path / "process")  # the whole call: wall time, and CPU of this process and its workers
    assert (call["figures"], call["runs"], call["cached_runs"], call["jobs"]) == (1, N, 0, 2)
    assert 0 < call["wall_time_s"] and call["cpu_time_s"] > 0.5  # the workers' planning, not only this process's
    by_ray = _reproduce(tmp_path / "ray", "--executor", "ray", "--quiet")
    assert _call(tmp_path / "ray")["cpu_time_s"] is None  # Ray's workers are not this process's children
    assert by_ray.stderr == ""  # --quiet: no progress lines
    plans = _plans(tmp_path / "process")
    assert len(plans) == N and _plans(tmp_path / "ray") == plans
    assert _claims(tmp_path / "ray") == _claims(tmp_path / "process")
    again = _reproduce(tmp_path / "ray", "--executor", "ray")  # cached: nothing submitted, no progress line
    assert json.loads(again.stdout.splitlines()[-1])["cached_runs"] == N
    assert [ln for ln in again.stderr.splitlines() if ln.strip()][-2].startswith(f"fig3.2a: {N} runs ({N} cached)")
    assert not any(PROGRESS.fullmatch(ln) for ln in again.stderr.splitlines())
    assert _call(tmp_path / "ray")["cached_runs"] == 0  # all cached: the call that computed them stays


def test_call_line_compares_a_complete_call_with_the_reproduce_target():
    """A call over every figure from an empty cache is held against the 600 s target (met, or missed by
    how much); any other call (some figures, a warm cache) gets no verdict."""
    from raico.thesis.reproduce import REPRODUCE_TARGET_S, call_line

    base = {"figures": 11, "runs": 569, "cached_runs": 6, "cpu_time_s": 1255.0, "main_cpu_time_s": 27.4,
            "jobs": 2, "when": "2026-11-24T21:20:42Z", "load_average_1min": 1.89}
    assert REPRODUCE_TARGET_S == 600.0
    over = call_line({**base, "wall_time_s": 649.0, "from_empty_cache": True})
    assert over.endswith("target of at most 600 s on the 2-core machine: missed by 49 s (8%).")
    under = call_line({**base, "wall_time_s": 571.5, "from_empty_cache": True})
    assert under.endswith(": met (28 s to spare).")
    for call in ({**base, "wall_time_s": 649.0, "from_empty_cache": False}, {**base, "wall_time_s": 649.0}):
        assert "target" not in call_line(call)


def test_cache_is_empty_until_a_stage_holds_an_entry(tmp_path):
    """``Cache.is_empty``: an empty or missing root, a report folder or stray files are empty; one key folder in
    a stage is not."""
    from raico.pipeline.engine.cache import Cache

    assert Cache(tmp_path / "missing").is_empty()
    (tmp_path / "report").mkdir()
    (tmp_path / "plan").mkdir()
    (tmp_path / "plan" / "notes.txt").write_text("x")
    assert Cache(tmp_path).is_empty()
    (tmp_path / "plan" / "0123456789abcdef").mkdir()
    assert not Cache(tmp_path).is_empty()


@pytest.mark.slow  # starts a Ray instance: 5-9 s
def test_ray_quiet_prints_nothing_at_all(tmp_path):
    """``raico reproduce --executor ray --quiet`` in its own process: not even Ray's own log lines (its C++ side
    writes to the process's stderr, which a CliRunner does not see)."""
    import subprocess
    import sys

    pytest.importorskip("ray")
    raico = str(Path(sys.executable).with_name("raico"))
    res = subprocess.run([raico, "reproduce", "--figure", "fig3.2a", "--quick", "--executor", "ray", "--jobs", "2",
                          "--quiet", "--no-record", "--artifacts", str(tmp_path)], capture_output=True, text=True,
                         timeout=300, env={k: v for k, v in os.environ.items() if not k.startswith("RAY_")})
    assert res.returncode == 0, res.stderr
    assert res.stderr == "" and res.stdout == ""
