"""Tests of the artifact cache (raico/pipeline/engine/cache.py) and the error classes."""

from __future__ import annotations

import hashlib
import json
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

from raico.pipeline.engine import cache as cache_mod
from raico.pipeline.engine import keys as keys_mod
from raico.pipeline.engine.cache import Cache, WriteResult
from raico.pipeline.engine.keys import stage_key
from raico.pipeline.errors import BadInput, CorruptArtifact, MissingArtifact, RaicoError
from raico.stages.base import Artifact
from tests.damage import flip_byte

REPO = Path(__file__).resolve().parents[2]
_REAL_GIT_COMMIT = keys_mod.git_commit
KEY = stage_key("plan", "v1", {"T": 100, "alpha": 0.5}, ["aaaaaaaaaaaaaaaa"])


@pytest.fixture(autouse=True)
def _no_repo_git(monkeypatch: pytest.MonkeyPatch) -> None:
    """Keep tests from querying the project's git repository."""
    monkeypatch.setattr(keys_mod, "git_commit", lambda path=None: "0" * 40)


def write_npz(d: Path) -> dict:
    np.savez(d / "data.npz", x=np.arange(10.0))
    (d / "sub").mkdir()
    (d / "sub" / "notes.txt").write_text("hello")
    return {"timings": {"solve_s": 0.25}, "summary": {"cost": np.float64(1.5)}}


# --------------------------------------------------------------------------- keys


def test_key_is_stable_and_short() -> None:
    k = stage_key("plan", "v1", {"T": 100, "alpha": 0.5}, ["aaaaaaaaaaaaaaaa"])
    assert k == KEY and len(k) == 16 and int(k, 16) >= 0
    # Fixed value: a change here invalidates every user's cache, so it must be deliberate.
    assert stage_key("s", "v", {}, []) == "930a4c3542528e4a"  # FORMAT 2: meta carries its checksum


def test_key_ignores_order_and_number_spelling() -> None:
    base = stage_key("fit", "v1", {"a": 1, "b": {"x": 2.0, "y": [1, 2]}}, [])
    same = [
        {"b": {"y": [1.0, 2.0], "x": 2}, "a": 1.0},
        {"a": np.int64(1), "b": {"x": np.float32(2.0), "y": np.array([1, 2])}},
        {"a": np.float64(1.0), "b": {"x": 2, "y": (1, 2)}},
    ]
    for cfg in same:
        assert stage_key("fit", "v1", cfg, []) == base
    assert stage_key("fit", "v1", {"a": -0.0}, []) == stage_key("fit", "v1", {"a": 0}, [])


def test_key_changes_with_what_matters() -> None:
    cfg = {"a": 1, "b": 0.5}
    base = stage_key("fit", "v1", cfg, ["k1"])
    others = {
        stage_key("plan", "v1", cfg, ["k1"]),
        stage_key("fit", "v2", cfg, ["k1"]),
        stage_key("fit", "v1", {"a": 1, "b": 0.5000001}, ["k1"]),
        stage_key("fit", "v1", {"a": 1, "b": 0.5, "c": None}, ["k1"]),
        stage_key("fit", "v1", {"a": True, "b": 0.5}, ["k1"]),
        stage_key("fit", "v1", cfg, ["k2"]),
        stage_key("fit", "v1", cfg, ["k1", "k2"]),
        stage_key("fit", "v1", cfg, []),
        stage_key("fit", "v1", {"a": 1, "b": float("nan")}, ["k1"]),
    }
    assert base not in others and len(others) == 9


def test_key_rejects_unhashable_values() -> None:
    with pytest.raises(TypeError, match="^cannot hash a config value of type object$"):
        stage_key("fit", "v1", {"f": object()}, [])


# --------------------------------------------------------------------------- write / lookup


