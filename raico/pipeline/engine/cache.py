"""Content-addressed artifact cache, in the style of DVC's run cache.

Layout: ``root/<stage>/<key>/`` holds ``meta.json`` plus the files the stage wrote; a valid entry is
returned as a :class:`raico.stages.base.Artifact` (its folder and its record).
A stage's key hashes its name, code version, declared config and input keys
(:func:`raico.pipeline.engine.keys.stage_key`). Writes go to
``root/<stage>/.tmp-<key>-<host>-<pid>-<start>-<rand>/`` and become visible in a single ``os.rename``; a folder is a valid entry only if its
``meta.json`` says ``"complete": true`` and every recorded file still has its size
and sha256 (files under :data:`HASH_LIMIT`; bigger ones: the size).

Integrity on every hit without re-hashing (like DVC's state database): ``state.json`` beside
``meta.json`` holds each file's *stamp* -- size, modification and status-change times (ns) and
inode -- with the sha256 the file was verified against. A file whose stamp still matches is not
read; any other (edited, copied, restored from a backup, or changed within the file system's clock
tick of its stamp) is re-hashed once and its new stamp recorded. ``meta.json`` stays immutable
(it carries its own checksum); ``state.json`` is only ever a cache of verified facts, so a lost,
stale or damaged one costs a re-hash, never a wrong answer.

Identical runs in flight compute once: a miss takes an exclusive ``fcntl`` lock on
``root/<stage>/.lock-<key>`` (:func:`raico.pipeline.engine.locks.key_lock`; removed on release), checks
again, and computes only if the entry is still missing; the others wait and find the entry. The derived files (recordings) are written and
stamped under the same lock, so no two writers interleave their files and records.
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
import hashlib
import json
import os
import re
import secrets
import shutil
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path, PurePath
from typing import Any

import numpy as np

from raico.pipeline.engine import keys  # keys.package_versions, keys.git_commit: looked up when called
from raico.pipeline.engine.atomic import fsync_dir
from raico.pipeline.engine.keys import FORMAT, META_SUM, meta_checksum, version_drift
from raico.pipeline.engine.locks import TMP_PREFIX, host_tag, key_lock, parse_tmp, pid_alive, tmp_name
from raico.pipeline.errors import BadInput, CorruptArtifact, MissingArtifact, StorageError, os_error_text
from raico.stages.base import Artifact

__all__ = ["HASH_LIMIT", "Cache", "EntryInfo", "RunResult", "WriteResult"]

META = "meta.json"
DERIVED = "derived.json"
STATE = "state.json"  # stamps of verified files (see the module docstring); not part of the entry's record
HASH_LIMIT = 50 * 1024 * 1024  # files at least this big are checked by size only
LOCK_PREFIX = ".lock-"  # root/<stage>/.lock-<key>: held while one call computes or records the entry
_STAGE_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")
_KEY_RE = re.compile(r"^[0-9a-f]{8,64}$")
_CHUNK = 1 << 20


# --------------------------------------------------------------------------- records


@dataclass(frozen=True)
class EntryInfo:
    """One row of :meth:`Cache.list` (valid entries, invalid ones and temporary folders); a valid
    entry's record is ``entry``."""

    stage: str
    key: str
    path: Path
    valid: bool
    reason: str  # "cached" when valid
    created: str | None  # ISO 8601 UTC from meta.json
    size: int  # bytes on disk
    entry: Artifact | None = field(default=None, compare=False, repr=False)  # a valid entry


@dataclass
class WriteResult:
    """Optional return value of a writer: extra meta and timings (seconds)."""

    meta: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class RunResult:
    """Outcome of :meth:`Cache.run`: the entry, whether it was a hit, and why it ran."""

    entry: Artifact
    cached: bool
    reason: str  # "cached" or why the writer had to run


Writer = Callable[[Path], "WriteResult | Mapping[str, Any] | None"]


# --------------------------------------------------------------------------- stamps and files


