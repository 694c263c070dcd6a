"""Fast analytic dynamics: Drake's own equations of motion compiled to vectorized numpy (SPEC §4).

``FastAnalyticDynamics(robot, dt)`` is a drop-in for :class:`plants.dynamics.AnalyticDynamics`:
same interface, same numbers up to rounding (~1e-15 relative), but ``linearize_trajectory`` is
vectorized over time (no Python loop over steps) and single points skip Drake's per-call cost.

The route (derived from the Drake plant itself, no hand-written dynamics):

1. ``plant.ToSymbolic()`` with ``pydrake.symbolic`` variables ``q, v, a``: Drake builds the
   expressions of the inverse dynamics ``ID(q, v, a) = M(q) a + h(q, v)``
   (``CalcForceElementsContribution`` + ``CalcInverseDynamics``: gravity, joint damping) and of
   the mass matrix ``M(q)`` (``CalcMassMatrix``, reflected rotor inertia included).
2. The expression trees are read through ``Expression.Unapply()`` / ``get_kind()`` into a
   hash-consed DAG of binary operations (equal subtrees merged, constants folded, simple
   algebraic rewrites). Positions of *cyclic* joints -- revolute joints on a body welded to the
   world whose axis is parallel to gravity, in a plant whose only force element is gravity --
   are set to 0: ``M`` and ``h`` do not depend on them (rotating everything outboard about a
   vertical world axis changes neither kinetic nor potential energy), and Drake's world-frame
   expressions shrink by about half.
3. ``dID/d(q, v)`` is differentiated on the DAG in forward mode (exact; each node only along the
   inputs it depends on). Drake's ``symbolic.Jacobian`` works on the unshared trees and needs
   minutes for a 5-joint arm; this takes well under a second.
4. The DAG is emitted as straight-line Python source (recycled local names), compiled once per
   plant name and kept in memory. The same code runs on ``(T,)`` numpy arrays (a whole
   trajectory per call) and on Python floats (single points).
5. Self-check at build time: the generated ``M``, ``h`` and ``dID`` are compared with Drake's
   float and AutoDiffXd evaluation at random states; a mismatch disables the cyclic-joint
   rewrite, then refuses the plant.

Evaluation uses the formulas of ``AnalyticDynamics``: ``qddot = M_r^-1 (u - h_r)``,
``d qddot/d(q, v) = -M_r^-1 dID_r/d(q, v)`` at ``a = qddot``, ``d qddot/du = M_r^-1`` with
``M_r = P^T M P``, ``h_r = P^T h`` and ``dID_r = P^T dID [P 0; 0 P]``; with ``a`` an input of
the generated derivative code, ``d(M a)/dq`` is included. Everything not depending on ``a`` is
computed in a first pass (``M``, ``h``, ``dh/dv``, ...), the rest after the solve for ``a``.

Plants that are too big to read (the 26-joint Nao: the trees are unshared when read) or that
use unsupported joints raise ``NotImplementedError``; :func:`make_fast_or_exact` then returns
``AnalyticDynamics``. No dependency beyond drake and numpy.
"""

from __future__ import annotations

import math
import sys

import numpy as np

from plants.dynamics import AnalyticDynamics, SemiImplicitEuler

# Plants with more tree joints than this are not compiled (reading Drake's unshared expression
# trees grows quickly with the depth and branching of the tree).
MAX_PLANT_DOFS = 12
# Budget on Expression nodes visited while reading one plant's trees (arm5 needs ~1.1e5).
MAX_VISITS = 2_000_000
# Build-time self-check: relative agreement required with Drake's own evaluation.
SELF_CHECK_RTOL = 1e-9


class _Unsupported(NotImplementedError):
    pass


# --------------------------------------------------------------------------------------------
# A hash-consed DAG of scalar operations
# --------------------------------------------------------------------------------------------
_BINARY = ("+", "-", "*", "/")