def test_write_then_lookup(tmp_path: Path) -> None:
    c = Cache(tmp_path)
    assert c.lookup("plan", KEY) is None and c.why("plan", KEY) == "no cache entry"
    before, t0 = datetime.now(UTC).replace(microsecond=0), time.perf_counter()
    e = c.write("plan", KEY, write_npz, {"config": {"T": 100}, "inputs": ["aaaaaaaaaaaaaaaa"]})
    elapsed, after = time.perf_counter() - t0, datetime.now(UTC)
    assert type(e) is Artifact and e.path == tmp_path / "plan" / KEY
    assert sorted(os.listdir(tmp_path / "plan")) == [KEY]  # no tmp folder left
    m = json.loads((e.path / "meta.json").read_text())
    assert m["complete"] is True and m["stage"] == "plan" and m["key"] == KEY
    assert m["config"] == {"T": 100} and m["inputs"] == ["aaaaaaaaaaaaaaaa"]
    assert set(m["files"]) == {"data.npz", "sub/notes.txt"}
    assert m["files"]["sub/notes.txt"] == {
        "size": 5, "sha256": "2cf24dba5fb0a30e26e83b2ac5b9e29e1b161e5c1fa7425e73043362938b9824"}
    # the writer's own timing, then the cache's: writing and hashing, both within the call
    assert list(m["timings"]) == ["hash_s", "solve_s", "write_s"] and m["timings"]["solve_s"] == 0.25
    assert 0 <= m["timings"]["write_s"] and 0 <= m["timings"]["hash_s"]
    assert m["timings"]["write_s"] + m["timings"]["hash_s"] <= elapsed
    assert m["summary"] == {"cost": 1.5} and m["git_commit"] == "0" * 40
    assert m["packages"]["numpy"] == np.__version__
    assert m["packages"]["drake"] == metadata.version("drake")
    assert m["packages"]["scikit-learn"] == metadata.version("scikit-learn")
    created = datetime.strptime(m["created"], "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=UTC)
    assert before <= created <= after
    got = c.lookup("plan", KEY)
    assert got is not None and got.meta == e.meta and c.why("plan", KEY) == "cached"
    assert np.array_equal(got.arrays("data.npz")["x"], np.arange(10.0)) and "data.npz" in got.meta["files"]


def test_write_result_dataclass(tmp_path: Path) -> None:
    def w(d: Path) -> WriteResult:
        (d / "a.txt").write_text("a")
        return WriteResult(meta={"status": "diverged"}, timings={"plan_s": 1.0})

    e = Cache(tmp_path).write("plan", KEY, w, {})
    assert e.meta["status"] == "diverged" and e.meta["timings"]["plan_s"] == 1.0


def test_hit_never_calls_writer(tmp_path: Path) -> None:
    c = Cache(tmp_path)
    calls = 0

    def w(d: Path) -> None:
        nonlocal calls
        calls += 1
        (d / "x.txt").write_text("x")

    r1 = c.run("plan", KEY, w)
    assert (calls, r1.cached, r1.reason) == (1, False, "no cache entry")
    r2 = c.run("plan", KEY, w)
    r3 = c.run("plan", KEY, w)
    assert calls == 1 and r2.cached and r3.cached and r2.reason == "cached"
    assert r2.entry.path == r1.entry.path


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt()])
def test_writer_failure_leaves_nothing(tmp_path: Path, exc: BaseException) -> None:
    c = Cache(tmp_path)

    def w(d: Path) -> None:
        (d / "half.npz").write_bytes(b"x" * 1000)
        raise exc

    with pytest.raises(type(exc)) as ei:
        c.write("plan", KEY, w, {})
    assert ei.value is exc  # the writer's own exception, passed through
    assert os.listdir(tmp_path / "plan") == []
    assert c.lookup("plan", KEY) is None and c.list() == []


@pytest.mark.parametrize("name", ["meta.json", "state.json"])
def test_writer_may_not_write_meta(tmp_path: Path, name: str) -> None:
    with pytest.raises(ValueError, match=f"^the writer of stage 'plan' must not create {name}$"):
        Cache(tmp_path).write("plan", KEY, lambda d: (d / name).write_text("{}") and None)
    assert os.listdir(tmp_path / "plan") == []


def test_bad_names_rejected(tmp_path: Path) -> None:
    c = Cache(tmp_path)
    for stage, key, message in [
        ("../x", KEY, "invalid stage name '../x'"),
        (".tmp", KEY, "invalid stage name '.tmp'"),
        ("plan", "../../etc", "invalid cache key '../../etc' (expected lowercase hex)"),
        ("plan", "ABC", "invalid cache key 'ABC' (expected lowercase hex)"),
    ]:
        with pytest.raises(BadInput, match=f"^{re.escape(message)}$"):
            c.lookup(stage, key)


