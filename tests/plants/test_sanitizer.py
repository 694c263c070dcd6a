"""The sanitizer job itself (``make test-sanitize``: ``python -m raico.plants.codegen.sanitize``).

It is only worth running if it catches the class of bug it is for: a scratch copy of the iLQG
backward pass with its work buffer one region short (the heap overflow once found in it: ``tmp``
given ``n`` doubles where the loop writes ``m``) must make the sanitizer run fail with
AddressSanitizer's report, while the same run on the shipped source passes. A UBSan finding
(a signed overflow compiled in) must fail it too.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from raico.planning import ilqg
from raico.plants.codegen import c_backend

REPO = Path(__file__).resolve().parents[2]

SHORT_BUFFER = ("+ n * m + m);", "+ n * m + n);")           # tmp gets n doubles, m are written
SIGNED_OVERFLOW = ("    int n = (int)n_, m = (int)m_;\n",
                   "    int n = (int)n_, m = (int)m_;\n    volatile int big = 2147483647; big += (int)T;\n")

_SCRATCH_TEST = '''
import ctypes
import numpy as np
import pytest

from raico.plants.codegen import c_backend

pytestmark = pytest.mark.compiled


def test_scratch_kernel():
    lib = c_backend.load_library(open({src!r}).read(), "ilqg_backward_scratch")
    T, n, m = 3, 2, 5                                   # more controls than states
    rng = np.random.default_rng(0)
    A, B = np.tile(np.eye(n), (T, 1, 1)), rng.standard_normal((T, n, m))
    lx, lxx = np.zeros((T + 1, n)), np.tile(np.eye(n), (T + 1, 1, 1))
    lu, luu = np.zeros((T, m)), np.tile(np.eye(m), (T, 1, 1))
    k, K, dV = np.empty((T, m)), np.empty((T, m, n)), np.empty(2)
    L, V = ctypes.c_long, ctypes.c_void_p
    lib.ilqg_backward.argtypes = [L, L, L, V, V, V, V, V, V, ctypes.c_double, V, V, V]
    rc = lib.ilqg_backward(T, n, m, *(z.ctypes.data for z in (A, B, lx, lxx, lu, luu)), 0.0,
                           k.ctypes.data, K.ctypes.data, dV.ctypes.data)
    assert rc == 0
'''


def _sanitizer_run(tmp_path: Path, source: str) -> subprocess.CompletedProcess:
    """``python -m raico.plants.codegen.sanitize`` (the job's entry point) on one test that loads ``source``."""
    src = tmp_path / "scratch.c"
    src.write_text(source)
    test = tmp_path / "test_scratch.py"
    test.write_text(_SCRATCH_TEST.format(src=str(src)))
    env = {**os.environ, "RAICO_KERNEL_DIR": str(tmp_path / "kernels"), "PYTHONPATH": str(REPO)}
    env.pop("LD_PRELOAD", None)
    return subprocess.run([sys.executable, "-m", "raico.plants.codegen.sanitize", "-q", "-p", "no:cacheprovider",
                           "-m", "compiled", str(test)], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=300)


@pytest.fixture(scope="module")
def shipped_source() -> str:
    if not c_backend.enabled():
        pytest.skip(f"no compiled kernels ({c_backend.why_unavailable()})")
    if not c_backend.sanitizer_runtimes():
        pytest.fail("gcc is installed without libasan.so / libubsan.so: the sanitizer job cannot run")
    return c_backend.c_source(ilqg.__file__, "ilqg_backward.c")


@pytest.mark.slow  # builds with AddressSanitizer and runs pytest in a child: 1-2 s each
def test_the_shipped_kernel_passes_the_sanitizer_run(tmp_path, shipped_source):
    out = _sanitizer_run(tmp_path, shipped_source)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert "1 passed" in out.stdout


@pytest.mark.slow  # builds with AddressSanitizer and runs pytest in a child: 1-2 s each
def test_an_out_of_bounds_write_fails_the_sanitizer_run(tmp_path, shipped_source):
    assert SHORT_BUFFER[0] in shipped_source
    out = _sanitizer_run(tmp_path, shipped_source.replace(*SHORT_BUFFER))
    assert out.returncode != 0
    report = out.stdout + out.stderr
    assert "AddressSanitizer: heap-buffer-overflow" in report, report[-3000:]
    assert "ilqg_backward" in report          # the report names the kernel's frame


@pytest.mark.slow  # builds with AddressSanitizer and runs pytest in a child: 1-2 s each
def test_undefined_behaviour_fails_the_sanitizer_run(tmp_path, shipped_source):
    assert SIGNED_OVERFLOW[0] in shipped_source
    out = _sanitizer_run(tmp_path, shipped_source.replace(*SIGNED_OVERFLOW))
    assert out.returncode != 0
    assert "runtime error: signed integer overflow" in out.stdout + out.stderr, (out.stdout + out.stderr)[-3000:]


def test_a_sanitized_kernel_refuses_a_process_without_the_runtimes(monkeypatch):
    """Loading a sanitized library into a Python started without the runtimes is one clear error."""
    monkeypatch.setenv("RAICO_SANITIZE", "1")
    monkeypatch.delenv("LD_PRELOAD", raising=False)
    with pytest.raises(c_backend.CompileError, match="LD_PRELOAD"):
        c_backend.load_library("int f(void) { return 0; }\n", "refused")
