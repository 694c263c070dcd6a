"""A hash-consed DAG of scalar operations with simplification and forward-mode derivatives.

Nodes are tuples ``(op, *args)`` kept in topological order (children first), so every pass
over the graph is a loop over node ids, never a deep recursion. The graph knows nothing of
Drake or of Python source: :mod:`raico.plants.codegen.drake_reader` fills it, :mod:`raico.plants.codegen.emit`
turns it into code.
"""

from __future__ import annotations

import math

BINARY = ("+", "-", "*", "/")


class Unsupported(NotImplementedError):
    """A plant or an expression the code generator does not handle."""


class Graph:
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
                kids = [n[1]] if n[0] not in BINARY else [n[1], n[2]]
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
            kids = [] if n[0] in ("c", "x") else ([n[1]] if n[0] not in BINARY else [n[1], n[2]])
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
        raise Unsupported(op)  # pragma: no cover - every op built above is handled
