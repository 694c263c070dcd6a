"""The AICO sweeps compiled: ``csweep.c`` loaded with ``ctypes`` (speed only, Algorithm 1 unchanged).

``csweep.c`` is ``raico.planning.aico.sweeps.Sweeps``'s forward / backward / belief / settle code in C, on
the register-tiled dense linear algebra of ``dense.c`` (no BLAS: at the sweeps' sizes it beats
OpenBLAS, see the measurements there; its entry points ``k_*`` are tested against numpy by
tests/planning/test_kernels.py). The two files are compiled as one translation unit (:data:`SOURCES`, in
that order: the dense functions stay ``static`` and inline as before). The sources ship with the package (package data) and is compiled
on first use by the build helper :func:`raico.plants.codegen.c_backend.build_library` into the kernel
cache (``make kernels`` builds it ahead: ``python -m raico.planning.kernels``). :data:`FLAGS` follow
this host's CPU (``-mavx2 -mfma`` only where ``/proc/cpuinfo`` lists both, :func:`wide_flags` where it
lists AVX-512 too), or the level ``RAICO_ISA`` names (``x86-64-v2``, ``x86-64-v3``: see
:mod:`raico.plants.codegen.c_backend`), and are part of the cached
file's key, so a library built for AVX2/FMA is never loaded on a CPU without them: there the
portable build is made and loaded.

Only an explicit opt-out (``RAICO_NO_C=1``) or a machine without ``gcc`` gives :func:`library`
``None`` (then ``Sweeps`` runs its numpy code); a failed build where ``gcc`` exists raises
:class:`raico.plants.codegen.c_backend.CompileError`.

``SweepState`` mirrors ``sweep_t`` of ``csweep.c`` field for field (all 8-byte fields). The MPC
workspace's kernels: ``sweep_linearize`` and ``all_finite`` (``csweep.c``), :func:`box_library` (``box_al.c``).
"""

from __future__ import annotations

import ctypes
from enum import IntEnum
from pathlib import Path

from raico.planning.term_kinds import TASK_MAX_ROWS, MessageKind, kind_of_map
from raico.plants.codegen import c_backend

SOURCES = (Path(__file__).with_name("dense.c"), Path(__file__).with_name("csweep.c"))


def source_text() -> str:
    """The kernel's one translation unit: ``dense.c`` then ``csweep.c``."""
    return "".join(p.read_text() for p in SOURCES)


def wide_flags(level: str | None = None) -> tuple[str, ...]:
    """``-mavx512f`` where the CPU has it (with AVX2 and FMA) and the instruction-set level is the
    host's (``RAICO_ISA``, :func:`raico.plants.codegen.c_backend.isa_level`; the named levels have no
    AVX-512): dense.c's products then take 16-column tiles in 512-bit vectors, the same operations per
    entry (the same numbers bit for bit, fewer instructions); ``-mprefer-vector-width=256`` keeps every
    loop the compiler vectorizes by itself at the 4-wide vectors of the AVX2 build (its vectorized sums
    group their terms by the vector width)."""
    level = c_backend.isa_level(strict=False) if level is None else level
    if level == "host" and {"avx512f", "avx2", "fma"} <= c_backend.cpu_features():
        return ("-mavx512f", "-mprefer-vector-width=256")
    return ()


def flags_for(level: str | None = None) -> tuple[str, ...]:
    """The sweep kernel's flags at an instruction-set level (default ``RAICO_ISA``'s): :data:`FLAGS`."""
    return (*c_backend.BASE_FLAGS, *c_backend.isa_flags(level), "-O3", "-ffp-contract=fast", "-fopenmp-simd",
            *c_backend.fma_flags(level), *wide_flags(level))


# -O3 vectorizes the small dense loops; contraction into fused multiply-adds and the vectorized
# sums marked `omp simd` (-fopenmp-simd: the pragmas only, no OpenMP runtime) are allowed here (the
# sweeps are compared with the numpy code to a tolerance, not bit for bit). Later flags win.
FLAGS = flags_for()

# sweep_t.phase / dyn_mode values and sweep_run's error codes
PH_FWD, PH_BWD = 0, 1
DYN_NONE, DYN_C, DYN_PY = 0, 1, 2
ERR_CHOL, ERR_LIN, ERR_H = -1, -2, -3
LIN_DYN = 1                       # sweep_linearize's flag: the dynamics at every step
NEED_DYN, NEED_TASK = 1, 2

_L, _D, _V = ctypes.c_long, ctypes.c_double, ctypes.c_void_p


