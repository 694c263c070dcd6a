"""The compiled kernels (speed only) against the numpy / Drake code they replace.

- the AICO sweep kernel (``raico/planning/csweep.c``) against ``Sweeps``'s numpy code, on every
  route it takes: dynamics linearized in Python (``NEED_DYN``), compiled (``dyn_linearize``) or
  never (LTI, sparse shared ``C``); task messages from Python (``NEED_TASK``) or compiled
  (``taskset_eval``); theta = inf;
- the generated dynamics in C (``FastAnalyticDynamics``) against the same generated code run by
  Python, and the tree dynamics (``TreeAnalyticDynamics``, the Nao's route) against Drake's
  AutoDiffXd (``AnalyticDynamics``) and finite differences;
- the tree kernels (forward kinematics, Jacobians, mass matrix, inverse dynamics and its
  derivatives) against Drake; the compiled task maps and task messages against Drake's;
- that the kernel cannot vanish silently: no skip when the library is missing (a
  missing kernel fails here), the aico runs of this file take the compiled path, a source that
  gcc rejects raises, the source ships as package data, and the build flags match this CPU.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from raico.planning import kernels
from raico.planning.aico import AICOOptions, aico
from raico.planning.aico.sweeps import Sweeps
from raico.plants.codegen import c_backend, rbd
from raico.plants.dynamics import AnalyticDynamics
from raico.plants.fast_analytic import FastAnalyticDynamics, TreeAnalyticDynamics
from raico.plants.numdiff import check_dynamics
from raico.plants.robots import PLANTS, shared_robot
from raico.plants.taskmaps import TASKMAP_EXAMPLES
from raico.stages.plan.stage import PlanConfig, build_problem
from tests.planning.test_aico_speed_equivalence import make_problem
from tests.tolerance import REL, assert_close, bound, cond_of, scale_of

pytestmark = pytest.mark.compiled   # reaches a C kernel: run under the sanitizers too

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def _the_kernel():
    """Every test here needs the compiled kernel: missing, it fails (never skips), saying why."""
    if kernels.library() is None:
        pytest.fail(f"the compiled sweep kernel is not available ({c_backend.why_unavailable()}): "
                    "install gcc (with RAICO_NO_C set only the numpy code runs)")


def test_the_compiled_path_is_the_one_that_ran(monkeypatch):
    """aico with the kernel available runs its sweeps in C (``_sweep_compiled``), not the numpy code."""
    calls = []
    real = Sweeps._sweep_compiled
    monkeypatch.setattr(Sweeps, "_sweep_compiled", lambda self, lib: (calls.append(1), real(self, lib))[1])
    aico(make_problem(), AICOOptions(alpha=1.0, iterations=2, tol_rel=0.0))
    assert calls


def test_a_broken_kernel_source_fails_loudly(tmp_path):
    """gcc present and the source broken (a syntax error): the build raises CompileError (never the
    silent numpy fallback), and so does ``python -m raico.planning.kernels`` (make kernels)."""
    broken = kernels.source_text().replace("sweep_run(", "sweep_run((", 1)
    with pytest.raises(c_backend.CompileError, match="gcc failed on csweep"):
        c_backend.build_library(broken, "csweep", directory=tmp_path, flags=kernels.FLAGS)
    assert not list(tmp_path.glob("*.so"))
    # the build helper of make kernels, on a copy of the package whose csweep.c is broken
    copy = tmp_path / "repo"
    for pkg in ("plants", "planning"):
        shutil.copytree(REPO / "raico" / pkg, copy / "raico" / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    (copy / "raico" / "planning" / "csweep.c").write_text(kernels.SOURCES[1].read_text().replace("sweep_run(", "sweep_run((", 1))
    env = {**os.environ, "RAICO_KERNEL_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(copy)}
    env.pop("RAICO_NO_C", None)
    p = subprocess.run([sys.executable, "-m", "raico.planning.kernels"], cwd=copy, env=env,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode != 0 and "CompileError" in p.stderr, p.stderr[-2000:]


def test_the_kernel_source_is_package_data():
    """A wheel or non-editable install has ``raico/planning/csweep.c`` (pyproject's package data)."""
    data = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    import fnmatch

    for name in ("dense.c", "csweep.c"):
        assert any(fnmatch.fnmatch(f"planning/{name}", pat) for pat in data["raico"]), name
        assert (REPO / "raico" / "planning" / name).exists()


def test_the_kernel_flags_follow_this_cpu():
    """-mavx2 / -mfma only where /proc/cpuinfo lists the CPU flags (or the level RAICO_ISA names has
    them); they are part of the cached library's key, so a build for another CPU is never the one
    loaded here."""
    cpu, level = c_backend.cpu_features(), c_backend.isa_level()
    if level == "host":
        assert ("-mavx2" in kernels.FLAGS) == ("avx2" in cpu)
        assert ("-mfma" in kernels.FLAGS) == ({"avx2", "fma"} <= cpu)
        assert ("-mavx512f" in kernels.FLAGS) == ({"avx2", "fma", "avx512f"} <= cpu)
    else:
        assert f"-march={level}" in kernels.FLAGS and "-mavx512f" not in kernels.FLAGS
        assert ("-mfma" in kernels.FLAGS) == ("-mavx2" in kernels.FLAGS) == (level == "x86-64-v3")
    source = kernels.source_text()
    here = c_backend.library_path(source, "csweep", flags=kernels.FLAGS)
    portable = tuple(f for f in kernels.FLAGS if f not in ("-mavx2", "-mfma", *kernels.wide_flags()))
    assert c_backend.library_path(source, "csweep", flags=portable) != here
    loaded = kernels.library()
    assert Path(loaded._name) == here


def _instructions(path: Path) -> set[str]:
    """The mnemonics and registers of the machine code of the library at ``path`` (objdump's disassembly)."""
    out = subprocess.run(["objdump", "-d", "--no-show-raw-insn", str(path)], capture_output=True, text=True,
                         check=True).stdout
    words = set()
    for line in out.splitlines():
        parts = line.split("\t")
        if len(parts) >= 2 and parts[0].strip().endswith(":"):
            words.add(parts[1].split()[0] if parts[1].split() else "")
            words.update(re.findall(r"%([xyz]mm)\d+", parts[-1]))
    return words


@pytest.mark.numerics
def test_an_instruction_set_level_builds_its_own_kernels_with_its_instructions_only(tmp_path, monkeypatch):
    """RAICO_ISA's levels: x86-64-v2 has no AVX (no VEX-encoded instruction, no ymm or zmm register),
    x86-64-v3 has AVX2 and FMA but no AVX-512; each level's flags are part of the cache key (three
    files, never mixed); the sweeps built for x86-64-v2 give the numpy sweeps' numbers within the
    rounding bound of the run, as the host's build does. An unknown level is refused in one line."""
    if shutil.which("objdump") is None:
        pytest.skip("objdump (binutils) is not installed")
    v2, v3, host = (kernels.flags_for(level) for level in ("x86-64-v2", "x86-64-v3", "host"))
    assert "-march=x86-64-v2" in v2 and not {"-mavx2", "-mfma", "-mavx512f"} & set(v2)
    assert {"-march=x86-64-v3", "-mavx2", "-mfma"} <= set(v3) and "-mavx512f" not in v3
    source = kernels.source_text()
    paths = {c_backend.library_path(source, "csweep", tmp_path, flags) for flags in (v2, v3, host)}
    assert len(paths) == 3
    built = {}
    for level, flags in (("x86-64-v2", v2), ("x86-64-v3", v3)):
        missing = c_backend.ISA_LEVELS[level] - c_backend.cpu_features()
        if missing:
            continue   # this CPU cannot run that level's code
        built[level] = c_backend.build_library(source, "csweep", directory=tmp_path, flags=flags)
    if "x86-64-v2" not in built:
        pytest.skip("this CPU cannot run x86-64-v2 code")
    words = _instructions(built["x86-64-v2"])
    assert "xmm" in words and not {"ymm", "zmm"} & words and not any(w.startswith("v") for w in words)
    if "x86-64-v3" in built:
        words = _instructions(built["x86-64-v3"])
        assert "ymm" in words and "zmm" not in words and any(w.startswith("vfmadd") for w in words)
    # the same run with the numpy sweeps, the host's kernel and the x86-64-v2 kernel
    opts = AICOOptions(alpha=1.0, iterations=3, tol_rel=0.0, theta=0.02)
    compiled, ref, rel = _both_with_bound(make_problem, opts, monkeypatch)
    _assert_same(compiled, ref, rel)
    monkeypatch.setattr(Sweeps, "compiled", True)
    monkeypatch.setattr(kernels.library, "_lib", _sweep_lib_at(built["x86-64-v2"]))
    monkeypatch.setattr(kernels.library, "_loaded", True)
    _assert_same(aico(make_problem(), opts), ref, rel)
    # an unknown level: one line, before anything is built
    monkeypatch.setenv("RAICO_ISA", "x86-64-v9")
    with pytest.raises(c_backend.IsaError, match=r"^RAICO_ISA='x86-64-v9' is not an instruction-set level: give one of"):
        c_backend.build_library(source + "\n", "csweep", directory=tmp_path / "refused")
    assert not (tmp_path / "refused").exists()
    env = {**os.environ, "RAICO_ISA": "avx9000", "RAICO_KERNEL_DIR": str(tmp_path / "cli")}
    p = subprocess.run([sys.executable, "-m", "raico.planning.kernels"], cwd=REPO, env=env, capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 2 and p.stderr.strip().count("\n") == 0 and "RAICO_ISA='avx9000'" in p.stderr, p.stderr


def _sweep_lib_at(path: Path):
    """The sweep kernel built at ``path``, its entry points typed as :func:`raico.planning.kernels.library` types them."""
    import ctypes

    return kernels.library.typed(ctypes.CDLL(str(path)))


@pytest.mark.numerics
def test_wide_tiles_give_the_avx2_numbers_bit_for_bit(tmp_path, monkeypatch):
    """Where the CPU has AVX-512 the products take 16-column tiles (kernels.wide_flags): every entry gets
    the operations of the AVX2 build's 8-column tiles in the same order, so both builds give the same
    bits: the dense kernels on shapes across the tiles' edges, and whole runs on the block form (coupled
    pendulums) and on the dense route of a learned model (whose figures depend on its rounding)."""
    from raico.planning.costs import ControlCost, StateTarget
    from raico.planning.problem import Problem
    from raico.plants.learned import LearnedDynamics
    from tests.planning.test_aico_speed_equivalence import CoupledPendulums
    from tests.planning.test_kernel_shapes import _gp

    if not kernels.wide_flags():
        pytest.skip("no AVX-512 on this CPU: one build only")
    narrow = tuple(f for f in kernels.FLAGS if f not in kernels.wide_flags())
    path = c_backend.build_library(kernels.source_text(), "csweep", directory=tmp_path, flags=narrow)
    wide_lib, narrow_lib = kernels.library(), _sweep_lib_at(path)
    rng = np.random.default_rng(5)
    for a, r, c in ((16, 16, 16), (17, 33, 31), (40, 21, 65), (64, 32, 97), (5, 64, 48)):
        A, B, C0, S = rng.standard_normal((a, r)), rng.standard_normal((r, c)), rng.standard_normal((a, c)), _spd(rng, c)
        out = []
        for lib in (_dense_lib(wide_lib), _dense_lib(narrow_lib)):
            C, W, R = C0.copy(), np.zeros((c, c)), S.copy()
            lib.k_gemm_nn(a, r, c, -0.5, A.ctypes.data, r, B.ctypes.data, c, C.ctypes.data, c)
            lib.k_syrk_tn(r, c, 2.0, B.ctypes.data, c, W.ctypes.data, c, 1)
            assert lib.k_chol_u(c, R.ctypes.data, c) == 0
            Inv, Y = np.empty((c, c)), np.full((c, c), np.nan)
            lib.k_spd_inverse(c, R.ctypes.data, c, Inv.ctypes.data, c, Y.ctypes.data)
            out.append((C, np.triu(W), np.triu(R), Inv))
        for x, y in zip(*out):
            assert np.array_equal(x, y), (a, r, c)
    nq, T = 10, 15
    goal = np.concatenate([np.full(nq, 0.4), np.zeros(nq)])
    cases = (lambda: CoupledPendulums(nq, 0.02), lambda: LearnedDynamics(_gp(30, 3 * nq, nq, seed=3), n_q=nq, dt=0.02))
    counts = _recording_block_steps(monkeypatch)
    for make_dyn in cases:
        runs = []
        for lib in (wide_lib, narrow_lib):
            monkeypatch.setattr(kernels.library, "_lib", lib)
            monkeypatch.setattr(kernels.library, "_loaded", True)
            problem = Problem(make_dyn(), np.zeros(2 * nq), T, [StateTarget(goal, [T], weight=1e3, name="goal")],
                              [ControlCost(1e-2)])
            runs.append(aico(problem, AICOOptions(alpha=1.0, iterations=2, tol_rel=0.0, theta=0.01)))
        assert np.array_equal(runs[0].X, runs[1].X) and np.array_equal(runs[0].U, runs[1].U)
    assert any(counts) and not all(counts)   # the block form on the pendulums, the dense route on the model


def _plan_problem(plant: str, task: str, dynamics: str, T: int | None = None):
    problem = build_problem(PlanConfig(plant=plant, task=task, dynamics=dynamics, seed=0))[2]
    return problem


def _both_with_bound(make, options: AICOOptions, monkeypatch):
    """The same run with the compiled sweeps and with the numpy sweeps, and the rounding bound between the
    two (:func:`tests.tolerance.bound`): ``n_ops`` = iterations x n (each step factors the belief precision
    and the messages, of order n = n_x, once per sweep; the precision matrices' recursion over time
    forgets a step's rounding, so the steps of one sweep do not add up), ``cond`` = the largest
    condition number of the matrices the numpy sweeps factored, the belief precisions
    ``S_t^-1 + V_t^-1 + R_t`` at every step of the last sweep."""
    out, seen = {}, []
    real = Sweeps.__init__

    def init(self, *args, **kwargs):
        real(self, *args, **kwargs)
        seen.append(self)

    for compiled in (True, False):
        monkeypatch.setattr(Sweeps, "compiled", compiled)
        with monkeypatch.context() as m:
            m.setattr(Sweeps, "__init__", init)
            out[compiled] = aico(make(), options)
    s, n = seen[-1], out[False].X.shape[1]
    cond = cond_of(s.SA[..., :n] + s.VA[..., :n] + s.RA[..., :n])
    return out[True], out[False], bound(max(out[False].iterations, 1) * n, cond)


def _both(make, options: AICOOptions, monkeypatch):
    """The same run with the compiled sweeps and with the numpy sweeps."""
    return _both_with_bound(make, options, monkeypatch)[:2]


def _assert_same(a, b, rel: float = REL):
    """Two runs of one problem by two routes: the same statuses, iterations and settle repeats, costs and
    trajectories, controllers and beliefs within ``rel`` of their scale (at least 1), the latter at least
    within 10 REL (the trajectories accumulate T steps' rounding where the costs sum them)."""
    assert a.status == b.status and a.iterations == b.iterations, (a.message, b.message)
    assert [h.repeats for h in a.history] == [h.repeats for h in b.history]
    assert_close(a.costs, b.costs, rel=rel, err_msg="costs")
    for key in ("X", "U", "o", "O", "beliefs"):
        assert_close(getattr(a, key), getattr(b, key), rel=max(rel, 10 * REL), scale=1.0, err_msg=key)


@pytest.mark.numerics
@pytest.mark.parametrize("dynamics,limits,opts", [
    ("pendulums", False, dict(alpha=1.0, iterations=4)),                  # Python dynamics + tasks
    ("pendulums", True, dict(alpha=0.5, gamma=0.8, iterations=3, theta=0.02)),
    ("pendulums", False, dict(alpha=1.0, iterations=3, theta=math.inf)),  # backward sweep only
    ("pseudo", False, dict(alpha=1.0, iterations=4, theta=0.02)),         # LTI: sparse shared C
    # V*: Cholesky (large q), Cholesky and 3-term series mixed, 1-term series (tiny q); the
    # default q gives the 2- and 3-term series
    ("pendulums", False, dict(alpha=1.0, iterations=3, process_noise=1e-2)),
    ("pseudo", False, dict(alpha=1.0, iterations=3, theta=0.02, process_noise=1e-7)),
    ("pendulums", False, dict(alpha=1.0, iterations=3, process_noise=1e-14)),
], ids=["python-dynamics", "limits", "theta-inf", "lti", "vstar-cholesky", "vstar-mixed", "vstar-one-term"])
def test_compiled_sweeps_equal_numpy_sweeps(dynamics, limits, opts, monkeypatch):
    a, b = _both(lambda: make_problem(dynamics, limits), AICOOptions(tol_rel=0.0, **opts), monkeypatch)
    _assert_same(a, b)
    if math.isfinite(opts.get("theta", 0.1)):
        assert sum(h.repeats for h in a.history) > 0


@pytest.mark.numerics
@pytest.mark.parametrize("plant,task,dynamics", [
    ("arm5", "reach-roll", "analytic"),   # compiled dynamics and task messages (Drake maps in C)
    ("nao", "balance", "pseudo"),         # n = 50, LTI, a task term at every step
])
def test_compiled_sweeps_on_the_plans(plant, task, dynamics, monkeypatch):
    assert kernels.compile_task_set(_plan_problem(plant, task, dynamics)) is not None
    a, b = _both(lambda: _plan_problem(plant, task, dynamics),
                 AICOOptions(alpha=1.0, iterations=2, tol_rel=0.0), monkeypatch)
    _assert_same(a, b)
    assert sum(h.repeats for h in a.history) > 0


@pytest.mark.numerics
@pytest.mark.parametrize("plant,task,dynamics", [
    ("arm5", "reach-roll", "analytic"), ("nao", "balance", "pseudo"), ("nao", "reach", "pseudo"),
    ("biorob", "reach", "analytic"), ("pendulum", "swing-up", "analytic")])
def test_compiled_task_messages_equal_the_terms(plant, task, dynamics):
    problem = _plan_problem(plant, task, dynamics)
    fn, ctx, keep = kernels.compile_task_set(problem)
    import ctypes

    evaluate = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p,
                                ctypes.c_void_p, ctypes.c_void_p)(fn)
    rng = np.random.default_rng(0)
    active = problem.active_state_terms()
    n = problem.n_x
    steps = [t for t in range(problem.T + 1) if active[t]][:3] + [problem.T]
    for t in steps:
        x = problem.x0 + 0.2 * rng.standard_normal(n)
        lx, lxx = np.empty(n), np.empty((n, n))
        evaluate(ctx, t, x.ctypes.data, lx.ctypes.data, lxx.ctypes.data)
        g, G = problem.point_state_derivatives(x, t, active[t])
        scale = max(np.abs(G).max(), 1.0)
        np.testing.assert_allclose(lx, g, rtol=0, atol=1e-9 * max(np.abs(g).max(), 1.0))
        np.testing.assert_allclose(lxx, G, rtol=0, atol=1e-9 * scale)


def _recording_block_steps(monkeypatch) -> list[int]:
    """After each compiled sweep, how many of its backward messages and dynamics relinearizations took
    the semi-implicit Euler block form (``Sweeps.block_steps``)."""
    counts: list[int] = []
    real = Sweeps._sweep_compiled

    def run(self, lib):
        before = self.block_steps
        real(self, lib)
        counts.append(self.block_steps - before)

    monkeypatch.setattr(Sweeps, "_sweep_compiled", run)
    return counts


def _dense_route(monkeypatch) -> None:
    """The compiled sweeps without the block form (no time step given to the kernel): the dense products."""
    real = Sweeps._kernel_state

    def state(self, lib):
        st = real(self, lib)
        st.dt = 0.0
        return st

    monkeypatch.setattr(Sweeps, "_kernel_state", state)


_MODEL_FILES = ("raico/problems/examples/ur5_reach.toml", "raico/problems/examples/xarm7_reach.toml",
                "raico/problems/crocoddyl/kinova_reach.toml")


def _file_problem(path: str):
    from raico.plants.model_file import example_robot_data

    if example_robot_data() is None:
        pytest.skip("example-robot-data is not installed (it comes with the extra raico[baseline])")
    return build_problem(PlanConfig(problem=str(REPO / path), bounds="none").normalized())[2]


@pytest.mark.numerics
@pytest.mark.parametrize("case", [
    ("arm5", "reach-roll", "analytic"), ("pendulum", "swing-up", "analytic"), ("biorob", "reach", "analytic"),
    *_MODEL_FILES], ids=["arm5", "pendulum", "biorob", "ur5", "xarm7", "kinova"])
def test_block_form_sweeps_equal_numpy_sweeps(case, monkeypatch):
    """The semi-implicit Euler step's block form (A = J + e A_b, B = e B_b) is taken on the thesis's analytic
    plans and on model-file robots, and gives the numpy sweeps' numbers (dense A, B) to rounding; the
    dense compiled products give them too."""
    make = (lambda: _plan_problem(*case)) if isinstance(case, tuple) else (lambda: _file_problem(case))
    opts = AICOOptions(alpha=1.0, iterations=2, tol_rel=0.0)
    counts = _recording_block_steps(monkeypatch)
    a, b, rel = _both_with_bound(make, opts, monkeypatch)   # the model-file arms: condition ~5e8
    _assert_same(a, b, rel)
    assert counts and all(c > 0 for c in counts)
    _dense_route(monkeypatch)
    counts.clear()
    monkeypatch.setattr(Sweeps, "compiled", True)
    d = aico(make(), opts)
    _assert_same(d, b, rel)
    assert counts and not any(counts)


class _NotQuiteSemiImplicit:
    """The test pendulums with the position rows of ``A`` off the block form by a relative 1e-6: the
    kernel must take the dense products (and still give the numpy sweeps' numbers)."""

    def __init__(self, inner):
        self.inner, self.n_q, self.n_x, self.n_u, self.dt = inner, inner.n_q, inner.n_x, inner.n_u, inner.dt

    def step(self, x, u):
        return self.inner.step(x, u)

    def linearize(self, x, u):
        A, a, B = self.inner.linearize(x, u)
        A[: self.n_q] *= 1.0 + 1e-6
        return A, a, B

    def linearize_trajectory(self, X, U):
        parts = [self.linearize(x, u) for x, u in zip(X, U)]
        return tuple(np.stack([p[i] for p in parts]) for i in range(3))


@pytest.mark.numerics
def test_block_form_only_where_the_matrices_have_it(monkeypatch):
    import dataclasses

    def make():
        p = make_problem()
        return dataclasses.replace(p, dynamics=_NotQuiteSemiImplicit(p.dynamics))

    counts = _recording_block_steps(monkeypatch)
    a, b = _both(make, AICOOptions(alpha=1.0, iterations=2, tol_rel=0.0), monkeypatch)
    _assert_same(a, b)
    assert counts and not any(counts)
    counts.clear()
    monkeypatch.setattr(Sweeps, "compiled", True)
    aico(make_problem(), AICOOptions(alpha=1.0, iterations=2, tol_rel=0.0))   # the same model, exact
    assert counts and all(c > 0 for c in counts)


@pytest.mark.numerics
def test_fallback_without_the_kernel(monkeypatch):
    """No compiler (or RAICO_NO_C): the numpy sweeps run (and give the compiled numbers)."""
    a = aico(make_problem(), AICOOptions(alpha=1.0, iterations=2, tol_rel=0.0))
    monkeypatch.setattr(kernels, "library", lambda: None)
    b = aico(make_problem(), AICOOptions(alpha=1.0, iterations=2, tol_rel=0.0))
    _assert_same(a, b)


# -- the dense kernels of the sweeps, by themselves ------------------------------------------------
# every edge of the 4-row, 4-, 8- and 16-column tiles (16: the AVX-512 build) and the sizes the sweeps reach
_SIZES = [1, 2, 3, 4, 5, 7, 8, 9, 12, 13, 15, 16, 17, 25, 31, 32, 33, 50, 63, 64, 65]
_PAD = 12345.0     # written around every operand: a kernel reading or writing outside its block fails


def _dense_lib(lib=None):
    import ctypes

    lib = kernels.library() if lib is None else lib
    L, D, P = ctypes.c_long, ctypes.c_double, ctypes.c_void_p
    lib.k_chol_u.argtypes, lib.k_chol_u.restype = [L, P, L], ctypes.c_int
    for f in ("k_solve_rt", "k_solve_r"):
        getattr(lib, f).argtypes = [L, P, L, P, L, L]
    lib.k_spd_inverse.argtypes = [L, P, L, P, L, P]
    lib.k_gemm_nn.argtypes = lib.k_gemm_tn.argtypes = lib.k_gemm_nn_set.argtypes = [L, L, L, D, P, L, P, L,
                                                                                     P, L]
    lib.k_syrk_tn.argtypes = [L, L, D, P, L, P, L, L]
    lib.k_transpose.argtypes = [L, L, P, L, P, L]
    return lib


def _padded(M: np.ndarray, extra: int = 3) -> np.ndarray:
    """``M`` inside a larger row-major buffer (``extra`` more columns and one more row of _PAD)."""
    r, c = M.shape
    out = np.full((r + 1, c + extra), _PAD)
    out[:r, :c] = M
    return out


def _spd(rng, n: int) -> np.ndarray:
    G = rng.standard_normal((n, n))
    return G.T @ G + 0.1 * np.eye(n)


@pytest.mark.numerics
@pytest.mark.parametrize("n", _SIZES)
def test_dense_cholesky_solves_and_inverse(n):
    """Cholesky factor (upper, only the upper triangle read), R^-T B, R^-1 B and the SPD inverse
    against numpy, on every edge shape of the register tiles, nothing touched outside the block."""
    lib, rng = _dense_lib(), np.random.default_rng(n)
    A = _spd(rng, n)
    buf = _padded(np.triu(A) + np.tril(np.full((n, n), np.nan), -1))
    ld = buf.shape[1]
    assert lib.k_chol_u(n, buf.ctypes.data, ld) == 0
    R = np.triu(buf[:n, :n])
    np.testing.assert_allclose(R, np.linalg.cholesky(A).T, rtol=0, atol=1e-9 * np.abs(A).max())
    assert (buf[:n, n:] == _PAD).all() and (buf[n] == _PAD).all()
    for c in (1, 3, 4, 5, 8, 11, n + 1):
        B = rng.standard_normal((n, c))
        for f, ref in (("k_solve_rt", np.linalg.solve(R.T, B)), ("k_solve_r", np.linalg.solve(R, B))):
            Bb = _padded(B)
            getattr(lib, f)(n, buf.ctypes.data, ld, Bb.ctypes.data, Bb.shape[1], c)
            np.testing.assert_allclose(Bb[:n, :c], ref, rtol=0, atol=1e-9 * max(np.abs(ref).max(), 1.0),
                                       err_msg=f"{f} c={c}")
            assert (Bb[:n, c:] == _PAD).all() and (Bb[n] == _PAD).all()
    out, Y = _padded(np.full((n, n), np.nan)), np.full((n, n), np.nan)
    lib.k_spd_inverse(n, buf.ctypes.data, ld, out.ctypes.data, out.shape[1], Y.ctypes.data)
    Ainv = np.linalg.inv(A)
    np.testing.assert_allclose(out[:n, :n], Ainv, rtol=0, atol=1e-9 * np.abs(Ainv).max())
    assert (out[:n, :n] == out[:n, :n].T).all() and (out[:n, n:] == _PAD).all()
    bad = _padded(-np.eye(n))
    assert lib.k_chol_u(n, bad.ctypes.data, bad.shape[1]) == 1     # not positive definite: row 1


@pytest.mark.numerics
@pytest.mark.parametrize("a,r,c", [(1, 1, 1), (3, 5, 2), (4, 4, 4), (5, 7, 9), (9, 3, 13),
                                   (25, 50, 76), (50, 51, 51), (50, 25, 50), (13, 50, 8),
                                   (4, 16, 16), (5, 17, 15), (16, 31, 17), (17, 33, 32), (33, 16, 33),
                                   (15, 9, 31), (64, 64, 64), (3, 65, 65), (65, 2, 48)])
def test_dense_products_and_transpose(a, r, c):
    """A B, A^T B, the upper triangle of W^T W and transposes against numpy, with alpha,
    accumulated into C or setting it (C not read: NaN before), nothing touched outside the block."""
    lib, rng = _dense_lib(), np.random.default_rng(a * 100 + r)
    A, At, B, C0 = (rng.standard_normal(s) for s in ((a, r), (r, a), (r, c), (a, c)))
    for f, X, ref in (("k_gemm_nn", A, C0 - 0.5 * A @ B), ("k_gemm_tn", At, C0 - 0.5 * At.T @ B)):
        Xb, Bb, Cb = _padded(X), _padded(B), _padded(C0)
        args = (a, r, c) if f == "k_gemm_nn" else (r, a, c)
        getattr(lib, f)(*args, -0.5, Xb.ctypes.data, Xb.shape[1], Bb.ctypes.data, Bb.shape[1],
                        Cb.ctypes.data, Cb.shape[1])
        np.testing.assert_allclose(Cb[:a, :c], ref, rtol=0, atol=1e-9 * r, err_msg=f)
        assert (Cb[:a, c:] == _PAD).all() and (Cb[a] == _PAD).all()
    Xb, Bb, Cb = _padded(A), _padded(B), _padded(np.full((a, c), np.nan))
    lib.k_gemm_nn_set(a, r, c, -0.5, Xb.ctypes.data, Xb.shape[1], Bb.ctypes.data, Bb.shape[1],
                      Cb.ctypes.data, Cb.shape[1])
    np.testing.assert_allclose(Cb[:a, :c], -0.5 * A @ B, rtol=0, atol=1e-9 * r)
    W, S0 = rng.standard_normal((r, a)), rng.standard_normal((a, a))
    iu = np.triu_indices(a)
    for set_, before, ref in ((0, S0, S0 + 2.0 * W.T @ W), (1, np.full((a, a), np.nan), 2.0 * W.T @ W)):
        Wb, Sb = _padded(W), _padded(before)
        lib.k_syrk_tn(r, a, 2.0, Wb.ctypes.data, Wb.shape[1], Sb.ctypes.data, Sb.shape[1], set_)
        np.testing.assert_allclose(Sb[:a, :a][iu], ref[iu], rtol=0, atol=1e-9 * r)
        assert (Sb[:a, a:] == _PAD).all() and (Sb[a] == _PAD).all()
    M = rng.standard_normal((a, c))
    Mb, Tb = _padded(M), _padded(np.zeros((c, a)))
    lib.k_transpose(a, c, Mb.ctypes.data, Mb.shape[1], Tb.ctypes.data, Tb.shape[1])
    assert (Tb[:c, :a] == M.T).all() and (Tb[:c, a:] == _PAD).all() and (Tb[c] == _PAD).all()


# -- dynamics ---------------------------------------------------------------------------------------
@pytest.mark.numerics
@pytest.mark.parametrize("plant", ["pendulum", "arm5", "biorob"])
def test_generated_dynamics_in_c_equal_python(plant):
    robot = shared_robot(plant)
    fast, slow = FastAnalyticDynamics(robot, 0.01), FastAnalyticDynamics(robot, 0.01)
    slow._c = False                                  # the generated Python code
    assert fast._compiled() is not None
    rng = np.random.default_rng(1)
    n = robot.n_q
    X = np.concatenate([robot.default_q + rng.uniform(-1.5, 1.5, (6, n)), rng.standard_normal((6, n))], 1)
    U = 3.0 * rng.standard_normal((6, n))
    for x, u in zip(X, U):
        for got, ref in zip(fast.linearize(x, u), slow.linearize(x, u)):
            assert_close(got, ref, scale=1.0)   # the C is built with FMA: equal up to rounding
        assert_close(fast.step(x, u), slow.step(x, u), scale=scale_of(x, u))
    for got, ref in zip(fast.linearize_trajectory(X, U), slow.linearize_trajectory(X, U)):
        assert_close(got, ref, scale=1.0)
    O = 0.1 * rng.standard_normal((6, n, 2 * n))
    for got, ref in zip(fast.controller_rollout(X[0], U, O), slow.controller_rollout(X[0], U, O)):
        assert_close(got, ref, scale=1.0)


@pytest.mark.numerics
@pytest.mark.parametrize("plant", PLANTS)
def test_tree_kernels_equal_drake(plant):
    robot = shared_robot(plant)
    k = rbd.tree_kernels(robot)
    assert rbd.self_check(robot.plant, k, n_states=4, seed=11) <= REL   # relative to each quantity's scale


@pytest.mark.numerics
def test_tree_dynamics_of_the_nao_equal_autodiff():
    nao = shared_robot("nao")
    fast, exact = TreeAnalyticDynamics(nao, 0.01), AnalyticDynamics(nao, 0.01)
    rng = np.random.default_rng(2)
    n = nao.n_q
    X = np.concatenate([nao.default_q + 0.5 * rng.standard_normal((3, n)), rng.standard_normal((3, n))], 1)
    U = rng.standard_normal((3, n))
    for x, u in zip(X, U):
        A, a, B = fast.linearize(x, u)
        A0, a0, B0 = exact.linearize(x, u)
        assert_close(A, A0)
        assert_close(B, B0)
        assert_close(a, a0, scale=1 + scale_of(x) + scale_of(u))
        assert_close(fast.step(x, u), exact.step(x, u), scale=scale_of(x, u))
        q, v = x[:n], x[n:]
        for got, ref in zip(fast.qddot_derivatives(q, v, u), exact.qddot_derivatives(q, v, u)):
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9 * max(np.abs(ref).max(), 1.0))
        assert_close(fast.inverse_dynamics(q, v, u), exact.inverse_dynamics(q, v, u), scale=1.0)
    check_dynamics(fast, X[:2], U[:2]).assert_passed()   # and against finite differences


