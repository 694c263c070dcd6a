"""The AICO sweeps compiled: ``csweep.c`` loaded with ``ctypes`` (speed only, Algorithm 1 unchanged).

``csweep.c`` is ``planning.aico._Sweeps``'s forward / backward / belief / settle code in C, on
the register-tiled dense linear algebra of ``dense.c`` (no BLAS: at the sweeps' sizes it beats
OpenBLAS, see the measurements there; its entry points ``k_*`` are tested against numpy by
tests/test_kernels.py). The two files are compiled as one translation unit (:data:`SOURCES`, in
that order: the dense functions stay ``static`` and inline as before). The sources ship with the package (package data) and is compiled
on first use by the build helper :func:`plants.codegen.c_backend.build_library` into the kernel
cache (``make kernels`` builds it ahead: ``python -m planning.kernels``). :data:`FLAGS` follow
this host's CPU (``-mavx2 -mfma`` only where ``/proc/cpuinfo`` lists both) and are part of the cached
file's key, so a library built for AVX2/FMA is never loaded on a CPU without them: there the
portable build is made and loaded.

Only an explicit opt-out (``RAICO_NO_C=1``) or a machine without ``gcc`` gives :func:`library`
``None`` (then ``_Sweeps`` runs its numpy code); a failed build where ``gcc`` exists raises
:class:`plants.codegen.c_backend.CompileError`.

``SweepState`` mirrors ``sweep_t`` of ``csweep.c`` field for field (all 8-byte fields).
"""

from __future__ import annotations

import ctypes
from enum import IntEnum
from pathlib import Path

from plants.codegen import c_backend

SOURCES = (Path(__file__).with_name("dense.c"), Path(__file__).with_name("csweep.c"))


def source_text() -> str:
    """The kernel's one translation unit: ``dense.c`` then ``csweep.c``."""
    return "".join(p.read_text() for p in SOURCES)
# -O3 vectorizes the small dense loops; contraction into fused multiply-adds and the vectorized
# sums marked `omp simd` (-fopenmp-simd: the pragmas only, no OpenMP runtime) are allowed here (the
# sweeps are compared with the numpy code to a tolerance, not bit for bit). Later flags win.
FLAGS = (*c_backend.CFLAGS, "-O3", "-ffp-contract=fast", "-fopenmp-simd", *c_backend.fma_flags())

# sweep_t.phase / dyn_mode values and sweep_run's error codes
PH_FWD, PH_BWD = 0, 1
DYN_NONE, DYN_C, DYN_PY = 0, 1, 2
ERR_CHOL, ERR_LIN = -1, -2
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
    ]


_LIB: ctypes.CDLL | None | bool = None


def _load() -> ctypes.CDLL:
    lib = c_backend.load_library(source_text(), "csweep", flags=FLAGS)
    for f in ("sweep_work_size", "sweep_iwork_size"):
        getattr(lib, f).argtypes = [_L, _L]
        getattr(lib, f).restype = _L
    lib.lti_rollout.argtypes = [_L, _L, _L] + [_V] * 8
    lib.lti_rollout.restype = None
    for f in ("sweep_run", "sweep_beliefs"):
        getattr(lib, f).argtypes = [ctypes.POINTER(SweepState)]
        getattr(lib, f).restype = ctypes.c_int
    return lib


def library() -> ctypes.CDLL | None:
    """The compiled sweep kernel, or ``None`` (``RAICO_NO_C=1`` or no ``gcc``). A failed build
    (``CompileError``) or a library that does not load (``OSError``) propagates."""
    global _LIB
    if _LIB is None:
        try:
            if not c_backend.enabled():
                raise c_backend.CompileUnavailable("disabled")
            _LIB = _load()
        except c_backend.CompileUnavailable:
            _LIB = False
    return _LIB or None


# -- compiled task messages -------------------------------------------------------------------------
class MessageKind(IntEnum):
    """What a compiled task term evaluates: ``enum message_kind`` of ``planning/task_messages.c``
    (the same values; tests/test_kernels.py reads the C enum and compares)."""

    FRAME_POINTS = 0     # ViaPoint on FramePoints
    CENTER_OF_MASS = 1   # ViaPoint on CenterOfMass
    ROLL = 2             # ViaPoint on RollAngle
    JOINTS = 3           # ViaPoint on JointPositions (phi = S q)
    STATE_TARGET = 4     # StateTarget on the whole state


class _VTerm(ctypes.Structure):
    _fields_ = [("kind", _L), ("body", _L), ("npts", _L), ("dim", _L), ("R_BF", _V), ("p_BF", _V),
                ("pts", _V), ("rows", _V), ("S", _V), ("target", _V), ("C", _V), ("weight", _D),
                ("active", _V)]


class _TaskSet(ctypes.Structure):
    _fields_ = [("nq", _L), ("nx", _L), ("identity", _L), ("nterms", _L), ("m", _L), ("P", _V), ("terms", _V),
                ("frame_points", _V), ("com", _V), ("frame_rotation", _V)]


TASK_MAX_POSITIONS = 64   # MPMAX of task_messages.c
TASK_MAX_ROWS = 64        # TMAX of task_messages.c: rows of one task map's full output
_TASK_LIB: ctypes.CDLL | None | bool = None


def task_library() -> ctypes.CDLL | None:
    """The compiled task messages (``task_messages.c``, the tree libraries' flags: no contraction
    into fused multiply-adds, the numbers of the former in-tree build), or ``None`` as
    :func:`library`."""
    global _TASK_LIB
    if _TASK_LIB is None:
        try:
            if not c_backend.enabled():
                raise c_backend.CompileUnavailable("disabled")
            lib = c_backend.load_library(c_backend.c_source(__file__, "task_messages.c"), "task_messages")
            lib.taskset_eval_address.restype = ctypes.c_void_p
            _TASK_LIB = lib
        except c_backend.CompileUnavailable:
            _TASK_LIB = False
    return _TASK_LIB or None