class SweepState(ctypes.Structure):
    _fields_ = [
        *((k, _L) for k in ("T", "n", "m", "relocate", "max_repeats", "dyn_mode")),
        *((k, _D) for k in ("q", "theta", "rate", "start_unused")),
        *((k, _V) for k in ("SA", "VA", "RA", "C", "Qbar", "a_eff", "H", "h", "Hinv", "X", "U",
                            "b", "Z")),
        *((k, _L) for k in ("C_s", "Qbar_s", "H_s", "Hinv_s")),
        ("active", _V), ("lin_fn", _V), ("lin_ctx", _V), ("w", _V), ("iw", _V), ("sp_state", _L),
        ("task_fn", _V), ("task_ctx", _V), ("alpha", _D), ("Xprev", _V),
        *((k, _L) for k in ("phase", "t", "r", "sub", "dyn_flag", "task_flag", "repeats",
                            "err_info", "err_code")),
        ("dt", _D), ("block_steps", _L), ("blk", _V),
    ]


#: The compiled sweep kernel, or ``None`` (``RAICO_NO_C=1`` or no ``gcc``); a failed build (``CompileError``) or a
#: library that does not load (``OSError``) propagates.
library = c_backend.CompiledLibrary("csweep", source_text, {
    "sweep_work_size": ([_L, _L], _L), "sweep_iwork_size": ([_L, _L], _L),
    "lti_rollout": ([_L, _L, _L] + [_V] * 8, None),
    "sweep_run": ([ctypes.POINTER(SweepState)], ctypes.c_int),
    "sweep_beliefs": ([ctypes.POINTER(SweepState)], ctypes.c_int),
    "sweep_linearize": ([ctypes.POINTER(SweepState), _L], ctypes.c_int),
    "all_finite": ([_V, _L], ctypes.c_int)}, flags=FLAGS)


# -- compiled task messages -------------------------------------------------------------------------
class CostKind(IntEnum):
    """What a compiled term costs of its map's value: ``enum cost_kind`` of ``task_messages.c``."""

    VIA = 0      # ViaPoint: w (x* - phi)^T C (x* - phi)
    BOUNDS = 1   # TaskInequality: w sum_i max(0, a_i . phi - b_i)^2


class _VTerm(ctypes.Structure):
    _fields_ = [("kind", _L), ("body", _L), ("npts", _L), ("dim", _L), ("R_BF", _V), ("p_BF", _V),
                ("pts", _V), ("rows", _V), ("S", _V), ("target", _V), ("C", _V), ("weight", _D),
                ("active", _V), ("cost", _L), ("nb", _L), ("A", _V), ("b", _V), ("R_target", _V),
                ("p_target", _V), ("target_stride", _L), ("last_step", _L)]


class _TaskSet(ctypes.Structure):
    _fields_ = [("nq", _L), ("nx", _L), ("identity", _L), ("nterms", _L), ("m", _L), ("P", _V), ("terms", _V),
                ("frame_points", _V), ("com", _V), ("frame_rotation", _V), ("gravity", _V)]


TASK_MAX_POSITIONS = 64   # MPMAX of task_messages.c
TASK_MAX_BOUNDS = 128     # BMAX of task_messages.c: bounds of one term
#: The compiled task messages (``task_messages.c``, the tree libraries' flags: no contraction into fused
#: multiply-adds, the numbers of the former in-tree build), or ``None`` as :func:`library`.
task_library = c_backend.CompiledLibrary("task_messages", lambda: c_backend.c_source(__file__, "task_messages.c"), {
    "taskset_eval_address": (None, ctypes.c_void_p), "taskset_rows": ([_V, _L, _V, _V, _V, _V, _V], ctypes.c_int)})

#: The box constraints' augmented Lagrangian (``box_al.c``, the default flags: no contraction, the numpy code's
#: numbers), or ``None`` as :func:`library`.
box_library = c_backend.CompiledLibrary("box_al", lambda: c_backend.c_source(__file__, "box_al.c"), {
    "box_lams": ([_L, _L, _V, _V, _L, _V, _V, _L, _V, _D, _V, _V, _V], _L),
    "box_model": ([_L, _L, _V, _V, _D, _V, _L, _V, _L, _L, _V, _L, _V, _L], None)})