class _Graph:
    """Nodes are tuples ``(op, *args)``; args are node ids (a float for ``c`` and ``pow``).

    ops: ``c`` constant, ``x`` input k, ``+ - * /``, ``neg``, ``sin``, ``cos``, ``sqrt``,
    ``pow`` (constant exponent). Ids are topologically ordered (children first); a product with
    a constant keeps the constant first. ``deps[i]`` is the bit set of inputs node i depends on.
    """

    def __init__(self):
        self.nodes: list[tuple] = []
        self.deps: list[int] = []
        self._memo: dict[tuple, int] = {}
        self._dmemo: dict[tuple[int, int], int] = {}
        self.zero = self.const(0.0)
        self.one = self.const(1.0)

    # -- construction (with simplification) ---------------------------------------------------
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
        return self._intern(("c", c + 0.0), 0)  # + 0.0: no -0.0

    def x(self, k: int) -> int:
        return self._intern(("x", k), 1 << k)

    def cval(self, i: int):
        n = self.nodes[i]
        return n[1] if n[0] == "c" else None

    def _scaled(self, i: int):
        """``(c, j)`` with node i = c * node j (c = 1 when i is no constant multiple)."""
        n = self.nodes[i]
        if n[0] == "*" and self.nodes[n[1]][0] == "c":
            return self.nodes[n[1]][1], n[2]
        if n[0] == "neg":
            return -1.0, n[1]
        return 1.0, i

    def add(self, a: int, b: int) -> int:
        ca, cb = self.cval(a), self.cval(b)
        if ca is not None and cb is not None:
            return self.const(ca + cb)
        if ca == 0.0:
            return b
        if cb == 0.0:
            return a
        (sa, ya), (sb, yb) = self._scaled(a), self._scaled(b)
        if sb < 0 and sa > 0:  # a + (-s) y = a - s y
            return self.sub(a, self.mul(self.const(-sb), yb))
        if sa < 0 and sb > 0:
            return self.sub(b, self.mul(self.const(-sa), ya))
        if sa == sb and sa != 1.0:  # s ya + s yb = s (ya + yb)
            return self.mul(self.const(sa), self.add(ya, yb))
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
        (sa, ya), (sb, yb) = self._scaled(a), self._scaled(b)
        if sb < 0:  # a - (-s) y = a + s y
            return self.add(a, self.mul(self.const(-sb), yb))
        if sa == sb and sa != 1.0:  # s ya - s yb = s (ya - yb)
            return self.mul(self.const(sa), self.sub(ya, yb))
        return self._intern(("-", a, b), self.deps[a] | self.deps[b])

    def neg(self, a: int) -> int:
        n = self.nodes[a]
        if n[0] == "c":
            return self.const(-n[1])
        if n[0] == "neg":
            return n[1]
        if n[0] == "-":
            return self._intern(("-", n[2], n[1]), self.deps[a])
        s, y = self._scaled(a)
        if s != 1.0:
            return self.mul(self.const(-s), y)
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
            s, y = self._scaled(b)
            if s != 1.0:
                return self.mul(self.const(ca * s), y)
            if ca == -1.0:
                return self._intern(("neg", b), self.deps[b])
            return self._intern(("*", a, b), self.deps[b])
        (sa, ya), (sb, yb) = self._scaled(a), self._scaled(b)
        if sa != 1.0 or sb != 1.0:  # constants move outwards
            return self.mul(self.const(sa * sb), self.mul(ya, yb))
        if a > b:
            a, b = b, a
        return self._intern(("*", a, b), self.deps[a] | self.deps[b])

    def div(self, a: int, b: int) -> int:
        ca, cb = self.cval(a), self.cval(b)
        if ca is not None and cb is not None:
            return self.const(ca / cb)
        if ca == 0.0:
            return self.zero
        if cb is not None:
            return self.mul(self.const(1.0 / cb), a)
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

    def _rebuild(self, n: tuple, args: list[int]) -> int:
        op = n[0]
        if op == "+":
            return self.add(args[0], args[1])
        if op == "-":
            return self.sub(args[0], args[1])
        if op == "*":
            return self.mul(args[0], args[1])
        if op == "/":
            return self.div(args[0], args[1])
        if op == "neg":
            return self.neg(args[0])
        if op == "pow":
            return self.pow(args[0], n[2])
        return self.unary(op, args[0])

    # -- substitution and derivatives ---------------------------------------------------------
    def substitute(self, roots: list[int], values: dict[int, int]) -> list[int]:
        """``roots`` with input k replaced by node ``values[k]`` (rebuilt and simplified)."""
        mask = sum(1 << k for k in values)
        memo: dict[int, int] = {}
        for i in range(max(roots, default=-1) + 1):  # topological order: no recursion
            if not self.deps[i] & mask:
                continue
            n = self.nodes[i]
            if n[0] == "x":
                memo[i] = values[n[1]]
            else:
                kids = [n[1]] if n[0] not in _BINARY else [n[1], n[2]]
                memo[i] = self._rebuild(n, [memo.get(k, k) for k in kids])
        return [memo.get(r, r) for r in roots]

    def diff(self, i: int, k: int) -> int:
        """Node of ``d node_i / d input_k`` (memoized; zero where node i does not depend on k)."""
        if not (self.deps[i] >> k) & 1:
            return self.zero
        r = self._dmemo.get((i, k))
        if r is not None:
            return r
        # children first, without deep recursion
        stack = [i]
        while stack:
            j = stack[-1]
            n = self.nodes[j]
            kids = [] if n[0] in ("c", "x") else ([n[1]] if n[0] not in _BINARY else [n[1], n[2]])
            todo = [c for c in kids if (self.deps[c] >> k) & 1 and (c, k) not in self._dmemo]
            if todo:
                stack += todo
                continue
            stack.pop()
            if (j, k) not in self._dmemo:
                self._dmemo[(j, k)] = self._diff_node(j, k)
        return self._dmemo[(i, k)]

    def _d(self, i: int, k: int) -> int:
        return self._dmemo.get((i, k), self.zero) if (self.deps[i] >> k) & 1 else self.zero

    def _diff_node(self, i: int, k: int) -> int:
        n = self.nodes[i]
        op, d = n[0], self._d
        if op == "x":
            return self.one
        if op == "+":
            return self.add(d(n[1], k), d(n[2], k))
        if op == "-":
            return self.sub(d(n[1], k), d(n[2], k))
        if op == "neg":
            return self.neg(d(n[1], k))
        if op == "*":
            a, b = n[1], n[2]
            return self.add(self.mul(d(a, k), b), self.mul(a, d(b, k)))
        if op == "/":  # d(a/b) = (da - (a/b) db) / b
            a, b = n[1], n[2]
            return self.div(self.sub(d(a, k), self.mul(i, d(b, k))), b)
        if op == "sin":
            return self.mul(self.unary("cos", n[1]), d(n[1], k))
        if op == "cos":
            return self.neg(self.mul(self.unary("sin", n[1]), d(n[1], k)))
        if op == "sqrt":
            return self.div(d(n[1], k), self.mul(self.const(2.0), i))
        if op == "pow":
            a, p = n[1], n[2]
            return self.mul(self.mul(self.const(p), self.pow(a, p - 1.0)), d(a, k))
        raise _Unsupported(op)  # pragma: no cover - every op built above is handled

    # -- code generation ----------------------------------------------------------------------
    def live_ops(self, inputs: list[int], outputs: list[int]) -> list[int]:
        """Operation nodes needed for ``outputs`` given ``inputs``, in evaluation order."""
        given = set(inputs)
        live = bytearray(len(self.nodes))
        for o in outputs:
            live[o] = 1
        for i in range(len(self.nodes) - 1, -1, -1):
            n = self.nodes[i]
            if live[i] and i not in given and n[0] not in ("c", "x"):
                live[n[1]] = 1
                if n[0] in _BINARY:
                    live[n[2]] = 1
        missing = [i for i in range(len(self.nodes))
                   if live[i] and self.nodes[i][0] == "x" and i not in given]
        if missing:  # pragma: no cover - the callers pass every input
            raise ValueError(f"inputs not given: {missing}")
        return [i for i in range(len(self.nodes))
                if live[i] and i not in given and self.nodes[i][0] not in ("c", "x")]

    def emit(self, name: str, inputs: list[int], outputs: list[int],
             targets: list[str] | None = None, params: str = "xs, out") -> str:
        """Python source of ``name(<params>)``: node ``inputs[k]`` is ``xs[k]`` (floats or
        arrays); node ``outputs[j]`` is assigned to ``targets[j]`` (default ``out[j]``).

        Intermediate values live in recycled local names: an array is released after its last
        use, so a batched call keeps a few hundred ``(T,)`` arrays alive, not thousands.
        """
        nodes = self.nodes
        targets = [f"out[{j}]" for j in range(len(outputs))] if targets is None else targets
        order = self.live_ops(inputs, outputs)
        in_name = {node: f"x{k}" for k, node in enumerate(inputs)}
        last_use: dict[int, int] = {}
        for i in order:
            n = nodes[i]
            last_use[n[1]] = i
            if n[0] in _BINARY:
                last_use[n[2]] = i
        writes: dict[int, list[str]] = {}
        for t, o in zip(targets, outputs):
            writes.setdefault(o, []).append(t)
        reg: dict[int, str] = {}
        free: list[str] = []
        n_regs = 0

        def ref(j: int) -> str:
            if j in in_name:
                return in_name[j]
            n = nodes[j]
            if n[0] == "c":
                return repr(n[1]) if n[1] >= 0 else f"({n[1]!r})"
            return reg[j]

        lines = [f"def {name}({params}):"]
        if inputs:
            lines.append("    " + ", ".join(in_name[node] for node in inputs) + ", = xs")
        for o, js in writes.items():  # outputs that are constants or inputs
            if o in in_name or nodes[o][0] == "c":
                lines += [f"    {t} = {ref(o)}" for t in js]
        for i in order:
            n = nodes[i]
            op = n[0]
            if op in _BINARY:
                rhs, operands = f"{ref(n[1])} {op} {ref(n[2])}", {n[1], n[2]}
            elif op == "neg":
                rhs, operands = f"-{ref(n[1])}", {n[1]}
            elif op == "pow":
                rhs, operands = f"{ref(n[1])} ** {n[2]!r}", {n[1]}
            else:
                rhs, operands = f"{op}({ref(n[1])})", {n[1]}
            for o in operands:  # release operands used for the last time
                if o in reg and last_use[o] == i:
                    free.append(reg.pop(o))
            if free:
                reg[i] = free.pop()
            else:
                reg[i] = f"r{n_regs}"
                n_regs += 1
            lines.append(f"    {reg[i]} = {rhs}")
            lines += [f"    {t} = {reg[i]}" for t in writes.get(i, ())]
            if i not in last_use:
                free.append(reg.pop(i))
        lines.append(f"    return {params.split(', ')[1]}")
        return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------
