"""The Nao's motion panels and the counterbalance measures, on synthetic joint trajectories of the real Nao model."""

import numpy as np

from raico.plants.robots import shared_robot
from raico.thesis.figures import COUNTERBALANCE_JOINTS, counterbalance
from raico.thesis.panels import SKELETON, skeleton


def _plan(moved: tuple[str, ...], amount: float = 0.3) -> np.ndarray:
    """A plan ``X (21, n_x)`` from the default posture in which only the joints ``moved`` turn, linearly to
    ``amount`` rad."""
    robot = shared_robot("nao")
    q0 = np.asarray(robot.default_q, float)
    Q = np.tile(q0, (21, 1))
    for j in moved:
        Q[:, robot.joint_names.index(j)] += np.linspace(0.0, amount, 21)
    return np.hstack([Q, np.zeros_like(Q)])


def test_skeleton_chains_stand_on_the_welded_sole():
    robot = shared_robot("nao")
    X = _plan(())
    chains = skeleton(robot, X[:2, :robot.n_q])
    assert [c.shape for c in chains] == [(2, len(chain), 3) for chain in SKELETON]
    left_leg, head = chains[0], chains[-1]
    # the left sole is welded to the world: it does not move, and the head is above it
    assert np.array_equal(left_leg[0, 0], left_leg[1, 0])
    assert head[0, -1, 2] > left_leg[0, 0, 2] + 0.3


def test_counterbalance_drift_is_the_same_without_the_counterbalancing_joints_moving():
    """Held at their start, the head and left-arm joints change nothing: the two drifts are equal (the same
    positions, the same arithmetic); moved, they change the CoG's drift."""
    m = counterbalance(_plan(("RShoulderPitch", "RElbowRoll")))
    assert m["cog_drift"] == m["cog_drift_held"] and m["left_hand_excursion"] == 0.0
    m = counterbalance(_plan(("RShoulderPitch", *COUNTERBALANCE_JOINTS)))
    assert m["cog_drift"] != m["cog_drift_held"] and m["left_hand_excursion"] > 0.01
