"""Compiled C for the hot loops: a small gcc build cache and C from the graph.

- :func:`build_library`: C source -> shared library with the system's ``gcc``, cached on disk by a
  hash of the source and the flags (``RAICO_KERNEL_DIR``, default ``~/.cache/raico/kernels``),
  written atomically (parallel processes may build the same library); loaded with ``ctypes``.
  ``RAICO_NO_C=1`` (or no ``gcc``) disables every compiled path: the callers fall back to their
  numpy code, which computes the same numbers. Where ``gcc`` exists and fails, the build raises
  :class:`CompileError` (never a silent fallback).
- :func:`emit_c`: the C twin of :func:`raico.plants.codegen.emit.emit` (same operations in the same
  order, IEEE double, no FMA contraction: the numbers equal the Python float evaluation).

Flags: ``-O2 -fno-fast-math -ffp-contract=off`` (no reassociation, no fused multiply-add), so the
compiled arithmetic is the one written; ``-mavx2`` where the CPU has it (the flags are part of the
cache key: a library built for AVX2 is never the one loaded on a CPU without it, which builds its own).

Instruction set: ``RAICO_ISA`` overrides the host's flags for every kernel (hand-written and
generated): ``host`` (the default: the flags above, from ``/proc/cpuinfo``), ``x86-64-v2`` (``-march``
of that level, SSE4.2: no AVX2, FMA or AVX-512) or ``x86-64-v3`` (AVX2 and FMA, no AVX-512). The
level's flags are part of the cache key, so builds for different levels never mix; an unknown level,
or one this CPU cannot run, is refused in one line (:class:`IsaError`) before anything is built.
``make test-portable`` runs the float comparisons of the tests under each level.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from raico.plants.codegen.graph import Graph


def _cpu_flags() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            return f.read(200_000)
    except OSError:  # pragma: no cover - not Linux
        return ""


@functools.cache
def cpu_features() -> frozenset[str]:
    """The CPU's feature flags (the ``flags`` line of ``/proc/cpuinfo``; empty elsewhere)."""
    for line in _cpu_flags().splitlines():
        if line.startswith("flags"):
            return frozenset(line.split(":", 1)[1].split())
    return frozenset()


# The instruction-set levels RAICO_ISA may name: the x86-64 micro-architecture levels' CPU flags
# (/proc/cpuinfo names; gcc's -march=<level> assumes them), and ``host`` (this CPU's own flags).
ISA_LEVELS: dict[str, frozenset[str]] = {
    "host": frozenset(),
    "x86-64-v2": frozenset({"cx16", "popcnt", "sse4_1", "sse4_2", "ssse3"}),
    "x86-64-v3": frozenset({"cx16", "popcnt", "sse4_1", "sse4_2", "ssse3", "avx", "avx2", "bmi1", "bmi2",
                            "f16c", "fma", "movbe", "abm"}),
}


class IsaError(ValueError):
    """``RAICO_ISA`` names no level, or one this CPU cannot run (bad input: one line, exit 2)."""


def isa_level(strict: bool = True) -> str:
    """The instruction-set level of the kernels: ``RAICO_ISA`` (``host`` when unset or empty). With
    ``strict``, an unknown level or one whose instructions this CPU lacks raises :class:`IsaError`;
    without, such a value reads as ``host`` (the module's flags are computed at import; the build
    refuses it)."""
    level = os.environ.get("RAICO_ISA", "").strip() or "host"
    if level not in ISA_LEVELS:
        if not strict:
            return "host"
        raise IsaError(f"RAICO_ISA={level!r} is not an instruction-set level: give one of {', '.join(ISA_LEVELS)}")
    missing = ISA_LEVELS[level] - cpu_features()
    if missing and cpu_features():   # (no /proc/cpuinfo: nothing to check against)
        raise IsaError(f"RAICO_ISA={level}: this CPU lacks {' '.join(sorted(missing))}, so code built "
                       "for that level cannot run here")
    return level


def fma_flags(level: str | None = None) -> tuple[str, ...]:
    """``-mfma`` where the level has it (``host``: where the CPU has FMA and AVX2; ``x86-64-v3``: always;
    ``x86-64-v2``: never): for code whose results may depend on contraction (the sweep kernel,
    compared with numpy to a tolerance, never bit for bit). ``level`` defaults to :func:`isa_level`."""
    level = isa_level(strict=False) if level is None else level
    if level == "host":
        return ("-mfma",) if {"fma", "avx2"} <= cpu_features() else ()
    return ("-mfma",) if "fma" in ISA_LEVELS[level] else ()