# Reading Drake's expressions
# --------------------------------------------------------------------------------------------
class _Reader:
    """``pydrake.symbolic.Expression`` -> ``_Graph`` node; equal subtrees become one node."""

    def __init__(self, graph: _Graph, var_index: dict[int, int]):
        from pydrake.symbolic import ExpressionKind

        self.g = graph
        self.var_index = var_index  # Variable.get_id() -> input number
        self.visits = 0
        self.K = ExpressionKind
        self._unary = {ExpressionKind.Sin: "sin", ExpressionKind.Cos: "cos",
                       ExpressionKind.Sqrt: "sqrt"}

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
            acc = g.const(args[0])
            for f in args[1:]:
                acc = g.mul(acc, self.read(f))
            return acc
        if kind == K.Div:
            return g.div(self.read(args[0]), self.read(args[1]))
        if kind == K.Pow:
            base, ex = self.read(args[0]), self.read(args[1])
            p = g.cval(ex)
            if p is None:
                raise _Unsupported("pow with a symbolic exponent")
            return g.pow(base, p)
        if kind in self._unary:
            return g.unary(self._unary[kind], self.read(args[0]))
        raise _Unsupported(f"expression kind {kind.name} in the symbolic dynamics")


# --------------------------------------------------------------------------------------------
# Derivation from the plant, compiled per plant
# --------------------------------------------------------------------------------------------
def cyclic_positions(plant) -> list[int]:
    """Plant position indices that ``M`` and ``h`` cannot depend on.

    A revolute joint whose parent body is welded to the world and whose axis is parallel to
    gravity (any axis without gravity) turns its whole subtree about a fixed vertical world
    axis: kinetic and potential energy, damping and rotor inertia are unchanged, so with gravity
    as the only force element the equations of motion do not depend on its angle.
    """
    from pydrake.multibody.tree import ForceElementIndex, UniformGravityFieldElement

    for i in range(plant.num_force_elements()):
        if not isinstance(plant.get_force_element(ForceElementIndex(i)), UniformGravityFieldElement):
            return []
    g = np.asarray(plant.gravity_field().gravity_vector(), float)
    welded = {b.index() for b in plant.GetBodiesWeldedTo(plant.world_body())}
    ctx = plant.CreateDefaultContext()
    out = []
    for ji in plant.GetJointIndices():
        joint = plant.get_joint(ji)
        if joint.type_name() != "revolute" or joint.parent_body().index() not in welded \
                or joint.child_body().index() in welded:
            continue
        R_WF = joint.frame_on_parent().CalcPoseInWorld(ctx).rotation().matrix()
        axis = R_WF @ np.asarray(joint.revolute_axis(), float)
        if np.linalg.norm(np.cross(axis, g)) <= 1e-12 * np.linalg.norm(g):
            out.append(joint.position_start())
    return out


