"""Where the compiled tree kernels are missing, the gravity term and the compiled task set fall back to
Drake's and Python's evaluation (the same numbers, slower); a fault while building them (an
``AttributeError``: a bug in the code) is raised, never taken for a missing capability.

``raico.plants.codegen.rbd.tree_kernels`` is replaced by one that raises, the one way to make it fail on
demand: the robot itself is real (the pendulum)."""

from __future__ import annotations

import pytest

from raico.planning.kernels import robot_kernels
from raico.plants.codegen import c_backend, rbd
from raico.plants.dynamics import GravityTorques
from raico.plants.fast_analytic import TreeGravityTorques, gravity_torques
from raico.plants.robots import shared_robot


def _raising(exc: BaseException):
    def tree_kernels(robot):
        raise exc
    return tree_kernels


@pytest.mark.parametrize("missing", [NotImplementedError("joint type planar"),
                                     c_backend.CompileUnavailable("no C compiler")])
def test_a_plant_without_tree_kernels_takes_the_slow_route(monkeypatch, missing):
    robot = shared_robot("pendulum")
    monkeypatch.setattr(rbd, "tree_kernels", _raising(missing))
    g = gravity_torques(robot)
    assert type(g) is GravityTorques and not isinstance(g, TreeGravityTorques)
    assert robot_kernels(robot) is None


def test_a_bug_while_building_the_tree_kernels_is_raised_not_taken_for_a_missing_route(monkeypatch):
    robot = shared_robot("pendulum")
    monkeypatch.setattr(rbd, "tree_kernels", _raising(AttributeError("'Tree' object has no attribute 'axes'")))
    with pytest.raises(AttributeError, match="no attribute 'axes'"):
        gravity_torques(robot)
    with pytest.raises(AttributeError, match="no attribute 'axes'"):
        robot_kernels(robot)
