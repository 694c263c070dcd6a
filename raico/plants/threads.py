"""One BLAS thread per process (the one place this is set).

Small dense linear algebra dominates here: one BLAS thread per process is faster than several
(parallelism comes from worker processes). Must run before numpy loads, so the ``__init__`` of
every package (``plants``, ``stages``, ``pipeline``, ``bench``) and ``tests/conftest.py``
import this module first; users may override by setting the variables themselves.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def output_threads() -> int:
    """Threads for independent per-output GP work in this process (the outputs' hyperparameter fits,
    a batch posterior): ``RAICO_THREADS`` if set, else the CPUs this process may run on. Each thread
    runs single-threaded BLAS on its own output, so the numbers do not depend on the count. A pool
    worker of the pipeline gets its share (``raico.pipeline.engine.executors``: CPUs // workers; a Ray task 1)."""
    env = os.environ.get("RAICO_THREADS", "")
    if env.strip():
        try:
            return max(1, int(env))
        except ValueError:
            raise ValueError(f"RAICO_THREADS must be a positive integer, got {env!r}") from None
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def map_outputs(fn, n: int) -> list:
    """``[fn(0), ..., fn(n - 1)]`` on up to ``output_threads()`` threads (in this order; serial when
    one thread or one item). The first exception raised is re-raised."""
    threads = min(output_threads(), n)
    if threads <= 1:
        return [fn(j) for j in range(n)]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="raico-output") as pool:
        return list(pool.map(fn, range(n)))