def _hash_and_sync(path: Path, limit: int) -> tuple[int, str | None, os.stat_result]:
    """Size, sha256 (None if size >= limit) and stat of ``path``; fsyncs it on the way."""
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        digest: str | None = None
        if size < limit:
            h = hashlib.sha256()
            while chunk := f.read(_CHUNK):
                h.update(chunk)
            digest = h.hexdigest()
        os.fsync(f.fileno())
        st = os.fstat(f.fileno())
    return size, digest, st


def _stamp(st: os.stat_result, digest: str | None) -> list:
    """A file's stamp: ``[size, mtime_ns, ctime_ns, inode, sha256 it was verified against]``.

    ``ctime`` cannot be set from user space (``os.utime`` moves it to now), so a same-size edit
    whose modification time was put back still changes the stamp."""
    return [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino, digest]


def _trusted(stamp: Any, st: os.stat_result, digest: str | None, state_mtime_ns: int) -> bool:
    """True if ``stamp`` (from the state file) vouches for the file ``st`` having ``digest``: same
    size, times and inode, verified against the same digest, and last changed before the state file
    was written (a change within the same clock tick as the stamp would keep the times: racy)."""
    return (isinstance(stamp, list) and len(stamp) == 5 and stamp[4] == digest
            and stamp[:4] == [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino]
            and max(st.st_mtime_ns, st.st_ctime_ns) < state_mtime_ns)


def _read_state(path: Path) -> tuple[dict[str, Any], int]:
    """(name -> stamp, the state file's own mtime in ns) of entry folder ``path``; ({}, 0) if there
    is none or it is unreadable (then every file is re-hashed once)."""
    try:
        with open(path / STATE, "rb") as f:
            mtime = os.fstat(f.fileno()).st_mtime_ns
            doc = json.loads(f.read())
    except (OSError, ValueError):
        return {}, 0
    stamps = doc.get("stamps") if isinstance(doc, dict) else None
    return (stamps, mtime) if isinstance(stamps, dict) else ({}, 0)


def _write_state(path: Path, stamps: Mapping[str, Any]) -> None:
    """Replace the state file of entry folder ``path`` (atomically; not synced: it is a cache, and a
    lost one only costs a re-hash). A read-only cache keeps working without it."""
    tmp = path / f".{STATE}.{secrets.token_hex(4)}.tmp"
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump({"stamps": dict(sorted(stamps.items()))}, f, separators=(",", ":"))
        os.replace(tmp, path / STATE)
    except OSError:
        with contextlib.suppress(OSError):
            tmp.unlink()


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def _dir_size(path: Path) -> int:
    total = 0
    for dirpath, _, names in os.walk(path):
        for n in names:
            try:
                total += os.lstat(os.path.join(dirpath, n)).st_size
            except OSError:
                pass
    return total


def _os_text(err: OSError, tmp: Path | None, final: Path) -> str:
    """:func:`~raico.pipeline.errors.os_error_text` with paths in the temporary folder shown where they
    would have been published (the user never sees ``.tmp-*`` names)."""
    name = err.filename
    if name is not None and tmp is not None and str(name).startswith(str(tmp)):
        name = str(final) + str(name)[len(str(tmp)):]
    where = name if name is not None else final
    return os_error_text(OSError(err.errno, err.strerror or str(err), where))


