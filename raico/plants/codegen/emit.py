"""Straight-line Python source from a :class:`~raico.plants.codegen.graph.Graph`, and its compilation.

One walk of the graph (:func:`walk`: the live operations in order, the output assignments), two
printers: :func:`emit` here (Python, recycled local names) and ``c_backend.emit_c`` (C, one
``const double`` per operation).

The same source runs on Python floats (single points, ``math`` functions) and on numpy arrays
of shape ``(T,)`` (a whole trajectory per call, ``numpy`` ufuncs).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from raico.plants.codegen.graph import BINARY, Graph


def live_ops(g: Graph, inputs: list[int], outputs: list[int]) -> list[int]:
    """Operation nodes needed for ``outputs`` given ``inputs``, in evaluation order."""
    given = set(inputs)
    live = bytearray(len(g.nodes))
    for o in outputs:
        live[o] = 1
    for i in range(len(g.nodes) - 1, -1, -1):
        n = g.nodes[i]
        if live[i] and i not in given and n[0] not in ("c", "x"):
            live[n[1]] = 1
            if n[0] in BINARY:
                live[n[2]] = 1
    missing = [i for i in range(len(g.nodes))
               if live[i] and g.nodes[i][0] == "x" and i not in given]
    if missing:  # pragma: no cover - the callers pass every input
        raise ValueError(f"inputs not given: {missing}")
    return [i for i in range(len(g.nodes))
            if live[i] and i not in given and g.nodes[i][0] not in ("c", "x")]


@dataclass(frozen=True)
class Walk:
    """The one graph walk both emitters print (:func:`emit`: Python; ``c_backend.emit_c``: C).

    ``order``: the live operation nodes in evaluation order; ``writes``: node -> the targets it is
    assigned to (in output order); ``inputs``: node -> its input position."""

    nodes: list
    order: list[int]
    writes: dict[int, list[str]]
    inputs: dict[int, int]

    def operands(self, i: int) -> tuple[int, ...]:
        """The nodes operation ``i`` reads."""
        n = self.nodes[i]
        return (n[1], n[2]) if n[0] in BINARY else (n[1],)

    def direct_writes(self) -> list[tuple[int, str]]:
        """(node, target) of outputs that are an input or a constant (assigned before any operation)."""
        return [(o, t) for o, ts in self.writes.items() if o in self.inputs or self.nodes[o][0] == "c" for t in ts]

    def expression(self, i: int, ref: Callable[[int], str], power: Callable[[str, float], str]) -> str:
        """The right-hand side of operation ``i`` with operands named by ``ref`` (``power`` prints ``a ** p``)."""
        n = self.nodes[i]
        op = n[0]
        if op in BINARY:
            return f"{ref(n[1])} {op} {ref(n[2])}"
        if op == "neg":
            return f"-{ref(n[1])}"
        if op == "pow":
            return power(ref(n[1]), n[2])
        return f"{op}({ref(n[1])})"


def walk(g: Graph, inputs: list[int], outputs: list[int], targets: list[str]) -> Walk:
    """The evaluation order and output assignments of ``outputs`` given ``inputs`` (see :class:`Walk`)."""
    writes: dict[int, list[str]] = {}
    for t, o in zip(targets, outputs):
        writes.setdefault(o, []).append(t)
    return Walk(g.nodes, live_ops(g, inputs, outputs), writes, {node: k for k, node in enumerate(inputs)})


def emit(g: Graph, name: str, inputs: list[int], outputs: list[int],
         targets: list[str] | None = None, params: str = "xs, out") -> str:
    """Python source of ``name(<params>)``: node ``inputs[k]`` is ``xs[k]`` (floats or
    arrays); node ``outputs[j]`` is assigned to ``targets[j]`` (default ``out[j]``).

    Intermediate values live in recycled local names: an array is released after its last
    use, so a batched call keeps a few hundred ``(T,)`` arrays alive, not thousands.
    """
    targets = [f"out[{j}]" for j in range(len(outputs))] if targets is None else targets
    w = walk(g, inputs, outputs, targets)
    last_use: dict[int, int] = {}
    for i in w.order:
        for o in w.operands(i):
            last_use[o] = i
    reg: dict[int, str] = {}
    free: list[str] = []
    n_regs = 0

    def ref(j: int) -> str:
        if j in w.inputs:
            return f"x{w.inputs[j]}"
        n = w.nodes[j]
        if n[0] == "c":
            return repr(n[1]) if n[1] >= 0 else f"({n[1]!r})"
        return reg[j]

    lines = [f"def {name}({params}):"]
    if inputs:
        lines.append("    " + ", ".join(ref(node) for node in inputs) + ", = xs")
    lines += [f"    {t} = {ref(o)}" for o, t in w.direct_writes()]
    for i in w.order:
        rhs = w.expression(i, ref, lambda a, p: f"{a} ** {p!r}")
        for o in set(w.operands(i)):  # release operands used for the last time
            if o in reg and last_use[o] == i:
                free.append(reg.pop(o))
        if free:
            reg[i] = free.pop()
        else:
            reg[i] = f"r{n_regs}"
            n_regs += 1
        lines.append(f"    {reg[i]} = {rhs}")
        lines += [f"    {t} = {reg[i]}" for t in w.writes.get(i, ())]
        if i not in last_use:
            free.append(reg.pop(i))
    lines.append(f"    return {params.split(', ')[1]}")
    return "\n".join(lines) + "\n"


def compile_source(source: str, name: str) -> tuple[Callable, Callable]:
    """The function ``name`` defined by ``source``, compiled once and bound twice: on numpy
    (``(T,)`` arrays) and on ``math`` (Python floats)."""
    code = compile(source, f"<codegen:{name}>", "exec")
    ns_vec = {"sin": np.sin, "cos": np.cos, "sqrt": np.sqrt}
    ns_sca = {"sin": math.sin, "cos": math.cos, "sqrt": math.sqrt}
    exec(code, ns_vec)
    exec(code, ns_sca)
    return ns_vec[name], ns_sca[name]