def compile_task_set(problem):
    """The state terms of ``problem`` as a compiled task-message evaluator (``taskset_eval`` of
    ``task_messages.c``, calling the robot's tree library of :mod:`plants.codegen.rbd` for the
    kinematics): ``(function address, context address, keep-alive)``, or ``None`` when some term
    with a nonzero weight has no compiled counterpart (then the sweeps ask Python).

    Compiled: ``ViaPoint`` on ``FramePoints``, ``CenterOfMass``, ``RollAngle`` (one robot whose
    tree kernels exist) or ``JointPositions``; ``StateTarget``. Joint terms (the GP uncertainty)
    are not.
    """
    import numpy as np

    from planning.costs import StateTarget, ViaPoint
    from plants.taskmaps import CenterOfMass, FramePoints, JointPositions, RollAngle

    if any(t.weight != 0 for t in problem.joint_terms):
        return None
    T, nx = problem.T, problem.n_x
    nq = nx // 2
    if nx != 2 * nq or not 1 <= nq <= TASK_MAX_POSITIONS:
        return None    # outside the kernel's stack buffers: the Python messages
    keep, terms, kern, robot = [], [], None, None

    def arr(a, dtype=float):
        a = np.ascontiguousarray(a, dtype=dtype)
        keep.append(a)
        return a.ctypes.data

    steps = np.arange(T + 1)
    for term in problem.state_terms:
        if term.weight == 0:
            continue
        vt = _VTerm()
        vt.weight = float(term.weight)
        vt.active = arr(term.active(steps), np.uint8)
        if isinstance(term, StateTarget):
            vt.kind, vt.dim = MessageKind.STATE_TARGET, nx
            c_backend.check_shapes("taskset_eval", target=(term.target, (nx,)), C=(term.C, (nx, nx)))
            vt.target, vt.C = arr(term.target), arr(term.C)
            terms.append(vt)
            continue
        if type(term) is not ViaPoint:
            return None
        tm = term.taskmap
        vt.dim = tm.dim
        if not 1 <= tm.dim <= TASK_MAX_ROWS:
            return None
        c_backend.check_shapes("taskset_eval", target=(term.target, (tm.dim,)), C=(term.C, (tm.dim, tm.dim)))
        vt.target, vt.C = arr(term.target), arr(term.C)
        if type(tm) is JointPositions:
            c_backend.check_shapes("taskset_eval", S=(tm.S, (tm.dim, nq)))
            vt.kind, vt.S = MessageKind.JOINTS, arr(tm.S)
            terms.append(vt)
            continue
        if type(tm) not in (FramePoints, CenterOfMass, RollAngle):
            return None
        k = tm.tree_kernels()
        if k is None or (kern is not None and k is not kern) or (robot is not None and tm.robot is not robot):
            return None
        kern, robot = k, tm.robot
        # the map's full output (rows) and the rows the term keeps, within the kernel's buffers
        rows, kept = ((3 * len(tm.points), tm.rows) if type(tm) is FramePoints else
                      (3, tm.axes) if type(tm) is CenterOfMass else (1, np.array([0])))
        if rows > TASK_MAX_ROWS or np.shape(kept) != (tm.dim,) or min(kept) < 0 or max(kept) >= rows:
            return None
        if type(tm) is FramePoints:
            vt.kind, vt.npts = MessageKind.FRAME_POINTS, len(tm.points)
            vt.body = k.tree.body(tm.body_name)
            vt.R_BF, vt.p_BF, vt.pts = arr(tm.frame_rotation), arr(tm.frame_offset), arr(tm.points)
            vt.rows = arr(tm.rows, np.int64)
        elif type(tm) is CenterOfMass:
            vt.kind, vt.rows = MessageKind.CENTER_OF_MASS, arr(tm.axes, np.int64)
        else:
            vt.kind, vt.body = MessageKind.ROLL, k.tree.body(tm.body_name)
            vt.R_BF, vt.rows = arr(tm.frame_rotation), arr([0], np.int64)
        terms.append(vt)
    if kern is None:
        return None    # the kinematics live in a robot's tree library
    lib = task_library()
    P = np.asarray(robot.P, float)
    if lib is None or P.shape != (kern.m, nq) or kern.m > TASK_MAX_POSITIONS:
        return None
    ts = _TaskSet()
    ts.nq, ts.nx, ts.nterms, ts.m = nq, nx, len(terms), kern.m
    ts.frame_points, ts.com, ts.frame_rotation = (kern.addresses[f] for f in (
        "tree_frame_points", "tree_com", "tree_frame_rotation"))
    ts.identity = int(kern.m == nq and np.array_equal(P, np.eye(nq)))
    ts.P = arr(P)
    term_arr = (_VTerm * max(len(terms), 1))(*terms)
    ts.terms = ctypes.addressof(term_arr)
    keep += [term_arr, ts, kern]
    return lib.taskset_eval_address(), ctypes.addressof(ts), keep


if __name__ == "__main__":  # python -m planning.kernels (make kernels): build (or find) the kernel
    lib = library()   # a failed build raises: make stops
    print("csweep:", f"compiled ({' '.join(FLAGS)})" if lib is not None
          else f"not built ({c_backend.why_unavailable()}): the numpy sweeps run")
    print("task_messages:", "compiled" if task_library() is not None
          else f"not built ({c_backend.why_unavailable()}): the sweeps ask Python for task messages")
