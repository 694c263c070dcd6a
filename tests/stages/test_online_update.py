"""``--online-every``: the learned model's online update inside an MPC execution, its options and bad input."""

from pathlib import Path

import pytest

from raico.stages.execute.config import ExecuteConfig
from raico.stages.learn import LearnConfig


def test_online_every_is_an_mpc_option_and_not_negative():
    with pytest.raises(ValueError, match="--online-every is an option of --controller mpc"):
        ExecuteConfig(plan="x", online_every=5).validate()
    with pytest.raises(ValueError, match="--online-every must be 0"):
        ExecuteConfig(plan="x", controller="mpc", online_every=-1).validate()
    ExecuteConfig(plan="x", controller="mpc", online_every=5).validate()


PROBLEM = str(Path(__file__).resolve().parents[2] / "raico" / "problems" / "examples" / "ur5_payload_5kg.toml")


def test_learn_passes_online_every_to_the_episodes_executions():
    cfg = LearnConfig(problem=PROBLEM, controller="mpc", online_every=10, gp="sparse", inducing=50)
    assert cfg.execute_config("plan/k").online_every == 10
    assert LearnConfig(problem=PROBLEM).execute_config("plan/k").online_every == 0
    with pytest.raises(ValueError, match="--online-every is an option of --controller mpc"):
        LearnConfig(problem=PROBLEM, online_every=10).validate()