@pytest.mark.numerics
@pytest.mark.parametrize("name,plant", [(n, p) for n, ex in TASKMAP_EXAMPLES.items()
                                        for p in PLANTS if ex.applies_to(p)])
def test_compiled_task_maps_equal_drake(name, plant):
    robot = shared_robot(plant)
    tm = TASKMAP_EXAMPLES[name].build(robot)
    maps = getattr(tm, "maps", [tm])
    rng = np.random.default_rng(3)
    Q = robot.default_q + 0.3 * rng.standard_normal((3, robot.n_q))
    for m in maps:
        if not hasattr(m, "_in_plant"):   # a joint selection: no plant; its definition is the reference
            V, J = m.values_and_jacobians(Q)
            idx = np.argmax(m.S, axis=1)
            np.testing.assert_array_equal(V, Q[:, idx])
            np.testing.assert_array_equal(J, np.broadcast_to(np.eye(robot.n_q)[idx], J.shape))
            continue
        assert m.tree_kernels() is not None
        for q in Q:
            qp = robot.P @ q
            for got, ref in zip(m._compiled_in_plant(m.tree_kernels(), qp), m._in_plant(qp)):
                assert_close(got, ref, scale=1.0)   # metres, radians: a robot of about 1 m
        V, J = m.values_and_jacobians(Q)
        for i, q in enumerate(Q):
            v, Jd = m._in_plant(robot.P @ q)
            assert_close(V[i], v, scale=1.0)
            assert_close(J[i], Jd @ robot.P, scale=1.0)