class CompiledDynamics:
    """Generated functions of one plant, in plant coordinates (``m`` plant dofs, ``mm = m*m``).

    - ``mh(xs, out)``: ``xs = (q, v)``; ``out[:mm] = M`` (row-major), ``out[mm:mm+m] = h``.
    - ``first(xs, out, carry)``: as ``mh``, and ``carry[:n_carry]`` = the values that do not
      depend on ``a`` but that the second pass needs.
    - ``second(xs, out)``: ``xs = (a, *carry)``; ``out[i*2m + k] = dID_i/d(q, v)_k``.

    ``vec[name]`` runs on rows of ``(., T)`` arrays, ``sca[name]`` on lists of Python floats.
    """

    def __init__(self, m: int, n_carry: int, sources: dict[str, str], stats: dict):
        self.m = m
        self.n_carry = n_carry
        self.source = sources
        self.stats = stats
        self.vec, self.sca = {}, {}
        for key, src in sources.items():
            code = compile(src, f"<fastdyn:{key}>", "exec")
            ns_vec = {"sin": np.sin, "cos": np.cos, "sqrt": np.sqrt}
            ns_sca = {"sin": math.sin, "cos": math.cos, "sqrt": math.sqrt}
            exec(code, ns_vec)
            exec(code, ns_sca)
            self.vec[key], self.sca[key] = ns_vec[key], ns_sca[key]

    def evaluate(self, q: np.ndarray, v: np.ndarray, a: np.ndarray):
        """``M (m, m)``, ``h (m,)`` and ``dID/d(q, v) (m, 2m)`` at one plant state (tests)."""
        m, mm = self.m, self.m * self.m
        out, carry = [0.0] * (mm + m), [0.0] * self.n_carry
        self.sca["first"]([*map(float, q), *map(float, v)], out, carry)
        D = self.sca["second"]([*map(float, a), *carry], [0.0] * (2 * mm))
        return (np.array(out[:mm]).reshape(m, m), np.array(out[mm:]),
                np.array(D).reshape(m, 2 * m))


