"""User-facing errors of the raico pipeline (SPEC §12).

Every error the CLI reports is a :class:`RaicoError`: ``str(err)`` is one clear line
for stderr and ``err.exit_code`` is the non-zero process exit code.
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
    """An artifact exists but is partial, unreadable or does not match its recorded hash."""

    exit_code = 4