@pytest.mark.numerics
def test_emitted_c_is_the_python_arithmetic():
    """The generated C evaluates the very operations of the generated Python (bitwise here:
    same libm, no contraction)."""
    from raico.plants.codegen.derive import compiled_dynamics

    code = compiled_dynamics(shared_robot("arm5"))
    fast = FastAnalyticDynamics(shared_robot("arm5"), 0.01)
    rng = np.random.default_rng(5)
    x = rng.standard_normal(10)
    Mr, hr = fast._compiled().mh(x)
    out = code.sca["mh"]([*x.tolist()], [0.0] * 30)
    assert np.array_equal(Mr.reshape(-1), np.array(out[:25])) and np.array_equal(hr, np.array(out[25:]))
    assert "-ffp-contract=off" in c_backend.CFLAGS


def test_message_kinds_are_named_alike_in_python_and_c():
    """The compiled task terms are selected by named constants: raico.planning.kernels.MessageKind mirrors
    ``enum message_kind`` of raico/planning/task_messages.c value for value; the plants floor holds none of it."""
    import re

    src = (REPO / "raico" / "planning" / "task_messages.c").read_text()
    assert "message_kind" not in (REPO / "raico" / "plants" / "codegen" / "rbd_kernels.c").read_text()
    body = re.search(r"enum message_kind \{([^}]*)\}", src).group(1)
    c_enum = {name.strip().removeprefix("MK_"): int(v) for name, v in re.findall(r"(MK_\w+)\s*=\s*(\d+)", body)}
    assert c_enum == {k.name: int(k) for k in kernels.MessageKind}
    assert not re.search(r"tm->kind == \d", src)  # no bare numbers where the kinds are tested