def _symbolic_id_and_mass(plant):
    from pydrake.multibody.tree import MultibodyForces_
    from pydrake.symbolic import Expression, MakeVectorVariable

    m = plant.num_positions()
    ps = plant.ToSymbolic()
    ctx = ps.CreateDefaultContext()
    q, v, a = (MakeVectorVariable(m, s) for s in ("q", "v", "a"))
    ps.SetPositions(ctx, np.array([Expression(x) for x in q]))
    ps.SetVelocities(ctx, np.array([Expression(x) for x in v]))
    forces = MultibodyForces_[Expression](ps)
    ps.CalcForceElementsContribution(ctx, forces)
    tau = ps.CalcInverseDynamics(ctx, np.array([Expression(x) for x in a]), forces)
    M = np.asarray(ps.CalcMassMatrix(ctx)).ravel()
    return [*q, *v, *a], tau, M


def derive(plant, use_cyclic: bool = True) -> CompiledDynamics:
    """Symbolic inverse dynamics and mass matrix of ``plant`` from Drake, compiled and checked.

    Raises ``NotImplementedError`` for plants it does not handle (too many joints, quaternion
    joints, expression kinds without a generated counterpart, failed self-check).
    """
    m = plant.num_positions()
    if plant.num_velocities() != m:
        raise _Unsupported("plants with quaternion (free) joints are not supported")
    if m > MAX_PLANT_DOFS:
        raise _Unsupported(f"{m} tree joints: symbolic dynamics too large (max {MAX_PLANT_DOFS})")
    variables, tau, M = _symbolic_id_and_mass(plant)
    g = _Graph()
    reader = _Reader(g, {var.get_id(): k for k, var in enumerate(variables)})
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 50_000))
    try:
        id_nodes = [reader.read(e) for e in tau]
        m_nodes = [reader.read(e) for e in M]
    finally:
        sys.setrecursionlimit(limit)
    cyclic = cyclic_positions(plant) if use_cyclic else []
    if cyclic:
        zero = {k: g.zero for k in cyclic}
        id_nodes, m_nodes = g.substitute(id_nodes, zero), g.substitute(m_nodes, zero)
    h_nodes = g.substitute(id_nodes, {2 * m + k: g.zero for k in range(m)})  # h = ID(q, v, 0)
    did_nodes = [g.zero if k in cyclic else g.diff(i, k) for i in id_nodes for k in range(2 * m)]

    # second pass: what depends on a; its other operands are carried over from the first pass
    amask = sum(1 << (2 * m + k) for k in range(m))
    a_nodes = [g.x(2 * m + k) for k in range(m)]
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
        if n[0] in _BINARY:
            stack.append(n[2])
    carry = sorted(carry)
    qv_nodes = [g.x(k) for k in range(2 * m)]
    mm = m * m
    sources = {
        "mh": g.emit("mh", qv_nodes, m_nodes + h_nodes),
        "first": g.emit("first", qv_nodes, m_nodes + h_nodes + carry, params="xs, out, carry",
                        targets=[*(f"out[{j}]" for j in range(mm + m)),
                                 *(f"carry[{j}]" for j in range(len(carry)))]),
        "second": g.emit("second", a_nodes + carry, did_nodes),
    }
    stats = {"expression_nodes_read": reader.visits, "dag_nodes": len(g.nodes),
             "cyclic_positions": cyclic, "carried": len(carry),
             "ops_mh": len(g.live_ops(qv_nodes, m_nodes + h_nodes)),
             "ops_first": len(g.live_ops(qv_nodes, m_nodes + h_nodes + carry)),
             "ops_second": len(g.live_ops(a_nodes + carry, did_nodes))}
    compiled = CompiledDynamics(m, len(carry), sources, stats)
    err = self_check(plant, compiled)
    if err > SELF_CHECK_RTOL:
        if cyclic:
            return derive(plant, use_cyclic=False)
        raise _Unsupported(f"generated dynamics disagree with Drake (relative error {err:.1e})")
    return compiled


