"""Prismatic joints in the compiled kinematic-tree route (``raico.plants.codegen.rbd``).

A revolute-prismatic-revolute chain with joint damping, geared actuators (reflected inertia = rotor
inertia x gear ratio^2) and welds (base to world, a tool on the last link), loaded by Drake's
parser; once as written and once re-rooted at the tool (welded to the world, so the tree is
traversed against the joints' directions). The tree kernels against Drake: mass matrix, inverse
dynamics and its derivatives (AutoDiffXd), body poses, point / angular / centre-of-mass Jacobians;
the dynamics model on top (``TreeAnalyticDynamics``) against Drake's ``AnalyticDynamics``; the task
maps on the tree against finite differences; and the kernel shape checks of
``tests/planning/test_kernel_shapes.py`` run on this robot.
"""

from __future__ import annotations

import numpy as np
import pytest

from raico.plants.codegen import c_backend, rbd
from raico.plants.codegen.reference import DrakeReference
from raico.plants.model_file import RobotSpec
from tests.tolerance import REL, assert_close, bound, scale_of

pytestmark = [pytest.mark.compiled, pytest.mark.numerics]

URDF = """<?xml version="1.0"?>
<robot name="rpr">
  <link name="base"><inertial><mass value="2.0"/>
    <inertia ixx="0.02" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.02"/></inertial></link>
  <link name="l1"><inertial><origin xyz="0.1 0.02 -0.03" rpy="0.2 0 0.1"/><mass value="1.3"/>
    <inertia ixx="0.011" ixy="0.001" ixz="-0.002" iyy="0.013" iyz="0.0005" izz="0.009"/></inertial></link>
  <link name="slider"><inertial><origin xyz="0.05 -0.04 0.12" rpy="0 0.3 -0.2"/><mass value="0.8"/>
    <inertia ixx="0.004" ixy="0.0003" ixz="0" iyy="0.006" iyz="-0.0004" izz="0.005"/></inertial></link>
  <link name="l3"><inertial><origin xyz="0.2 0 0.01"/><mass value="0.6"/>
    <inertia ixx="0.002" ixy="0" ixz="0" iyy="0.008" iyz="0" izz="0.008"/></inertial></link>
  <link name="tool"><inertial><origin xyz="0.03 0 0"/><mass value="0.2"/>
    <inertia ixx="0.0002" ixy="0" ixz="0" iyy="0.0003" iyz="0" izz="0.0003"/></inertial></link>
  BASE_WELD
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1" rpy="0 0 0.4"/>
    <axis xyz="0 0.6 0.8"/><limit lower="-3" upper="3" effort="50" velocity="5"/>
    <dynamics damping="0.3"/></joint>
  <joint name="j2" type="prismatic"><parent link="l1"/><child link="slider"/>
    <origin xyz="0.3 0.05 0" rpy="0.5 0.1 -0.3"/><axis xyz="1 -1 0.5"/>
    <limit lower="-0.5" upper="0.5" effort="100" velocity="1"/><dynamics damping="DAMPING"/></joint>
  <joint name="j3" type="revolute"><parent link="slider"/><child link="l3"/><origin xyz="0.1 0 0.2" rpy="-0.3 0.2 0"/>
    <axis xyz="1 0 0"/><limit lower="-3" upper="3" effort="20" velocity="5"/><dynamics damping="0.05"/></joint>
  <joint name="tool_weld" type="fixed"><parent link="l3"/><child link="tool"/>
    <origin xyz="0.4 0.01 -0.02" rpy="0 0.5 0"/></joint>
</robot>
"""
BASE_WELD = ('<joint name="world_base" type="fixed"><parent link="world"/><child link="base"/>'
             '<origin xyz="0.1 -0.2 0.5" rpy="0.1 -0.2 0.3"/></joint>')
ROTOR, GEAR = (0.01, 0.02, 0.005), (3.0, 2.0, 5.0)   # reflected inertia 0.09, 0.08 (kg), 0.125


