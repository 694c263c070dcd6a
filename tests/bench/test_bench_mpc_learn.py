"""bench/mpc_learn.py's page per experiment file, and the effort-toward-gravity variant of the payload problem."""

from pathlib import Path

import pytest

from bench import mpc_learn

ROOT = Path(__file__).resolve().parents[2]
GRAV = ROOT / "experiments" / "ur5_payload_push_mpc_learn_grav.toml"


def test_page_names_follow_the_experiment_file():
    assert mpc_learn.page_name(mpc_learn.FIRST) == "mpc_learn"
    assert mpc_learn.page_name(GRAV) == "mpc_learn_grav"
    assert mpc_learn.page_name(Path("other.toml")) == "mpc_learn_other"


def test_the_variant_changes_only_the_effort_target(monkeypatch):
    """The grav experiment is the first one on the grav problem; the problem differs in the effort's target only."""
    import tomllib

    first, grav = (tomllib.loads(p.read_text()) for p in (mpc_learn.FIRST, GRAV))
    assert {k: v for k, v in first["base"].items() if k != "problem"} == \
        {k: v for k, v in grav["base"].items() if k != "problem"}
    assert first["point"] == grav["point"] and first["seeds"] == grav["seeds"]
    for path, effort in ((mpc_learn.FIRST, "zero"), (GRAV, "gravity")):
        monkeypatch.setattr(mpc_learn, "EXPERIMENT", path)
        assert mpc_learn.effort_target() == effort
    a, b = (tomllib.loads((p.parent / d["base"]["problem"]).read_text()) for p, d in
            ((mpc_learn.FIRST, first), (GRAV, grav)))
    assert b["costs"]["effort"].pop("target") == "gravity"
    assert {k: v for k, v in a.items() if k not in ("name", "description")} == \
        {k: v for k, v in b.items() if k not in ("name", "description")}
    from raico.planning.problem_file import read_problem

    pa, pb = (read_problem(p.parent / d["base"]["problem"]).doc for p, d in ((mpc_learn.FIRST, first), (GRAV, grav)))
    assert pb["costs"]["terms"]["effort"].pop("target") == "gravity"
    assert {k: v for k, v in pa.items() if k not in ("name", "description")} == \
        {k: v for k, v in pb.items() if k not in ("name", "description")}


def _doc(effort: str | None) -> dict:
    run = {"label": "MPC on the learned model", "seed": 0, "distance_m": [0.02, 0.009, 0.008],
           "status": ["ok"] * 3, "data_steps": [100] * 3, "tick_s": [0.1] * 3, "one_step_error": [0.03, 0.01, 0.01],
           "fit_s": [1.0] * 3, "plan_s": [1.0] * 3, "execute_s": [1.0] * 3}
    doc = {"model_file": [{"label": "plan's controller", "distance_m": 0.08, "status": "ok"}], "optimum": [],
           "runs": [run], "settings": {"episodes": 3}, "push": ["tool0:20:0.5:0.1"], "seeds": 1, "load": "1 1 1"}
    if effort:
        doc.update(effort=effort, problem="raico/problems/examples/ur5_payload_5kg_grav.toml",
                   experiment="experiments/ur5_payload_push_mpc_learn_grav.toml")
    return doc


@pytest.mark.parametrize("effort", [None, "gravity"])
def test_page_says_the_problem_and_its_effort(effort, tmp_path):
    text = mpc_learn.page(_doc(effort))
    if effort:
        assert "ur5_payload_5kg_grav.toml" in text and "u - g(q)" in text and "mpc_learn_grav.toml" in text
    else:   # a page of the first run's json (no problem stored): the first files
        assert "ur5_payload_5kg.toml`, the effort term toward zero torque" in text
    assert "| MPC on the learned model | 1 of 1 |" in text
    mpc_learn.plot(_doc(effort), tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 1000
