"""Fast analytic dynamics: Drake's own equations of motion, compiled to vectorized numpy (SPEC §4).

``FastAnalyticDynamics(robot, dt)`` is a drop-in for :class:`plants.dynamics.AnalyticDynamics`
(same interface, same numbers up to rounding) whose ``linearize_trajectory`` is vectorized over
time and whose single-point calls avoid Drake's per-call overhead.

How (the "verified faster route"): the plant is converted with ``plant.ToSymbolic()``; with
``pydrake.symbolic`` variables ``q, v, a`` Drake itself builds the expressions of the inverse
dynamics ``ID(q, v, a) = M(q) a + h(q, v)`` (``CalcInverseDynamics`` with
``CalcForceElementsContribution``: gravity and joint damping) and of the mass matrix ``M(q)``
(``CalcMassMatrix``, reflected rotor inertia included). Those expression trees are read with
``Expression.Unapply()`` into a hash-consed DAG of binary operations (constants folded, common
subexpressions merged), differentiated on the DAG in forward mode (exact, with the sparsity of
each node's dependencies; Drake's ``symbolic.Jacobian`` works on the unshared trees and takes
minutes for a 5-joint arm) and emitted as Python source, compiled once per plant and cached in
memory. The same source runs on ``(T,)`` numpy arrays (batched over time) and on Python floats
(single points). No new dependency.

Numbers: ``qddot = M_r^-1 (u - h_r)`` and ``d qddot/d(q, v) = -M_r^-1 dID/d(q, v)`` at
``a = qddot``, with ``M_r = P^T M P``, ``h_r = P^T h`` and the chain rule through ``P`` -- the
same formulas as ``AnalyticDynamics``; tests/test_fastdyn.py checks them against it, against
Drake's ``EvalTimeDerivatives`` and against finite differences.

Support: expression trees are unshared when read, so big plants are refused
(``NotImplementedError``; the 26-joint Nao) and :func:`make_fast_or_exact` falls back to
``AnalyticDynamics``.
"""

from __future__ import annotations

import math
import sys
from functools import cache

import numpy as np

# Plants with more tree joints than this are not compiled (reading Drake's unshared expression
# trees grows quickly with the depth and branching of the tree).
MAX_PLANT_DOFS = 12
# Budget on Expression nodes visited while reading one plant's trees (arm5 needs ~1.1e5).
MAX_VISITS = 2_000_000


class _Unsupported(NotImplementedError):
    pass


