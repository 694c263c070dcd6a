"""A stored entry as a stage reads it: :func:`as_artifact` gives the entry (a ``raico.stages.base.Artifact``)
whose loads turn a damaged file into one clean error naming the entry (``UnreadableArtifact``).

Used by the runner (a stage's inputs and steps) and by whatever reads entries beside it (the
recorders, the report), without importing the runner.
"""

from __future__ import annotations

import struct
import zipfile
import zlib
from typing import Any

from raico.pipeline.engine.cache import Cache
from raico.pipeline.errors import UnreadableArtifact
from raico.stages.base import Artifact


def as_artifact(entry: Artifact) -> CheckedArtifact:
    """The entry as a stage reads it: the same record, whose loads check the data."""
    return CheckedArtifact(entry.stage, entry.key, entry.path, entry.meta, entry.cached)


# what numpy, zipfile, zlib and json raise on a damaged file (a bad CRC, a garbled array header, a
# truncated member, bytes that are not UTF-8); MemoryError: a damaged header asking for a huge array
LOAD_ERRORS = (zipfile.BadZipFile, zlib.error, ValueError, EOFError, KeyError, struct.error, FileNotFoundError,
               IsADirectoryError, MemoryError)


class CheckedArtifact(Artifact):
    """:class:`raico.stages.base.Artifact` whose data loads turn a damaged file into one clean error naming
    the entry (:class:`~raico.pipeline.errors.UnreadableArtifact`, exit 4), never numpy's traceback or its
    message with the file's bytes in it. Stages see the same interface."""

    def arrays(self, name: str, keys: tuple[str, ...] | None = None) -> dict[str, Any]:
        try:
            return super().arrays(name, keys)
        except LOAD_ERRORS as e:
            raise unreadable(self, name, e) from None

    def document(self, name: str) -> Any:
        try:
            return super().document(name)
        except LOAD_ERRORS as e:
            raise unreadable(self, name, e) from None


def clean_error(e: BaseException) -> str:
    """``Type: message`` of a load error on one short printable line (numpy quotes the damaged header's
    bytes: left out)."""
    name = type(e).__name__
    if name == "error":  # zlib.error
        name = f"{type(e).__module__}.error"
    lines = str(e).strip().splitlines()
    text = lines[0] if lines else ""
    for cut in (": b'", ': b"', " b'", ' b"', ". "):  # the bytes numpy quotes; a second sentence
        text = text.split(cut)[0]
    text = "".join(c for c in text if c.isprintable() and c.isascii()).strip()
    if len(text) > 100:
        text = text[:99] + "…"
    return f"{name}: {text}" if text else name


def unreadable(art: Artifact, name: str, e: BaseException) -> BaseException:
    """The error for a file of ``art`` that could not be loaded: the entry is re-hashed; a mismatch
    (damage its stamps did not show) also drops its stamps, so the next check finds it. A
    ``MemoryError`` from a file that matches its hash is a real shortage, returned as it is."""
    cache = Cache(art.path.parent.parent)
    verdict = cache.verify(art.stage, art.key)
    if verdict == "cached" and isinstance(e, MemoryError):
        return e
    what = f"{name} cannot be read ({clean_error(e)})"
    if verdict == "cached":
        reason = f"{what}, although it matches its recorded sha256 (it was written damaged)"
    else:
        cache.forget(art.stage, art.key)
        reason = f"{what}: {verdict}"
    return UnreadableArtifact(f"artifact {art.ref} is damaged: {reason}", ref=art.ref, reason=reason)
