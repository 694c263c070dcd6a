"""Compiled C for the hot loops: a small gcc build cache and C from the graph.

- :func:`build_library`: C source -> shared library with the system's ``gcc``, cached on disk by a
  hash of the source and the flags (``RAICO_KERNEL_DIR``, default ``~/.cache/raico/kernels``),
  written atomically (parallel processes may build the same library); loaded with ``ctypes``.
  ``RAICO_NO_C=1`` (or no ``gcc``) disables every compiled path: the callers fall back to their
  numpy code, which computes the same numbers. Where ``gcc`` exists and fails, the build raises
  :class:`CompileError` (never a silent fallback).
- :func:`emit_c`: the C twin of :func:`plants.codegen.emit.emit` (same operations in the same
  order, IEEE double, no FMA contraction: the numbers equal the Python float evaluation).

Flags: ``-O2 -fno-fast-math -ffp-contract=off`` (no reassociation, no fused multiply-add), so the
compiled arithmetic is the one written; ``-mavx2`` where the CPU has it (the flags are part of the
cache key: a library built for AVX2 is never the one loaded on a CPU without it, which builds its own).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from plants.codegen.graph import Graph


def _cpu_flags() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            return f.read(200_000)
    except OSError:  # pragma: no cover - not Linux
        return ""


def cpu_features() -> frozenset[str]:
    """The CPU's feature flags (the ``flags`` line of ``/proc/cpuinfo``; empty elsewhere)."""
    for line in _cpu_flags().splitlines():
        if line.startswith("flags"):
            return frozenset(line.split(":", 1)[1].split())
    return frozenset()


def fma_flags() -> tuple[str, ...]:
    """``-mfma`` where the CPU has it (and AVX2): for code whose results may depend on contraction
    (the sweep kernel, compared with numpy to a tolerance, never bit for bit)."""
    return ("-mfma",) if {"fma", "avx2"} <= cpu_features() else ()


def _isa_flags() -> tuple[str, ...]:
    """``-mavx2`` where the CPU has it (wider vector registers for the derivative loops; no FMA:
    contraction stays off, so the numbers do not depend on it)."""
    return ("-mavx2",) if "avx2" in cpu_features() else ()


def c_source(module_file: str, name: str) -> str:
    """The text of the C file ``name`` beside the module ``module_file`` (``__file__``): every C source
    lives in a ``.c`` file next to what loads it (package data of the ``plants`` package)."""
    path = Path(module_file).resolve().with_name(name)
    try:
        return path.read_text(encoding="utf-8")
    except OSError as e:
        raise CompileError(f"the C source {path} is missing or unreadable ({type(e).__name__}): "
                           "reinstall raico (it ships its .c files as package data)") from None


CFLAGS = ("-O2", "-fPIC", "-shared", "-fno-fast-math", "-ffp-contract=off", "-fno-strict-aliasing",
          *_isa_flags())
_LIBS: dict[str, ctypes.CDLL] = {}


class CompileUnavailable(RuntimeError):
    """No compiled path: ``RAICO_NO_C`` set, or no ``gcc`` (the callers run their numpy code)."""


class CompileError(RuntimeError):
    """``gcc`` exists and failed on a source: a bug to see, not a reason to fall back."""


def enabled() -> bool:
    """Whether compiled kernels may be used (``RAICO_NO_C`` unset and ``gcc`` on the path)."""
    return os.environ.get("RAICO_NO_C", "") in ("", "0") and shutil.which("gcc") is not None


def why_unavailable() -> str:
    """Why :func:`enabled` is false (for messages)."""
    if os.environ.get("RAICO_NO_C", "") not in ("", "0"):
        return "RAICO_NO_C is set"
    return "no gcc on the path" if shutil.which("gcc") is None else "enabled"


def kernel_dir() -> Path:
    d = os.environ.get("RAICO_KERNEL_DIR")
    return Path(d) if d else Path.home() / ".cache" / "raico" / "kernels"


def library_path(source: str, name: str, directory: Path | None = None,
                 flags: tuple[str, ...] = CFLAGS) -> Path:
    """Where the library of ``source`` built with ``flags`` is (or will be) cached."""
    key = hashlib.sha256((" ".join(flags) + "\n" + source).encode()).hexdigest()[:20]
    return (directory or kernel_dir()) / f"{name}-{key}.so"


def build_library(source: str, name: str, directory: Path | None = None,
                  flags: tuple[str, ...] = CFLAGS) -> Path:
    """Compile ``source`` with ``flags`` (once per content and flags) and return the library's path.
    Raises :class:`CompileUnavailable` when compiling is off, :class:`CompileError` when gcc fails."""
    if not enabled():
        raise CompileUnavailable(f"compiled kernels disabled ({why_unavailable()})")
    path = library_path(source, name, directory, flags)
    if path.exists():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
        src = Path(tmp) / f"{name}.c"
        src.write_text(source)
        out = Path(tmp) / f"{name}.so"
        proc = subprocess.run(["gcc", *flags, "-o", str(out), str(src), "-lm"],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            raise CompileError(f"gcc failed on {name} (flags {' '.join(flags)}):\n{proc.stderr[-2000:]}")
        os.replace(out, path)  # atomic: a parallel build of the same source writes the same file
    return path


def load_library(source: str, name: str, directory: Path | None = None,
                 flags: tuple[str, ...] = CFLAGS) -> ctypes.CDLL:
    """``ctypes`` handle of the compiled ``source`` (kept for the process)."""
    path = build_library(source, name, directory, flags)
    lib = _LIBS.get(str(path))
    if lib is None:
        lib = _LIBS[str(path)] = ctypes.CDLL(str(path))
    return lib


# -- C from the graph ---------------------------------------------------------------------------
def _c_const(c: float) -> str:
    r = repr(float(c))
    if r in ("inf", "-inf", "nan"):  # pragma: no cover - Drake's equations have none
        raise ValueError(f"constant {r} in the generated code")
    if "e" not in r and "." not in r:
        r += ".0"
    return f"({r})" if c < 0 else r


def emit_c(g: Graph, name: str, inputs: list[int], outputs: list[int],
           targets: list[str] | None = None, params: str = "const double *xs, double *out") -> str:
    """C source of ``static void name(<params>)``: node ``inputs[k]`` is ``xs[k]``; node
    ``outputs[j]`` goes to ``targets[j]`` (default ``out[j]``). One ``const double`` per operation
    (SSA; the compiler allocates registers), operations in the order of :func:`emit.emit` (the
    same :func:`emit.walk`, printed as C)."""
    from plants.codegen.emit import walk

    targets = [f"out[{j}]" for j in range(len(outputs))] if targets is None else targets
    w = walk(g, inputs, outputs, targets)

    def ref(j: int) -> str:
        if j in w.inputs:
            return f"xs[{w.inputs[j]}]"
        n = w.nodes[j]
        return _c_const(n[1]) if n[0] == "c" else f"r{j}"

    lines = [f"static void {name}({params})", "{"]
    lines += [f"    {t} = {ref(o)};" for o, t in w.direct_writes()]
    for i in w.order:
        lines.append(f"    const double r{i} = {w.expression(i, ref, lambda a, p: f'pow({a}, {_c_const(p)})')};")
        lines += [f"    {t} = r{i};" for t in w.writes.get(i, ())]
    lines.append("}")
    return "\n".join(lines) + "\n"