# --------------------------------------------------------------------------------------------
# A hash-consed DAG of scalar operations
# --------------------------------------------------------------------------------------------
class _Graph:
    """Nodes are tuples ``(op, *args)``; ``args`` are node ids (or a float for ``c``/``pow``).

    ops: ``c`` constant, ``x`` input number k, ``+ - * /`` binary, ``neg``, ``sin``, ``cos``,
    ``sqrt``, ``pow`` (float exponent). Node ids are topologically ordered (children first).
    ``deps[i]`` is the bit set of inputs node ``i`` depends on.
    """

    def __init__(self):
        self.nodes: list[tuple] = []
        self.deps: list[int] = []
        self._memo: dict[tuple, int] = {}
        self._dmemo: dict[tuple[int, int], int] = {}
        self.zero = self.const(0.0)
        self.one = self.const(1.0)

    # -- construction -------------------------------------------------------------------------
    def _intern(self, key: tuple, deps: int) -> int:
        idx = self._memo.get(key)
        if idx is None:
            idx = len(self.nodes)
            self.nodes.append(key)
            self.deps.append(deps)
            self._memo[key] = idx
        return idx

    def const(self, c: float) -> int:
        c = float(c)
        if c == 0.0:
            c = 0.0  # one zero (no -0.0)
        return self._intern(("c", c), 0)

    def x(self, k: int) -> int:
        return self._intern(("x", k), 1 << k)

    def cval(self, i: int):
        n = self.nodes[i]
        return n[1] if n[0] == "c" else None

    def add(self, a: int, b: int) -> int:
        ca, cb = self.cval(a), self.cval(b)
        if ca is not None and cb is not None:
            return self.const(ca + cb)
        if ca == 0.0:
            return b
        if cb == 0.0:
            return a
        nb = self.nodes[b]
        if nb[0] == "neg":
            return self.sub(a, nb[1])
        na = self.nodes[a]
        if na[0] == "neg":
            return self.sub(b, na[1])
        if a > b:
            a, b = b, a
        return self._intern(("+", a, b), self.deps[a] | self.deps[b])

    def sub(self, a: int, b: int) -> int:
        ca, cb = self.cval(a), self.cval(b)
        if ca is not None and cb is not None:
            return self.const(ca - cb)
        if cb == 0.0:
            return a
        if ca == 0.0:
            return self.neg(b)
        if a == b:
            return self.zero
        nb = self.nodes[b]
        if nb[0] == "neg":
            return self.add(a, nb[1])
        return self._intern(("-", a, b), self.deps[a] | self.deps[b])

    def neg(self, a: int) -> int:
        na = self.nodes[a]
        if na[0] == "c":
            return self.const(-na[1])
        if na[0] == "neg":
            return na[1]
        if na[0] == "-":
            return self._intern(("-", na[2], na[1]), self.deps[a])
        return self._intern(("neg", a), self.deps[a])

    def mul(self, a: int, b: int) -> int:
        ca, cb = self.cval(a), self.cval(b)
        if ca is not None and cb is not None:
            return self.const(ca * cb)
        if cb is not None:
            a, b, ca, cb = b, a, cb, ca
        if ca is not None:  # constant * expression
            if ca == 0.0:
                return self.zero
            if ca == 1.0:
                return b
            if ca == -1.0:
                return self.neg(b)
        na, nb = self.nodes[a], self.nodes[b]
        if na[0] == "neg" and nb[0] == "neg":
            return self.mul(na[1], nb[1])
        if na[0] == "neg":
            return self.neg(self.mul(na[1], b))
        if nb[0] == "neg":
            return self.neg(self.mul(a, nb[1]))
        if ca is None and a > b:
            a, b = b, a
        return self._intern(("*", a, b), self.deps[a] | self.deps[b])

    def div(self, a: int, b: int) -> int:
        ca, cb = self.cval(a), self.cval(b)
        if ca is not None and cb is not None:
            return self.const(ca / cb)
        if ca == 0.0:
            return self.zero
        if cb == 1.0:
            return a
        return self._intern(("/", a, b), self.deps[a] | self.deps[b])

    def unary(self, op: str, a: int) -> int:
        ca = self.cval(a)
        if ca is not None:
            return self.const(getattr(math, op)(ca))
        return self._intern((op, a), self.deps[a])

    def pow(self, a: int, p: float) -> int:
        p = float(p)
        ca = self.cval(a)
        if ca is not None:
            return self.const(ca**p)
        if p == 0.0:
            return self.one
        if p == 1.0:
            return a
        if p == 2.0:
            return self.mul(a, a)
        if p == 0.5:
            return self.unary("sqrt", a)
        if p == -1.0:
            return self.div(self.one, a)
        return self._intern(("pow", a, p), self.deps[a])

    # -- substitution and derivatives ---------------------------------------------------------
    def substitute(self, roots: list[int], values: dict[int, int]) -> list[int]:
        """``roots`` with input ``k`` replaced by node ``values[k]`` (rebuilt, simplified)."""
        mask = 0
        for k in values:
            mask |= 1 << k
        memo: dict[int, int] = {}

        def rebuild(i: int) -> int:
            if not self.deps[i] & mask:
                return i
            if i in memo:
                return memo[i]
            n = self.nodes[i]
            op = n[0]
            if op == "x":
                r = values[n[1]]
            elif op == "+":
                r = self.add(rebuild(n[1]), rebuild(n[2]))
            elif op == "-":
                r = self.sub(rebuild(n[1]), rebuild(n[2]))
            elif op == "*":
                r = self.mul(rebuild(n[1]), rebuild(n[2]))
            elif op == "/":
                r = self.div(rebuild(n[1]), rebuild(n[2]))
            elif op == "neg":
                r = self.neg(rebuild(n[1]))
            elif op == "pow":
                r = self.pow(rebuild(n[1]), n[2])
            else:
                r = self.unary(op, rebuild(n[1]))
            memo[i] = r
            return r

        return [rebuild(i) for i in roots]

    def diff(self, i: int, k: int) -> int:
        """Node of ``d node_i / d input_k`` (memoized, zero where node i does not depend on k)."""
        if not (self.deps[i] >> k) & 1:
            return self.zero
        key = (i, k)
        r = self._dmemo.get(key)
        if r is not None:
            return r
        n = self.nodes[i]
        op = n[0]
        if op == "x":
            r = self.one
        elif op == "+":
            r = self.add(self.diff(n[1], k), self.diff(n[2], k))
        elif op == "-":
            r = self.sub(self.diff(n[1], k), self.diff(n[2], k))
        elif op == "neg":
            r = self.neg(self.diff(n[1], k))
        elif op == "*":
            a, b = n[1], n[2]
            r = self.add(self.mul(self.diff(a, k), b), self.mul(a, self.diff(b, k)))
        elif op == "/":
            a, b = n[1], n[2]
            # d(a/b) = (da - (a/b) db) / b
            r = self.div(self.sub(self.diff(a, k), self.mul(i, self.diff(b, k))), b)
        elif op == "sin":
            r = self.mul(self.unary("cos", n[1]), self.diff(n[1], k))
        elif op == "cos":
            r = self.neg(self.mul(self.unary("sin", n[1]), self.diff(n[1], k)))
        elif op == "sqrt":
            r = self.div(self.diff(n[1], k), self.mul(self.const(2.0), i))
        elif op == "pow":
            a, p = n[1], n[2]
            r = self.mul(self.mul(self.const(p), self.pow(a, p - 1.0)), self.diff(a, k))
        else:  # pragma: no cover - every op built above is handled
            raise _Unsupported(op)
        self._dmemo[key] = r
        return r

    # -- code generation ----------------------------------------------------------------------
    def emit(self, name: str, n_inputs: int, outputs: list[int]) -> str:
        """Python source of ``name(xs, out)``: ``xs`` a sequence of the inputs (floats or
        arrays), ``out[j] = output j`` for a preallocated ``out`` (list or array).

        Intermediate values live in recycled local names (an array is released after its
        last use, so a batched call keeps a few hundred ``(T,)`` arrays alive, not thousands).
        """
        nodes = self.nodes
        live = bytearray(len(nodes))
        for o in outputs:
            live[o] = 1
        for i in range(len(nodes) - 1, -1, -1):
            if live[i]:
                n = nodes[i]
                if n[0] not in ("c", "x"):
                    live[n[1]] = 1
                    if n[0] in ("+", "-", "*", "/"):
                        live[n[2]] = 1
        order = [i for i in range(len(nodes)) if live[i] and nodes[i][0] not in ("c", "x")]
        last_use: dict[int, int] = {}
        for i in order:
            n = nodes[i]
            last_use[n[1]] = i
            if n[0] in ("+", "-", "*", "/"):
                last_use[n[2]] = i
        by_node: dict[int, list[int]] = {}
        for j, o in enumerate(outputs):
            by_node.setdefault(o, []).append(j)

        reg: dict[int, str] = {}
        free: list[str] = []
        n_regs = 0

        def ref(j: int) -> str:
            n = nodes[j]
            if n[0] == "c":
                return repr(n[1]) if n[1] >= 0 else f"({n[1]!r})"
            if n[0] == "x":
                return f"x{n[1]}"
            return reg[j]

        lines = [f"def {name}(xs, out):"]
        if n_inputs:
            lines.append("    " + ", ".join(f"x{k}" for k in range(n_inputs)) + ", = xs")
        for o, js in by_node.items():  # outputs that are constants or inputs
            if nodes[o][0] in ("c", "x"):
                lines += [f"    out[{j}] = {ref(o)}" for j in js]
        for i in order:
            n = nodes[i]
            op = n[0]
            if op in ("+", "-", "*", "/"):
                rhs = f"{ref(n[1])} {op} {ref(n[2])}"
                operands = (n[1], n[2])
            elif op == "neg":
                rhs, operands = f"-{ref(n[1])}", (n[1],)
            elif op == "pow":
                rhs, operands = f"{ref(n[1])} ** {n[2]!r}", (n[1],)
            else:
                rhs, operands = f"{op}({ref(n[1])})", (n[1],)
            for o in set(operands):  # release operands used for the last time
                if o in reg and last_use.get(o) == i and o not in by_node:
                    free.append(reg.pop(o))
            if free:
                reg[i] = free.pop()
            else:
                reg[i] = f"r{n_regs}"
                n_regs += 1
            lines.append(f"    {reg[i]} = {rhs}")
            if i in by_node:
                lines += [f"    out[{j}] = {reg[i]}" for j in by_node[i]]
                if i not in last_use:
                    free.append(reg.pop(i))
            elif i not in last_use:  # pragma: no cover - live nodes are used
                free.append(reg.pop(i))
        lines.append("    return out")
        return "\n".join(lines) + "\n"

    def count_ops(self, outputs: list[int]) -> int:
        src = self.emit("_f", 0, outputs)
        return sum(1 for line in src.splitlines() if line.startswith("    r"))


