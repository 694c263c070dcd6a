"""Which exact dynamics model ``make_fast_or_exact`` builds: the symbolic route for plants of up to
``SYMBOLIC_MAX_POSITIONS`` positions (the built-in pendulum, arm5, biorob), the compiled kinematic
tree for larger ones (6- and 7-joint arms, whose symbolic derivation takes 10 s or fails after 30 s;
the Nao), each falling back to the other and then to Drake's AutoDiffXd model.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from raico.plants import fast_analytic as fa
from raico.plants.dynamics import AnalyticDynamics
from raico.plants.model_file import RobotSpec


def _fake(n: int):
    return SimpleNamespace(name=f"fake{n}", plant=SimpleNamespace(num_positions=lambda: n))


def _routes(monkeypatch, symbolic_ok: bool, tree_ok: bool) -> list[str]:
    """Replace the three models by recorders; returns the list of attempts (in order)."""
    tried: list[str] = []

    def model(kind: str, ok: bool):
        def build(robot, dt):
            tried.append(kind)
            if not ok:
                raise NotImplementedError(f"{kind} unavailable")
            return kind
        return build

    monkeypatch.setattr(fa, "FastAnalyticDynamics", model("symbolic", symbolic_ok))
    monkeypatch.setattr(fa, "TreeAnalyticDynamics", model("tree", tree_ok))
    monkeypatch.setattr(fa, "AnalyticDynamics", model("autodiff", True))
    return tried


@pytest.mark.parametrize("n,symbolic_ok,tree_ok,tried", [
    (1, True, True, ["symbolic"]),                          # the pendulum
    (5, True, True, ["symbolic"]),                          # arm5, biorob
    (5, False, True, ["symbolic", "tree"]),                 # a small plant the symbolic route refuses
    (6, True, True, ["tree"]),                              # a 6-joint arm: never derived symbolically
    (7, True, True, ["tree"]),
    (26, True, True, ["tree"]),                             # the Nao
    (7, True, False, ["tree", "symbolic"]),                 # no C compiler: the symbolic numpy code
    (7, False, False, ["tree", "symbolic", "autodiff"]),
    (3, False, False, ["symbolic", "tree", "autodiff"]),
])
def test_route_by_size(monkeypatch, n, symbolic_ok, tree_ok, tried):
    attempts = _routes(monkeypatch, symbolic_ok, tree_ok)
    assert fa.SYMBOLIC_MAX_POSITIONS == 5
    assert fa.make_fast_or_exact(_fake(n), 0.01) == tried[-1]
    assert attempts == tried


CHAIN = ["revolute", "revolute", "prismatic", "revolute", "revolute", "revolute"]


def chain_robot(name: str, kinds=CHAIN):
    """A serial chain of ``kinds`` joints (axes and offsets varied), base welded, actuated (rotor
    inertia, gear ratio 4), as a :class:`raico.plants.robots.Robot`."""
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant

    from raico.plants.robots import Robot

    axes = ["0 0 1", "0 1 0", "1 0 0.3", "1 0 0", "0 1 0", "0.2 0 1"]
    links, joints = [], ['<joint name="fix" type="fixed"><parent link="world"/><child link="l0"/></joint>']
    for i in range(len(kinds) + 1):
        links.append(f'<link name="l{i}"><inertial><origin xyz="{0.05 * i} 0.01 {0.1 - 0.01 * i}"/>'
                     f'<mass value="{1.5 - 0.15 * i}"/><inertia ixx="{0.01 + 0.001 * i}" ixy="0.0005" ixz="0" '
                     f'iyy="0.012" iyz="0" izz="{0.009 + 0.002 * i}"/></inertial></link>')
    for i, kind in enumerate(kinds):
        limit = '<limit lower="-0.3" upper="0.3" effort="50" velocity="1"/>' if kind == "prismatic" \
            else '<limit lower="-3" upper="3" effort="30" velocity="3"/>'
        joints.append(f'<joint name="j{i}" type="{kind}"><parent link="l{i}"/><child link="l{i + 1}"/>'
                      f'<origin xyz="0.02 {0.03 * (i % 2)} 0.2" rpy="{0.1 * i} 0 {-0.2 * i}"/>'
                      f'<axis xyz="{axes[i % len(axes)]}"/>{limit}<dynamics damping="{0.1 + 0.2 * i}"/></joint>')
    text = f'<?xml version="1.0"?><robot name="{name}">{"".join(links)}{"".join(joints)}</robot>'
    plant = MultibodyPlant(0.0)
    Parser(plant).AddModelsFromString(text, "urdf")
    for i in range(len(kinds)):
        act = plant.AddJointActuator(f"m{i}", plant.GetJointByName(f"j{i}"), 50.0)
        act.set_default_rotor_inertia(0.002 * (i + 1))
        act.set_default_gear_ratio(4.0)
    plant.Finalize()
    n = plant.num_positions()
    return Robot(name=name, plant=plant, scene_graph=None, builder=None,
                 joint_names=tuple(f"j{i}" for i in range(n)), P=np.eye(n), lower=-np.ones(n),
                 upper=np.ones(n), effort=np.full(n, 50.0), default_q=np.zeros(n), spec=RobotSpec(file=f"{name}.urdf"),
                 B_act=plant.MakeActuationMatrix())


@pytest.mark.numerics
@pytest.mark.compiled
def test_a_six_joint_arm_takes_the_tree_route_without_a_symbolic_derivation(monkeypatch):
    from raico.plants.codegen import c_backend

    if not c_backend.enabled():
        pytest.fail(f"compiled kernels unavailable ({c_backend.why_unavailable()}): this test is about them")

    def no_derivation(robot):
        raise AssertionError("the symbolic derivation was attempted")

    monkeypatch.setattr(fa, "compiled_dynamics", no_derivation)
    robot = chain_robot("test_chain6")
    dyn = fa.make_fast_or_exact(robot, 0.01)
    assert type(dyn) is fa.TreeAnalyticDynamics
    exact = AnalyticDynamics(robot, 0.01)
    rng = np.random.default_rng(0)
    for _ in range(3):
        x = np.concatenate([rng.uniform(-0.3, 0.3, 6), rng.standard_normal(6)])
        u = 5.0 * rng.standard_normal(6)
        for got, ref in zip(dyn.linearize(x, u), exact.linearize(x, u)):
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9 * max(1.0, np.abs(ref).max()))
