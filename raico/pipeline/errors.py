"""User-facing errors of the raico pipeline.

Every error the CLI reports is a :class:`RaicoError`: ``str(err)`` is one clear line
for stderr and ``err.exit_code`` is the non-zero process exit code. An interrupt (SIGINT, SIGTERM)
is not an error: :class:`raico.pipeline.lifecycle.Interrupted`.
"""

from __future__ import annotations


class RaicoError(Exception):
    """Bad input or a fault; the CLI prints ``str(err)`` on one line and exits non-zero."""

    exit_code: int = 1

    def __str__(self) -> str:
        text = " ".join(str(a) for a in self.args) if self.args else type(self).__name__
        return " ".join(text.split())  # one line, whatever the message held


class BadInput(RaicoError):
    """Unknown name, out-of-range number or otherwise invalid user input."""

    exit_code = 2


class MissingArtifact(RaicoError):
    """A required artifact (cache entry or file in it) does not exist."""

    exit_code = 3


class CorruptArtifact(RaicoError):
    """An artifact exists but is partial, unreadable or does not match its recorded hash.

    ``ref`` (``STAGE/KEY``) names the entry where known and ``reason`` says what is wrong with it
    (``file plan.npz changed (sha256 ...)``), so a caller can rebuild it; both survive pickling
    (an error raised in a worker process)."""

    exit_code = 4

    def __init__(self, *args: object, ref: str | None = None, reason: str | None = None) -> None:
        super().__init__(*args)
        self.ref, self.reason = ref, reason


class UnreadableArtifact(CorruptArtifact):
    """A data file of an entry that passed its check could not be loaded (damage its stamps did not
    show, or a file written damaged): numpy's or zipfile's error, as one clean line."""


class StorageError(RaicoError):
    """The file system refused an operation (a path that is a file or lies below one, a
    read-only or unwritable folder, a full disk); the message names the path and the cause."""

    exit_code = 5


def os_error_text(err: OSError, path: object = None) -> str:
    """``PATH: cause`` of an OS error, one line (``path`` if the error names none)."""
    where = err.filename if err.filename is not None else path
    cause = err.strerror or str(err) or type(err).__name__
    if err.filename2 is not None:
        where = f"{where} -> {err.filename2}"
    cause = cause[:1].lower() + cause[1:]
    return f"{where}: {cause}" if where is not None else cause


def check_folder(path, what: str) -> None:
    """:class:`StorageError` if ``path`` (a ``Path``) exists as something other than a folder, or if one of
    its parents is a file (it could never be created)."""
    for p in (path, *path.parents):
        try:
            if p.exists() and not p.is_dir():
                where = "is" if p == path else f"lies below {p}, which is"
                raise StorageError(f"{what} {path} {where} a file, not a folder")
        except OSError as e:
            raise StorageError(f"{what} {path}: {os_error_text(e)}") from None
