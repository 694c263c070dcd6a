"""``make test-portable``: the tests that compare floating-point results (marked ``numerics``, not ``slow``)
under the rounding of other processors, on this one machine.

Each variant runs the marked tests in a fresh Python with one setting changed:

- ``OPENBLAS_CORETYPE`` = Haswell, SkylakeX, Prescott: numpy's OpenBLAS takes that processor's kernels
  (AVX2, AVX-512, SSE3: other blockings, other orders of the sums); the compiled kernels are the host's;
- ``RAICO_ISA`` = x86-64-v2, x86-64-v3: the compiled kernels (the sweeps, the task messages, the plants'
  generated C) are built for that instruction-set level (no AVX; AVX2 and FMA without AVX-512) into
  their own files of the kernel cache (:mod:`raico.plants.codegen.c_backend`); OpenBLAS picks its own kernels.

Each variant prints its name and the OpenBLAS kernel ``threadpoolctl`` reports in it (OpenBLAS falls back
to another kernel where the CPU lacks the one asked for: the line says which ran), then pytest's result
and its time. A variant whose instruction-set level this CPU cannot run is skipped with the reason. Any
failure fails the run (exit 1). ``--jobs 2`` runs two variants at once (each single-threaded: the
tests' BLAS runs on one thread), their outputs printed whole, one after the other.

    python -m tests.portable [--jobs N] [--only NAME ...] [pytest arguments, e.g. test paths or -x]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
VARIANTS: dict[str, dict[str, str]] = {
    "OPENBLAS_CORETYPE=Haswell": {"OPENBLAS_CORETYPE": "Haswell"},
    "OPENBLAS_CORETYPE=SkylakeX": {"OPENBLAS_CORETYPE": "SkylakeX"},
    "OPENBLAS_CORETYPE=Prescott": {"OPENBLAS_CORETYPE": "Prescott"},
    "RAICO_ISA=x86-64-v2": {"RAICO_ISA": "x86-64-v2"},
    "RAICO_ISA=x86-64-v3": {"RAICO_ISA": "x86-64-v3"},
}
# the marked tests but the slow ones (the chain at 16-32 joints, ...): those run on the host's kernels in
# `make test`, and five variants of them would take CI's budget
MARK = "numerics and not slow"
# the names threadpoolctl reports for a core type where they differ from OPENBLAS_CORETYPE's (OpenBLAS's
# Prescott kernels are its generic SSE3 ones, named Katmai)
KERNEL_NAMES = {"prescott": {"prescott", "katmai"}}
PROBE = ("import numpy, threadpoolctl\n"
         "from raico.plants.codegen import c_backend\n"
         "blas = [i.get('architecture') or '?' for i in threadpoolctl.threadpool_info() if i.get('internal_api') == 'openblas']\n"
         "print(','.join(blas) or 'no OpenBLAS')\n"
         "print(c_backend.isa_level())\n")


def variant_env(settings: dict[str, str]) -> dict[str, str]:
    """This process's environment with the variant's settings, the others of this runner removed."""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "RAICO_ISA")}
    env.update(settings)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    return env


def probe(env: dict[str, str]) -> tuple[str | None, str]:
    """``(OpenBLAS kernel, kernels' instruction-set level)`` in a Python with ``env``, or ``(None, why)``
    when the variant cannot run here (an instruction-set level this CPU lacks)."""
    p = subprocess.run([sys.executable, "-c", PROBE], env=env, cwd=REPO, capture_output=True, text=True, timeout=300)
    if p.returncode != 0:
        return None, (p.stderr.strip().splitlines() or ["the probe failed"])[-1]
    blas, level = p.stdout.split()
    return blas, level


def run_variant(name: str, pytest_args: list[str]) -> tuple[bool, str]:
    """Run the marked tests in one variant: ``(passed, its report)``."""
    env = variant_env(VARIANTS[name])
    start = time.monotonic()
    blas, level = probe(env)
    if blas is None:
        return True, f"== {name}: skipped ({level})\n"
    head = f"== {name}: OpenBLAS kernel {blas}, compiled kernels for {level}"
    asked = VARIANTS[name].get("OPENBLAS_CORETYPE")
    if asked and blas.lower() not in KERNEL_NAMES.get(asked.lower(), {asked.lower()}):
        head += f" (OpenBLAS fell back from {asked}: this CPU lacks its instructions)"
    cmd = [sys.executable, "-m", "pytest", "-q", "-m", MARK, "-p", "no:cacheprovider", *pytest_args]
    p = subprocess.Popen(cmd, env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    output = p.stdout.read() if p.stdout else ""
    _, status, usage = os.wait4(p.pid, 0)   # the test process's own CPU time (not the other variant's)
    code = os.waitstatus_to_exitcode(status)
    lines = output.rstrip().splitlines()
    failures = [ln for ln in lines if ln.startswith(("FAILED", "ERROR"))]
    took = f"   (wall {time.monotonic() - start:.0f} s, CPU {usage.ru_utime + usage.ru_stime:.0f} s)"
    report = [head, *failures, lines[-1] if lines else "(no output)", took]
    if code != 0 and not failures:   # a crash or a collection error: its tail
        report[1:1] = lines[-40:]
    return code == 0, "\n".join(report) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.portable", description=__doc__.split("\n\n")[0])
    parser.add_argument("--jobs", type=int, default=1, help="variants run at once (default 1)")
    parser.add_argument("--only", nargs="+", choices=list(VARIANTS), help="run these variants only")
    args, pytest_args = parser.parse_known_args(argv)
    if args.jobs < 1:
        parser.error("--jobs must be at least 1")
    names = args.only or list(VARIANTS)
    start = time.monotonic()
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        futures = [pool.submit(run_variant, n, pytest_args) for n in names]
        results = []
        for f in futures:
            ok, report = f.result()
            print(report, end="", flush=True)
            results.append(ok)
    failed = [n for n, ok in zip(names, results) if not ok]
    print(f"test-portable: {len(names) - len(failed)} of {len(names)} variants passed in "
          f"{time.monotonic() - start:.0f} s" + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