def make_robot(name: str, rerooted: bool = False, damping: float = 1.7, rotor=ROTOR):
    """The chain as a :class:`raico.plants.robots.Robot` (``P`` the identity); ``rerooted``: the tool
    welded to the world instead of the base. ``name`` keys the tree-kernel cache: one per variant."""
    from pydrake.math import RigidTransform, RollPitchYaw
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder

    from raico.plants.robots import Robot

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    text = URDF.replace("BASE_WELD", "" if rerooted else BASE_WELD).replace("DAMPING", repr(damping))
    Parser(plant).AddModelsFromString(text, "urdf")
    if rerooted:
        plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("tool"),
                         RigidTransform(RollPitchYaw(0.2, 0.1, -0.4), [0.3, 0.1, 0.6]))
    for jname, r, g in zip(("j1", "j2", "j3"), rotor, GEAR):
        act = plant.AddJointActuator(f"{jname}_motor", plant.GetJointByName(jname), 100.0)
        act.set_default_rotor_inertia(r)
        act.set_default_gear_ratio(g)
    plant.Finalize()
    joints = [plant.GetJointByName(j) for j in ("j1", "j2", "j3")]
    joints.sort(key=lambda j: j.position_start())
    n = plant.num_positions()
    return Robot(name=name, plant=plant, scene_graph=scene_graph, builder=builder,
                 joint_names=tuple(j.name() for j in joints), P=np.eye(n),
                 lower=np.array([j.position_lower_limits()[0] for j in joints]),
                 upper=np.array([j.position_upper_limits()[0] for j in joints]),
                 effort=np.full(n, 100.0), default_q=np.array([0.3, -0.2, 0.5][:n]),
                 spec=RobotSpec(file=f"{name}.urdf", end_effectors=(("tool", "tool"),)), B_act=plant.MakeActuationMatrix())


@pytest.fixture(scope="module", params=[False, True], ids=["base-welded", "rerooted-at-tool"])
def robot(request):
    if not c_backend.enabled():
        pytest.fail(f"compiled kernels unavailable ({c_backend.why_unavailable()}): these tests are about them")
    return make_robot(f"test_rpr_{'rerooted' if request.param else 'base'}", rerooted=request.param)


def _states(m: int, K: int, seed: int):
    rng = np.random.default_rng(seed)
    for _ in range(K):
        yield rng.uniform(-1.5, 1.5, m), 2.0 * rng.standard_normal(m), 3.0 * rng.standard_normal(m)


def test_tree_reads_the_prismatic_joint(robot):
    tree = rbd.extract_tree(robot.plant)
    j2 = robot.plant.GetJointByName("j2")
    assert tree.prismatic.sum() == 1 and tree.qidx[tree.prismatic][0] == j2.position_start()
    np.testing.assert_allclose(tree.damping[j2.position_start()], 1.7)
    reflected = {robot.plant.GetJointByName(j).position_start(): r * g * g for j, r, g in zip(("j1", "j2", "j3"), ROTOR, GEAR)}
    # rotor * gear^2: two products, rounded in either order
    np.testing.assert_allclose(tree.reflected, [reflected[k] for k in range(3)], rtol=bound(2))
    assert rbd.self_check(robot.plant, rbd.tree_kernels(robot), n_states=2, seed=3) <= REL


def test_dynamics_against_drake(robot):
    """``M``, ``ID(q, v, a)`` and ``dID/d(q, v)`` (Drake's AutoDiffXd) at random states, by forward mode
    and by the analytical derivatives."""
    k = rbd.tree_kernels(robot)
    drake = DrakeReference(robot.plant)
    for q, v, a in _states(k.m, 5, seed=1):
        M, tau, _, D = drake.evaluate(q, v, a)
        assert_close(k.mass_matrix(q), M)
        assert_close(k.inverse_dynamics(q, v, a), tau)
        assert_close(k.id_derivatives(q, v, a), D)
        for got, ref in zip(k.id_analytic(q, v, a), (tau, M, D)):   # the dynamics driver's route
            assert_close(got, ref)


def test_kinematics_and_jacobians_against_drake(robot):
    """Every body's pose, a point's translational Jacobian, the angular and the centre-of-mass
    Jacobians (the prismatic joint: translation along its axis, no rotation)."""
    from pydrake.multibody.tree import JacobianWrtVariable

    plant, k = robot.plant, rbd.tree_kernels(robot)
    ctx = plant.CreateDefaultContext()
    world, wrt = plant.world_frame(), JacobianWrtVariable.kV
    pts = np.array([[0.0, 0.0, 0.0], [0.1, -0.2, 0.05]])
    moved = 0.0
    for q, _, _ in _states(k.m, 4, seed=2):
        plant.SetPositions(ctx, q)
        for b, name in enumerate(k.tree.names):
            frame = plant.GetBodyByName(name).body_frame()
            X = frame.CalcPoseInWorld(ctx)
            pos, J = k.frame_points(q, b, np.eye(3), np.zeros(3), pts)
            R, Jw = k.frame_rotation(q, b, np.eye(3))
            # metres and radians of a robot of about 1 m: scale 1
            assert_close(pos, (X.rotation().matrix() @ pts.T).T + X.translation(), scale=1.0)
            assert_close(R, X.rotation().matrix(), scale=1.0)
            J_ref = plant.CalcJacobianTranslationalVelocity(ctx, wrt, frame, pts.T, world, world)
            assert_close(J, J_ref, scale=1.0)
            assert_close(Jw, plant.CalcJacobianAngularVelocity(ctx, wrt, frame, world, world), scale=1.0)
        c, Jc = k.com(q)
        assert_close(c, plant.CalcCenterOfMassPositionInWorld(ctx), scale=1.0)
        assert_close(Jc, plant.CalcJacobianCenterOfMassTranslationalVelocity(ctx, wrt, world, world), scale=1.0)
        moved = max(moved, abs(q[plant.GetJointByName("j2").position_start()]))
    assert moved > 0.5   # the slider was far from 0