def compile_task_set(problem):
    """The state terms of ``problem`` as a compiled task-message evaluator (``taskset_eval`` of
    ``task_messages.c``, calling the robot's tree library of :mod:`raico.plants.codegen.rbd` for the
    kinematics): ``(function address, context address, keep-alive)``, or ``None`` when some term
    with a nonzero weight has no compiled counterpart (then the sweeps ask Python).

    Compiled: ``ViaPoint`` and ``TaskInequality`` on every task map whose row of the task-map
    table (:mod:`raico.planning.term_kinds`) names a compiled counterpart (frame points, CoM, roll,
    joints, a frame's orientation and placement errors; the frame maps on one robot whose tree
    kernels exist); ``StateTarget``; the state part of the control toward gravity (a joint term, at
    the controls :func:`set_task_controls` gives). The GP uncertainty is not.
    """
    import numpy as np

    from raico.planning.costs import ControlGravity, StateTarget, TaskInequality, ViaPoint

    T, nx = problem.T, problem.n_x
    nq = nx // 2
    if nx != 2 * nq or not 1 <= nq <= TASK_MAX_POSITIONS:
        return None    # outside the kernel's stack buffers: the Python messages
    if any(t.weight != 0 and type(t) is not ControlGravity for t in problem.joint_terms):
        return None    # the GP uncertainty: its model's messages
    # keep[0]: the controls the joint terms read (set_task_controls), u_t at row t
    keep, terms, kern, robot = [np.zeros((T, problem.n_u))], [], None, None

    def arr(a, dtype=float):
        a = np.ascontiguousarray(a, dtype=dtype)
        keep.append(a)
        return a.ctypes.data

    steps = np.arange(T + 1)
    for term in problem.joint_terms:   # toward gravity: its state part, at the controls of keep[0]
        if term.weight == 0:
            continue
        k = robot_kernels(term.gravity.robot)
        if k is None or (kern is not None and k is not kern) or term.c.shape != (nq,) or problem.n_u != nq:
            return None
        kern, robot = k, term.gravity.robot
        vt = _VTerm()
        vt.kind, vt.cost, vt.dim, vt.weight = MessageKind.GRAVITY, CostKind.VIA, nq, float(term.weight)
        vt.active, vt.last_step = arr(np.ones(T + 1), np.uint8), T
        vt.target, vt.target_stride, vt.C = keep[0].ctypes.data, nq, arr(np.diag(term.c))
        terms.append(vt)
    for term in problem.state_terms:
        if term.weight == 0:
            continue
        vt = _VTerm()
        vt.weight = float(term.weight)
        vt.active = arr(term.active(steps), np.uint8)
        if type(term) is StateTarget:
            vt.kind, vt.dim = MessageKind.STATE_TARGET, nx
            per_step = term.target.ndim == 2   # one target per step: read in place (an MPC window refills it)
            c_backend.check_shapes("taskset_eval", target=(term.target, (T + 1, nx) if per_step else (nx,)),
                                   C=(term.C, (nx, nx)))
            vt.target, vt.C = arr(term.target), arr(term.C)
            vt.target_stride = nx if per_step else 0
            terms.append(vt)
            continue
        if type(term) not in (ViaPoint, TaskInequality):
            return None
        tm = term.taskmap
        vt.dim = tm.dim
        if not 1 <= tm.dim <= TASK_MAX_ROWS:
            return None
        if type(term) is ViaPoint:
            c_backend.check_shapes("taskset_eval", target=(term.target, (tm.dim,)), C=(term.C, (tm.dim, tm.dim)))
            vt.cost, vt.target, vt.C = CostKind.VIA, arr(term.target), arr(term.C)
        else:
            nb = term.A.shape[0]
            if nb > TASK_MAX_BOUNDS:
                return None
            c_backend.check_shapes("taskset_eval", A=(term.A, (nb, tm.dim)), b=(term.b, (nb,)))
            vt.cost, vt.nb, vt.A, vt.b = CostKind.BOUNDS, nb, arr(term.A), arr(term.b)
        row = kind_of_map(tm)
        if row is None or row.compile is None:
            return None
        k = None
        if row.tree:    # the frame maps and the CoM: one robot's tree kernels
            k = tm.tree_kernels()
            if k is None or (kern is not None and k is not kern) or (robot is not None and tm.robot is not robot):
                return None
            kern, robot = k, tm.robot
        else:
            c_backend.check_shapes("taskset_eval", S=(tm.S, (tm.dim, nq)))
        if not row.compile(tm, vt, k, arr):
            return None
        terms.append(vt)
    lib = task_library()
    if lib is None:
        return None
    ts = _TaskSet()
    if kern is None:    # joints and state targets only: no kinematics
        P, m = np.eye(nq), nq
    else:
        P, m = np.asarray(robot.P, float), kern.m
        if P.shape != (kern.m, nq) or kern.m > TASK_MAX_POSITIONS:
            return None
        ts.frame_points, ts.com, ts.frame_rotation, ts.gravity = (
            kern.addresses[f] for f in ("tree_frame_points", "tree_com", "tree_frame_rotation", "tree_gravity"))
    ts.nq, ts.nx, ts.nterms, ts.m = nq, nx, len(terms), m
    ts.identity = int(m == nq and np.array_equal(P, np.eye(nq)))
    ts.P = arr(P)
    term_arr = (_VTerm * max(len(terms), 1))(*terms)
    ts.terms = ctypes.addressof(term_arr)
    keep += [term_arr, ts, kern]
    return lib.taskset_eval_address(), ctypes.addressof(ts), keep