def isa_flags(level: str | None = None) -> tuple[str, ...]:
    """The instruction-set flags of every kernel at ``level`` (default :func:`isa_level`): ``host``,
    ``-mavx2`` where the CPU has it (wider vector registers for the derivative loops; no FMA:
    contraction stays off, so the numbers do not depend on it); a named level, ``-march=<level>``
    and ``-mavx2`` where the level has AVX2."""
    level = isa_level(strict=False) if level is None else level
    if level == "host":
        return ("-mavx2",) if "avx2" in cpu_features() else ()
    return (f"-march={level}", *(("-mavx2",) if "avx2" in ISA_LEVELS[level] else ()))


def c_source(module_file: str, name: str) -> str:
    """The text of the C file ``name`` beside the module ``module_file`` (``__file__``): every C source
    lives in a ``.c`` file next to what loads it (package data of the ``plants`` package)."""
    path = Path(module_file).resolve().with_name(name)
    try:
        return path.read_text(encoding="utf-8")
    except OSError as e:
        raise CompileError(f"the C source {path} is missing or unreadable ({type(e).__name__}): "
                           "reinstall raico (it ships its .c files as package data)") from None


BASE_FLAGS = ("-O2", "-fPIC", "-shared", "-fno-fast-math", "-ffp-contract=off", "-fno-strict-aliasing")
CFLAGS = (*BASE_FLAGS, *isa_flags())
_LIBS: dict[str, ctypes.CDLL] = {}

# The sanitizer build (``RAICO_SANITIZE=1``, ``make test-sanitize``): every kernel, hand-written and
# generated, compiled with AddressSanitizer and UBSan on top of its own flags (UB aborts, it is not
# only reported), into its own folder. Python must start with both runtimes preloaded
# (:func:`sanitizer_env`): a sanitized library dlopen'ed into a process without them cannot run.
SANITIZE_FLAGS = ("-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer", "-g")


def sanitizing() -> bool:
    """Whether kernels are built with the sanitizers (``RAICO_SANITIZE`` set and not ``0``)."""
    return os.environ.get("RAICO_SANITIZE", "") not in ("", "0")


def sanitizer_runtimes() -> list[str]:
    """Paths of gcc's AddressSanitizer and UBSan runtimes (``libasan.so``, ``libubsan.so``), in the
    order they must be preloaded; empty when gcc does not have them."""
    paths = []
    for lib in ("libasan.so", "libubsan.so"):
        try:
            out = subprocess.run(["gcc", f"-print-file-name={lib}"], capture_output=True, text=True).stdout.strip()
        except OSError:
            return []
        if not os.path.isabs(out) or not os.path.exists(out):
            return []
        paths.append(out)
    return paths


