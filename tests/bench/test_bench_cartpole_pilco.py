"""bench/cartpole_pilco.py's measure and bench/cartpole_pilco_diagnosis.py's angle, without simulation."""

import math

import pytest

from bench import cartpole_pilco, cartpole_pilco_diagnosis


@pytest.mark.numerics
def test_wrap_is_the_distance_from_upright_over_whole_turns():
    for a, want in [(math.pi, 0.0), (math.pi + 0.3, 0.3), (math.pi - 0.3, 0.3), (3 * math.pi - 0.2, 0.2),
                    (0.0, math.pi), (-math.pi + 0.1, 0.1)]:
        assert cartpole_pilco_diagnosis.wrap(a) == pytest.approx(want, rel=0, abs=1e-9 * math.pi)


def test_seconds_to_upright_counts_the_babbling_and_the_episodes_up_to_the_first_upright():
    m = {"first_success_episode": 2, "babble_seconds": 4.0, "executed_seconds": [8.0, 4.0, 4.0]}
    assert cartpole_pilco.seconds_to_upright(m) == 16.0
    assert math.isinf(cartpole_pilco.seconds_to_upright({**m, "first_success_episode": None}))

