"""The compiled kernels under AddressSanitizer and UBSan: ``python -m raico.plants.codegen.sanitize [PYTEST ARGS]``.

Runs pytest (default: the tests marked ``compiled``, every test that reaches a C kernel) in a process
started with gcc's sanitizer runtimes preloaded and ``RAICO_SANITIZE=1``, so that every kernel,
hand-written and generated, is built with ``-fsanitize=address,undefined`` into its own folder
(``RAICO_KERNEL_DIR``, default ``~/.cache/raico/kernels-sanitize``) and any out-of-bounds access,
use after free or undefined behaviour aborts the run with the sanitizer's report. ``make
test-sanitize`` calls it; CI runs it on every submission.

Exit code: pytest's, or 2 with one line on stderr when the sanitizer runtimes or gcc are missing.
"""

from __future__ import annotations

import os
import sys

from raico.plants.codegen import c_backend

DEFAULT_ARGS = ("-q", "-m", "compiled", "-p", "no:cacheprovider")
# pytest's default capture redirects file descriptor 2 while a test runs: a sanitizer that aborts the
# process there would take its report with it. Capturing sys.stdout/stderr only lets it reach the log.
CAPTURE = "--capture=sys"


def main(argv: list[str]) -> int:
    if not c_backend.enabled():
        print(f"raico: error: no sanitizer build: compiled kernels are disabled ({c_backend.why_unavailable()})",
              file=sys.stderr)
        return 2
    try:
        env = c_backend.sanitizer_env()
    except c_backend.CompileUnavailable as e:
        print(f"raico: error: no sanitizer build: {e} (Debian: apt-get install gcc)", file=sys.stderr)
        return 2
    args = list(argv) or list(DEFAULT_ARGS)
    if not any(a == "-s" or a.startswith("--capture") for a in args):
        args.insert(0, CAPTURE)
    os.execvpe(sys.executable, [sys.executable, "-m", "pytest", *args], env)
    return 0  # pragma: no cover - execvpe does not return


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