# --------------------------------------------------------------------------- corruption


def _corrupt_truncate(e: Artifact) -> None:
    p = e.path / "data.npz"
    p.write_bytes(p.read_bytes()[:-7])


def _corrupt_same_size(e: Artifact) -> None:
    p = e.path / "sub" / "notes.txt"
    p.write_text("HELLO")


def _corrupt_delete_file(e: Artifact) -> None:
    (e.path / "data.npz").unlink()


def _corrupt_delete_meta(e: Artifact) -> None:
    (e.path / "meta.json").unlink()


def _corrupt_flip_complete(e: Artifact) -> None:
    m = json.loads((e.path / "meta.json").read_text())
    m["complete"] = False
    (e.path / "meta.json").write_text(json.dumps(m))


def _corrupt_garble_meta(e: Artifact) -> None:
    (e.path / "meta.json").write_text('{"complete": tr')


def _corrupt_edit_metric(e: Artifact) -> None:
    m = json.loads((e.path / "meta.json").read_text())
    m["metrics"] = {"final_cost": 2.0}
    (e.path / "meta.json").write_text(json.dumps(m))


def _corrupt_empty_file_list(e: Artifact) -> None:
    m = json.loads((e.path / "meta.json").read_text())
    m["files"] = {}
    (e.path / "meta.json").write_text(json.dumps(m))


@pytest.mark.parametrize(
    ("corrupt", "reason"),
    [
        (_corrupt_truncate, "file data.npz changed (size"),
        (_corrupt_same_size, "file sub/notes.txt changed (sha256"),  # at once: racy stamps are re-hashed
        (_corrupt_delete_file, "file data.npz missing"),
        (_corrupt_delete_meta, "cache entry incomplete (meta.json missing)"),
        (_corrupt_flip_complete, "cache entry incomplete (not marked complete)"),
        (_corrupt_garble_meta, "cache entry corrupt (meta.json unreadable"),
        (_corrupt_edit_metric, "cache entry corrupt (meta.json was edited"),
        (_corrupt_empty_file_list, "cache entry corrupt (meta.json was edited"),
    ],
)
def test_corrupt_entry_detected_and_recomputed(tmp_path: Path, corrupt, reason: str) -> None:
    c = Cache(tmp_path)
    e = c.write("plan", KEY, write_npz, {})
    corrupt(e)
    assert c.lookup("plan", KEY) is None
    assert c.why("plan", KEY).startswith(reason), c.why("plan", KEY)
    [info] = c.list()
    assert not info.valid and info.reason.startswith(reason)
    with pytest.raises(CorruptArtifact, match=f"^artifact plan/{KEY} is invalid: {re.escape(reason)}"):
        c.require("plan", KEY)
    calls = []
    r = c.run("plan", KEY, lambda d: calls.append(1) or write_npz(d))
    assert calls == [1] and not r.cached and r.reason.startswith(reason)
    assert c.why("plan", KEY) == "cached" and sorted(os.listdir(tmp_path / "plan")) == [KEY]


