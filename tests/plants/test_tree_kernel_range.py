"""The generated kinematic-tree kernels (``raico/plants/codegen/rbd_kernels.c`` with a tree's numbers baked
in, and the dynamics driver on top) over the range of trees they accept, not only the plants' trees:
1 to 70 joints, revolute, continuous and prismatic joints, welds between them, branching trees, and
trees welded to the world at a leaf (traversed against the joints' directions). Each tree is
self-checked against Drake when built (``tree_kernels``); then every kernel entry point runs at batch
lengths 1, 2, 4 and 17 with 1 and 21 points (``tests/planning/test_kernel_shapes.py``'s checks). Marked
``compiled``: ``make test-sanitize`` runs them under AddressSanitizer and UBSan.
"""

from __future__ import annotations

import numpy as np
import pytest

from raico.plants.model_file import RobotSpec, load_model
from tests.tolerance import assert_close, scale_of

pytestmark = [pytest.mark.compiled, pytest.mark.numerics]

INERTIA = '<inertia ixx="0.004" iyy="0.004" izz="0.002" ixy="0" ixz="0" iyz="0"/>'


def tree_urdf(n: int, branches: int, seed: int) -> str:
    """A tree of ``n`` moving joints (revolute, continuous, prismatic in turn, random axes), split into
    ``branches`` chains off the base, with a weld after every third joint."""
    rng = np.random.default_rng(seed)
    kinds = ("revolute", "continuous", "prismatic")
    parts = [f'<link name="base"><inertial><mass value="2"/>{INERTIA}</inertial></link>']
    tips = ["base"] * branches
    for k in range(n):
        b = k % branches
        axis = rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
        kind = kinds[k % 3]
        limit = '<limit lower="-0.5" upper="0.5" effort="50" velocity="5"/>' if kind != "continuous" else \
            '<limit effort="50" velocity="5"/>'
        xyz = " ".join(f"{v:.3f}" for v in 0.1 * rng.standard_normal(3) + [0, 0, 0.15])
        parts.append(f'<joint name="j{k}" type="{kind}"><parent link="{tips[b]}"/><child link="l{k}"/>'
                     f'<origin xyz="{xyz}" rpy="{rng.uniform(-1, 1):.3f} 0.2 0"/>'
                     f'<axis xyz="{axis[0]:.4f} {axis[1]:.4f} {axis[2]:.4f}"/>{limit}'
                     f'<dynamics damping="{0.01 * (k % 4)}"/></joint>')
        parts.append(f'<link name="l{k}"><inertial><origin xyz="0 0.02 0.07"/><mass value="{0.3 + 0.1 * (k % 5)}"/>'
                     f'{INERTIA}</inertial></link>')
        tips[b] = f"l{k}"
        if k % 3 == 2:  # a weld between moving joints
            parts.append(f'<joint name="w{k}" type="fixed"><parent link="l{k}"/><child link="f{k}"/>'
                         f'<origin xyz="0 0 0.05" rpy="0 0 0.3"/></joint>')
            parts.append(f'<link name="f{k}"><inertial><mass value="0.1"/>{INERTIA}</inertial></link>')
            tips[b] = f"f{k}"
    return f'<?xml version="1.0"?>\n<robot name="tree{n}">{"".join(parts)}</robot>\n'


# (joints, branches, welded at a leaf)
TREES = [(1, 1, False), (2, 1, True), (9, 3, False), (9, 2, True), (33, 4, False), (33, 1, True), (70, 5, False)]


@pytest.fixture(params=TREES, ids=[f"n{n}-b{b}{'-leaf' if leaf else ''}" for n, b, leaf in TREES])
def tree_robot(request, tmp_path):
    n, branches, leaf = request.param
    path = tmp_path / f"tree{n}.urdf"
    path.write_text(tree_urdf(n, branches, seed=n + branches))
    weld = f"l{n - 1}" if leaf else None   # the last link welded to the world: the tree re-rooted there
    return load_model(RobotSpec(file=str(path), weld=weld, armature=0.01))


def test_tree_kernels_over_the_range_of_trees(tree_robot, monkeypatch):
    from raico.plants.codegen import c_backend, rbd
    from raico.plants.fast_analytic import TreeAnalyticDynamics
    from tests.planning import test_kernel_shapes as shapes

    if not c_backend.enabled():
        pytest.fail(f"compiled kernels unavailable ({c_backend.why_unavailable()}): these tests are about them")
    k = rbd.tree_kernels(tree_robot)   # self-checked against Drake's M, h and dID (float and AutoDiffXd)
    assert k.m == tree_robot.n_q
    monkeypatch.setattr(shapes, "shared_robot", lambda name: tree_robot)
    monkeypatch.setattr(shapes, "_dynamics", lambda name: (tree_robot, TreeAnalyticDynamics(tree_robot, 0.01)))
    shapes.test_tree_kernels_at_every_shape(tree_robot.name)
    shapes.test_compiled_dynamics_batches_at_every_length(tree_robot.name)
    # the mass matrix and inverse dynamics against Drake at a state away from the self-check's
    rng = np.random.default_rng(1)
    q, v, a = (0.4 * rng.standard_normal(k.m) for _ in range(3))
    plant, ctx = tree_robot.plant, tree_robot.plant.CreateDefaultContext()
    plant.SetPositions(ctx, q)
    plant.SetVelocities(ctx, v)
    M = plant.CalcMassMatrix(ctx)
    assert_close(k.mass_matrix(q), M)  # Drake counts the armature too


