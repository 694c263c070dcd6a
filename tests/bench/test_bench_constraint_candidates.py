"""bench.constraint_candidates: its registry, the efforts-only problem and the page from a document (no planning)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bench import constraint_candidates as cc
from raico.planning.problem import Bounds
from tests.planning.test_solvers_lq import N_U, make_lq


def test_a_candidate_name_is_registered_once_and_the_box_qp_applies_to_a_control_box_only():
    assert {"unbounded", "lagrangian", "boxddp"} <= set(cc.CANDIDATES)
    with pytest.raises(ValueError, match="registered twice"):
        cc.register(cc.CANDIDATES["boxddp"])
    pb = make_lq(T=5)
    b = Bounds(u_lower=np.full(N_U, -1.0), u_upper=np.full(N_U, 1.0), q_index=np.array([0]),
               q_lower=np.array([-1.0]), q_upper=np.array([1.0]))
    boxed = dataclasses.replace(pb, bounds=b)
    assert cc.CANDIDATES["boxddp"].applies(boxed)
    assert not cc.CANDIDATES["boxddp"].applies(dataclasses.replace(pb, bounds=dataclasses.replace(
        b, u_lower=None, u_upper=None)))
    only = cc.efforts_only(boxed).bounds
    assert only.has_controls and not only.has_positions and not only.has_velocities


def test_the_page_has_a_row_per_run_and_names_what_was_not_measured():
    row = {"problem": "p", "label": "box", "budget": 40, "status": "converged", "final_cost": 1.5, "inside": False,
           "effort_excess": 0.0, "joint_range_excess": 0.1, "velocity_excess": 0.0, "first_inside": None,
           "at_box": 3, "iterations": 12, "cpu_s": 0.25}
    doc = {"date": "d", "load": (1.0, 1.0, 1.0), "cpus": 2, "rows": [row, {**row, "inside": True, "first_inside": 4}],
           "skipped": {"q": "no candidate beyond the augmented Lagrangian applies"}}
    text = cc.markdown(doc)
    assert "| p | box | 40 | converged | 1.5 | no (effort 0 N m, range 0.1 rad, speed 0 rad/s) | - | 3 | 12 | 0.2 |" \
        in text
    assert "| p | box | 40 | converged | 1.5 | yes | 4 | 3 | 12 |" in text
    assert "Not measured: q (no candidate" in text