# -- per-solve shortcuts on a compiled model ----------------------------------------------------------
@pytest.mark.numerics
@pytest.mark.parametrize("compiled", [True, False], ids=["c", "generated-python"])
def test_a_constant_start_is_linearized_once_with_the_same_numbers(compiled, monkeypatch):
    """At the default start (``x0`` at every step, zero controls) the sweeps linearize the dynamics at one
    point, and every step gets the numbers the whole batch would give; any other trajectory is the batch."""
    problem = _plan_problem("arm5", "reach-roll", "analytic")
    dyn, T = problem.dynamics, 40
    if not compiled:
        dyn._c = False
    sizes = []
    real = type(dyn).linearize_trajectory
    monkeypatch.setattr(type(dyn), "linearize_trajectory", lambda self, X, U: (sizes.append(len(X)), real(self, X, U))[1])
    sw = Sweeps(problem, AICOOptions(alpha=1.0))
    X, U = np.tile(problem.x0, (T, 1)), np.zeros((T, problem.n_u))
    for got, ref in zip(sw._linearize_dynamics(X, U), real(dyn, X, U)):
        assert got.shape == ref.shape[1:] and (np.broadcast_to(got, ref.shape) == ref).all()
    assert sizes == [1]
    X[7, 0] += 1e-9                          # one step elsewhere: the whole batch
    for got, ref in zip(sw._linearize_dynamics(X, U), real(dyn, X, U)):
        assert (got == ref).all()
    assert sizes == [1, T]


