"""Fault-injection helpers shared by the cache and fault tests: same-size damage to a file, and the
process tree below a pid (Linux /proc)."""

import os
from pathlib import Path


def flip_byte(path: Path, keep_mtime: bool = False) -> None:
    """A byte in the middle of ``path`` flipped in place, as a careful operator's fault run does it (the
    size stays, the modification time moves; with ``keep_mtime`` it is put back by ``os.utime``)."""
    st = path.stat()
    with open(path, "r+b") as f:
        f.seek(st.st_size // 2)
        b = f.read(1)
        f.seek(st.st_size // 2)
        f.write(bytes([b[0] ^ 0xFF]))
    if keep_mtime:
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
        assert path.stat().st_mtime_ns == st.st_mtime_ns and path.stat().st_size == st.st_size


def parents() -> dict[int, int]:
    """Pid -> parent pid of every process (Linux /proc; processes that end meanwhile left out)."""
    out: dict[int, int] = {}
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                st = (p / "stat").read_text()
            except OSError:
                continue
            out[int(p.name)] = int(st[st.rfind(")") + 2:].split()[1])
    return out
