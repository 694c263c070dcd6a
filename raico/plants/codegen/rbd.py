"""A plant's kinematic tree read from Drake, compiled to C: kinematics, task maps and dynamics.

For plants whose symbolic equations are too large or too slow to generate (the 26-joint Nao, arms
of 6 or more joints: see :mod:`raico.plants.codegen.derive` and
:data:`raico.plants.fast_analytic.SYMBOLIC_MAX_POSITIONS`), the same quantities come from the classical
recursive algorithms on the tree, with the tree's numbers (frames, axes, masses, inertias, damping,
reflected rotor inertia, gravity) read from the Drake plant and baked into the C source:

- forward kinematics, point / centre-of-mass / angular-velocity Jacobians (the task maps of
  :mod:`raico.plants.taskmaps`);
- the inverse dynamics ``ID(q, v, a)`` by the recursive Newton-Euler algorithm in world coordinates;
- its exact derivatives ``dID/d(q, v)`` by forward-mode automatic differentiation of that code and,
  for :class:`raico.plants.fast_analytic.TreeAnalyticDynamics`, by the analytical derivatives of the
  recursive Newton-Euler algorithm with the mass matrix ``M`` from the same pass, on the dynamics'
  own tree (:func:`dynamics_tree`);
- the C entry points of these maps (``TreeKernels.addresses``) for the planning floor's compiled
  task messages (:func:`raico.planning.kernels.compile_task_set`).

Supported: trees of revolute, prismatic and weld joints, gravity as the only force element.
:func:`tree_kernels` checks ``M``, ``h`` and ``dID`` (both routes) against Drake's float and AutoDiffXd
evaluation at random states and refuses the plant on a mismatch (``NotImplementedError``), as
:func:`raico.plants.codegen.derive.derive` does for the generated code. The algorithms in detail:
docs/kernels.md, "The kinematic tree in C".
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass
from typing import Any

import numpy as np

from raico.plants.codegen import c_backend
from raico.plants.codegen.graph import Unsupported

SELF_CHECK_RTOL = 1e-9


@dataclass
class Tree:
    """Bodies (world excluded) in topological order; ``X_PJ``, ``X_JB``: fixed ``(R (3, 3), p (3,))``
    from the parent body's frame to the joint frame and from the moved joint frame to the body;
    the joint turns by ``q[qidx]`` about ``axis`` (joint frame; ``qidx = -1``: a weld), or, where
    ``prismatic``, translates by ``q[qidx]`` along it."""

    names: list[str]
    parent: np.ndarray      # (nb,) int, -1 = world
    qidx: np.ndarray        # (nb,) int
    R_PJ: np.ndarray        # (nb, 3, 3)
    p_PJ: np.ndarray        # (nb, 3)
    axis: np.ndarray        # (nb, 3)
    R_JB: np.ndarray        # (nb, 3, 3)
    p_JB: np.ndarray        # (nb, 3)
    mass: np.ndarray        # (nb,)
    com: np.ndarray         # (nb, 3) body frame
    I_com: np.ndarray       # (nb, 3, 3) about the com, body frame
    damping: np.ndarray     # (m,)
    reflected: np.ndarray   # (m,)
    gravity: np.ndarray     # (3,)
    m: int
    prismatic: np.ndarray | None = None   # (nb,) bool; None: no prismatic joint

    def __post_init__(self):
        if self.prismatic is None:
            self.prismatic = np.zeros(len(self.names), bool)

    def body(self, name: str) -> int:
        return self.names.index(name)


def _pose(X) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(X.rotation().matrix(), float), np.asarray(X.translation(), float)


def extract_tree(plant) -> Tree:
    """The tree of ``plant`` (raises :class:`Unsupported` for other joints or force elements)."""
    from pydrake.multibody.tree import (
        BodyIndex,
        ForceElementIndex,
        JointActuatorIndex,
        JointIndex,
        UniformGravityFieldElement,
    )

    m = plant.num_positions()
    if plant.num_velocities() != m:
        raise Unsupported("plants with quaternion (free) joints are not supported")
    for i in range(plant.num_force_elements()):
        if not isinstance(plant.get_force_element(ForceElementIndex(i)), UniformGravityFieldElement):
            raise Unsupported("force elements other than gravity")
    joints = [plant.get_joint(JointIndex(i)) for i in range(plant.num_joints())]
    for j in joints:
        if j.type_name() not in ("revolute", "prismatic", "weld"):
            raise Unsupported(f"joint type {j.type_name()}")
    world = plant.world_body().index()
    known = {world: -1}
    order: list[Any]
    order, parent, qidx, R_PJ, p_PJ, axis, R_JB, p_JB, prismatic = [], [], [], [], [], [], [], [], []
    frontier = [world]
    used = set()
    while frontier:
        k = frontier.pop(0)
        for j in joints:
            if j.index() in used:
                continue
            pb, cb = j.parent_body().index(), j.child_body().index()
            if k not in (pb, cb):
                continue
            used.add(j.index())
            forward = pb == k
            new = cb if forward else pb
            if new in known:
                raise Unsupported("kinematic loops")
            R_KF, p_KF = _pose(j.frame_on_parent().GetFixedPoseInBodyFrame())
            R_NM, p_NM = _pose(j.frame_on_child().GetFixedPoseInBodyFrame())
            if not forward:  # K holds the joint's child frame M, N the parent frame F
                R_KF, p_KF, R_NM, p_NM = R_NM, p_NM, R_KF, p_KF
            # from the new body's frame to its joint frame, inverted: X_JN = X_NJ^-1
            R_JN, p_JN = R_NM.T, -R_NM.T @ p_NM
            if j.type_name() == "weld":
                R_FM, p_FM = _pose(j.X_FM())
                if not forward:
                    R_FM, p_FM = R_FM.T, -R_FM.T @ p_FM
                # fold the fixed X_FM into the joint frame
                R_KF, p_KF = R_KF @ R_FM, p_KF + R_KF @ p_FM
                ax, qi = np.zeros(3), -1
            else:
                # reversed: X_MF(q) = X_FM(q)^-1 turns (translates) by q about (along) -axis;
                # a prismatic joint's X_FM has no rotation, so its axis is the same in F and M
                ax = np.asarray(j.revolute_axis() if j.type_name() == "revolute" else j.translation_axis(),
                                float) * (1.0 if forward else -1.0)
                qi = j.position_start()
            prismatic.append(j.type_name() == "prismatic")
            known[new] = len(order)
            order.append(new)
            parent.append(known[k])
            qidx.append(qi)
            R_PJ.append(R_KF)
            p_PJ.append(p_KF)
            axis.append(ax)
            R_JB.append(R_JN)
            p_JB.append(p_JN)
            frontier.append(new)
    if len(order) != plant.num_bodies() - 1:
        raise Unsupported("bodies not connected to the world")
    bodies = [plant.get_body(BodyIndex(int(b))) for b in order]
    mass = np.array([b.default_mass() for b in bodies], float)
    com = np.array([np.asarray(b.default_com(), float) for b in bodies])
    I_com = []
    for b, mb, c in zip(bodies, mass, com):
        I_o = np.asarray(b.default_rotational_inertia().CopyToFullMatrix3(), float)  # about Bo
        # parallel axis: I_com = I_o - m (|c|^2 I - c c^T)
        I_com.append(I_o - mb * (c @ c * np.eye(3) - np.outer(c, c)))
    damping = np.zeros(m)
    for j in joints:
        if j.type_name() in ("revolute", "prismatic"):
            damping[j.position_start()] = j.default_damping()
    reflected = np.zeros(m)
    for i in range(plant.num_actuators()):
        a = plant.get_joint_actuator(JointActuatorIndex(i))
        reflected[a.joint().position_start()] += a.default_reflected_inertia()
    return Tree([b.name() for b in bodies], np.array(parent), np.array(qidx), np.array(R_PJ),
                np.array(p_PJ), np.array(axis), np.array(R_JB), np.array(p_JB), mass, com,
                np.array(I_com), damping, reflected,
                np.asarray(plant.gravity_field().gravity_vector(), float), m, np.array(prismatic, bool))


def _parallel_axis(m: float, d: np.ndarray) -> np.ndarray:
    """The inertia (3, 3) a mass ``m`` (kg) adds when moved by ``d`` (m) from its centre: ``m (|d|^2 1 - d d^T)``."""
    return m * (d @ d * np.eye(3) - np.outer(d, d))


def dynamics_tree(tree: Tree) -> Tree:
    """The moving bodies of ``tree`` only, for the dynamics: a body welded to another (directly or through
    welds) merged into it (mass, centre of mass and inertia about it combined in its frame), the moving
    bodies below it re-attached to it through the composed fixed poses; the bodies welded to the world
    (no moving joint above them) left out (their forces go to the world). Same motion, same ``M``, ``ID``."""
    nb = len(tree.names)
    parent = [int(x) for x in tree.parent]
    R_PJ, p_PJ = [r.copy() for r in tree.R_PJ], [x.copy() for x in tree.p_PJ]
    mass = [float(x) for x in tree.mass]
    com = [c.copy() for c in tree.com]
    I_com = [i.copy() for i in tree.I_com]
    for b in range(nb - 1, -1, -1):   # children after their parents: welds below b are merged into b already
        if tree.qidx[b] >= 0:
            continue
        # the weld's fixed pose in its parent's frame (or the world's)
        R_PB, p_PB = R_PJ[b] @ tree.R_JB[b], p_PJ[b] + R_PJ[b] @ tree.p_JB[b]
        pa = parent[b]
        for c in range(b + 1, nb):   # the moving bodies attached to b: to b's parent
            if parent[c] == b:
                R_PJ[c], p_PJ[c] = R_PB @ R_PJ[c], p_PB + R_PB @ p_PJ[c]
                parent[c] = pa
        if pa < 0:
            continue
        m1, m2 = mass[pa], mass[b]
        c1, c2 = com[pa], p_PB + R_PB @ com[b]
        I2 = R_PB @ I_com[b] @ R_PB.T
        m = m1 + m2
        cm = (m1 * c1 + m2 * c2) / m if m > 0.0 else np.zeros(3)
        I_com[pa] = I_com[pa] + _parallel_axis(m1, c1 - cm) + I2 + _parallel_axis(m2, c2 - cm)
        mass[pa], com[pa] = m, cm
    keep = [b for b in range(nb) if tree.qidx[b] >= 0]
    index = {b: i for i, b in enumerate(keep)}
    return Tree([tree.names[b] for b in keep], np.array([index[parent[b]] if parent[b] >= 0 else -1 for b in keep], int),
                tree.qidx[keep], np.array([R_PJ[b] for b in keep]).reshape(-1, 3, 3),
                np.array([p_PJ[b] for b in keep]).reshape(-1, 3), tree.axis[keep], tree.R_JB[keep], tree.p_JB[keep],
                np.array([mass[b] for b in keep]), np.array([com[b] for b in keep]).reshape(-1, 3),
                np.array([I_com[b] for b in keep]).reshape(-1, 3, 3), tree.damping, tree.reflected, tree.gravity,
                tree.m, tree.prismatic[keep])


def _arr(name: str, ctype: str, a: np.ndarray) -> str:
    flat = np.asarray(a).reshape(-1)
    if ctype == "int":
        body = ", ".join(str(int(x)) for x in flat)
    else:
        body = ", ".join(repr(float(x)) for x in flat)
    return f"static const {ctype} {name}[{max(len(flat), 1)}] = {{{body or '0'}}};\n"


def _tree_arrays(prefix: str, tree: Tree) -> str:
    """The C arrays of ``tree``'s bodies, their names prefixed (the kinematics' tree, ``D``: the dynamics')."""
    return "".join([_arr(prefix + "PARENT", "int", tree.parent), _arr(prefix + "QIDX", "int", tree.qidx),
                    _arr(prefix + "PRISMATIC", "int", tree.prismatic.astype(int)),
                    _arr(prefix + "R_PJ", "double", tree.R_PJ), _arr(prefix + "P_PJ", "double", tree.p_PJ),
                    _arr(prefix + "AXIS", "double", tree.axis), _arr(prefix + "R_JB", "double", tree.R_JB),
                    _arr(prefix + "P_JB", "double", tree.p_JB), _arr(prefix + "MASS", "double", tree.mass),
                    _arr(prefix + "COM", "double", tree.com), _arr(prefix + "I_COM", "double", tree.I_com)])