def sanitizer_env(base: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of a Python process that runs the sanitized kernels: ``RAICO_SANITIZE=1``, the
    runtimes in ``LD_PRELOAD``, leak detection off (CPython's allocations at exit are not leaks of
    the kernels) and errors fatal. Raises :class:`CompileUnavailable` without the runtimes."""
    runtimes = sanitizer_runtimes()
    if not runtimes:
        raise CompileUnavailable("gcc's libasan.so / libubsan.so are not installed")
    env = dict(os.environ if base is None else base)
    env["RAICO_SANITIZE"] = "1"
    env["LD_PRELOAD"] = " ".join(runtimes)
    env["ASAN_OPTIONS"] = "detect_leaks=0:abort_on_error=1:halt_on_error=1"
    env["UBSAN_OPTIONS"] = "print_stacktrace=1:halt_on_error=1"
    return env


def _check_sanitizer_runtime() -> None:
    """Refuse to load a sanitized library into a process that was not started with the runtimes."""
    if "libasan" not in os.environ.get("LD_PRELOAD", ""):
        raise CompileError("RAICO_SANITIZE is set but the sanitizer runtimes are not preloaded: start Python "
                           "with LD_PRELOAD=\"$(gcc -print-file-name=libasan.so) $(gcc -print-file-name=libubsan.so)\" "
                           "(make test-sanitize does)")


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
    """Where compiled kernels are kept: ``RAICO_KERNEL_DIR``, default ``~/.cache/raico/kernels``
    (``kernels-sanitize`` for the sanitizer build, so the two never mix)."""
    d = os.environ.get("RAICO_KERNEL_DIR")
    default = "kernels-sanitize" if sanitizing() else "kernels"
    return Path(d) if d else Path.home() / ".cache" / "raico" / default


def _flags(flags: tuple[str, ...]) -> tuple[str, ...]:
    """``flags`` with the sanitizers' appended when :func:`sanitizing`."""
    return (*flags, *SANITIZE_FLAGS) if sanitizing() else tuple(flags)


def library_path(source: str, name: str, directory: Path | None = None,
                 flags: tuple[str, ...] = CFLAGS) -> Path:
    """Where the library of ``source`` built with ``flags`` is (or will be) cached."""
    key = hashlib.sha256((" ".join(_flags(flags)) + "\n" + source).encode()).hexdigest()[:20]
    return (directory or kernel_dir()) / f"{name}-{key}.so"


def build_library(source: str, name: str, directory: Path | None = None,
                  flags: tuple[str, ...] = CFLAGS) -> Path:
    """Compile ``source`` with ``flags`` (once per content and flags) and return the library's path.
    Raises :class:`CompileUnavailable` when compiling is off, :class:`CompileError` when gcc fails."""
    if not enabled():
        raise CompileUnavailable(f"compiled kernels disabled ({why_unavailable()})")
    isa_level()   # an unknown level, or one this CPU cannot run: refused before any build
    path = library_path(source, name, directory, flags)
    if path.exists():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
        src = Path(tmp) / f"{name}.c"
        src.write_text(source)
        out = Path(tmp) / f"{name}.so"
        flags = _flags(flags)
        proc = subprocess.run(["gcc", *flags, "-o", str(out), str(src), "-lm"],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            raise CompileError(f"gcc failed on {name} (flags {' '.join(flags)}):\n{proc.stderr[-2000:]}")
        os.replace(out, path)  # atomic: a parallel build of the same source writes the same file
    return path


def load_library(source: str, name: str, directory: Path | None = None,
                 flags: tuple[str, ...] = CFLAGS) -> ctypes.CDLL:
    """``ctypes`` handle of the compiled ``source`` (kept for the process)."""
    if sanitizing():
        _check_sanitizer_runtime()
    path = build_library(source, name, directory, flags)
    lib = _LIBS.get(str(path))
    if lib is None:
        lib = _LIBS[str(path)] = ctypes.CDLL(str(path))
    return lib


Signature = tuple  # (argtypes or None, restype) of one C entry point


class CompiledLibrary:
    """A loader of one compiled library, built on its first call and kept for the process: calling it gives the
    ``ctypes`` handle with ``signatures`` (``{function: (argtypes or None, restype)}``) set, or ``None`` where
    compiling is off (``RAICO_NO_C=1``, no ``gcc``). A failed build (``CompileError``) or a library that does
    not load (``OSError``) propagates: never a silent fallback. ``source``: the C text, or a function giving
    it (read at the first call); ``flags``: :data:`CFLAGS` unless given."""

    def __init__(self, name: str, source, signatures: dict[str, Signature],
                 flags: tuple[str, ...] | None = None) -> None:
        self.name, self.source, self.signatures = name, source, signatures
        self.flags = CFLAGS if flags is None else flags
        self._lib: ctypes.CDLL | None = None
        self._loaded = False

    def typed(self, lib: ctypes.CDLL) -> ctypes.CDLL:
        """``lib`` (this library, built anywhere) with its entry points' signatures set."""
        for fn, (args, res) in self.signatures.items():
            f = getattr(lib, fn)
            if args is not None:
                f.argtypes = list(args)
            f.restype = res
        return lib

    def __call__(self) -> ctypes.CDLL | None:
        if not self._loaded:
            if enabled():
                try:
                    self._lib = self.typed(load_library(self.source() if callable(self.source) else self.source,
                                                        self.name, flags=self.flags))
                except CompileUnavailable:
                    self._lib = None
            self._loaded = True
        return self._lib


def check_shapes(kernel: str, **arrays) -> None:
    """Refuse a call into compiled code whose arrays do not have the shapes its C entry point accepts:
    ``name=(array, expected_shape)`` pairs; raises ``ValueError`` naming the kernel, the array, the
    shape given and the one expected (a C kernel reads and writes by the sizes it is passed, so a
    wrong shape must stop here, never reach a buffer)."""
    for name, (a, shape) in arrays.items():
        got = tuple(np.shape(a))
        if got != tuple(shape):
            raise ValueError(f"{kernel}: {name} has shape {got}, expected {tuple(shape)}")


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
    from raico.plants.codegen.emit import walk

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