@pytest.mark.numerics
def test_the_start_rollout_is_the_python_loop_also_where_it_blows_up():
    """``aico``'s open-loop start rollout on a compiled model: the bits of ``raico.plants.dynamics.rollout``, for
    a rollout that stays finite and for one that leaves the finite numbers part-way."""
    from raico.planning.aico.solve import open_loop_rollout
    from raico.plants.dynamics import rollout

    problem = _plan_problem("arm5", "reach-roll", "analytic")
    rng = np.random.default_rng(3)
    U = rng.standard_normal((problem.T, problem.n_u))
    X = open_loop_rollout(problem, U)
    assert np.isfinite(X).all() and np.array_equal(X, rollout(problem.dynamics, problem.x0, U))
    # a huge control: the state goes all NaN at once (every later state is NaN), or first to a mix of
    # inf and NaN (the loop goes on from there)
    for big, all_nan in ((1e200, True), (1.7e308, False)):
        U[problem.T // 2] = big
        with np.errstate(all="ignore"):
            ref = rollout(problem.dynamics, problem.x0, U)
        X = open_loop_rollout(problem, U)
        k = int(np.argmin(np.isfinite(ref).all(axis=1)))
        assert problem.T // 2 < k < problem.T and bool(np.isnan(ref[k]).all()) is all_nan
        assert np.isfinite(X[:k]).all() and np.array_equal(X, ref, equal_nan=True)


@pytest.mark.numerics
def test_the_cost_of_a_rollout_gives_the_next_linearization_its_task_rows(monkeypatch):
    """``Sweeps.cost`` keeps the compiled task rows' derivatives of the trajectory it costs; a linearization
    at that trajectory (the next iteration's) takes them instead of a second pass, with the same task
    messages as a pass of its own; at another trajectory it makes its own pass."""
    problem = build_problem(PlanConfig(problem=str(REPO / "raico/problems/examples/ur5_reach.toml"), bounds="none")
                            .normalized())[2]
    rng = np.random.default_rng(4)
    X = np.tile(problem.x0, (problem.T + 1, 1)) + 0.05 * rng.standard_normal((problem.T + 1, problem.n_x))
    U = rng.standard_normal((problem.T, problem.n_u))
    fresh = Sweeps(problem, AICOOptions(alpha=1.0))
    fresh.linearize_all(X, U, X, 1.0)
    sw = Sweeps(problem, AICOOptions(alpha=1.0))
    assert sw.cost(X, U) == fresh.cost(X, U)
    passes = []
    real = kernels.task_rows
    monkeypatch.setattr(kernels, "task_rows", lambda *a, **k: (passes.append(1), real(*a, **k))[1])
    sw.linearize_all(X, U, X, 1.0)
    assert passes == [] and np.array_equal(sw.RA, fresh.RA)
    X[3] += 1e-3
    sw.linearize_all(X, U, X, 1.0)
    assert passes == [1]