def self_check(plant, compiled: CompiledDynamics, n_states: int = 3, seed: int = 0) -> float:
    """Largest relative difference of the generated ``M``, ``h``, ``dID/d(q, v)`` from Drake's
    float and AutoDiffXd evaluation at random states (angles over a full turn)."""
    from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, InitializeAutoDiff
    from pydrake.multibody.tree import MultibodyForces_

    m = compiled.m
    rng = np.random.default_rng(seed)
    ctx = plant.CreateDefaultContext()
    forces = MultibodyForces_[float](plant)
    plant_ad = plant.ToAutoDiffXd()
    ctx_ad = plant_ad.CreateDefaultContext()
    forces_ad = MultibodyForces_[AutoDiffXd](plant_ad)
    worst = 0.0
    for _ in range(n_states):
        q, v, a = rng.uniform(-np.pi, np.pi, m), rng.standard_normal(m), rng.standard_normal(m)
        plant.SetPositions(ctx, q)
        plant.SetVelocities(ctx, v)
        plant.CalcForceElementsContribution(ctx, forces)
        h_ref = plant.CalcInverseDynamics(ctx, np.zeros(m), forces)
        M_ref = plant.CalcMassMatrix(ctx)
        qv = InitializeAutoDiff(np.concatenate([q, v])).reshape(-1)
        plant_ad.SetPositions(ctx_ad, qv[:m])
        plant_ad.SetVelocities(ctx_ad, qv[m:])
        plant_ad.CalcForceElementsContribution(ctx_ad, forces_ad)
        D_ref = ExtractGradient(plant_ad.CalcInverseDynamics(ctx_ad, a, forces_ad))
        M, h, D = compiled.evaluate(q, v, a)
        for got, ref in ((M, M_ref), (h, h_ref), (D, D_ref)):
            scale = max(np.max(np.abs(ref)), 1e-12)
            worst = max(worst, float(np.max(np.abs(got - ref))) / scale)
    return worst


_COMPILED: dict[str, CompiledDynamics | Exception] = {}


def compiled_dynamics(robot) -> CompiledDynamics:
    """The generated code of ``robot``'s plant, derived once per plant name and kept in memory.

    Robots of one name come from one model file; a plant of a cached name is still compared
    with the code at one state (``M``, ``h``; tens of microseconds) and derived anew, uncached,
    if its parameters differ."""
    hit = _COMPILED.get(robot.name)
    if hit is None:
        try:
            hit = derive(robot.plant)
        except NotImplementedError as exc:
            hit = exc
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
    """Whether :class:`FastAnalyticDynamics` handles ``robot`` (derives it on first call)."""
    try:
        compiled_dynamics(robot)
    except NotImplementedError:
        return False
    return True