def _central_differences(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """``df/dx (len f, len x)`` by central differences of step ``h``."""
    return np.stack([(f(x + h * e) - f(x - h * e)) / (2.0 * h) for e in np.eye(x.size)], axis=1)


def test_analytical_dynamics_derivatives_over_the_range_of_trees(tree_robot):
    """The analytical derivatives of the inverse dynamics (``tree_id_analytic``: the dynamics driver's
    ``M``, ``ID`` and ``dID/d(q, v)``) against Drake's float and AutoDiffXd evaluation and the forward-mode
    kernel, relative to their scale, and against central differences of the inverse dynamics; the driver's
    ``qddot`` derivatives on top against Drake's ``AnalyticDynamics`` (AutoDiffXd) and central differences of
    ``qddot``."""
    from raico.plants.codegen import rbd
    from raico.plants.codegen.reference import DrakeReference
    from raico.plants.dynamics import AnalyticDynamics
    from raico.plants.fast_analytic import TreeAnalyticDynamics

    k = rbd.tree_kernels(tree_robot)
    m = k.m
    rng = np.random.default_rng(7)
    q, v, a, u = 0.4 * rng.standard_normal(m), rng.standard_normal(m), rng.standard_normal(m), rng.standard_normal(m)
    tau, M, D = k.id_analytic(q, v, a)
    M_ref, tau_ref, _, D_ref = DrakeReference(tree_robot.plant).evaluate(q, v, a)
    assert_close(tau, tau_ref)
    assert_close(M, M_ref)
    assert_close(D, D_ref)
    assert_close(D, k.id_derivatives(q, v, a))
    # central differences: truncation h^2 and rounding eps / h, about 1e-10 of the scale
    assert_close(D, _central_differences(lambda z: k.id_analytic(z[:m], z[m:], a)[0], np.concatenate([q, v])),
                 rel=1e-6)
    dyn, exact = TreeAnalyticDynamics(tree_robot, 0.01), AnalyticDynamics(tree_robot, 0.01)
    got, ref = dyn.qddot_derivatives(q, v, u), exact.qddot_derivatives(q, v, u)
    for g, r in zip(got, ref):   # relative to the largest derivative (one may vanish: a single joint's d/dq)
        assert_close(g, r, scale=scale_of(*ref[1:]))
    fd = _central_differences(lambda z: dyn.qddot(z[:m], z[m:2 * m], z[2 * m:]), np.concatenate([q, v, u]))
    assert_close(np.hstack(got[1:]), fd, rel=1e-6)


def test_gravity_torques_and_their_jacobian_over_the_range_of_trees(tree_robot):
    """The gravity torques' one pass (``tree_gravity``: the analytical derivatives at rest) equals the
    Newton-Euler torques and the forward-mode ``dID/dq`` at ``v = a = 0`` (the same derivative: to rounding),
    Drake's float and AutoDiffXd evaluation at rest, and central differences of the torques; without the
    Jacobian it gives the same torques."""
    from raico.plants.codegen import rbd
    from raico.plants.codegen.reference import DrakeReference

    k = rbd.tree_kernels(tree_robot)
    m, zero = k.m, np.zeros(k.m)
    rng = np.random.default_rng(5)
    drake = DrakeReference(tree_robot.plant)
    for q in (0.4 * rng.standard_normal(m), rng.uniform(-np.pi, np.pi, m)):
        g, G = k.gravity(q)
        assert G is not None
        scale = scale_of(g, G)   # one joint's torque or derivative may vanish (an axis along gravity)
        assert_close(g, k.inverse_dynamics(q, zero, zero), scale=scale)
        assert_close(G, k.id_derivatives(q, zero, zero)[:, :m], scale=scale)
        _, tau_ref, _, D_ref = drake.evaluate(q, zero, zero)
        assert_close(g, tau_ref, scale=scale)
        assert_close(G, D_ref[:, :m], scale=scale)
        g_only, none = k.gravity(q, jacobian=False)
        assert none is None and np.array_equal(g_only, g)
        # central differences: truncation h^2 and rounding eps / h, about 1e-10 of the scale
        assert_close(G, _central_differences(lambda z: k.gravity(z, jacobian=False)[0], q), rel=1e-6, scale=scale)
    with pytest.raises(ValueError):
        k.gravity(np.zeros(m + 1))
