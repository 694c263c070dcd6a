"""Straight-line Python source from a :class:`~plants.codegen.graph.Graph`, and its compilation.

The same source runs on Python floats (single points, ``math`` functions) and on numpy arrays
of shape ``(T,)`` (a whole trajectory per call, ``numpy`` ufuncs).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from plants.codegen.graph import BINARY, Graph


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


def emit(g: Graph, name: str, inputs: list[int], outputs: list[int],
         targets: list[str] | None = None, params: str = "xs, out") -> str:
    """Python source of ``name(<params>)``: node ``inputs[k]`` is ``xs[k]`` (floats or
    arrays); node ``outputs[j]`` is assigned to ``targets[j]`` (default ``out[j]``).

    Intermediate values live in recycled local names: an array is released after its last
    use, so a batched call keeps a few hundred ``(T,)`` arrays alive, not thousands.
    """
    nodes = g.nodes
    targets = [f"out[{j}]" for j in range(len(outputs))] if targets is None else targets
    order = live_ops(g, inputs, outputs)
    in_name = {node: f"x{k}" for k, node in enumerate(inputs)}
    last_use: dict[int, int] = {}
    for i in order:
        n = nodes[i]
        last_use[n[1]] = i
        if n[0] in BINARY:
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
        if op in BINARY:
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


def compile_source(source: str, name: str) -> tuple[Callable, Callable]:
    """The function ``name`` defined by ``source``, compiled once and bound twice: on numpy
    (``(T,)`` arrays) and on ``math`` (Python floats)."""
    code = compile(source, f"<codegen:{name}>", "exec")
    ns_vec = {"sin": np.sin, "cos": np.cos, "sqrt": np.sqrt}
    ns_sca = {"sin": math.sin, "cos": math.cos, "sqrt": math.sqrt}
    exec(code, ns_vec)
    exec(code, ns_sca)
    return ns_vec[name], ns_sca[name]