def robot_kernels(robot):
    """The robot's compiled tree kernels (``raico.plants.codegen.rbd``), or ``None`` where the plant has none
    (a joint or force element the generator does not handle, no C compiler): the Python terms then run.
    Any other error is a fault and is raised."""
    from raico.plants.codegen.rbd import tree_kernels

    try:
        return tree_kernels(robot)
    except (NotImplementedError, c_backend.CompileUnavailable):
        return None


def set_task_controls(compiled, U) -> None:
    """The controls ``U (T, n_u)`` the compiled joint terms read (toward gravity: the nominal controls
    of the sweeps' linearization, or a rollout's controls for its cost)."""
    buf = compiled[2][0]
    c_backend.check_shapes("taskset controls", U=(U, buf.shape))
    buf[:] = U


def task_rows(compiled, T: int, X, steps, derivatives: bool = True, costs: bool = False, out=None):
    """The compiled task terms (``compile_task_set``'s result for a horizon of ``T`` steps) at the
    rows ``X (K, n_x)`` of steps ``steps (K,)`` (each in ``0..T``): ``(l_x (K, n_x), l_xx (K, n_x, n_x))`` as
    ``Problem.state_derivatives`` (``None`` without ``derivatives``) and the per-row costs ``(K,)``
    as the state terms' ``value`` summed (``None`` without ``costs``). ``X`` must be finite (the
    tree kernels are not asked at NaN; callers keep the Python terms for such rows). ``out``: ``(l_x,
    l_xx, costs)`` C-contiguous arrays of those shapes to write into (the ones asked for)."""
    import numpy as np

    lib = task_library()
    X = np.ascontiguousarray(X, dtype=float)
    steps = np.ascontiguousarray(steps, dtype=np.int64)
    ts = _TaskSet.from_address(compiled[1])
    K, nx = X.shape
    c_backend.check_shapes("taskset_rows", X=(X, (len(steps), int(ts.nx))))
    if len(steps) and (steps.min() < 0 or steps.max() > T):
        raise ValueError(f"taskset_rows: steps must lie in 0..{T}")
    if out is not None:
        lx, lxx, per_row = out
        c_backend.check_shapes("taskset_rows", **{k: (a, shape) for k, a, shape in (
            ("lx", lx, (K, nx)), ("lxx", lxx, (K, nx, nx)), ("costs", per_row, (K,))) if a is not None})
        if not all(a is None or (a.flags.c_contiguous and a.dtype == np.float64) for a in out):
            raise ValueError("taskset_rows: out arrays must be C-contiguous float64")
        lx, lxx = (lx, lxx) if derivatives else (None, None)
        per_row = per_row if costs else None
    else:
        lx = np.empty((K, nx)) if derivatives else None
        lxx = np.empty((K, nx, nx)) if derivatives else None
        per_row = np.empty(K) if costs else None
    if (derivatives and (lx is None or lxx is None)) or (costs and per_row is None):
        raise ValueError("taskset_rows: an out array asked for is missing")
    lib.taskset_rows(compiled[1], K, steps.ctypes.data, X.ctypes.data, *(None if a is None else a.ctypes.data
                                                                         for a in (lx, lxx, per_row)))
    return (lx, lxx) if derivatives else None, per_row


if __name__ == "__main__":  # python -m raico.planning.kernels (make kernels): build (or find) the kernel
    import sys

    try:
        c_backend.isa_level()
    except c_backend.IsaError as e:   # bad input: one line, exit 2
        print(f"raico.planning.kernels: error: {e}", file=sys.stderr)
        sys.exit(2)
    lib = library()   # a failed build raises: make stops
    print("csweep:", f"compiled ({' '.join(FLAGS)})" if lib is not None
          else f"not built ({c_backend.why_unavailable()}): the numpy sweeps run")
    print("task_messages:", "compiled" if task_library() is not None
          else f"not built ({c_backend.why_unavailable()}): the sweeps ask Python for task messages")
    print("box_al:", "compiled" if box_library() is not None
          else f"not built ({c_backend.why_unavailable()}): the MPC workspace's boxes run in numpy")