def _json_default(obj: Any) -> Any:
    """``json.dump`` fallback for meta values (numpy, paths, sets, enums, dataclasses)."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, PurePath):
        return obj.as_posix()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj, key=repr)
    if isinstance(obj, enum.Enum):
        return obj.value
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dataclasses.asdict(obj)
    raise TypeError(f"meta value of type {type(obj).__name__} is not JSON serializable")


# --------------------------------------------------------------------------- cache


class Cache:
    """Artifact cache rooted at ``root`` (see module docstring)."""

    def __init__(
        self, root: Path | str, *, hash_limit: int = HASH_LIMIT, stale_after: float = 600.0,
        notify: Callable[[str], None] | None = None,
    ) -> None:
        """``stale_after``: age (s) after which a temporary folder whose owner cannot be
        checked (other host, unparseable name) counts as abandoned. ``notify(line)`` hears of
        repairs the cache makes on its own (a damaged recording written again)."""
        self.root = Path(root)
        self.hash_limit = hash_limit
        self.stale_after = stale_after
        self.notify = notify

    # ---- paths and validation

    @staticmethod
    def _check_stage(stage: str) -> None:
        if not _STAGE_RE.match(stage):
            raise BadInput(f"invalid stage name {stage!r}")

    def path(self, stage: str, key: str) -> Path:
        """Folder of entry ``stage/key`` (validates both names)."""
        self._check_stage(stage)
        if not _KEY_RE.match(key):
            raise BadInput(f"invalid cache key {key!r} (expected lowercase hex)")
        return self.root / stage / key

    def _check(self, stage: str, key: str, deep: bool = False) -> tuple[Artifact | None, str]:
        """(entry, "cached") if valid, else (None, reason); ``deep`` re-hashes every file, else only
        those whose stamps do not vouch for them."""
        path = self.path(stage, key)
        meta, reason = self._read_meta(path, stage, key)
        if meta is None:
            return None, reason
        files = meta["files"]
        stamps, state_mtime = _read_state(path)
        reason, fresh = self._check_files(path, files, deep, stamps, state_mtime)
        if reason:
            return None, reason
        if fresh:
            _write_state(path, {**stamps, **fresh})
        return Artifact(stage, key, path, meta), "cached"

    def stored_meta(self, stage: str, key: str) -> tuple[dict[str, Any] | None, str]:
        """(meta, "") if entry ``stage/key`` has an intact, complete ``meta.json`` (whatever the
        state of its data files: what a rebuild needs), else (None, why not)."""
        return self._read_meta(self.path(stage, key), stage, key)

    @staticmethod
    def _read_meta(path: Path, stage: str, key: str) -> tuple[dict[str, Any] | None, str]:
        if not path.is_dir():
            return None, "no cache entry"
        meta_path = path / META
        if not meta_path.is_file():
            return None, f"cache entry incomplete ({META} missing)"
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            return None, f"cache entry corrupt ({META} unreadable: {type(exc).__name__})"
        if not isinstance(meta, dict):
            return None, f"cache entry corrupt ({META} is not an object)"
        if meta.get("complete") is not True:
            return None, "cache entry incomplete (not marked complete)"
        if meta.get(META_SUM) != meta_checksum(meta):
            return None, f"cache entry corrupt ({META} was edited: its checksum does not match its content)"
        if meta.get("stage") != stage or meta.get("key") != key:
            owner = f"{meta.get('stage')}/{meta.get('key')}"
            return None, f"cache entry corrupt ({META} belongs to {owner})"
        if not isinstance(meta.get("files"), dict):
            return None, f"cache entry corrupt ({META} has no file list)"
        return meta, ""

    def _check_files(self, path: Path, files: Mapping[str, Any], deep: bool,
                     stamps: Mapping[str, Any] | None = None, state_mtime: int = 0) -> tuple[str, dict[str, list]]:
        """("", fresh stamps) if every recorded file has its size and sha256, else (why not, {}).

        A file whose stamp in ``stamps`` vouches for it is not read (unless ``deep``); any other is
        re-hashed, and its new stamp returned. Files without a sha256 (at least :attr:`hash_limit`
        bytes) are checked by size only."""
        root = path.resolve()
        stamps = stamps or {}
        fresh: dict[str, list] = {}
        for name, rec in sorted(files.items()):
            fp = path / name
            if not isinstance(rec, dict) or not isinstance(rec.get("size"), int):
                return f"cache entry corrupt (bad record for file {name})", {}
            if ".." in PurePath(name).parts or not fp.resolve().is_relative_to(root):
                return f"cache entry corrupt (file {name} outside the entry)", {}
            try:
                st = fp.stat()
            except OSError:
                return f"file {name} missing", {}
            if st.st_size != rec["size"]:
                return f"file {name} changed (size {st.st_size} B, recorded {rec['size']} B)", {}
            digest = rec.get("sha256")
            if not digest or st.st_size >= self.hash_limit:
                continue
            if not deep and _trusted(stamps.get(name), st, digest, state_mtime):
                continue
            try:
                actual = _sha256(fp)
            except OSError as exc:
                return f"file {name} unreadable ({exc.strerror})", {}
            if actual != digest:
                return f"file {name} changed (sha256 {actual[:12]}…, recorded {digest[:12]}…)", {}
            fresh[name] = _stamp(st, digest)
        return "", fresh

    def check(self, stage: str, key: str) -> tuple[Artifact | None, str]:
        """(entry, "cached") if ``stage/key`` is valid and was made with the installed versions of
        ``NUMERIC_PACKAGES``, else (None, why not): what a run asks before it computes."""
        return self._check_current(stage, key)

    def _check_current(self, stage: str, key: str) -> tuple[Artifact | None, str]:
        entry, reason = self._check(stage, key)
        drift = version_drift(entry.meta) if entry is not None else ""
        return (None, drift) if drift else (entry, reason)

    def verify(self, stage: str, key: str) -> str:
        """Deep check (every file re-hashed): "cached" if valid, else the reason."""
        return self._check(stage, key, deep=True)[1]

    def lookup(self, stage: str, key: str) -> Artifact | None:
        """The entry if it is complete and valid, else None (see :meth:`why`)."""
        return self._check(stage, key)[0]

    def why(self, stage: str, key: str) -> str:
        """"cached" for a valid entry, otherwise why the stage must run."""
        return self._check(stage, key)[1]

    def require(self, stage: str, key: str) -> Artifact:
        """The entry, or :class:`MissingArtifact` / :class:`CorruptArtifact` (an input; its ``ref``
        and ``reason`` say which entry and why)."""
        entry, reason = self._check(stage, key)
        if entry is not None:
            return entry
        if reason == "no cache entry":
            raise MissingArtifact(f"missing artifact {stage}/{key} under {self.root}")
        raise CorruptArtifact(f"artifact {stage}/{key} is invalid: {reason}", ref=f"{stage}/{key}", reason=reason)

    def forget(self, stage: str, key: str) -> None:
        """Drop the stamps of entry ``stage/key``: its next check re-hashes every file (after a
        stage failed to read a file whose stamp looked intact)."""
        with contextlib.suppress(OSError):
            (self.path(stage, key) / STATE).unlink()

    def remove(self, stage: str, key: str) -> bool:
        """Delete entry ``stage/key`` (valid or not) atomically; True if something was there."""
        path = self.path(stage, key)
        if not path.exists():
            return False
        trash = path.parent / tmp_name(key)
        try:
            os.rename(path, trash)
        except FileNotFoundError:
            return False
        if trash.is_dir() and not trash.is_symlink():
            shutil.rmtree(trash, ignore_errors=True)
        else:
            trash.unlink(missing_ok=True)
        return True

    # ---- writing

    @contextlib.contextmanager
    def lock(self, stage: str, key: str) -> Iterator[None]:
        """Hold entry ``stage/key``'s lock (:func:`key_lock`): one call at a time computes it or writes
        its derived files; ``notify`` hears once that this one waits for another."""
        final = self.path(stage, key)

        def waiting() -> None:
            if self.notify is not None:
                self.notify(f"{stage} {key}: an identical call is computing it; waiting for it")

        with contextlib.ExitStack() as stack:
            try:
                final.parent.mkdir(parents=True, exist_ok=True)
                stack.enter_context(key_lock(final.parent / f"{LOCK_PREFIX}{key}", waiting))
            except OSError as e:   # a read-only or full cache: said as for any write there
                cause = OSError(e.errno, e.strerror or str(e), final.parent)
                raise StorageError(f"cannot write artifact {stage}/{key}: {_os_text(cause, None, final)}") from None
            yield

    def write(
        self, stage: str, key: str, writer: Writer, meta: Mapping[str, Any] | None = None
    ) -> Artifact:
        """Run ``writer(tmp_dir)`` and publish its files as entry ``stage/key`` atomically.

        Always calls the writer (use :meth:`run` to skip on a hit). If the writer raises
        (also KeyboardInterrupt or an interrupt), the temporary folder is removed and the
        exception propagates; an ``OSError`` (read-only, full, not a folder) becomes a
        :class:`~raico.pipeline.errors.StorageError` naming the entry's path and the cause. If a
        valid entry appeared meanwhile it is kept and ours discarded; an invalid one is replaced.
        """
        final = self.path(stage, key)
        stage_dir = final.parent
        tmp = stage_dir / tmp_name(key)
        try:
            stage_dir.mkdir(parents=True, exist_ok=True)
            self.cleanup_stale(stage)
            tmp.mkdir()
        except OSError as e:
            raise StorageError(f"cannot write artifact {stage}/{key}: {_os_text(e, tmp, final)}") from None
        try:
            return self._write_into(stage, key, writer, meta, tmp, final)
        except OSError as e:
            raise StorageError(f"cannot write artifact {stage}/{key}: {_os_text(e, tmp, final)}; "
                               f"nothing was cached") from None
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)

    def _write_into(self, stage: str, key: str, writer: Writer, meta: Mapping[str, Any] | None, tmp: Path,
                    final: Path) -> Artifact:
        """The body of :meth:`write`: the writer's files, ``meta.json``, publication."""
        t0 = time.perf_counter()
        result = writer(tmp)
        t_write = time.perf_counter() - t0
        extra, timings = self._result_parts(result)
        for reserved in (META, STATE):
            if (tmp / reserved).exists():
                raise ValueError(f"the writer of stage {stage!r} must not create {reserved}")
        t1 = time.perf_counter()
        files, stamps = self._record_files(tmp)
        timings = {"write_s": t_write, **timings, "hash_s": time.perf_counter() - t1}
        doc = self._meta(stage, key, dict(meta or {}), extra, timings, files)
        with open(tmp / META, "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=2, sort_keys=True, default=_json_default)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        _write_state(tmp, stamps)  # the files as published (a rename of their folder keeps their stamps)
        fsync_dir(tmp)
        return self._publish(stage, key, tmp, final, doc)

    def run(
        self, stage: str, key: str, writer: Writer, meta: Mapping[str, Any] | None = None
    ) -> RunResult:
        """Return the cached entry (writer not called) or write it; says why it ran."""
        entry, reason = self._check_current(stage, key)
        if entry is not None:
            return RunResult(entry, True, reason)
        with self.lock(stage, key):   # an identical call in flight computes it once; this one waits
            entry, _ = self._check_current(stage, key)
            if entry is not None:
                return RunResult(entry, True, "cached")
            return RunResult(self.write(stage, key, writer, meta), False, reason)

    @staticmethod
    def _result_parts(result: Any) -> tuple[dict[str, Any], dict[str, float]]:
        if result is None:
            return {}, {}
        if isinstance(result, WriteResult):
            return dict(result.meta), dict(result.timings)
        if isinstance(result, Mapping):
            extra = dict(result)
            timings = extra.pop("timings", None) or {}
            return extra, dict(timings)
        kind = type(result).__name__
        raise TypeError(f"a writer must return WriteResult, dict or None, not {kind}")

    def _record_files(self, tmp: Path) -> tuple[dict[str, dict[str, Any]], dict[str, list]]:
        """(name -> {size, sha256}, name -> stamp) of every file the writer left in ``tmp``."""
        files: dict[str, dict[str, Any]] = {}
        stamps: dict[str, list] = {}
        for dirpath, dirnames, names in os.walk(tmp):
            dirnames.sort()
            for n in sorted(names):
                p = Path(dirpath) / n
                if p.is_symlink():
                    raise ValueError(f"artifacts must be self-contained; {n!r} is a symlink")
                size, digest, st = _hash_and_sync(p, self.hash_limit)
                name = p.relative_to(tmp).as_posix()
                files[name] = {"size": size, "sha256": digest}
                stamps[name] = _stamp(st, digest)
            if Path(dirpath) != tmp:
                fsync_dir(Path(dirpath))
        return files, stamps

    @staticmethod
    def _meta(
        stage: str, key: str, meta: dict[str, Any], extra: dict[str, Any],
        timings: dict[str, float], files: dict[str, dict[str, Any]],
    ) -> dict[str, Any]:
        doc = {
            "config": {},
            "inputs": [],
            **meta,
            **extra,
            "format": FORMAT,
            "stage": stage,
            "key": key,
            "packages": keys.package_versions(),
            "git_commit": keys.git_commit(),
            "timings": {**(meta.get("timings") or {}), **timings},
            "created": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "files": files,
            "complete": True,
        }
        doc = json.loads(json.dumps(doc, default=_json_default))  # what the file will hold
        doc[META_SUM] = meta_checksum(doc)
        return doc

    def _publish(
        self, stage: str, key: str, tmp: Path, final: Path, doc: dict[str, Any]
    ) -> Artifact:
        """Rename ``tmp`` to ``final``; keep a valid, current entry already there, replace an invalid one
        or one made with other package versions (:func:`version_drift`)."""
        for _ in range(5):
            try:
                os.rename(tmp, final)  # atomic; fails if final is a non-empty folder
            except OSError:
                existing, _ = self._check_current(stage, key)
                if existing is not None:
                    return existing  # someone else finished first; ours is discarded
                if final.exists():
                    self.remove(stage, key)  # invalid: move aside, then retry
                continue
            fsync_dir(final.parent)
            return Artifact(stage, key, final, json.loads(json.dumps(doc, default=_json_default)))
        raise CorruptArtifact(f"could not publish artifact {stage}/{key}: {final} keeps changing")

    # ---- derived files (recordings made from the stored data)

    def derived(self, entry: Artifact) -> dict[str, dict[str, Any]]:
        """Name -> record of the derived files of ``entry`` that are intact (checked like data
        files: stamps, else sha256)."""
        return self.derived_check(entry)[0]

    def derived_check(self, entry: Artifact) -> tuple[dict[str, dict[str, Any]], dict[str, str]]:
        """(name -> record of each intact derived file, name -> why each other recorded one is not:
        ``recording.rrd changed (size ...)``, ``trajectory.mcap missing``)."""
        try:
            recs = json.loads((entry.path / DERIVED).read_text(encoding="utf-8"))
        except FileNotFoundError:
            return {}, {}
        except (OSError, ValueError) as exc:
            return {}, {DERIVED: f"{DERIVED} unreadable ({type(exc).__name__})"}
        if not isinstance(recs, dict):
            return {}, {DERIVED: f"{DERIVED} is not an object"}
        stamps, state_mtime = _read_state(entry.path)
        good: dict[str, dict[str, Any]] = {}
        bad: dict[str, str] = {}
        fresh: dict[str, list] = {}
        for n, r in recs.items():
            reason, new = self._check_files(entry.path, {n: r}, False, stamps, state_mtime)
            writer_version = r.get("rerun-sdk", None) if isinstance(r, dict) else None
            if reason:
                bad[n] = reason.removeprefix("file ")
            elif writer_version is not None and writer_version != keys.package_versions()["rerun-sdk"]:
                bad[n] = f"{n} written by rerun-sdk {writer_version} (installed {keys.package_versions()['rerun-sdk']})"
            else:
                good[n] = r
                fresh.update(new)
        if fresh:
            _write_state(entry.path, {**stamps, **fresh})
        return good, bad

    def write_derived(self, entry: Artifact, writer: Callable[[Path], None]) -> dict[str, dict[str, Any]]:
        """Run ``writer(tmp_dir)`` and move what it wrote into ``entry`` beside the data.

        Each file is renamed into place (atomic per file), then ``derived.json`` is
        replaced atomically; a failure leaves the entry's data untouched and no temporary
        folder. Returns the records of the files written.
        """
        damaged = self.derived_check(entry)[1]
        tmp = entry.path.parent / tmp_name(entry.key)
        try:
            tmp.mkdir()
            new = self._write_derived_from(entry, writer, tmp)
            repaired = [why for name, why in sorted(damaged.items()) if name in new or name == DERIVED]
            if repaired and self.notify is not None:
                self.notify(f"{entry.stage} {entry.key}: recording regenerated: {'; '.join(repaired)}")
            return new
        except OSError as e:
            raise StorageError(f"cannot write the derived files (recording) of {entry.stage}/{entry.key}: "
                               f"{_os_text(e, tmp, entry.path)}; its data stay cached and the next call "
                               f"writes them") from None
        finally:
            shutil.rmtree(tmp, ignore_errors=True)

    def _write_derived_from(self, entry: Artifact, writer: Callable[[Path], None], tmp: Path
                            ) -> dict[str, dict[str, Any]]:
        writer(tmp)
        new: dict[str, dict[str, Any]] = {}
        for p in sorted(tmp.iterdir()):
            if p.name in (META, DERIVED, STATE) or p.name in entry.meta.get("files", {}) or not p.is_file():
                raise ValueError(f"a derived file may not be called {p.name!r}")
            size, digest, _ = _hash_and_sync(p, self.hash_limit)
            new[p.name] = {"size": size, "sha256": digest, "rerun-sdk": keys.package_versions()["rerun-sdk"]}
        for name in new:
            os.replace(tmp / name, entry.path / name)
        recs = {**self.derived(entry), **new}
        doc = tmp / DERIVED
        doc.write_text(json.dumps(recs, indent=2, sort_keys=True) + "\n", encoding="utf-8")
        os.replace(doc, entry.path / DERIVED)
        fsync_dir(entry.path)
        stamps, _ = _read_state(entry.path)
        for name, rec in new.items():  # stamped where they now are (a rename moves a file's ctime)
            with contextlib.suppress(OSError):
                stamps[name] = _stamp((entry.path / name).stat(), rec["sha256"])
        _write_state(entry.path, stamps)
        return new

    # ---- listing and cleanup

    def _stage_dirs(self, stage: str | None) -> list[Path]:
        if stage is not None:
            self._check_stage(stage)
            d = self.root / stage
            return [d] if d.is_dir() else []
        if not self.root.is_dir():
            return []
        return sorted(p for p in self.root.iterdir() if p.is_dir() and _STAGE_RE.match(p.name))

    def _tmp_state(self, path: Path) -> tuple[bool, str]:
        """(stale, description) of a temporary folder."""
        parsed = parse_tmp(path.name)
        if parsed is not None and parsed[1] == host_tag():
            pid, start = parsed[2], parsed[3]
            if pid_alive(pid, start):
                return False, f"write in progress (pid {pid})"
            return True, f"abandoned temporary folder (writer pid {pid} is gone)"
        try:
            age = time.time() - path.stat().st_mtime
        except OSError:
            return True, "vanished temporary folder"
        if age > self.stale_after:
            return True, f"abandoned temporary folder ({age:.0f} s old)"
        return False, "temporary folder (owner unknown)"

    def cleanup_stale(self, stage: str | None = None) -> list[Path]:
        """Remove temporary folders of dead or long-gone writers; returns what was removed."""
        removed: list[Path] = []
        for d in self._stage_dirs(stage):
            for p in sorted(d.glob(TMP_PREFIX + "*")):
                if p.is_dir() and self._tmp_state(p)[0]:
                    shutil.rmtree(p, ignore_errors=True)
                    removed.append(p)
        return removed

    def is_empty(self) -> bool:
        """Whether no stage holds an entry (a key folder, valid or not): a run from here starts from an
        empty cache. Stops at the first entry found."""
        return not any(_KEY_RE.match(p.name) and p.is_dir() for d in self._stage_dirs(None) for p in d.iterdir())

    def list(self, stage: str | None = None, *, deep: bool = False) -> list[EntryInfo]:
        """Every entry (valid or not) and temporary folder, for ``raico ls``.

        ``deep=True`` also re-hashes every file (``raico ls --verify``).
        """
        rows: list[EntryInfo] = []
        for d in self._stage_dirs(stage):
            for p in sorted(d.iterdir()):
                if not p.is_dir():
                    continue
                if p.name.startswith(TMP_PREFIX):
                    parsed = parse_tmp(p.name)
                    _, desc = self._tmp_state(p)
                    rows.append(EntryInfo(d.name, parsed[0] if parsed else "?", p, False, desc,
                                          None, _dir_size(p)))
                elif _KEY_RE.match(p.name):
                    entry, reason = self._check(d.name, p.name, deep=deep)
                    if entry is not None and deep and version_drift(entry.meta):
                        reason = version_drift(entry.meta)  # valid data, stale for this installation
                    created = entry.meta.get("created") if entry else None
                    rows.append(EntryInfo(d.name, p.name, p, entry is not None, reason,
                                          created, _dir_size(p), entry))
        return rows