def _count_hashes(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Names of the files the cache re-hashes from now on."""
    calls: list[str] = []
    real = cache_mod._sha256
    monkeypatch.setattr(cache_mod, "_sha256", lambda p: calls.append(Path(p).name) or real(p))
    return calls


def _settled(c: Cache, stage: str = "plan", key: str = KEY) -> Artifact:
    """The entry after its first hit once the clock has moved on: its stamps no longer racy."""
    time.sleep(0.05)
    e = c.lookup(stage, key)
    assert e is not None
    return e


def test_clean_hit_reads_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A hit whose files all match their stamps (size, mtime, ctime, inode) is served after one stat
    per file: nothing is read or hashed."""
    c = Cache(tmp_path)
    c.write("plan", KEY, write_npz, {})
    _settled(c)
    hashed = _count_hashes(monkeypatch)
    for _ in range(3):
        assert c.lookup("plan", KEY) is not None and c.why("plan", KEY) == "cached"
    assert [r.valid for r in c.list()] == [True] and hashed == []
    assert c.verify("plan", KEY) == "cached" and sorted(hashed) == ["data.npz", "notes.txt"]  # deep: every file


@pytest.mark.parametrize("keep_mtime", [False, True], ids=["flip", "flip-mtime-put-back"])
@pytest.mark.parametrize("name", ["data.npz", "sub/notes.txt"])
def test_same_size_change_is_found_on_the_hit(tmp_path: Path, name: str, keep_mtime: bool) -> None:
    """A byte flipped inside a data file keeps its size; its stamp changes (and with its mtime put back
    by ``os.utime``, its ctime still does), so the hit re-hashes it and finds the change."""
    c = Cache(tmp_path)
    c.write("plan", KEY, write_npz, {})
    _settled(c)
    flip_byte(tmp_path / "plan" / KEY / name, keep_mtime)
    assert c.lookup("plan", KEY) is None
    assert re.fullmatch(rf"file {re.escape(name)} changed \(sha256 [0-9a-f]{{12}}…, recorded [0-9a-f]{{12}}…\)",
                        c.why("plan", KEY)), c.why("plan", KEY)
    calls = []
    r = c.run("plan", KEY, lambda d: calls.append(1) or write_npz(d))
    assert calls == [1] and not r.cached and r.reason.startswith(f"file {name} changed (sha256")
    assert c.lookup("plan", KEY) is not None and c.verify("plan", KEY) == "cached"


def test_entry_without_stamps_is_rehashed_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An entry published before stamps existed (no ``state.json``), or whose state file is garbled,
    is re-hashed on its next hit, which records the stamps; later hits read nothing."""
    c = Cache(tmp_path)
    e = c.write("plan", KEY, write_npz, {})
    hashed = _count_hashes(monkeypatch)
    for damage in (lambda p: p.unlink(), lambda p: p.write_text('{"stamps": [1, 2')):
        damage(e.path / "state.json")
        hashed.clear()
        time.sleep(0.05)
        assert c.lookup("plan", KEY) is not None and sorted(hashed) == ["data.npz", "notes.txt"]
        assert json.loads((e.path / "state.json").read_text())["stamps"].keys() == {"data.npz", "sub/notes.txt"}
        hashed.clear()
        assert c.lookup("plan", KEY) is not None and hashed == []
    assert json.loads((e.path / "meta.json").read_text()) == e.meta  # meta.json is never rewritten


def test_racy_stamp_is_rehashed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A stamp taken in the same clock tick as the file's last change cannot tell a later change in
    that tick (same times): such a file is re-hashed until its stamp is older than the state file."""
    c = Cache(tmp_path)
    c.write("plan", KEY, write_npz, {})
    e = _settled(c)
    state = e.path / "state.json"
    changed = min(max(p.stat().st_mtime_ns, p.stat().st_ctime_ns) for p in (e.path / "data.npz", e.path / "sub"
                                                                               / "notes.txt"))
    os.utime(state, ns=(changed, changed))  # as if the stamps were taken in the tick of the files' last change
    hashed = _count_hashes(monkeypatch)
    assert c.lookup("plan", KEY) is not None and sorted(hashed) == ["data.npz", "notes.txt"]


def test_damage_the_stamps_do_not_show_is_found_by_verify(tmp_path: Path) -> None:
    """The residual case (DVC's trade-off): damage that keeps size, times and inode -- only possible
    below the file system, simulated here by stamping the damaged file -- is served by a hit; the
    deep check of ``raico ls --verify`` finds it, and a stage that fails to load it says so
    (``raico.pipeline.engine.artifacts.CheckedArtifact``)."""
    c = Cache(tmp_path)
    c.write("plan", KEY, write_npz, {})
    e = _settled(c)
    p = e.path / "sub" / "notes.txt"
    flip_byte(p)
    stamps = json.loads((e.path / "state.json").read_text())["stamps"]
    st = p.stat()
    stamps["sub/notes.txt"] = [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino, stamps["sub/notes.txt"][4]]
    (e.path / "state.json").write_text(json.dumps({"stamps": stamps}))
    future = time.time_ns() + 10**9
    os.utime(e.path / "state.json", ns=(future, future))
    assert c.lookup("plan", KEY) is not None
    assert c.verify("plan", KEY).startswith("file sub/notes.txt changed (sha256")
    [info] = c.list(deep=True)
    assert not info.valid and info.reason.startswith("file sub/notes.txt changed (sha256")
    c.forget("plan", KEY)  # what a failed load does: the next hit re-hashes
    assert c.why("plan", KEY).startswith("file sub/notes.txt changed (sha256")


def test_derived_files_beside_the_data(tmp_path: Path) -> None:
    said: list[str] = []
    c = Cache(tmp_path, notify=said.append)
    e = c.write("plan", KEY, write_npz, {"metrics": {"x": 1}})
    assert c.derived(e) == {} and c.derived_check(e) == ({}, {})
    rec = c.write_derived(e, lambda d: (d / "recording.rrd").write_bytes(b"r" * 10))
    assert set(rec) == {"recording.rrd"} and rec["recording.rrd"]["size"] == 10
    assert set(c.derived(e)) == {"recording.rrd"} and c.lookup("plan", KEY) is not None
    assert said == []  # written for the first time: not a repair
    (e.path / "recording.rrd").write_bytes(b"r" * 3)  # damaged: no longer counts, the entry stays valid
    assert c.derived_check(e) == ({}, {"recording.rrd": "recording.rrd changed (size 3 B, recorded 10 B)"})
    assert c.lookup("plan", KEY) is not None
    c.write_derived(e, lambda d: (d / "recording.rrd").write_bytes(b"r" * 10))
    assert said == [f"plan {KEY}: recording regenerated: recording.rrd changed (size 3 B, recorded 10 B)"]
    time.sleep(0.05)
    assert set(c.derived(e)) == {"recording.rrd"}
    flip_byte(e.path / "recording.rrd", keep_mtime=True)  # same size, same mtime: its stamp still differs
    assert c.derived_check(e)[1]["recording.rrd"].startswith("recording.rrd changed (sha256")
    (e.path / "recording.rrd").unlink()
    assert c.derived_check(e)[1] == {"recording.rrd": "recording.rrd missing"}
    for name in ("data.npz", "state.json", "derived.json"):
        with pytest.raises(ValueError, match=f"may not be called '{name}'"):
            c.write_derived(e, lambda d, name=name: (d / name).write_bytes(b"x"))
    assert not [p for p in (tmp_path / "plan").iterdir() if p.name.startswith(".tmp-")]
    assert c.lookup("plan", KEY) is not None


def test_big_files_checked_by_size_only(tmp_path: Path) -> None:
    c = Cache(tmp_path, hash_limit=100)

    def w(d: Path) -> None:
        (d / "big.bin").write_bytes(b"a" * 200)
        (d / "small.bin").write_bytes(b"a" * 10)

    e = c.write("plan", KEY, w)
    assert e.meta["files"]["big.bin"]["sha256"] is None
    assert e.meta["files"]["small.bin"] == {"size": 10, "sha256": hashlib.sha256(b"a" * 10).hexdigest()}
    (e.path / "big.bin").write_bytes(b"b" * 200)  # same size: not detected (by design)
    assert c.lookup("plan", KEY) is not None
    (e.path / "big.bin").write_bytes(b"b" * 199)
    assert c.why("plan", KEY).startswith("file big.bin changed (size")


def test_require_missing(tmp_path: Path) -> None:
    with pytest.raises(MissingArtifact, match=f"^missing artifact fit/{KEY} under {re.escape(str(tmp_path))}$"):
        Cache(tmp_path).require("fit", KEY)


# --------------------------------------------------------------------------- races


def test_valid_entry_appearing_meanwhile_is_kept(tmp_path: Path) -> None:
    c = Cache(tmp_path)

    def other_process(d: Path) -> None:  # someone else publishes the same key first
        (d / "x.txt").write_text("ours")
        c.write("plan", KEY, lambda d2: (d2 / "x.txt").write_text("theirs") and None,
                {"who": "theirs"})

    e = c.write("plan", KEY, other_process, {"who": "ours"})
    assert e.meta["who"] == "theirs" and (e.path / "x.txt").read_text() == "theirs"
    assert sorted(os.listdir(tmp_path / "plan")) == [KEY]


def test_invalid_entry_there_is_replaced(tmp_path: Path) -> None:
    c = Cache(tmp_path)
    (tmp_path / "plan" / KEY).mkdir(parents=True)
    (tmp_path / "plan" / KEY / "junk.npz").write_bytes(b"junk")
    assert c.why("plan", KEY) == "cache entry incomplete (meta.json missing)"
    e = c.write("plan", KEY, write_npz, {})
    assert not (e.path / "junk.npz").exists() and c.lookup("plan", KEY) is not None
    assert sorted(os.listdir(tmp_path / "plan")) == [KEY]


def test_remove(tmp_path: Path) -> None:
    c = Cache(tmp_path)
    c.write("plan", KEY, write_npz)
    assert c.remove("plan", KEY) and not c.remove("plan", KEY)
    assert os.listdir(tmp_path / "plan") == []


# --------------------------------------------------------------------------- list / stale


def test_list_skips_non_entries(tmp_path: Path) -> None:
    c = Cache(tmp_path)
    (tmp_path / "README.md").write_text("x")
    (tmp_path / "report" / "figures").mkdir(parents=True)
    c.write("plan", KEY, write_npz, {})
    c.write("fit", KEY, write_npz, {})
    rows = c.list()
    assert [(r.stage, r.key, r.valid) for r in rows] == [("fit", KEY, True), ("plan", KEY, True)]
    meta = json.loads((tmp_path / "fit" / KEY / "meta.json").read_text())
    # on disk: the recorded data files plus meta.json itself and the stamps (state.json)
    size = sum(f["size"] for f in meta["files"].values()) + sum(
        (tmp_path / "fit" / KEY / n).stat().st_size for n in ("meta.json", "state.json"))
    assert rows[0].size == size and rows[0].created == meta["created"] and rows[0].reason == "cached"
    assert [r.stage for r in c.list("plan")] == ["plan"] and c.list("nostage") == []


def test_old_tmp_without_owner_is_stale(tmp_path: Path) -> None:
    c = Cache(tmp_path, stale_after=60)
    fresh = tmp_path / "plan" / ".tmp-junk"
    old = tmp_path / "plan" / ".tmp-old"
    for p in (fresh, old):
        p.mkdir(parents=True)
    os.utime(old, (time.time() - 3600, time.time() - 3600))
    assert c.cleanup_stale() == [old] and fresh.exists()


def test_live_writer_tmp_is_not_removed(tmp_path: Path) -> None:
    c = Cache(tmp_path, stale_after=0)
    seen: list[list[Path]] = []

    def w(d: Path) -> None:
        os.utime(d, (0, 0))  # looks ancient, but its writer (this process) is alive
        seen.append(Cache(tmp_path, stale_after=0).cleanup_stale())
        (d / "x.txt").write_text("x")

    c.write("plan", KEY, w)
    assert seen == [[]] and c.lookup("plan", KEY) is not None


def test_sigkill_mid_write_leaves_no_entry(tmp_path: Path) -> None:
    script = textwrap.dedent(
        f"""
        import sys, time
        from pathlib import Path
        from raico.pipeline.engine.cache import Cache
        def writer(d):
            (d / "data.npz").write_bytes(b"x" * 4096)
            print("started", flush=True)
            time.sleep(60)
        Cache(Path({str(tmp_path)!r})).write("plan", {KEY!r}, writer, {{}})
        """
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert line.strip() == "started", proc.stderr.read() if proc.poll() is not None else line
        os.kill(proc.pid, signal.SIGKILL)
        assert proc.wait(timeout=10) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()

    c = Cache(tmp_path)
    [tmp] = os.listdir(tmp_path / "plan")
    assert tmp.startswith(".tmp-" + KEY)
    assert c.lookup("plan", KEY) is None and c.why("plan", KEY) == "no cache entry"
    rows = c.list()
    assert [(r.valid, r.reason) for r in rows] == [
        (False, f"abandoned temporary folder (writer pid {proc.pid} is gone)")]

    calls = []
    r = c.run("plan", KEY, lambda d: calls.append(1) or write_npz(d))
    assert calls == [1] and not r.cached
    assert sorted(os.listdir(tmp_path / "plan")) == [KEY]  # stale tmp cleaned by the write
    assert [(x.key, x.valid) for x in c.list()] == [(KEY, True)]


# --------------------------------------------------------------------------- provenance, errors


def test_git_commit_tolerates_no_repo(tmp_path: Path) -> None:
    assert _REAL_GIT_COMMIT(tmp_path) is None


def test_errors_one_line() -> None:
    err = BadInput("unknown plant 'foo'\n  choose one of: arm2, arm7")
    assert str(err) == "unknown plant 'foo' choose one of: arm2, arm7"
    assert isinstance(err, RaicoError)
    # one exit code per kind of error: bad input 2, missing 3, corrupt 4, other 1
    codes = {cls.__name__: cls("x").exit_code for cls in (RaicoError, BadInput, MissingArtifact, CorruptArtifact)}
    assert codes == {"RaicoError": 1, "BadInput": 2, "MissingArtifact": 3, "CorruptArtifact": 4}
    assert issubclass(CorruptArtifact, RaicoError) and issubclass(MissingArtifact, RaicoError)
    assert str(MissingArtifact()) == "MissingArtifact"


# --------------------------------------------------------------------------- package versions


def _installed(monkeypatch: pytest.MonkeyPatch, **versions: str) -> None:
    """Pretend other versions of some packages are installed from now on."""
    real = dict(keys_mod.package_versions())
    fake = {**real, **{k.replace("_", "-"): v for k, v in versions.items()}}
    monkeypatch.setattr(keys_mod, "package_versions", lambda: fake)


def test_entry_made_with_other_package_versions_is_computed_again(tmp_path: Path, monkeypatch) -> None:
    """A hit must be made with the installed numeric packages: another numpy is a recompute that says why;
    the entry stays a valid input (its data are what they are) and `ls --verify` flags it."""
    c = Cache(tmp_path)
    c.write("plan", KEY, write_npz, {})
    made = keys_mod.package_versions()["numpy"]
    assert c.run("plan", KEY, write_npz).cached
    _installed(monkeypatch, numpy="0.0.test")
    assert c.lookup("plan", KEY) is not None and c.require("plan", KEY)  # an input as it is
    [info] = c.list(deep=True)
    assert info.valid and info.reason == f"made with numpy {made} (installed 0.0.test)"
    assert c.list()[0].reason == "cached"  # the cheap listing does not compare
    calls = []
    r = c.run("plan", KEY, lambda d: calls.append(1) or write_npz(d))
    assert calls == [1] and not r.cached and r.reason == f"made with numpy {made} (installed 0.0.test)"
    assert r.entry.meta["packages"]["numpy"] == "0.0.test"
    assert c.run("plan", KEY, write_npz).cached  # the new entry is current


def test_other_versions_of_packages_outside_the_numbers_keep_the_hit(tmp_path: Path, monkeypatch) -> None:
    c = Cache(tmp_path)
    c.write("plan", KEY, write_npz, {})
    _installed(monkeypatch, typer="0.0.test", mcap="0.0.test")
    assert c.run("plan", KEY, write_npz).cached


def test_recording_written_by_another_rerun_is_written_again(tmp_path: Path, monkeypatch) -> None:
    c = Cache(tmp_path)
    e = c.write("plan", KEY, write_npz, {})
    c.write_derived(e, lambda d: (d / "recording.rrd").write_bytes(b"rrd"))
    assert c.derived_check(e) == ({"recording.rrd": c.derived(e)["recording.rrd"]}, {})
    made = keys_mod.package_versions()["rerun-sdk"]
    _installed(monkeypatch, rerun_sdk="0.0.test")
    intact, bad = c.derived_check(e)
    assert intact == {} and bad == {"recording.rrd": f"recording.rrd written by rerun-sdk {made} (installed 0.0.test)"}
    assert c.run("plan", KEY, write_npz).cached  # the data stay a hit: only the recording is stale


def test_key_lock_one_holder_a_waiter_told_reentrant_and_no_file_left(tmp_path, monkeypatch):
    """One holder at a time (a second thread waits and is told once), re-entrant in its thread, the
    lock file removed on release; a file system without locks runs unlocked rather than failing."""
    import errno
    import fcntl
    import threading

    from raico.pipeline.engine.locks import key_lock

    path, order, told = tmp_path / ".lock-k", [], []

    def other():
        with key_lock(path, lambda: told.append(1)):
            order.append("other")

    with key_lock(path):
        with key_lock(path):   # nested in the same thread: no deadlock
            t = threading.Thread(target=other)
            t.start()
            for _ in range(200):
                if told:
                    break
                time.sleep(0.01)
            order.append("first")
    t.join(10)
    assert order == ["first", "other"] and told == [1] and not path.exists()

    def no_locks(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    with key_lock(path):
        order.append("unlocked")
    assert order[-1] == "unlocked" and not path.exists()