def test_damping_and_reflected_inertia_of_the_prismatic_joint():
    """Other damping and rotor inertia on the prismatic joint change its torque by exactly
    ``d_damping v + d_reflected a`` (and nothing else): both are read for prismatic joints."""
    a_robot = make_robot("test_rpr_damping_a", damping=1.7)
    b_robot = make_robot("test_rpr_damping_b", damping=4.2, rotor=(ROTOR[0], 0.05, ROTOR[2]))
    ka, kb = rbd.tree_kernels(a_robot), rbd.tree_kernels(b_robot)
    i = a_robot.plant.GetJointByName("j2").position_start()
    for q, v, a in _states(3, 3, seed=4):
        diff = kb.inverse_dynamics(q, v, a) - ka.inverse_dynamics(q, v, a)
        want = np.zeros(3)
        want[i] = (4.2 - 1.7) * v[i] + (0.05 - 0.02) * GEAR[1] ** 2 * a[i]
        # a difference of two torques: zero up to their rounding, so their scale counts
        assert_close(diff, want, scale=scale_of(ka.inverse_dynamics(q, v, a)))
        dM = np.zeros((3, 3))
        dM[i, i] = (0.05 - 0.02) * GEAR[1] ** 2
        assert_close(kb.mass_matrix(q) - ka.mass_matrix(q), dM, scale=scale_of(ka.mass_matrix(q)))


def test_tree_dynamics_model_against_drakes_analytic_model(robot):
    """``TreeAnalyticDynamics`` (the C driver on the tree kernels) against ``AnalyticDynamics``
    (Drake, AutoDiffXd): the step and its linearization."""
    from raico.plants.dynamics import AnalyticDynamics
    from raico.plants.fast_analytic import TreeAnalyticDynamics

    tree, exact = TreeAnalyticDynamics(robot, 0.01), AnalyticDynamics(robot, 0.01)
    for q, v, u in _states(3, 4, seed=6):
        x = np.concatenate([q, v])
        assert_close(tree.step(x, u), exact.step(x, u), scale=scale_of(x, u))
        for got, ref in zip(tree.linearize(x, u), exact.linearize(x, u)):
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9 * max(1.0, np.abs(ref).max()))


def test_task_maps_on_the_prismatic_tree(robot):
    """Task maps through the tree kernels against finite differences and Drake's route."""
    from raico.plants.numdiff import check_taskmap
    from raico.plants.taskmaps import CenterOfMass, FramePlacementError, FramePoints, RollAngle

    R_t = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    maps = [FramePoints(robot, "tool", points=[[0, 0, 0], [0.1, 0.02, 0]]), CenterOfMass(robot),
            RollAngle(robot, "tool"), FramePlacementError(robot, "tool", R_t, [0.3, 0.2, 0.4])]
    Q = np.random.default_rng(8).uniform(-1.0, 1.0, (3, 3))
    for tm in maps:
        assert tm.tree_kernels() is not None
        check_taskmap(tm, Q).assert_passed()
        for q in Q:
            v_c, J_c = tm._compiled_in_plant(tm.tree_kernels(), q)
            v_d, J_d = tm._in_plant(q)
            assert_close(v_c, v_d, scale=1.0)
            assert_close(J_c, J_d, scale=1.0)


def test_the_kernel_shape_checks_on_the_prismatic_tree(robot, monkeypatch):
    """The shape checks of ``tests/planning/test_kernel_shapes.py`` (tree kernels' batches against single calls,
    refused shapes; the compiled dynamics' batches and rollouts) with this robot in the place of a plant."""
    from raico.plants.fast_analytic import TreeAnalyticDynamics
    from tests.planning import test_kernel_shapes as shapes

    monkeypatch.setattr(shapes, "shared_robot", lambda name: robot)
    monkeypatch.setattr(shapes, "_dynamics", lambda name: (robot, TreeAnalyticDynamics(robot, 0.01)))
    shapes.test_tree_kernels_at_every_shape(robot.name)
    shapes.test_compiled_dynamics_batches_at_every_length(robot.name)


def test_a_wrong_prismatic_axis_is_refused_by_the_self_check():
    """The self-check sees a prismatic joint read wrongly (here: as revolute about its axis)."""
    robot = make_robot("test_rpr_wrong_axis")
    tree = rbd.extract_tree(robot.plant)
    tree.prismatic[:] = False
    k = rbd.TreeKernels(tree, "test_rpr_wrong_axis")
    assert rbd.self_check(robot.plant, k, n_states=1) > 1e-3
