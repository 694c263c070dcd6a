"""Reading Drake's symbolic equations of motion into a :class:`~raico.plants.codegen.graph.Graph`.

``plant.ToSymbolic()`` with ``pydrake.symbolic`` variables ``q, v, a`` gives the expressions of
the inverse dynamics ``ID(q, v, a) = M(q) a + h(q, v)`` and of the mass matrix ``M(q)``; their
trees are read through ``Expression.Unapply()`` / ``get_kind()`` into the hash-consed graph
(equal subtrees merged, constants folded). :func:`cyclic_positions` finds the joint angles the
equations cannot depend on (see there).
"""

from __future__ import annotations

import sys

import numpy as np

from raico.plants.codegen.graph import Graph, Unsupported

# Budget on Expression nodes visited while reading one plant's trees (arm5 needs ~1.1e5).
MAX_VISITS = 2_000_000


class DrakeReader:
    """``pydrake.symbolic.Expression`` -> ``Graph`` node; equal subtrees become one node."""

    def __init__(self, graph: Graph, var_index: dict[int, int]):
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
            raise Unsupported("symbolic dynamics too large to compile")
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
                raise Unsupported("pow with a symbolic exponent")
            return g.pow(base, p)
        if kind in self._unary:
            return g.unary(self._unary[kind], self.read(args[0]))
        raise Unsupported(f"expression kind {kind.name} in the symbolic dynamics")


def symbolic_inverse_dynamics(plant) -> tuple[list, np.ndarray, np.ndarray]:
    """Drake's symbolic ``ID(q, v, a) (m,)`` and row-major ``M(q) (m*m,)`` of ``plant``.

    Returns the variables ``[q, v, a]`` (``3 m`` ``pydrake.symbolic.Variable``, input ``k`` of
    the graph is ``variables[k]``), the inverse dynamics (gravity and joint damping through
    ``CalcForceElementsContribution``) and the mass matrix (reflected rotor inertia included).
    """
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


def read_equations(plant) -> tuple[Graph, list[int], list[int], int]:
    """The plant's equations in a new graph: input ``k`` is ``(q, v, a)[k]`` (``3 m`` inputs).

    Returns the graph, the nodes of ``ID (m,)`` and of row-major ``M (m*m,)``, and the number
    of expression nodes visited (raises :class:`Unsupported` beyond ``MAX_VISITS``).
    """
    variables, tau, M = symbolic_inverse_dynamics(plant)
    g = Graph()
    reader = DrakeReader(g, {var.get_id(): k for k, var in enumerate(variables)})
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 50_000))
    try:
        id_nodes = [reader.read(e) for e in tau]
        m_nodes = [reader.read(e) for e in M]
    finally:
        sys.setrecursionlimit(limit)
    return g, id_nodes, m_nodes, reader.visits
