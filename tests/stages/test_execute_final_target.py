"""``--final-target``: a term at the problem's last step in the MPC's window (receding end or fixed)."""

from __future__ import annotations

import numpy as np
import pytest

from raico.stages.execute.config import ARM_FINAL_TARGET, FINAL_TARGETS, ExecuteConfig
from tests.planning.test_solvers_lq import make_lq


def _final_term_times(mpc, name: str = "sT") -> list[list[int]]:
    return next([t.tolist() for t in per_tick] for c, per_tick in mpc._timed if c.name == name)


@pytest.mark.compiled
@pytest.mark.parametrize("final_target", [None, *FINAL_TARGETS])
def test_the_arms_mpc_follows_the_final_target_option(final_target):
    from raico.stages.execute.fixed import _mpc_for

    pb, H = make_lq(seed=3, T=30), 20
    plan = {"X": np.zeros((pb.T + 1, pb.n_x)), "U": np.zeros((pb.T, pb.n_u)), "o": np.zeros((pb.T, pb.n_u)),
            "O": np.zeros((pb.T, pb.n_u, pb.n_x))}
    cfg = ExecuteConfig(plan="x", controller="mpc", horizon=H, final_target=final_target)
    cfg.validate()
    mpc, _ = _mpc_for(cfg, pb, plan, 0.01, 0.001)
    times = _final_term_times(mpc)
    receding = (final_target or ARM_FINAL_TARGET) == "receding"
    assert times[0] == ([H] if receding else [])           # the problem's end (30) lies beyond the window
    assert times[pb.T - H] == [H] and times[pb.T - 1] == [1]  # inside the window: both alike


def test_the_defaults_per_controller():
    cfg = ExecuteConfig(plan="x", controller="mpc")
    assert cfg.receding_end(ARM_FINAL_TARGET) is (ARM_FINAL_TARGET == "receding")
    assert cfg.receding_end("fixed") is False       # the floating robot's MPC's default
    assert ExecuteConfig(plan="x", controller="mpc", final_target="receding").receding_end("fixed") is True


@pytest.mark.parametrize("kw, message", [
    ({"controller": "mpc", "final_target": "end"}, "--final-target must be one of receding, fixed"),
    ({"final_target": "fixed"}, "--final-target is an option of --controller mpc"),
])
def test_bad_final_target(kw, message):
    with pytest.raises(ValueError, match=message):
        ExecuteConfig(plan="x", **kw).validate()