# --------------------------------------------------------------------------------------------
# The dynamics model
# --------------------------------------------------------------------------------------------
class FastAnalyticDynamics(SemiImplicitEuler):
    """Drop-in for :class:`plants.dynamics.AnalyticDynamics` on the compiled symbolic dynamics.

    Same contract and numbers: semi-implicit Euler with step ``dt``, controls are torques,
    ``qddot = M_r^-1 (u - h_r)``, ``d qddot/d(q, v) = -M_r^-1 dID_r/d(q, v)`` at
    ``a = qddot``, ``d qddot/du = M_r^-1``. ``linearize_trajectory`` (and the batched
    ``qddot_trajectory``, ``step_trajectory``) evaluate all time steps in one pass of numpy
    operations; single-point calls run the generated code on Python floats.
    Raises ``NotImplementedError`` for plants it does not compile (see :func:`derive`).
    """

    def __init__(self, robot, dt: float):
        self.robot = robot
        self.dt = float(dt)
        self.n_q = robot.n_q
        self.n_x = 2 * robot.n_q
        self.n_u = robot.n_q
        self.P = np.asarray(robot.P, float)
        self._code = compiled_dynamics(robot)
        m = self._code.m
        if self.P.shape != (m, self.n_q):
            raise ValueError(f"P has shape {self.P.shape}, the plant has {m} positions")
        self._identity = m == self.n_q and np.array_equal(self.P, np.eye(m))

    # -- coordinates --------------------------------------------------------------------------
    def _plant(self, z: np.ndarray) -> np.ndarray:
        """Planning ``(..., n)`` -> plant ``(..., m)``."""
        return z if self._identity else z @ self.P.T

    def _reduce_M(self, M: np.ndarray) -> np.ndarray:
        return M if self._identity else self.P.T @ M @ self.P

    def _reduce_h(self, h: np.ndarray) -> np.ndarray:
        return h if self._identity else h @ self.P

    def _reduce_D(self, D: np.ndarray) -> np.ndarray:
        """``dID/d(qp, vp) (..., m, 2m)`` -> ``dID_r/d(q, v) (..., n, 2n)``."""
        if self._identity:
            return D
        m, P = self._code.m, self.P
        return np.concatenate([P.T @ D[..., :m] @ P, P.T @ D[..., m:] @ P], axis=-1)

    # -- single points (generated code on Python floats) --------------------------------------
    def _mh_point(self, q, v):
        m, mm = self._code.m, self._code.m * self._code.m
        qp, vp = self._plant(np.asarray(q, float)), self._plant(np.asarray(v, float))
        out = self._code.sca["mh"]([*qp.tolist(), *vp.tolist()], [0.0] * (mm + m))
        return self._reduce_M(np.array(out[:mm]).reshape(m, m)), self._reduce_h(np.array(out[mm:]))

    def _derivatives_point(self, q, v, u):
        """``a (n,)``, ``dqddot/d(q, v) (n, 2n)``, ``M_r^-1 (n, n)``."""
        code = self._code
        m, mm = code.m, code.m * code.m
        qp, vp = self._plant(np.asarray(q, float)), self._plant(np.asarray(v, float))
        out, carry = [0.0] * (mm + m), [0.0] * code.n_carry
        code.sca["first"]([*qp.tolist(), *vp.tolist()], out, carry)
        Mr = self._reduce_M(np.array(out[:mm]).reshape(m, m))
        hr = self._reduce_h(np.array(out[mm:]))
        Mr_inv = np.linalg.inv(Mr)
        a = Mr_inv @ (np.asarray(u, float) - hr)
        D = code.sca["second"]([*self._plant(a).tolist(), *carry], [0.0] * (2 * mm))
        D = np.array(D).reshape(m, 2 * m)
        return a, -(Mr_inv @ self._reduce_D(D)), Mr_inv

    # -- batches (generated code on (T,) arrays) ----------------------------------------------
    def _mh_batch(self, Q, V):
        code = self._code
        m, mm, T = code.m, code.m * code.m, Q.shape[0]
        xs = np.empty((2 * m, T))
        xs[:m], xs[m:] = self._plant(Q).T, self._plant(V).T
        out = code.vec["mh"](xs, np.empty((mm + m, T)))
        return self._reduce_M(out[:mm].T.reshape(T, m, m)), self._reduce_h(out[mm:].T)

    def _derivatives_batch(self, Q, V, U):
        """``a (T, n)``, ``dqddot/d(q, v) (T, n, 2n)``, ``M_r^-1 (T, n, n)``."""
        code = self._code
        m, mm, T = code.m, code.m * code.m, Q.shape[0]
        xs = np.empty((2 * m, T))
        xs[:m], xs[m:] = self._plant(Q).T, self._plant(V).T
        out, carry = np.empty((mm + m, T)), [None] * code.n_carry  # carried arrays: no copies
        code.vec["first"](xs, out, carry)
        Mr = self._reduce_M(out[:mm].T.reshape(T, m, m))
        hr = self._reduce_h(out[mm:].T)
        Mr_inv = np.linalg.inv(Mr)
        a = np.einsum("tij,tj->ti", Mr_inv, U - hr)
        D = code.vec["second"]([*self._plant(a).T, *carry], np.empty((2 * mm, T)))
        D = D.T.reshape(T, m, 2 * m)
        return a, -(Mr_inv @ self._reduce_D(D)), Mr_inv

    def _assemble(self, X, U, a, F, Mr_inv):
        """``A, a, B`` of semi-implicit Euler from ``qddot`` and its derivatives (batched)."""
        n, dt = self.n_q, self.dt
        lead = X.shape[:-1]
        A = np.empty((*lead, 2 * n, 2 * n))
        flat = A.reshape(-1, 4 * n * n)  # a view: diagonal entries by stride
        np.multiply(F, dt, out=A[..., n:, :])  # dv'/dx = dt F + [0 I]
        flat[:, 2 * n * n + n::2 * n + 1] += 1.0
        np.multiply(A[..., n:, :], dt, out=A[..., :n, :])  # dq'/dx = [I 0] + dt dv'/dx
        flat[:, 0:2 * n * n:2 * n + 1] += 1.0
        B = np.empty((*lead, 2 * n, n))
        np.multiply(Mr_inv, dt, out=B[..., n:, :])
        np.multiply(B[..., n:, :], dt, out=B[..., :n, :])
        # f(x, u) - A x - B u, simplified: with r = qddot - F x - M_r^-1 u the velocity rows
        # are dt r and the position rows dt^2 r (no cancellation against the state)
        if X.ndim == 1:
            r = a - F @ X - Mr_inv @ U
        else:
            r = a - np.einsum("tij,tj->ti", F, X) - np.einsum("tij,tj->ti", Mr_inv, U)
        aff = np.concatenate([(dt * dt) * r, dt * r], axis=-1)
        return A, aff, B

    # -- the AnalyticDynamics interface --------------------------------------------------------
    def qddot(self, q: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Joint accelerations ``(n_q,)`` (rad/s^2) for torques ``u (n_q,)`` (N m)."""
        Mr, hr = self._mh_point(q, v)
        return np.linalg.solve(Mr, np.asarray(u, float) - hr)

    def inverse_dynamics(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Torques ``(n_q,)`` that produce accelerations ``a`` (computed torque)."""
        Mr, hr = self._mh_point(q, v)
        return Mr @ np.asarray(a, float) + hr

    def qddot_derivatives(self, q, v, u) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``qddot``, ``d/dq``, ``d/dv`` ``(n_q, n_q)`` and ``d/du`` ``(n_q, n_q)``."""
        a, F, Mr_inv = self._derivatives_point(q, v, u)
        return a, F[:, :self.n_q], F[:, self.n_q:], Mr_inv

    def linearize(self, x, u):
        x, u = np.asarray(x, float), np.asarray(u, float)
        n = self.n_q
        a, F, Mr_inv = self._derivatives_point(x[:n], x[n:], u)
        return self._assemble(x, u, a, F, Mr_inv)

    def linearize_trajectory(self, X: np.ndarray, U: np.ndarray):
        """``(A (T, n_x, n_x), a (T, n_x), B (T, n_x, n_u))`` along ``X (T, n_x)``, ``U (T, n_u)``,
        every time step in the same numpy operations."""
        X, U = self._check_batch(X, U)
        n = self.n_q
        a, F, Mr_inv = self._derivatives_batch(X[:, :n], X[:, n:], U)
        return self._assemble(X, U, a, F, Mr_inv)

    # -- batched extras -----------------------------------------------------------------------
    def qddot_trajectory(self, Q: np.ndarray, V: np.ndarray, U: np.ndarray) -> np.ndarray:
        """:meth:`qddot` at T points at once: ``(T, n_q)`` from ``Q, V, U (T, n_q)``."""
        Mr, hr = self._mh_batch(np.asarray(Q, float), np.asarray(V, float))
        return np.linalg.solve(Mr, (np.asarray(U, float) - hr)[..., None])[..., 0]

    def step_trajectory(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """:meth:`step` at T points at once (not a rollout): ``(T, n_x)``."""
        X, U = self._check_batch(X, U)
        n = self.n_q
        v1 = X[:, n:] + self.dt * self.qddot_trajectory(X[:, :n], X[:, n:], U)
        return np.concatenate([X[:, :n] + self.dt * v1, v1], axis=1)

    def _check_batch(self, X, U):
        X, U = np.asarray(X, float), np.asarray(U, float)
        if X.ndim != 2 or U.ndim != 2 or X.shape[0] != U.shape[0] or X.shape[1] != self.n_x \
                or U.shape[1] != self.n_u:
            raise ValueError(f"X {X.shape}, U {U.shape}: expected (T, {self.n_x}), (T, {self.n_u})")
        return X, U


def make_fast_or_exact(robot, dt: float):
    """:class:`FastAnalyticDynamics` when the robot's plant compiles, else ``AnalyticDynamics``."""
    try:
        return FastAnalyticDynamics(robot, dt)
    except NotImplementedError:
        return AnalyticDynamics(robot, dt)
