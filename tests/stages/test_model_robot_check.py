"""``plan --model``: the fit's ``fit.json`` says which robot its GP was fit on, and a GP of another
robot is refused. A fit whose ``fit.json`` is missing, damaged or names no plant is refused in one
line too (the fit stage always writes it): its robot cannot be checked, and a GP of another robot with
as many joints would plan silently wrong."""

from __future__ import annotations

import json

import pytest

from raico.plants.robots import shared_robot
from raico.stages.base import Artifact
from raico.stages.plan.stage import check_model_robot

KEY = "0123456789abcdef"


def _fit(tmp_path, text: str | bytes | None) -> Artifact:
    """A fit entry whose ``fit.json`` holds ``text`` (none written for ``None``)."""
    folder = tmp_path / "fit" / KEY
    folder.mkdir(parents=True)
    if text is not None:
        (folder / "fit.json").write_bytes(text if isinstance(text, bytes) else text.encode())
    return Artifact("fit", KEY, folder, {"status": "ok"})


def test_a_gp_of_this_robot_passes_and_one_of_another_is_refused(tmp_path):
    robot = shared_robot("pendulum")
    check_model_robot(_fit(tmp_path / "a", json.dumps({"plant": "pendulum"})), robot)
    with pytest.raises(ValueError, match=f"--model {KEY} is a GP of arm5, this problem's robot is pendulum"):
        check_model_robot(_fit(tmp_path / "b", json.dumps({"plant": "arm5"})), robot)


@pytest.mark.parametrize("text, why", [
    (None, r"its fit.json cannot be read \(FileNotFoundError: "),
    ('{"plant": "pendu', r"its fit.json cannot be read \(JSONDecodeError: Unterminated string"),
    (b'{"plant": "\xff"}', r"its fit.json cannot be read \(UnicodeDecodeError: "),
    (json.dumps({"n_points": 3}), "its fit.json names no plant"),
    (json.dumps(["pendulum"]), "its fit.json names no plant"),
])
def test_a_fit_json_that_cannot_be_read_is_refused_in_one_line(tmp_path, text, why):
    with pytest.raises(ValueError, match=why) as err:
        check_model_robot(_fit(tmp_path, text), shared_robot("pendulum"))
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"--model {KEY}: ") and msg.endswith("cannot be checked: fit it again")
