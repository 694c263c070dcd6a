"""Faults and bad input: signals and child processes, tamper-evident entries,
atomic report files, OS errors as one line, bounded inputs, SIGKILL / corruption / concurrency per
stage. Real processes where the fault is about processes; injected OS errors where the machine
cannot produce them on demand (a full disk, a read-only folder for root).

Module level imports stay light: pool workers of ``test_sweep_*`` import this module."""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from tests.damage import flip_byte, parents

REPO = Path(__file__).resolve().parents[2]
RAICO = str(Path(sys.executable).with_name("raico"))
ERROR = re.compile(r"raico: error: \S.*")


def lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


def one_error_line(text: str) -> str:
    """The single non-empty line of ``text``, which must be a ``raico: error:`` line."""
    ls = lines(text)
    assert len(ls) == 1 and ERROR.fullmatch(ls[0]), text
    return ls[0]


def children(pid: int) -> list[int]:
    """Pids whose parent is ``pid`` (Linux /proc)."""
    return [c for c, pp in parents().items() if pp == pid]


def running(pid: int) -> bool:
    """True if ``pid`` exists and is not a zombie (a zombie runs nothing; init reaps it)."""
    try:
        st = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return st[st.rfind(")") + 2] not in "ZX"


def tmp_folders(root: Path) -> list[Path]:
    return sorted(root.rglob(".tmp-*")) + sorted(root.rglob(".*.tmp*"))


def valid_entries(root: Path, stage: str | None = None) -> list:
    from raico.pipeline.engine.cache import Cache

    return [r for r in Cache(root).list(stage) if r.valid]


def cli(*args, env: dict | None = None):
    from typer.testing import CliRunner

    from raico.pipeline.interface.cli import app

    return CliRunner().invoke(app, [str(a) for a in args], env=env)


linux_only = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")