# --------------------------------------------------------------------------------------------
# Reading Drake's expressions
# --------------------------------------------------------------------------------------------
class _Reader:
    """``pydrake.symbolic.Expression`` -> ``_Graph`` node, merging equal subtrees."""

    def __init__(self, graph: _Graph, var_index: dict[int, int]):
        from pydrake.symbolic import ExpressionKind as K

        self.g = graph
        self.var_index = var_index  # Variable.get_id() -> input number
        self.visits = 0
        self._unary = {K.Sin: "sin", K.Cos: "cos", K.Sqrt: "sqrt", K.Tan: "tan",
                       K.Exp: "exp", K.Log: "log", K.Asin: "asin", K.Acos: "acos",
                       K.Atan: "atan", K.Sinh: "sinh", K.Cosh: "cosh", K.Tanh: "tanh"}
        self.K = K

    def read(self, e) -> int:
        self.visits += 1
        if self.visits > MAX_VISITS:
            raise _Unsupported("symbolic dynamics too large to compile")
        K, g = self.K, self.g
        kind = e.get_kind()
        if kind == K.Constant:
            return g.const(e.Evaluate())
        _, args = e.Unapply()
        if kind == K.Var:
            return g.x(self.var_index[args[0].get_id()])
        if kind == K.Add:  # [constant, term, term, ...]
            acc = g.const(args[0])
            for t in args[1:]:
                acc = g.add(acc, self.read(t))
            return acc
        if kind == K.Mul:  # [coefficient, factor, factor, ...]
            acc = None
            for f in args[1:]:
                r = self.read(f)
                acc = r if acc is None else g.mul(acc, r)
            return g.mul(g.const(args[0]), acc)
        if kind == K.Div:
            return g.div(self.read(args[0]), self.read(args[1]))
        if kind == K.Pow:
            base, ex = self.read(args[0]), self.read(args[1])
            p = g.cval(ex)
            if p is None:
                raise _Unsupported("pow with a symbolic exponent")
            return g.pow(base, p)
        op = self._unary.get(kind)
        if op in ("sin", "cos", "sqrt"):
            return g.unary(op, self.read(args[0]))
        raise _Unsupported(f"expression kind {kind} in the symbolic dynamics")