_KERNEL_C = c_backend.c_source(__file__, "rbd_kernels.c")  # the C beside this module


def tree_source(tree: Tree, header: bool = True) -> str:
    """The C source of the tree's kernels (numbers baked in); ``header=False``: without the
    includes and the ``MP``, ``NCARRY`` definitions (the dynamics driver supplies them)."""
    nb = len(tree.names)
    head = ("#include <math.h>\n#include <string.h>\n"
            f"#define MP {tree.m}\n#define NCARRY (2 * MP)\n") if header else ""
    dyn = dynamics_tree(tree)
    data = "".join([f"#define NB {nb}\n#define DNB {len(dyn.names)}\n#define TREE_DYN 1\n",
                    _tree_arrays("", tree), _tree_arrays("D", dyn),
                    _arr("DAMPING", "double", tree.damping), _arr("REFLECTED", "double", tree.reflected),
                    _arr("GRAVITY", "double", tree.gravity)])
    return head + data + _KERNEL_C


class TreeKernels:
    """The compiled kernels of one plant's tree (``ctypes``); ``m`` plant positions."""

    def __init__(self, tree: Tree, name: str):
        self.tree = tree
        self.plant = None   # the plant last checked against (tree_kernels' cache)
        self.m = tree.m
        self.source = tree_source(tree)
        lib = c_backend.load_library(self.source, f"tree_{name}")
        vp, i = ctypes.c_void_p, ctypes.c_int
        sigs = {"tree_frame_points": [vp, i, vp, vp, i, vp, vp, vp],
                "tree_frame_rotation": [vp, i, vp, vp, vp], "tree_com": [vp, vp, vp],
                "tree_mass_matrix": [vp, vp], "tree_inverse_dynamics": [vp, vp, vp, vp],
                "tree_id_derivatives": [vp, vp, vp, vp], "tree_id_analytic": [vp] * 6,
                "tree_gravity": [vp, vp, vp],
                "tree_frame_points_batch": [i, vp, i, vp, vp, i, vp, vp, vp],
                "tree_com_batch": [i, vp, vp, vp], "tree_frame_rotation_batch": [i, vp, i, vp, vp, vp],
                "tree_body_frames_batch": [i, vp, i, vp, vp, vp]}
        for f, args in sigs.items():
            getattr(lib, f).argtypes = args
            getattr(lib, f).restype = ctypes.c_int
        self.lib = lib
        # C entry points for compiled callers (raico/planning/task_messages.c calls these)
        self.addresses = {f: ctypes.cast(getattr(lib, f), ctypes.c_void_p).value
                          for f in ("tree_frame_points", "tree_com", "tree_frame_rotation", "tree_gravity")}

    @staticmethod
    def _a(x) -> np.ndarray:
        return np.ascontiguousarray(x, dtype=float)

    def _check(self, kernel: str, body: int | None = None, **arrays) -> None:
        """The shapes the C entry point accepts (``name=(array, shape)``) and a body index in range:
        ``ValueError`` before the call, never a read or write past a buffer."""
        if body is not None and not 0 <= int(body) < len(self.tree.names):
            raise ValueError(f"{kernel}: body index {body} out of range (the tree has {len(self.tree.names)} bodies)")
        c_backend.check_shapes(kernel, **arrays)

    def _frame(self, kernel: str, R_BF, p_BF=None) -> None:
        point: dict[str, Any] = {} if p_BF is None else {"p_BF": (p_BF, (3,))}
        self._check(kernel, R_BF=(R_BF, (3, 3)), **point)

    def frame_points(self, qp, body: int, R_BF, p_BF, points) -> tuple[np.ndarray, np.ndarray]:
        """World positions ``(k, 3)`` of ``points (k, 3)`` in frame F on ``body`` and the
        Jacobian ``(3 k, m)`` (point k's x, y, z at rows 3k..3k+2)."""
        qp, R_BF, p_BF, points = (self._a(z) for z in (qp, R_BF, p_BF, points))
        k = points.shape[0] if points.ndim == 2 else -1
        self._check("tree_frame_points", body, qp=(qp, (self.m,)), points=(points, (max(k, 0), 3)))
        self._frame("tree_frame_points", R_BF, p_BF)
        pos, J = np.empty((k, 3)), np.empty((3 * k, self.m))
        self.lib.tree_frame_points(qp.ctypes.data, body, R_BF.ctypes.data, p_BF.ctypes.data, k,
                                   points.ctypes.data, pos.ctypes.data, J.ctypes.data)
        return pos, J

    def frame_points_batch(self, Qp, body: int, R_BF, p_BF, points):
        """:meth:`frame_points` at the rows of ``Qp (K, m)``: ``(K, k, 3)``, ``(K, 3 k, m)``."""
        Qp, R_BF, p_BF, points = (self._a(z) for z in (Qp, R_BF, p_BF, points))
        K, k = (Qp.shape[0] if Qp.ndim else 0), (points.shape[0] if points.ndim == 2 else 0)
        self._check("tree_frame_points_batch", body, Qp=(Qp, (K, self.m)), points=(points, (k, 3)))
        self._frame("tree_frame_points_batch", R_BF, p_BF)
        pos, J = np.empty((K, k, 3)), np.empty((K, 3 * k, self.m))
        self.lib.tree_frame_points_batch(K, Qp.ctypes.data, body, R_BF.ctypes.data, p_BF.ctypes.data,
                                         k, points.ctypes.data, pos.ctypes.data, J.ctypes.data)
        return pos, J

    def body_frames_batch(self, Qp, bodies):
        """Per row of ``Qp (K, m)`` and body index of ``bodies``, the kinematics once per row: the body's origin and
        its axes' tips in the world ``(K, nb, 4, 3)`` and their Jacobians ``(K, nb, 12, m)``."""
        Qp = self._a(Qp)
        K = Qp.shape[0] if Qp.ndim else 0
        b = np.ascontiguousarray(bodies, dtype=np.intc)
        self._check("tree_body_frames_batch", Qp=(Qp, (K, self.m)), bodies=(b, (len(b),)))
        if len(b) and not (0 <= b.min() and b.max() < len(self.tree.names)):
            raise ValueError(f"tree_body_frames_batch: a body index out of range (the tree has {len(self.tree.names)})")
        pos, J = np.empty((K, len(b), 4, 3)), np.empty((K, len(b), 12, self.m))
        self.lib.tree_body_frames_batch(K, Qp.ctypes.data, len(b), b.ctypes.data, pos.ctypes.data, J.ctypes.data)
        return pos, J

    def com_batch(self, Qp):
        Qp = self._a(Qp)
        K = Qp.shape[0] if Qp.ndim else 0
        self._check("tree_com_batch", Qp=(Qp, (K, self.m)))
        c, J = np.empty((K, 3)), np.empty((K, 3, self.m))
        self.lib.tree_com_batch(K, Qp.ctypes.data, c.ctypes.data, J.ctypes.data)
        return c, J

    def frame_rotation_batch(self, Qp, body: int, R_BF):
        Qp, R_BF = self._a(Qp), self._a(R_BF)
        K = Qp.shape[0] if Qp.ndim else 0
        self._check("tree_frame_rotation_batch", body, Qp=(Qp, (K, self.m)))
        self._frame("tree_frame_rotation_batch", R_BF)
        R, Jw = np.empty((K, 3, 3)), np.empty((K, 3, self.m))
        self.lib.tree_frame_rotation_batch(K, Qp.ctypes.data, body, R_BF.ctypes.data, R.ctypes.data,
                                           Jw.ctypes.data)
        return R, Jw

    def frame_rotation(self, qp, body: int, R_BF) -> tuple[np.ndarray, np.ndarray]:
        qp, R_BF = self._a(qp), self._a(R_BF)
        self._check("tree_frame_rotation", body, qp=(qp, (self.m,)))
        self._frame("tree_frame_rotation", R_BF)
        R, Jw = np.empty((3, 3)), np.empty((3, self.m))
        self.lib.tree_frame_rotation(qp.ctypes.data, body, R_BF.ctypes.data, R.ctypes.data,
                                     Jw.ctypes.data)
        return R, Jw

    def com(self, qp) -> tuple[np.ndarray, np.ndarray]:
        qp = self._a(qp)
        self._check("tree_com", qp=(qp, (self.m,)))
        c, J = np.empty(3), np.empty((3, self.m))
        self.lib.tree_com(qp.ctypes.data, c.ctypes.data, J.ctypes.data)
        return c, J

    def mass_matrix(self, qp) -> np.ndarray:
        qp = self._a(qp)
        self._check("tree_mass_matrix", qp=(qp, (self.m,)))
        M = np.empty((self.m, self.m))
        self.lib.tree_mass_matrix(qp.ctypes.data, M.ctypes.data)
        return M

    def inverse_dynamics(self, qp, vp, ap) -> np.ndarray:
        qp, vp, ap = self._a(qp), self._a(vp), self._a(ap)
        self._check("tree_inverse_dynamics", q=(qp, (self.m,)), v=(vp, (self.m,)), a=(ap, (self.m,)))
        tau = np.empty(self.m)
        self.lib.tree_inverse_dynamics(qp.ctypes.data, vp.ctypes.data, ap.ctypes.data, tau.ctypes.data)
        return tau

    def id_analytic(self, qp, vp, ap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``ID(q, v, a) (m,)``, ``M (m, m)`` and ``dID/d(q, v) (m, 2 m)`` by the analytical derivatives
        of the inverse dynamics (the dynamics driver's route; :meth:`id_derivatives` by forward mode)."""
        qp, vp, ap = self._a(qp), self._a(vp), self._a(ap)
        self._check("tree_id_analytic", q=(qp, (self.m,)), v=(vp, (self.m,)), a=(ap, (self.m,)))
        tau, M, D = np.empty(self.m), np.empty((self.m, self.m)), np.empty((self.m, 2 * self.m))
        self.lib.tree_id_analytic(qp.ctypes.data, vp.ctypes.data, ap.ctypes.data, tau.ctypes.data,
                                  M.ctypes.data, D.ctypes.data)
        return tau, M, D

    def id_derivatives(self, qp, vp, ap) -> np.ndarray:
        """``dID/d(q, v) (m, 2 m)``."""
        qp, vp, ap = self._a(qp), self._a(vp), self._a(ap)
        self._check("tree_id_derivatives", q=(qp, (self.m,)), v=(vp, (self.m,)), a=(ap, (self.m,)))
        D = np.empty((self.m, 2 * self.m))
        self.lib.tree_id_derivatives(qp.ctypes.data, vp.ctypes.data, ap.ctypes.data, D.ctypes.data)
        return D

    def gravity(self, qp, jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """The gravity torques ``ID(q, 0, 0) (m,)`` and, if ``jacobian``, their Jacobian ``dID(q, 0, 0)/dq
        (m, m)`` (else None) by the analytical derivatives at rest (:meth:`inverse_dynamics` and
        :meth:`id_derivatives`' first ``m`` columns at ``v = a = 0``, to rounding)."""
        qp = self._a(qp)
        self._check("tree_gravity", q=(qp, (self.m,)))
        g, G = np.empty(self.m), (np.empty((self.m, self.m)) if jacobian else None)
        self.lib.tree_gravity(qp.ctypes.data, g.ctypes.data, None if G is None else G.ctypes.data)
        return g, G


def self_check(plant, kernels: TreeKernels, n_states: int = 3, seed: int = 0) -> float:
    """Largest relative difference of ``M``, ``h``, ``dID/d(q, v)``, a frame's pose and the centre
    of mass from Drake's own evaluation (float and AutoDiffXd) at random states, and of the gravity
    torques' pass (``g``, ``dg/dq``) from Newton-Euler and forward mode at rest."""
    from raico.plants.codegen.reference import DrakeReference

    m = kernels.m
    rng = np.random.default_rng(seed)
    drake = DrakeReference(plant)
    ctx = drake.ctx
    worst = 0.0

    def rel(got, ref):
        return float(np.max(np.abs(got - ref))) / max(float(np.max(np.abs(ref))), 1e-12)

    tree = kernels.tree
    for _ in range(n_states):
        q, v, a = rng.uniform(-np.pi, np.pi, m), rng.standard_normal(m), rng.standard_normal(m)
        M_ref, tau_ref, _, D_ref = drake.evaluate(q, v, a)
        tau, M, D = kernels.id_analytic(q, v, a)
        zero = np.zeros(m)   # the gravity torques' pass against Newton-Euler and forward mode at rest
        gravity_ref = (kernels.inverse_dynamics(q, zero, zero), kernels.id_derivatives(q, zero, zero)[:, :m])
        worst = max(worst, rel(kernels.mass_matrix(q), M_ref),
                    rel(kernels.inverse_dynamics(q, v, a), tau_ref),
                    rel(kernels.id_derivatives(q, v, a), D_ref),
                    rel(tau, tau_ref), rel(M, M_ref), rel(D, D_ref),
                    *(rel(got, ref) for got, ref in zip(kernels.gravity(q), gravity_ref)))
        c_ref = plant.CalcCenterOfMassPositionInWorld(ctx)
        worst = max(worst, rel(kernels.com(q)[0], c_ref))
        for b in range(len(tree.names)):
            X = plant.GetBodyByName(tree.names[b]).EvalPoseInWorld(ctx)
            pos, _ = kernels.frame_points(q, b, np.eye(3), np.zeros(3), np.zeros((1, 3)))
            R, _ = kernels.frame_rotation(q, b, np.eye(3))
            worst = max(worst, float(np.max(np.abs(pos[0] - X.translation())))
                        / max(1.0, float(np.max(np.abs(X.translation())))),
                        rel(R, X.rotation().matrix()))
    return worst


_KERNELS: dict[str, TreeKernels | Exception] = {}


def tree_kernels(robot) -> TreeKernels:
    """The checked tree kernels of ``robot``'s plant (built once per plant name; a plant whose
    numbers differ from the cached one's gets its own). Raises ``NotImplementedError``."""
    tree = None
    hit = _KERNELS.get(robot.name)
    if isinstance(hit, TreeKernels) and hit.plant is robot.plant:
        return hit
    if isinstance(hit, TreeKernels):
        tree = extract_tree(robot.plant)
        if tree_source(tree) == hit.source:
            hit.plant = robot.plant
            return hit
        hit = None
    if hit is None:
        try:
            tree = tree if tree is not None else extract_tree(robot.plant)
            k = TreeKernels(tree, robot.name)
            k.plant = robot.plant
            err = self_check(robot.plant, k)
            if not err <= SELF_CHECK_RTOL:
                raise Unsupported(f"tree kernels disagree with Drake (relative error {err:.1e})")
            hit = k
        except (NotImplementedError, c_backend.CompileUnavailable, OSError) as exc:
            hit = exc
        _KERNELS[robot.name] = hit
    if isinstance(hit, Exception):
        raise NotImplementedError(f"{robot.name}: {hit}")
    return hit