# ============================================================================= 1. signals, children
def _wait_for(cond, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def test_sigint_during_imports_is_one_line(tmp_path):
    proc = subprocess.Popen([RAICO, "babble", "--plant", "pendulum", "--artifacts", str(tmp_path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(0.4)  # python is loading the modules (typer, numpy, drake): no traceback from there
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert one_error_line(err).startswith("raico: error: interrupted by SIGINT")
    assert not (tmp_path / "babble").exists() or not list((tmp_path / "babble").iterdir())


@pytest.mark.slow  # runs a figure or Ray in child processes: 2-11 s
@linux_only
def test_sigterm_reproduce_exits_143_and_no_child_remains(tmp_path):
    """The acceptance check: ``kill -TERM`` on a running ``raico reproduce --figure fig3.2a --quick``."""
    proc = subprocess.Popen([RAICO, "reproduce", "--figure", "fig3.2a", "--quick", "--jobs", "2",
                             "--artifacts", str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen: set[int] = set()

    def computing() -> bool:  # both workers started and one of them writes a plan
        seen.update(children(proc.pid))
        return (len(seen) >= 3 and bool(list((tmp_path / "plan").glob(".tmp-*")))) or proc.poll() is not None

    _wait_for(computing, 120, "the workers")
    assert proc.poll() is None, "reproduce ended before it could be interrupted"
    seen.update(children(proc.pid))  # resource tracker + 2 workers
    t0 = time.monotonic()
    proc.terminate()
    out, err = proc.communicate(timeout=30)
    elapsed = time.monotonic() - t0
    assert proc.returncode == 143, err
    line = one_error_line(err)
    assert re.fullmatch(r"raico: error: interrupted by SIGTERM; \d+ runs had finished and are cached \(the next "
                        r"call reuses them\); the interrupted runs left no partial artifact", line), line
    assert elapsed < 10, elapsed
    time.sleep(1.0)
    assert [p for p in seen if running(p)] == []
    assert tmp_folders(tmp_path) == []
    n = int(re.search(r"(\d+) runs had finished", line).group(1))
    assert len(valid_entries(tmp_path, "plan")) >= n


def _sleep_job(args):
    """A pool job for the sweep tests: mark that it runs (its pid), then sleep."""
    marker, seconds = args
    Path(marker).write_text(str(os.getpid()))
    time.sleep(seconds)
    return {}


SWEEP_PARENT = textwrap.dedent("""
    import sys
    from pathlib import Path
    from raico.pipeline.lifecycle import Interrupted, install_signal_handlers, stop_resource_tracker
    from raico.pipeline.engine.executors import Batch, Job, make_executor, run_flow
    from tests.pipeline.test_faults import _sleep_job

    install_signal_handlers()
    root = Path(sys.argv[1])
    jobs = [(str(root / f"job{i}"), 60) for i in range(4)]
    def flow():
        return (yield Batch("run", [Job(_sleep_job, j) for j in jobs]))

    try:
        run_flow(make_executor("process", 2), flow(), scheduled=len(jobs))
    except Interrupted as e:
        msg, code = e.message(), e.exit_code
        del e
        print("raico: error: " + msg, file=sys.stderr)
        stop_resource_tracker()
        sys.exit(code)
""")


@linux_only
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL], ids=["SIGINT", "SIGKILL"])
def test_sweep_workers_die_with_the_parent(tmp_path, sig):
    """Ctrl-C sent to the parent only stops the sweep at once (workers terminated and reaped,
    one line saying how many runs finished); SIGKILL of the parent takes its workers along
    (``PR_SET_PDEATHSIG``), and the resource tracker with them."""
    proc = subprocess.Popen([sys.executable, "-c", SWEEP_PARENT, str(tmp_path)], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for(lambda: len(list(tmp_path.glob("job*"))) >= 2 or proc.poll() is not None, 60, "the jobs")
    assert proc.poll() is None, proc.stderr.read()
    kids = children(proc.pid)
    workers = {int(p.read_text()) for p in tmp_path.glob("job*")}
    assert workers <= set(kids) and len(kids) == 3  # 2 workers + multiprocessing's resource tracker
    t0 = time.monotonic()
    os.kill(proc.pid, sig)
    out, err = proc.communicate(timeout=30)
    if sig == signal.SIGINT:
        assert proc.returncode == 130 and time.monotonic() - t0 < 5
        assert one_error_line(err) == ("raico: error: interrupted by SIGINT; 0 of 4 runs had finished and are "
                                       "cached (the next call reuses them); the interrupted runs left no "
                                       "partial artifact")
        assert [p for p in kids if Path(f"/proc/{p}").exists()] == []  # reaped, not even zombies
    else:
        assert proc.returncode == -signal.SIGKILL and err == ""
        _wait_for(lambda: not any(running(p) for p in kids), 1.0, "the workers to die with their parent")


# ============================================================================= 2. atomic files, damaged report
def test_atomic_write_keeps_the_old_file_when_the_write_fails(tmp_path, monkeypatch):
    from raico.pipeline.engine.atomic import atomic_path, write_file_atomic

    target = tmp_path / "claims.json"
    write_file_atomic(target, '{"old": 1}\n')
    with pytest.raises(OSError) as info, atomic_path(target) as tmp:
        tmp.write_text('{"new": ')  # half written, then the disk fills
        raise OSError(errno.ENOSPC, "No space left on device")
    assert info.value.filename == str(target) and info.value.errno == errno.ENOSPC
    assert target.read_text() == '{"old": 1}\n' and sorted(p.name for p in tmp_path.iterdir()) == ["claims.json"]
    write_file_atomic(target, b"\x00new")
    assert target.read_bytes() == b"\x00new" and len(list(tmp_path.iterdir())) == 1


def test_damaged_report_file_is_skipped_with_a_warning_and_rebuilt(tmp_path):
    from raico.pipeline.engine.ui import Reporter
    from raico.thesis.reproduce import cached_report, write_readme

    root = tmp_path / "report-quick"
    good = {"figure": "fig3.2a", "description": "arm", "claims": [
        {"figure": "fig3.2a", "claim": "R-AICO converges", "criterion": "c", "measured": "m", "verdict": "holds"}]}
    (root / "fig3.2a").mkdir(parents=True)
    (root / "fig3.2a" / "claims.json").write_text(json.dumps(good))
    (root / "fig3.2b").mkdir()
    (root / "fig3.2b" / "claims.json").write_text('{"figure": "fig3.2b", "claims": [{"claim": "R-AICO conv')

    class Collect(Reporter):
        said: list[str] = []

        def say(self, message: str) -> None:
            self.said.append(message)

    rep = Collect(quiet=True)
    write_readme(root, rep)
    readme = (root / "README.md").read_text()
    assert "### fig3.2a: arm" in readme and "fig3.2b" not in readme.split("## Deviations")[0]
    assert len(rep.said) == 1 and rep.said[0].startswith(f"raico: warning: {root / 'fig3.2b' / 'claims.json'} "
                                                         "is damaged (not valid JSON")
    assert rep.said[0].endswith("`raico reproduce --figure fig3.2b` rebuilds it")
    # the figure's own run does not trust it either: rebuilt, whatever its stamp says
    (root / "fig3.2b" / "figure.png").write_bytes(b"png")
    (root / "fig3.2b" / "report_key.txt").write_text("k\n")
    assert cached_report(root / "fig3.2b", "k") is None
    (root / "fig3.2b" / "claims.json").write_text(json.dumps({**good, "figure": "fig3.2b"}))
    assert cached_report(root / "fig3.2b", "k")["figure"] == "fig3.2b"


# ============================================================================= 3. OS errors
@pytest.mark.parametrize("where, message", [
    ("file/below", "artifacts folder {tmp}/file/below lies below {tmp}/file, which is a file, not a folder"),
    ("file/below/deeper", "artifacts folder {tmp}/file/below/deeper lies below {tmp}/file, which is a file, "
                          "not a folder"),
])
def test_artifacts_below_a_file(tmp_path, where, message):
    (tmp_path / "file").write_text("x")
    res = cli("babble", "--plant", "pendulum", "--artifacts", tmp_path / where)
    assert res.exit_code == 5
    assert one_error_line(res.stderr) == "raico: error: " + message.replace("{tmp}", str(tmp_path))


@pytest.mark.parametrize("err", [errno.EROFS, errno.EACCES, errno.ENOSPC])
def test_unwritable_artifacts_folder_is_one_line(tmp_path, monkeypatch, err):
    """Read-only, unwritable or full at the first folder the cache makes (injected: root writes anyway)."""
    real = Path.mkdir

    def mkdir(self, *a, **k):
        if str(self).startswith(str(tmp_path / "a")):
            raise OSError(err, os.strerror(err), str(self))
        return real(self, *a, **k)

    monkeypatch.setattr(Path, "mkdir", mkdir)
    res = cli("babble", "--plant", "pendulum", "--episodes", 1, "--duration", 0.2, "--artifacts", tmp_path / "a")
    assert res.exit_code == 5
    cause = os.strerror(err)
    assert one_error_line(res.stderr) == (f"raico: error: cannot write artifact babble/{_babble_key()}: "
                                          f"{tmp_path / 'a' / 'babble'}: {cause[0].lower() + cause[1:]}")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_artifacts_folder_real(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o555)
    res = cli("babble", "--plant", "pendulum", "--episodes", 1, "--duration", 0.2, "--artifacts", ro)
    assert res.exit_code == 5 and "permission denied" in one_error_line(res.stderr)


def _babble_key() -> str:
    from raico.pipeline.engine import runner
    from raico.stages.babble import BabbleConfig

    return runner.prepare(None, "babble", BabbleConfig(plant="pendulum", episodes=1, duration=0.2))[-1]


def test_full_disk_in_numpy_writer_publishes_nothing(tmp_path, monkeypatch):
    import numpy as np

    real = np.savez

    def full(f, **arrays):
        real(f, **arrays)
        raise OSError(errno.ENOSPC, "No space left on device")  # like zipfile's write: no file name

    monkeypatch.setattr(np, "savez", full)
    res = cli("babble", "--plant", "pendulum", "--episodes", 1, "--duration", 0.2, "--artifacts", tmp_path)
    assert res.exit_code == 5
    key = _babble_key()
    assert one_error_line(res.stderr) == (f"raico: error: cannot write artifact babble/{key}: "
                                          f"{tmp_path / 'babble' / key}: no space left on device; nothing was cached")
    assert tmp_folders(tmp_path) == [] and valid_entries(tmp_path) == []


def test_full_disk_in_mcap_writer_keeps_the_data(tmp_path, monkeypatch):
    import raico.pipeline.recordings.mcap_io as mcap_io

    class FullWriter(mcap_io.Writer):
        def finish(self):
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(mcap_io, "Writer", FullWriter)
    res = cli("babble", "--plant", "pendulum", "--episodes", 1, "--duration", 0.2, "--artifacts", tmp_path)
    assert res.exit_code == 5
    key = _babble_key()
    assert one_error_line(res.stderr) == (
        f"raico: error: cannot write the derived files (recording) of babble/{key}: "
        f"{tmp_path / 'babble' / key / 'trajectory.mcap'}: no space left on device; its data stay cached and "
        f"the next call writes them")
    assert tmp_folders(tmp_path) == [] and [r.key for r in valid_entries(tmp_path)] == [key]
    assert not (tmp_path / "babble" / key / "recording.rrd").exists()  # derived files move in together


# ============================================================================= 4. bounds, empty strings
@pytest.mark.parametrize("args, code, message", [
    (["babble", "--plant", "pendulum", "--dt", "1e-12"], 2,
     "duration / dt gives 1e+12 samples per episode; at most 1,000,000 (raise dt or shorten the duration)"),
    (["babble", "--plant", "nao", "--episodes", "10000"], 2,
     "episodes x samples per episode = 5.01e+06; at most 2,000,000 samples in one run"),
    (["babble", "--plant", "pendulum", "--episodes", "10001"], 2, "episodes must be <= 10000"),
    (["babble", "--plant", "pendulum", "--seed", "-1"], 2, "seed must be in [0, 2^32 - 1]"),
    (["babble", "--plant", ""], 2, "--plant: an empty value (leave the option out for its default)"),
    (["babble", "--plant", "pendulum", "--artifacts", ""], 2, "--artifacts: an empty path"),
    (["plan", "--plant", "arm5", "--task", "reach", "--iterations", "10001"], 2, "iterations must be in [1, 10000]"),
    (["plan", "--plant", "arm5", "--task", "reach", "--seed", str(2**32)], 2, "seed must be in [0, 2^32 - 1]"),
    (["plan", "--plant", "arm5", "--task", "reach", "--dynamics", ""], 2,
     "--dynamics: an empty value (leave the option out for its default)"),
    (["plan", "--plant", "arm5", "--task", " "], 2, "--task: an empty value (leave the option out for its default)"),
    (["execute", "--plan", " "], 2, "plan: an empty artifact reference"),
    (["evaluate", "--plan", ""], 2, "plan: an empty artifact reference"),
    (["fit", "--data", ""], 2, "data: an empty artifact reference"),
    (["fit", "--data", "x", "--max-points", "5001"], 2, "max-points must be in [10, 5000]"),
    (["learn", "--plant", "pendulum", "--task", "swing-up", "--episodes", "101"], 2, "episodes must be in [1, 100]"),
    (["learn", "--plant", "pendulum", "--task", "swing-up", "--babble-points", "100001"], 2,
     "babble-points must be 0 (the plant's default) or in [2, 100000]"),
    (["reproduce", "--figure", "fig3.2a", "--jobs", "65"], 2, "--jobs must be in [1, 64]"),
    (["reproduce", "--figure", ""], 2, "unknown experiment '': choose one of fig3.2a"),
    (["ls", ""], 2, "unknown stage '': choose one of babble, plan"),
    (["ls", "plann"], 2, "unknown stage 'plann': choose one of babble, plan"),
    (["show", ""], 2, "an empty artifact key"),
    (["show", " "], 2, "an empty artifact key"),
])
def test_bounds_and_empty_strings_refused_before_work(tmp_path, args, code, message):
    import raico.pipeline.interface.cli  # noqa: F401  (loaded before the clock starts)

    t0 = time.monotonic()
    if "--artifacts" not in args:
        args = [*args, "--artifacts", str(tmp_path)]
    res = cli(*args)
    assert res.exit_code == code
    assert one_error_line(res.stderr).startswith("raico: error: " + message)
    assert time.monotonic() - t0 < 5 and tmp_folders(tmp_path) == [] and valid_entries(tmp_path) == []


def test_ls_missing_folder_is_an_error(tmp_path):
    res = cli("ls", "--artifacts", tmp_path / "nope")
    assert res.exit_code == 3 and one_error_line(res.stderr) == f"raico: error: no artifacts folder {tmp_path / 'nope'}"


def test_show_open_without_a_display_is_an_error(tmp_path):
    res = cli("babble", "--plant", "pendulum", "--episodes", 1, "--duration", 0.2, "--json", "--artifacts", tmp_path)
    key = json.loads(res.stdout.splitlines()[-1])["key"]
    env = {"DISPLAY": "", "WAYLAND_DISPLAY": "", "WAYLAND_SOCKET": ""}
    res = cli("show", key, "--open", "--artifacts", tmp_path, env=env)
    assert res.exit_code == 1
    assert one_error_line(res.stderr) == (
        "raico: error: cannot open the Rerun viewer: no display (DISPLAY and WAYLAND_DISPLAY are unset); copy "
        f"the recording and run `rerun {tmp_path / 'babble' / key / 'recording.rrd'}` where there is one")


# ============================================================================= one helper process: CLI runs (1, 3) and every stage (5)
HELPER = textwrap.dedent("""
    # One process imports the CLI and Drake once, then forks: each fork is a fresh `raico` run
    # (raico.pipeline.interface.cli.main with its argv) or a stage run, killed or raced as the test asks.
    import json, os, resource, signal, sys, time
    from pathlib import Path
    import raico.plants.threads  # noqa: F401
    from raico.pipeline.engine import runner
    from raico.pipeline.interface import cli
    from raico.pipeline.engine.cache import Cache
    from raico.stages.babble import BabbleConfig
    from raico.stages.evaluate.stage import EvaluateConfig
    from raico.stages.execute.config import ExecuteConfig
    from raico.stages.fit.stage import FitConfig
    from raico.stages.learn import LearnConfig
    from raico.stages.plan.stage import PlanConfig

    root = Path(sys.argv[1])
    cache = Cache(root / "matrix")
    report = {}

    def raico(name, argv, rlimit=None, signal_when=None):
        # `raico ARGV` in a fork (stdout/stderr to files); SIGTERM once signal_when() holds
        out, err = root / f"{name}.out", root / f"{name}.err"
        pid = os.fork()
        if pid == 0:
            code = 70
            try:
                os.dup2(os.open(out, os.O_WRONLY | os.O_CREAT), 1)
                os.dup2(os.open(err, os.O_WRONLY | os.O_CREAT), 2)
                if rlimit:
                    resource.setrlimit(resource.RLIMIT_FSIZE, (rlimit, rlimit))
                sys.argv = ["raico", *argv]
                cli.main()
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else 0
            finally:
                sys.stdout.flush()
                sys.stderr.flush()
                os._exit(code)
        killed, status = False, None
        deadline = time.monotonic() + 60
        while signal_when is not None and time.monotonic() < deadline:
            done, st = os.waitpid(pid, os.WNOHANG)
            if done:
                status = st
                break
            if signal_when():
                time.sleep(0.3)
                os.kill(pid, signal.SIGTERM)
                killed = True
                break
            time.sleep(0.05)
        if status is None:
            status = os.waitpid(pid, 0)[1]
        report[name] = {"rc": os.waitstatus_to_exitcode(status), "stdout": out.read_text(), "stderr": err.read_text(),
                        "killed": killed}

    def go(stage, cfg):
        return runner.run(cache, stage, cfg, record=False)

    def forked(stage, cfg, pause_at_publish):
        r, w = os.pipe()
        pid = os.fork()
        if pid == 0:
            os.close(r)
            if pause_at_publish:
                real = Cache._publish
                def publish(self, st, *a, **k):
                    if st == stage:
                        os.write(w, b"1")
                        time.sleep(120)
                    return real(self, st, *a, **k)
                Cache._publish = publish
            try:
                out = go(stage, cfg)
                os.write(w, json.dumps([out.key, out.cached]).encode())
            finally:
                os._exit(0)
        os.close(w)
        return pid, r

    def stable(m):
        return {k: v for k, v in m.items() if "time" not in k and not k.endswith("_s")}

    def check(stage, cfg):
        # SIGKILL just before the entry is published (its temporary folder then holds every file,
        # meta.json included), then the same run again
        pid, r = forked(stage, cfg, True)
        ready = os.read(r, 1)
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        os.close(r)
        tmps = [p.name for p in (cache.root / stage).glob(".tmp-*")]
        valid_after_kill = [x.key for x in cache.list(stage) if x.valid]
        out = go(stage, cfg)
        again = go(stage, cfg)
        report[stage] = {"ready": ready == b"1", "tmp_after_kill": len(tmps), "valid_after_kill": valid_after_kill,
                         "rerun_cached": out.cached, "reason": out.reason, "key": out.key, "again_cached": again.cached,
                         "tmp_after_rerun": len(list((cache.root / stage).glob(".tmp-*"))),
                         "metrics_equal": stable(again.metrics) == stable(out.metrics)}
        return out

    def race(stage, cfg):
        # two identical runs at once
        kids = [forked(stage, cfg, False) for _ in range(2)]
        outs = []
        for pid, r in kids:
            data = b""
            while chunk := os.read(r, 4096):
                data += chunk
            _, status = os.waitpid(pid, 0)
            outs.append((status, json.loads(data or b"null")))
        keys = {o[1][0] for o in outs if o[1]}
        valid = [x.key for x in cache.list(stage) if x.valid and x.key in keys]
        report[stage + "-race"] = {"statuses": [o[0] for o in outs], "keys": len(keys), "valid": len(valid),
                                   "tmp": len(list((cache.root / stage).glob(".tmp-*")))}

    (root / "hostname").write_text("x\\n")
    raico("file", ["plan", "--plant", "arm5", "--task", "reach", "--artifacts", str(root / "hostname")])
    raico("efbig", ["babble", "--plant", "pendulum", "--episodes", "1", "--duration", "0.2",
                    "--artifacts", str(root / "efbig")], rlimit=60_000)
    raico("sigterm", ["babble", "--plant", "arm5", "--episodes", "40", "--no-record", "--artifacts",
                      str(root / "sigterm")], signal_when=lambda: list((root / "sigterm" / "babble").glob(".tmp-*")))
    b = check("babble", BabbleConfig(plant="pendulum", episodes=1, duration=0.2))
    f = check("fit", FitConfig(data=(b.key,), restarts=0, max_points=50))
    p = check("plan", PlanConfig(plant="pendulum", task="swing-up", solver="ilqg", iterations=1))
    e = check("execute", ExecuteConfig(plan=p.key))
    check("evaluate", EvaluateConfig(plan=p.key, rollout=e.key))
    check("learn", LearnConfig(plant="pendulum", task="swing-up", episodes=1, babble_points=5, iterations=1,
                               restarts=0, max_points=20))
    race("babble", BabbleConfig(plant="pendulum", episodes=1, duration=0.2, seed=7))
    race("plan", PlanConfig(plant="pendulum", task="swing-up", solver="ilqg", iterations=1, seed=7))
    print(json.dumps({"report": report, "keys": {"babble": b.key, "fit": f.key, "plan": p.key, "execute": e.key}}))
""")

STAGES = ("babble", "fit", "plan", "execute", "evaluate", "learn")


@pytest.fixture(scope="module")
def helper(tmp_path_factory):
    """Runs :data:`HELPER` once: its report (per check) and its folder, whose ``matrix`` cache then
    holds a valid chain babble -> fit, plan -> execute -> evaluate, and a learn loop."""
    if not hasattr(os, "fork"):
        pytest.skip("needs fork")
    root = tmp_path_factory.mktemp("faults")
    env = {k: v for k, v in os.environ.items() if k != "RUST_LOG"}  # Rerun's own logging: as a user has it
    p = subprocess.run([sys.executable, "-c", HELPER, str(root)], cwd=REPO, env=env, capture_output=True, text=True,
                       timeout=600)
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout.splitlines()[-1])
    return root, doc["report"], doc["keys"]


def test_artifacts_path_that_is_a_file_is_one_line(helper):
    """The acceptance check ``raico plan --plant arm5 --task reach --artifacts /etc/hostname``."""
    root, report, _ = helper
    r = report["file"]
    assert r["rc"] == 5 and r["stdout"] == ""
    assert r["stderr"] == f"raico: error: artifacts folder {root / 'hostname'} is a file, not a folder\n"


def test_rerun_file_writer_failure_is_one_line_without_rerun_noise(helper):
    """Rerun's own writer fails (the file passes RLIMIT_FSIZE; Python ignores SIGXFSZ, so writes get
    EFBIG): one line, none of Rerun's coloured log lines, no hang, no truncated recording passed off
    as one, the data entry intact, no temporary folder."""
    root, report, _ = helper
    r = report["efbig"]
    assert r["rc"] == 5, r
    key = re.search(r"babble/([0-9a-f]{16})", r["stderr"]).group(1)
    assert one_error_line(r["stderr"]) == (
        f"raico: error: cannot write the derived files (recording) of babble/{key}: "
        f"{root / 'efbig' / 'babble' / key / 'recording.rrd'}: file too large; its data stay cached and the next "
        f"call writes them")
    assert tmp_folders(root / "efbig") == [] and [r.key for r in valid_entries(root / "efbig")] == [key]
    assert sorted(p.name for p in (root / "efbig" / "babble" / key).iterdir()) == ["data.npz", "meta.json", "state.json"]


def test_sigterm_mid_stage_one_line_no_temp_folder(helper):
    root, report, _ = helper
    r = report["sigterm"]
    assert r["killed"] and r["rc"] == 143, r
    assert one_error_line(r["stderr"]) == ("raico: error: interrupted by SIGTERM; the interrupted run left no "
                                           "partial artifact")
    assert tmp_folders(root / "sigterm") == [] and valid_entries(root / "sigterm") == []


@pytest.mark.parametrize("stage", STAGES)
def test_sigkill_before_publish_leaves_nothing_valid_and_the_rerun_completes(helper, stage):
    _, report, _ = helper
    r = report[stage]
    assert r["ready"] and r["tmp_after_kill"] == 1  # killed with every file in its temporary folder
    assert r["key"] not in r["valid_after_kill"]
    assert r["rerun_cached"] is False and r["reason"] == "no cache entry" and r["tmp_after_rerun"] == 0
    assert r["again_cached"] is True and r["metrics_equal"]


@pytest.mark.parametrize("stage", ["babble", "plan"])
def test_two_identical_concurrent_runs_leave_one_valid_entry(helper, stage):
    _, report, _ = helper
    assert report[stage + "-race"] == {"statuses": [0, 0], "keys": 1, "valid": 1, "tmp": 0}


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _edit_number(meta: Path) -> None:
    text = meta.read_text()
    new = re.sub(r'("compute_s": )(\d)', lambda m: m[1] + str((int(m[2]) + 1) % 10), text, count=1)
    assert new != text
    meta.write_text(new)


CORRUPTIONS = {
    "truncated data file": (lambda e, data: _truncate(e / data), r"file {data} changed \(size \d+ B, recorded \d+ B\)"),
    "byte flipped in a data file (same size)": (lambda e, data: flip_byte(e / data),
                                                r"file {data} changed \(sha256 [0-9a-f]{12}…, recorded [0-9a-f]{12}…\)"),
    "byte flipped, mtime put back": (lambda e, data: flip_byte(e / data, keep_mtime=True),
                                     r"file {data} changed \(sha256 [0-9a-f]{12}…, recorded [0-9a-f]{12}…\)"),
    "deleted data file": (lambda e, data: (e / data).unlink(), "file {data} missing"),
    "edited meta.json": (lambda e, data: _edit_number(e / "meta.json"),
                         r"cache entry corrupt \(meta\.json was edited: its checksum does not match its content\)"),
    "emptied file list": (lambda e, data: (e / "meta.json").write_text(
        json.dumps({**json.loads((e / "meta.json").read_text()), "files": {}})),
        r"cache entry corrupt \(meta\.json was edited: its checksum does not match its content\)"),
    "truncated meta.json": (lambda e, data: _truncate(e / "meta.json"),
                            r"cache entry corrupt \(meta\.json unreadable: JSONDecodeError\)"),
}
DATA = {"babble": "data.npz", "fit": "model.npz", "plan": "plan.npz", "execute": "rollout.npz",
        "evaluate": "evaluation.json"}
CASES = [("babble", "truncated data file"), ("fit", "emptied file list"), ("plan", "edited meta.json"),
         ("execute", "truncated meta.json"), ("evaluate", "deleted data file")]  # every stage, every kind
CASES += [(stage, "byte flipped in a data file (same size)") for stage in DATA]  # each stage's data file
CASES += [("plan", "byte flipped, mtime put back")]  # size and mtime as recorded: the ctime still moved


@pytest.mark.parametrize("stage, kind", CASES)
def test_corrupted_entry_is_detected_said_and_recomputed(helper, stage, kind):
    from raico.pipeline.engine import runner
    from raico.pipeline.engine.cache import Cache
    from raico.stages.babble import BabbleConfig
    from raico.stages.evaluate.stage import EvaluateConfig
    from raico.stages.execute.config import ExecuteConfig
    from raico.stages.fit.stage import FitConfig
    from raico.stages.plan.stage import PlanConfig

    root, _, keys = helper
    root = root / "matrix"
    cfg = {"babble": BabbleConfig(plant="pendulum", episodes=1, duration=0.2),
           "fit": FitConfig(data=(keys["babble"],), restarts=0, max_points=50),
           "plan": PlanConfig(plant="pendulum", task="swing-up", solver="ilqg", iterations=1),
           "execute": ExecuteConfig(plan=keys["plan"]),
           "evaluate": EvaluateConfig(plan=keys["plan"], rollout=keys["execute"])}[stage]
    cache = Cache(root)
    before = runner.run(cache, stage, cfg, record=False)  # cached by the helper (unless the code changed since)
    entry = Path(before.path)
    data = DATA[stage]
    assert (entry / data).is_file(), sorted(p.name for p in entry.iterdir())
    corrupt, reason = CORRUPTIONS[kind]
    corrupt(entry, data)
    assert cache.lookup(stage, before.key) is None
    after = runner.run(cache, stage, cfg, record=False)
    assert not after.cached and re.fullmatch(reason.replace("{data}", re.escape(data)), after.reason), after.reason
    assert after.key == before.key and after.status == before.status
    stable = lambda m: {k: v for k, v in m.items() if "time" not in k and not k.endswith("_s")}  # noqa: E731
    assert stable(after.metrics) == stable(before.metrics)
    assert runner.run(cache, stage, cfg, record=False).cached and tmp_folders(root) == []


# ============================================================================= 6. integrity of inputs, recordings
SHA = r"\(sha256 [0-9a-f]{12}…, recorded [0-9a-f]{12}…\)"


def _matrix_copy(helper, tmp_path: Path) -> tuple[Path, dict]:
    """A copy of the helper's cache (new inodes and times: every entry is re-hashed once) and its keys."""
    root, _, keys = helper
    dst = tmp_path / "a"
    shutil.copytree(root / "matrix", dst, ignore=shutil.ignore_patterns(".tmp-*"))
    return dst, keys


def _restamp(entry: Path, name: str) -> None:
    """Make the stamp of ``name`` vouch for its current (damaged) bytes: damage the stamps do not show
    (size, times and inode kept, as below the file system), the residual case of a stat-based check."""
    stamps = json.loads((entry / "state.json").read_text())["stamps"]
    st = (entry / name).stat()
    stamps[name][:4] = [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino]
    (entry / "state.json").write_text(json.dumps({"stamps": stamps}))
    later = time.time_ns() + 10**9
    os.utime(entry / "state.json", ns=(later, later))


def _damage_header(path: Path) -> None:
    """Garble the start of the first array in an ``.npz`` (same size): the first bytes of the zip
    member's data (stored uncompressed), which hold the array's header."""
    import struct

    data = path.read_bytes()
    assert data[:4] == b"PK\x03\x04"
    name_len, extra_len = struct.unpack("<HH", data[26:30])
    start = 30 + name_len + extra_len
    with open(path, "r+b") as f:
        f.seek(start + 3)
        f.write(bytes([data[start + 3] ^ 0xFF]))


@pytest.mark.parametrize("command", ["execute", "evaluate"])
def test_stage_on_a_damaged_plan_rebuilds_it_first(helper, tmp_path, command):
    """``raico execute`` / ``evaluate`` on a plan whose data file had a byte flipped: the plan is rebuilt
    from its stored config (one line says so, under its key), then the stage answers; no traceback."""
    from raico.pipeline.engine.cache import Cache

    a, keys = _matrix_copy(helper, tmp_path)
    plan = keys["plan"]
    flip_byte(a / "plan" / plan / "plan.npz")
    args = ["--plan", plan] + (["--rollout", keys["execute"]] if command == "evaluate" else [])
    res = cli(command, *args, "--no-record", "--artifacts", a)
    assert res.exit_code == 0, res.stderr
    rebuilt, answer = lines(res.stderr)
    assert re.fullmatch(rf"plan {plan} \(input of {command}\): damaged \(file plan\.npz changed {SHA}\); rebuilt "
                        r"from its stored config", rebuilt), rebuilt
    assert answer.startswith(f"{command} ") and ": cached -> " in answer  # its own entry was intact
    assert Cache(a).verify("plan", plan) == "cached" and tmp_folders(a) == []


@pytest.mark.parametrize("damage", ["crc", "header"])
def test_unreadable_plan_is_one_clean_line_and_rebuilt(helper, tmp_path, damage):
    """Damage the stamps cannot show (stamped as intact) makes numpy fail when execute loads the plan
    (``BadZipFile: Bad CRC-32``, or a garbled array header): one clean line naming the entry and the
    cause -- no traceback, none of the file's bytes, not exit 2 -- and the plan rebuilt, then executed."""
    from raico.pipeline.engine.cache import Cache

    a, keys = _matrix_copy(helper, tmp_path)
    plan = keys["plan"]
    entry = a / "plan" / plan
    assert Cache(a).lookup("plan", plan) is not None  # stamps recorded for the copy
    (flip_byte if damage == "crc" else _damage_header)(entry / "plan.npz")
    _restamp(entry, "plan.npz")
    assert Cache(a).lookup("plan", plan) is not None  # served by a hit: the residual case
    res = cli("execute", "--plan", plan, "--seed", 3, "--no-record", "--artifacts", a)  # not cached: reads it
    assert res.exit_code == 0, res.stderr
    rebuilt, answer = lines(res.stderr)
    cause = (r"BadZipFile: Bad CRC-32 for file '\w+\.npy'" if damage == "crc" else
             r"(?:BadZipFile|ValueError|zlib\.error|EOFError)(?:: [ -~]+)?")
    assert re.fullmatch(rf"plan {plan} \(input of execute\): damaged \(plan\.npz cannot be read \({cause}\): file "
                        rf"plan\.npz changed {SHA}\); rebuilt from its stored config", rebuilt), rebuilt
    assert "\\x" not in rebuilt and "b'" not in rebuilt
    assert answer.startswith("execute ") and ": ran (no cache entry)" in answer
    assert Cache(a).verify("plan", plan) == "cached"


def test_damaged_plan_that_cannot_be_rebuilt_is_one_line(helper, tmp_path, monkeypatch):
    """Where raico cannot rebuild the input -- its meta.json (its config) damaged too, or the plan code
    changed since (the same config would give another key) -- one line, exit 4, naming the entry."""
    from raico.pipeline.engine import keys as keys_mod

    a, keys = _matrix_copy(helper, tmp_path)
    plan = keys["plan"]
    flip_byte(a / "plan" / plan / "plan.npz")
    real = keys_mod.code_version
    monkeypatch.setattr(keys_mod, "code_version", lambda st: "plan+edited" if st.name == "plan" else real(st))
    res = cli("execute", "--plan", plan, "--no-record", "--artifacts", a)
    assert res.exit_code == 4
    line = one_error_line(res.stderr)
    assert re.fullmatch(rf"raico: error: artifact plan/{plan} is damaged \(file plan\.npz changed {SHA}\) and cannot "
                        r"be rebuilt: it was made by another version of the plan code \(this one gives key "
                        r"[0-9a-f]{16}\); run the command that made it again", line), line
    monkeypatch.undo()
    _edit_number(a / "plan" / plan / "meta.json")
    res = cli("evaluate", "--plan", plan, "--rollout", keys["execute"], "--artifacts", a)
    assert res.exit_code == 4
    assert one_error_line(res.stderr) == (
        f"raico: error: artifact plan/{plan} is damaged (cache entry corrupt (meta.json was edited: its checksum "
        f"does not match its content)) and cannot be rebuilt: its config is in its meta.json, which is damaged or "
        f"missing; run the command that made it again")
    assert tmp_folders(a) == []


def test_repaired_recording_says_so(tmp_path):
    """A truncated, garbled (same size) or deleted recording.rrd / trajectory.mcap is written again from
    the stored data on the next call, which says why in one line before its answer."""
    args = ["plan", "--plant", "pendulum", "--task", "swing-up", "--solver", "ilqg", "--iterations", 1,
            "--artifacts", tmp_path]
    res = cli(*args, "--json")
    key = json.loads(res.stdout.splitlines()[-1])["key"]
    entry = tmp_path / "plan" / key
    for damage, why in (
            (lambda: _truncate(entry / "recording.rrd"), r"recording\.rrd changed \(size \d+ B, recorded \d+ B\)"),
            (lambda: flip_byte(entry / "recording.rrd"), rf"recording\.rrd changed {SHA}"),
            (lambda: (entry / "trajectory.mcap").unlink(), r"trajectory\.mcap missing")):
        damage()
        res = cli(*args)
        assert res.exit_code == 0, res.stderr
        said, answer = lines(res.stderr)
        assert re.fullmatch(rf"plan {key}: recording regenerated: {why}", said), said
        assert answer.startswith(f"plan {key}: cached -> ")
        assert lines(cli(*args).stderr)[0].startswith(f"plan {key}: cached -> ")  # repaired: nothing more to say


def _descendants(pid: int) -> dict[int, str]:
    """Pid -> command line of every process below ``pid`` (Linux /proc)."""
    parent = parents()
    out, todo = {}, [pid]
    while todo:
        x = todo.pop()
        for c, pp in parent.items():
            if pp == x and c not in out:
                try:
                    out[c] = Path(f"/proc/{c}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                except OSError:
                    out[c] = "?"
                todo.append(c)
    return out


def _sigkill_and_time_the_pipes(proc: subprocess.Popen, seen: dict[int, str]) -> float:
    """SIGKILL ``proc``; seconds until its stdout and stderr close (what ``subprocess.run(...,
    capture_output=True)`` waits for), at most 30."""
    import threading

    done = threading.Event()
    t = threading.Thread(target=lambda: (proc.communicate(), done.set()), daemon=True)
    seen.update(_descendants(proc.pid))
    t0 = time.monotonic()
    proc.kill()
    t.start()
    done.wait(30)
    return time.monotonic() - t0


@pytest.mark.slow  # runs a figure or Ray in child processes: 2-11 s
@linux_only
def test_sigkill_of_reproduce_leaves_no_process_and_closes_the_callers_pipes(tmp_path):
    """``raico reproduce --figure fig3.2a --quick`` SIGKILLed while its
    workers compute, then (the next call, from the cache) while the headless viewer renders the report's
    screenshots: each time the caller's pipes close within 2 s (the viewer's output never went to them)
    and no process of the run is left running; the finished runs stay cached."""
    from raico.pipeline.recordings.screenshots import renderer_unavailable

    cmd = [RAICO, "reproduce", "--figure", "fig3.2a", "--quick", "--jobs", "2", "--artifacts", str(tmp_path)]
    seen: dict[int, str] = {}
    # 1. while the workers compute plans
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _wait_for(lambda: bool(list((tmp_path / "plan").glob(".tmp-*"))) or proc.poll() is not None, 120, "a plan")
    assert proc.poll() is None, "reproduce ended before it could be killed"
    assert _sigkill_and_time_the_pipes(proc, seen) < 2.0
    _wait_for(lambda: not [p for p in seen if running(p)], 5, f"the processes of the run to end: {seen}")
    if renderer_unavailable() is not None:
        pytest.skip(f"no screenshot step here: {renderer_unavailable()}")
    # 2. while the viewer renders (the runs finish from where the killed call stopped)
    seen.clear()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _wait_for(lambda: any("rerun" in c for c in _descendants(proc.pid).values()) or proc.poll() is not None, 180,
              "the viewer")
    assert proc.poll() is None, proc.stderr.read()
    time.sleep(1.0)  # the viewer loads the recording
    elapsed = _sigkill_and_time_the_pipes(proc, seen)
    assert any("rerun" in c for c in seen.values()), seen
    assert elapsed < 2.0, elapsed
    _wait_for(lambda: not [p for p in seen if running(p)], 5, f"the processes of the run to end: {seen}")
    from raico.thesis.figures import EXPERIMENTS

    exp = EXPERIMENTS["fig3.2a"]
    runs = sum(v.seed_count(exp.seeds, True) for v in exp.variants)
    assert len(valid_entries(tmp_path, "plan")) == runs and tmp_folders(tmp_path) == []  # data lost: 0


REAPER_OWNER = textwrap.dedent("""
    # Stands in for raico with a local Ray instance: a reaper, a marked child, and below it a process
    # without the mark (like Ray's agents, whose process titles overwrite their environment)
    import os, subprocess, sys, time
    from raico.pipeline.engine.executors import RAY_OWNER, start_reaper

    mark, reaper = start_reaper()
    os.environ[RAY_OWNER] = mark.split("=", 1)[1]
    child = subprocess.Popen([sys.executable, "-c",
        "import subprocess, sys, time; g = subprocess.Popen(['sleep', '60'], env={}); print(g.pid, flush=True); "
        "time.sleep(60)"], stdout=subprocess.PIPE, text=True)
    grandchild = child.stdout.readline().strip()
    print(reaper.pid, child.pid, grandchild, flush=True)
    time.sleep(60)
""")


@pytest.mark.slow  # runs a figure or Ray in child processes: 2-11 s
@linux_only
def test_ray_reaper_kills_the_instance_when_raico_is_sigkilled(tmp_path):
    """What the reaper of a local Ray instance does when raico is SIGKILLed, without Ray: the processes
    below raico that carry the instance's mark, and the processes below those (learnt while raico ran),
    are SIGKILLed; another process is left alone; the reaper ends."""
    bystander = subprocess.Popen(["sleep", "60"])
    owner = subprocess.Popen([sys.executable, "-c", REAPER_OWNER], cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        reaper, child, grandchild = (int(x) for x in owner.stdout.readline().split())
        assert running(reaper) and running(child) and running(grandchild)
        time.sleep(1.2)  # the reaper looks twice a second
        owner.kill()
        owner.wait()
        _wait_for(lambda: not any(running(p) for p in (reaper, child, grandchild)), 3, "the reaper's work")
        assert running(bystander.pid)
    finally:
        bystander.kill()
        bystander.wait()
        if owner.poll() is None:
            owner.kill()
            owner.wait()


def _files_agree_with_their_records(entry: Path) -> None:
    """Every data and derived file of the entry folder has the size and sha256 its record says, and
    every stamp in ``state.json`` describes the file now there (size, inode, digest)."""
    import hashlib

    meta = json.loads((entry / "meta.json").read_text())
    derived = json.loads((entry / "derived.json").read_text())
    stamps = json.loads((entry / "state.json").read_text())["stamps"]
    for name, rec in {**meta["files"], **derived}.items():
        data = (entry / name).read_bytes()
        assert rec["size"] == len(data) and rec["sha256"] == hashlib.sha256(data).hexdigest(), name
    for name, (size, _, _, ino, digest) in stamps.items():
        st = (entry / name).stat()
        assert (size, ino) == (st.st_size, st.st_ino), name
        assert digest == hashlib.sha256((entry / name).read_bytes()).hexdigest(), name


@pytest.mark.slow  # runs a figure or Ray in child processes: 2-11 s
def test_identical_plans_in_flight_compute_once(tmp_path):
    """Four identical ``raico plan`` calls started at once: one computes (and records), the others wait
    for it and report a cache hit; every record and stamp of the entry agrees with its file."""
    args = [RAICO, "plan", "--plant", "pendulum", "--task", "swing-up", "--iterations", "40",
            "--artifacts", str(tmp_path)]
    procs = [subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
             for _ in range(4)]
    outs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0] * 4, [err for _, err in outs]
    lines = [next(ln for ln in err.splitlines() if ln.startswith("plan ") and " -> " in ln) for _, err in outs]
    assert sum(": ran (no cache entry) -> " in ln for ln in lines) == 1, lines
    assert sum(": cached -> " in ln for ln in lines) == 3, lines
    assert all(ln.endswith("recording.rrd") for ln in lines), lines
    [entry] = valid_entries(tmp_path, "plan")
    _files_agree_with_their_records(entry.path)
    assert tmp_folders(tmp_path) == [] and not list((tmp_path / "plan").glob(".lock-*"))


@linux_only
def test_sigint_during_exp_run_removes_the_workers_temporary_folders(tmp_path):
    """Ctrl-C while an experiment's workers write their plans: exit 130, one line, and no ``.tmp-*`` folder left
    for the next call to remove."""
    f = tmp_path / "slow.toml"
    f.write_text('name = "slow"\nstages = ["plan"]\nseeds = "range(4)"\n[base]\nplant = "arm5"\ntask = "reach"\n'
                 'dynamics = "analytic"\niterations = 300\n')
    arts = tmp_path / "arts"
    proc = subprocess.Popen([RAICO, "exp", "run", str(f), "--jobs", "2", "--artifacts", str(arts)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for(lambda: bool(list((arts / "plan").glob(".tmp-*"))) or proc.poll() is not None, 120, "a plan")
    assert proc.poll() is None, "exp run ended before it could be interrupted"
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert one_error_line(err).startswith("raico: error: interrupted by SIGINT")
    assert tmp_folders(arts) == []


def test_an_interrupt_during_a_held_extension_s_initialization_is_raised_once_it_is_loaded(tmp_path, monkeypatch):
    """Drake's extension logs an exception raised inside its initialization with a C++ stack: a signal that
    lands while such a module loads is held and raised as the one interrupt once the module is in."""
    from raico.pipeline import lifecycle

    done = tmp_path / "ran to its end"
    (tmp_path / "slow_ext.py").write_text(f"import os, signal\nos.kill(os.getpid(), signal.SIGINT)\n"
                                          f"open({str(done)!r}, 'w').close()\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(lifecycle, "HOLD_SIGNALS_DURING", ("slow_ext",))
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    meta = list(sys.meta_path)
    try:
        lifecycle.install_signal_handlers()
        with pytest.raises(lifecycle.Interrupted):
            import slow_ext  # noqa: F401
        assert done.exists()     # the whole module ran before the interrupt was raised
    finally:
        sys.meta_path[:] = meta
        sys.modules.pop("slow_ext", None)
        for s, h in old.items():
            signal.signal(s, h)
