"""Derivation of a plant's generated dynamics from Drake, with a self-check, cached per plant.

The route (derived from the Drake plant itself, no hand-written dynamics):

1. :func:`~raico.plants.codegen.drake_reader.read_equations`: Drake's symbolic inverse dynamics
   ``ID(q, v, a) = M(q) a + h(q, v)`` and mass matrix ``M(q)`` in a hash-consed graph.
   Positions of *cyclic* joints (:func:`~raico.plants.codegen.drake_reader.cyclic_positions`) are
   set to 0: ``M`` and ``h`` do not depend on them, and Drake's world-frame expressions shrink
   by about half.
2. ``dID/d(q, v)`` is differentiated on the graph in forward mode (exact; each node only along
   the inputs it depends on). Drake's ``symbolic.Jacobian`` works on the unshared trees and
   needs minutes for a 5-joint arm; this takes well under a second.
3. The graph is emitted as straight-line Python (:mod:`raico.plants.codegen.emit`) in three
   functions (see :class:`CompiledDynamics`): everything not depending on ``a`` in a first
   pass, the rest after the caller's solve for ``a``.
4. Self-check at build time: the generated ``M``, ``h`` and ``dID`` are compared with Drake's
   float and AutoDiffXd evaluation at random states; a mismatch disables the cyclic-joint
   rewrite, then refuses the plant.

Plants that are too big to read (the 26-joint Nao: the trees are unshared when read) or that
use unsupported joints raise ``NotImplementedError``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from raico.plants.codegen.c_backend import emit_c
from raico.plants.codegen.drake_reader import cyclic_positions, read_equations
from raico.plants.codegen.emit import compile_source, emit, live_ops
from raico.plants.codegen.graph import BINARY, Graph, Unsupported

# Plants with more tree joints than this are not compiled (reading Drake's unshared expression
# trees grows quickly with the depth and branching of the tree).
MAX_PLANT_DOFS = 12
# Build-time self-check: relative agreement required with Drake's own evaluation.
SELF_CHECK_RTOL = 1e-9


class CompiledDynamics:
    """Generated functions of one plant, in plant coordinates (``m`` plant dofs, ``mm = m*m``).

    - ``mh(xs, out)``: ``xs = (q, v)``; ``out[:mm] = M`` (row-major), ``out[mm:mm+m] = h``.
    - ``first(xs, out, carry)``: as ``mh``, and ``carry[:n_carry]`` = the values that do not
      depend on ``a`` but that the second pass needs.
    - ``second(xs, out)``: ``xs = (a, *carry)``; ``out[i*2m + k] = dID_i/d(q, v)_k``.

    ``vec[name]`` runs on rows of ``(., T)`` arrays, ``sca[name]`` on lists of Python floats.
    ``c_source``: the same three functions in C (:func:`raico.plants.codegen.c_backend.emit_c`, same
    operations in the same order), compiled on demand by :mod:`raico.plants.fast_analytic`.
    """

    def __init__(self, m: int, n_carry: int, sources: dict[str, str], stats: dict,
                 c_source: str = ""):
        self.m = m
        self.n_carry = n_carry
        self.source = sources
        self.c_source = c_source
        self.stats = stats
        self.vec: dict[str, Callable] = {}
        self.sca: dict[str, Callable] = {}
        for key, src in sources.items():
            self.vec[key], self.sca[key] = compile_source(src, key)

    def evaluate(self, q: np.ndarray, v: np.ndarray, a: np.ndarray):
        """``M (m, m)``, ``h (m,)`` and ``dID/d(q, v) (m, 2m)`` at one plant state (tests)."""
        m, mm = self.m, self.m * self.m
        out, carry = [0.0] * (mm + m), [0.0] * self.n_carry
        self.sca["first"]([*map(float, q), *map(float, v)], out, carry)
        D = self.sca["second"]([*map(float, a), *carry], [0.0] * (2 * mm))
        return (np.array(out[:mm]).reshape(m, m), np.array(out[mm:]),
                np.array(D).reshape(m, 2 * m))


def derive(plant, use_cyclic: bool = True) -> CompiledDynamics:
    """Symbolic inverse dynamics and mass matrix of ``plant`` from Drake, compiled and checked.

    Raises ``NotImplementedError`` for plants it does not handle (too many joints, quaternion
    joints, expression kinds without a generated counterpart, failed self-check).
    """
    m = plant.num_positions()
    if plant.num_velocities() != m:
        raise Unsupported("plants with quaternion (free) joints are not supported")
    if m > MAX_PLANT_DOFS:
        raise Unsupported(f"{m} tree joints: symbolic dynamics too large (max {MAX_PLANT_DOFS})")
    g, id_nodes, m_nodes, visits = read_equations(plant)
    cyclic = cyclic_positions(plant) if use_cyclic else []
    if cyclic:
        zero = {k: g.zero for k in cyclic}
        id_nodes, m_nodes = g.substitute(id_nodes, zero), g.substitute(m_nodes, zero)
    h_nodes = g.substitute(id_nodes, {2 * m + k: g.zero for k in range(m)})  # h = ID(q, v, 0)
    did_nodes = [g.zero if k in cyclic else g.diff(i, k) for i in id_nodes for k in range(2 * m)]
    compiled = _generate(g, m, m_nodes, h_nodes, did_nodes)
    compiled.stats = {"expression_nodes_read": visits, "dag_nodes": len(g.nodes),
                      "cyclic_positions": cyclic, **compiled.stats}
    err = self_check(plant, compiled)
    if err > SELF_CHECK_RTOL:
        if cyclic:
            return derive(plant, use_cyclic=False)
        raise Unsupported(f"generated dynamics disagree with Drake (relative error {err:.1e})")
    return compiled


def _carried(g: Graph, did_nodes: list[int], a_nodes: list[int], amask: int) -> list[int]:
    """Nodes the second pass (everything depending on ``a``) takes from the first: the
    ``a``-free operands of ``a``-dependent nodes of ``dID``, sorted."""
    carry, seen, stack = set(), set(), list(did_nodes)
    while stack:
        i = stack.pop()
        if i in seen:
            continue
        seen.add(i)
        n = g.nodes[i]
        if n[0] == "c" or i in a_nodes:
            continue
        if not g.deps[i] & amask:
            carry.add(i)
            continue
        stack.append(n[1])
        if n[0] in BINARY:
            stack.append(n[2])
    return sorted(carry)


def _generate(g: Graph, m: int, m_nodes: list[int], h_nodes: list[int],
              did_nodes: list[int]) -> CompiledDynamics:
    """The three functions of :class:`CompiledDynamics` (inputs ``x0..x{3m-1}`` = ``q, v, a``)."""
    amask = sum(1 << (2 * m + k) for k in range(m))
    a_nodes = [g.x(2 * m + k) for k in range(m)]
    carry = _carried(g, did_nodes, a_nodes, amask)
    qv_nodes = [g.x(k) for k in range(2 * m)]
    mm = m * m
    sources = {
        "mh": emit(g, "mh", qv_nodes, m_nodes + h_nodes),
        "first": emit(g, "first", qv_nodes, m_nodes + h_nodes + carry, params="xs, out, carry",
                      targets=[*(f"out[{j}]" for j in range(mm + m)),
                               *(f"carry[{j}]" for j in range(len(carry)))]),
        "second": emit(g, "second", a_nodes + carry, did_nodes),
    }
    c_source = "".join([
        emit_c(g, "gen_mh", qv_nodes, m_nodes + h_nodes),
        emit_c(g, "gen_first", qv_nodes, m_nodes + h_nodes + carry,
               params="const double *xs, double *out, double *carry",
               targets=[*(f"out[{j}]" for j in range(mm + m)),
                        *(f"carry[{j}]" for j in range(len(carry)))]),
        emit_c(g, "gen_second", a_nodes + carry, did_nodes),
    ])
    stats = {"carried": len(carry),
             "ops_mh": len(live_ops(g, qv_nodes, m_nodes + h_nodes)),
             "ops_first": len(live_ops(g, qv_nodes, m_nodes + h_nodes + carry)),
             "ops_second": len(live_ops(g, a_nodes + carry, did_nodes))}
    return CompiledDynamics(m, len(carry), sources, stats, c_source)


def self_check(plant, compiled: CompiledDynamics, n_states: int = 3, seed: int = 0) -> float:
    """Largest relative difference of the generated ``M``, ``h``, ``dID/d(q, v)`` from Drake's
    float and AutoDiffXd evaluation at random states (angles over a full turn)."""
    from raico.plants.codegen.reference import DrakeReference

    m = compiled.m
    rng = np.random.default_rng(seed)
    drake = DrakeReference(plant)
    worst = 0.0
    for _ in range(n_states):
        q, v, a = rng.uniform(-np.pi, np.pi, m), rng.standard_normal(m), rng.standard_normal(m)
        M_ref, _, h_ref, D_ref = drake.evaluate(q, v, a)
        M, h, D = compiled.evaluate(q, v, a)
        for got, ref in ((M, M_ref), (h, h_ref), (D, D_ref)):
            scale = max(np.max(np.abs(ref)), 1e-12)
            worst = max(worst, float(np.max(np.abs(got - ref))) / scale)
    return worst


_COMPILED: dict[str, CompiledDynamics | Exception] = {}


def _disk_path(name: str, m: int):
    """Where the derived code of plant ``name`` (``m`` dofs) is kept between processes: the kernel cache
    (``RAICO_KERNEL_DIR``), keyed by the code generator's own source and Drake's version."""
    import hashlib
    from pathlib import Path

    import pydrake

    from raico.plants.codegen.c_backend import kernel_dir

    here = Path(__file__).parent
    h = hashlib.sha256(f"{name}\n{m}\n{getattr(pydrake, '__version__', '')}\n".encode())
    for f in sorted(here.glob("*.py")):
        h.update(f.read_bytes())
    return kernel_dir() / f"derived-{name}-{h.hexdigest()[:20]}.json"


def load_derived(plant, path) -> CompiledDynamics | None:
    """The derived code stored at ``path`` if it is readable and passes the build's self-check against
    ``plant`` (a stale or damaged file is ignored: the caller derives anew)."""
    import json

    try:
        d = json.loads(path.read_text(encoding="utf-8"))
        if d.pop("sha256", None) != derived_digest(d):  # damaged (the C source is not covered by the self-check)
            return None
        code = CompiledDynamics(int(d["m"]), int(d["n_carry"]), dict(d["sources"]), dict(d["stats"]),
                                str(d["c_source"]))
    except (OSError, ValueError, KeyError, TypeError, SyntaxError):
        return None
    if code.m != plant.num_positions() or not self_check(plant, code) <= SELF_CHECK_RTOL:
        return None
    return code


def derived_digest(doc: dict) -> str:
    import hashlib
    import json

    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def store_derived(code: CompiledDynamics, path) -> None:
    """Write the derived code to ``path`` atomically (best effort: a read-only cache only costs time)."""
    import contextlib
    import json
    import os
    import tempfile

    doc = {"m": code.m, "n_carry": code.n_carry, "sources": code.source, "stats": code.stats,
           "c_source": code.c_source}
    doc["sha256"] = derived_digest(doc)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(doc, f)
        os.replace(tmp, path)
    except OSError:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def compiled_dynamics(robot) -> CompiledDynamics:
    """The generated code of ``robot``'s plant, derived once per plant name and kept in memory, and
    on disk beside the compiled kernels (a new process loads it and runs the self-check, 0.05 s,
    instead of deriving it again: 3.5 s for arm5, 1.7 s for biorob).

    Robots of one name come from one model file; a plant of a cached name is still compared
    with the code at one state (``M``, ``h``; tens of microseconds) and derived anew, uncached,
    if its parameters differ."""
    hit = _COMPILED.get(robot.name)
    if hit is None:
        m = robot.plant.num_positions()
        path = _disk_path(robot.name, m) if m <= MAX_PLANT_DOFS else None
        hit = load_derived(robot.plant, path) if path is not None else None
        if hit is None:
            try:
                hit = derive(robot.plant)
            except NotImplementedError as exc:
                hit = exc
            if path is not None and isinstance(hit, CompiledDynamics):
                store_derived(hit, path)
        _COMPILED[robot.name] = hit
    if isinstance(hit, Exception):
        raise NotImplementedError(f"{robot.name}: {hit}")
    if not _agrees(robot.plant, hit):
        return derive(robot.plant)
    return hit


def _agrees(plant, compiled: CompiledDynamics) -> bool:
    """``M`` and ``h`` of the code equal the plant's (Drake, float) at one generic state."""
    from pydrake.multibody.tree import MultibodyForces_

    m = compiled.m
    if plant.num_positions() != m or plant.num_velocities() != m:
        return False
    k = np.arange(1, m + 1)
    q, v = np.sin(1.3 * k) * 2.0, np.cos(0.7 * k)
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, q)
    plant.SetVelocities(ctx, v)
    forces = MultibodyForces_[float](plant)
    plant.CalcForceElementsContribution(ctx, forces)
    h_ref = plant.CalcInverseDynamics(ctx, np.zeros(m), forces)
    M_ref = plant.CalcMassMatrix(ctx)
    out = compiled.sca["mh"]([*q.tolist(), *v.tolist()], [0.0] * (m * m + m))
    M, h = np.array(out[:m * m]).reshape(m, m), np.array(out[m * m:])
    return all(np.max(np.abs(got - ref)) <= SELF_CHECK_RTOL * max(np.max(np.abs(ref)), 1e-12)
               for got, ref in ((M, M_ref), (h, h_ref)))


def is_supported(robot) -> bool:
    """Whether :class:`raico.plants.fast_analytic.FastAnalyticDynamics` handles ``robot`` (derives it on first call)."""
    try:
        compiled_dynamics(robot)
    except NotImplementedError:
        return False
    return True