# --------------------------------------------------------------------------------------------
# Compiled per plant
# --------------------------------------------------------------------------------------------
class _Compiled:
    """Generated functions of one plant (plant coordinates, ``m`` = plant dofs).

    ``mh(xs, out)``: inputs ``q, v`` (2m), outputs ``M`` row-major (m*m) then ``h`` (m).
    ``did(xs, out)``: inputs ``q, v, a`` (3m), outputs ``dID/d(q, v)`` row-major (m * 2m).
    """

    def __init__(self, m: int, mh_src: str, did_src: str, id_src: str, stats: dict):
        self.m = m
        self.source = {"mh": mh_src, "did": did_src, "id": id_src}
        self.stats = stats
        self.vec = {k: _compile(k, src, vectorized=True) for k, src in self.source.items()}
        self.sca = {k: _compile(k, src, vectorized=False) for k, src in self.source.items()}


def _compile(name: str, src: str, vectorized: bool):
    ns = {"sin": np.sin, "cos": np.cos, "sqrt": np.sqrt} if vectorized else \
        {"sin": math.sin, "cos": math.cos, "sqrt": math.sqrt}
    exec(compile(src, f"<fastdyn:{name}>", "exec"), ns)
    return ns[name]


def _derive(plant) -> _Compiled:
    from pydrake.multibody.tree import MultibodyForces_
    from pydrake.symbolic import Expression, MakeVectorVariable

    m = plant.num_positions()
    if plant.num_velocities() != m:
        raise _Unsupported("plants with quaternion (free) joints are not supported")
    if m > MAX_PLANT_DOFS:
        raise _Unsupported(f"{m} tree joints: symbolic dynamics too large (max {MAX_PLANT_DOFS})")
    ps = plant.ToSymbolic()
    ctx = ps.CreateDefaultContext()
    q, v, a = (MakeVectorVariable(m, s) for s in ("q", "v", "a"))
    ps.SetPositions(ctx, np.array([Expression(x) for x in q]))
    ps.SetVelocities(ctx, np.array([Expression(x) for x in v]))
    forces = MultibodyForces_[Expression](ps)
    ps.CalcForceElementsContribution(ctx, forces)
    tau = ps.CalcInverseDynamics(ctx, np.array([Expression(x) for x in a]), forces)
    M = ps.CalcMassMatrix(ctx)

    g = _Graph()
    index = {var.get_id(): k for k, var in enumerate([*q, *v, *a])}
    reader = _Reader(g, index)
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 20000))
    try:
        id_nodes = [reader.read(e) for e in tau]
        m_nodes = [reader.read(e) for e in np.asarray(M).ravel()]
    finally:
        sys.setrecursionlimit(limit)
    # h(q, v) = ID(q, v, 0)
    h_nodes = g.substitute(id_nodes, {2 * m + k: g.zero for k in range(m)})
    did_nodes = [g.diff(i, k) for i in id_nodes for k in range(2 * m)]
    stats = {"visits": reader.visits, "ops_mh": g.count_ops(m_nodes + h_nodes),
             "ops_did": g.count_ops(did_nodes), "ops_id": g.count_ops(id_nodes)}
    return _Compiled(m, g.emit("mh", 2 * m, m_nodes + h_nodes), g.emit("did", 3 * m, did_nodes),
                     g.emit("id", 3 * m, id_nodes), stats)


_CACHE: dict[int, _Compiled] = {}


@cache
def _compiled_for_name(name: str) -> _Compiled:
    from plants.robots import shared_robot

    return _derive(shared_robot(name).plant)


def compiled_dynamics(robot) -> _Compiled:
    """The generated code of ``robot``'s plant, derived once per plant name (in memory)."""
    return _compiled_for_name(robot.name)
