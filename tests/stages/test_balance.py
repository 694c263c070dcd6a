"""The balance-aware Nao objective (``raico.stages.plan.balance``): the support term's
values, the polygon geometry, the infeasibility check of CoG via-points before planning, and
``raico plan --balance`` end to end. The term's derivatives against finite differences:
``tests/plants/test_derivatives.py`` (the ``support_polygon`` and ``lower_bound`` examples)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from raico.pipeline.interface.cli import app
from raico.planning import objective as ob
from raico.planning.costs import TaskInequality
from raico.plants.polygons import halfplanes, nearest_feasible, shrink, signed_margin
from raico.plants.robots import shared_robot
from raico.plants.taskmaps import CenterOfMass, JointPositions
from raico.stages.plan.balance import (
    MARGIN,
    NO_BALANCE_MARGIN,
    apply_balance,
    cog_margins,
    sole_corners,
    support_polygon,
)
from raico.stages.plan.stage import PlanConfig, build_problem, objective_from_description
from tests.tolerance import REL, assert_close, close

pytestmark = pytest.mark.compiled   # reaches a C kernel: run under the sanitizers too

runner = CliRunner()
SOLE = shared_robot("nao").support_polygon  # x in [-0.055, 0.105], y in [-0.044, 0.044] (m)


def _sole_term(margin: float = 0.015) -> TaskInequality:
    """The sole polygon with a margin on a 2-d point ``phi(q) = q`` (m)."""
    A, b = halfplanes(SOLE)
    return TaskInequality(JointPositions(2), A, b - margin, None, 1e6, name="support")


def _x(p) -> np.ndarray:
    return np.r_[p, 0.0, 0.0][None, :]  # a state (q, qdot) with q = p


@pytest.mark.numerics
def test_support_term_is_zero_inside_with_margin_and_grows_outside():
    term = _sole_term()
    for p in ([0.0, 0.0], [0.08, 0.02], [-0.035, -0.028], [0.0899, 0.0289]):  # at least 1.5 cm in
        assert term.value(_x(p))[0] == 0.0
        lx, lxx = term.derivatives(_x(p))
        assert not lx.any() and not lxx.any()
    # moving out across the left edge (y = 0.044): inside the margin band, on the edge, outside
    ys = np.array([0.0295, 0.035, 0.044, 0.06, 0.1, 0.2])
    costs = np.array([term.value(_x([0.02, y]))[0] for y in ys])
    assert np.all(np.diff(costs) > 0)
    np.testing.assert_allclose(costs, 1e6 * (ys - (0.044 - 0.015)) ** 2, rtol=1e-9)
    # past a corner two edges count
    assert term.value(_x([0.2, 0.2]))[0] == pytest.approx(1e6 * ((0.2 - 0.09) ** 2 + (0.2 - 0.029) ** 2))
    # the gradient points out, the Gauss-Newton Hessian is 2 w a a^T on the violated edge
    lx, lxx = term.derivatives(_x([0.02, 0.06]))
    np.testing.assert_allclose(lx[0, :2], [0.0, 2e6 * (0.06 - 0.029)], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(lxx[0, :2, :2], [[0.0, 0.0], [0.0, 2e6]], atol=1e-6)
    assert not lx[0, 2:].any() and not lxx[0, 2:].any()


@pytest.mark.numerics
def test_polygon_geometry_on_the_sole():
    A, b = halfplanes(SOLE)
    np.testing.assert_allclose(np.linalg.norm(A, axis=1), 1.0)
    assert np.all(b - A @ SOLE.mean(0) > 0)  # counter-clockwise: outward normals
    assert signed_margin(SOLE, np.array([0.0, 0.0])) == pytest.approx(0.044)
    assert signed_margin(SOLE, np.array([0.0, 0.1])) == pytest.approx(-0.056)
    assert signed_margin(SOLE, np.array([0.125, 0.064])) == pytest.approx(-np.hypot(0.02, 0.02))
    inner = shrink(SOLE, 0.015)
    # positions in metres on a robot of about 1 m: equal up to rounding at that scale
    assert_close(np.sort(inner, axis=0), np.sort([[-0.04, -0.029], [0.09, -0.029], [0.09, 0.029],
                                                  [-0.04, 0.029]], axis=0), scale=1.0)
    assert_close(nearest_feasible(SOLE, 0.015, np.array([0.0, 0.1])), [0.0, 0.029], scale=1.0)
    assert_close(nearest_feasible(SOLE, 0.015, np.array([0.2, -0.2])), [0.09, -0.029], scale=1.0)
    np.testing.assert_allclose(nearest_feasible(SOLE, 0.015, np.array([0.01, 0.02])), [0.01, 0.02])
    with pytest.raises(ValueError, match="no point 0.05 m inside"):
        shrink(SOLE, 0.05)


def _cog_via(target, step: int = 10) -> dict:
    return ob.via("via_cog", ob.cog(), target, [step], 1.0, [10.0, 1e6, 10.0])


@pytest.mark.numerics
@pytest.mark.parametrize("mode", ["support", "single"])
def test_infeasible_via_point_is_reported_and_moved_feasible_one_is_not(mode):
    nao = shared_robot("nao")
    q0 = nao.default_q
    poly = support_polygon(nao, q0, mode)
    c0 = CenterOfMass(nao).value(q0)
    # inside: the start posture's CoG (over the left sole, 4.4 cm from its side edges)
    terms, rep = apply_balance(nao, q0, 20, [_cog_via(c0)], mode)
    assert rep.moved == [] and rep.line() is None and terms[0]["target"] == c0.tolist()
    assert "requested_target" not in terms[0]
    # outside: 5 cm beyond the left sole's outer edge (y = +0.044 m, both modes' outer edge)
    target = np.array([0.02, 0.094, c0[2]])
    terms, rep = apply_balance(nao, q0, 20, [_cog_via(target, 10)], mode)
    (m,) = rep.moved
    assert (m.name, m.step) == ("via_cog", 10) and m.static_margin == pytest.approx(-0.05, abs=1e-9)
    assert terms[0]["requested_target"] == target.tolist()
    assert_close(terms[0]["target"], [0.02, 0.044 - MARGIN, c0[2]], scale=1.0)
    assert signed_margin(poly, np.array(terms[0]["target"][:2])) == pytest.approx(MARGIN)
    line = rep.line()
    assert "\n" not in line and "via_cog (step 10) is statically infeasible" in line
    assert "0.0500 m outside the support polygon" in line and f"planned at (0.0200, {0.044 - MARGIN:.4f}) m" in line
    # the support term is at every step 1..T; single support drops the right sole's hold
    names = [d["name"] for d in terms]
    assert names == (["via_cog", "support", "joint_range"] if mode == "support" else
                     ["via_cog", "support", "joint_range", "r_sole_clear", "r_sole_lift"])
    if mode == "single":  # the right sole's four corners above ground to step T/3 - 1, lifted from T/3
        clear, lift = terms[3], terms[4]
        assert clear["times"] == {"from": 1, "to": 5} and lift["times"] == {"from": 6, "to": 20}
        assert close(clear["b"], np.zeros(4), scale=1.0) and lift["b"] == [-0.025] * 4
        assert lift["A"] == clear["A"] == (-np.eye(4)).tolist()
    support = next(d for d in terms if d["name"] == "support")
    assert support["times"] == {"from": 1, "to": 20} and support["margin"] == MARGIN


@pytest.mark.numerics
def test_fig34_via_point_static_margins_from_the_model():
    """The thesis's +0.1 m CoG via-point (fig. 3.4): 5.5 cm beyond the stance sole's outer edge
    with raico's posture, about 6 mm with the zero posture."""
    nao = shared_robot("nao")
    for q, want in ((nao.default_q, -0.0553), (np.zeros(nao.n_q), -0.0060)):
        c = CenterOfMass(nao).value(q)
        for mode in ("support", "single"):
            poly = support_polygon(nao, q, mode)
            assert signed_margin(poly, c[:2] + [0.0, 0.1]) == pytest.approx(want, abs=5e-4)
    # the -0.1 m one is over the right foot: feasible in double support only
    c = CenterOfMass(nao).value(nao.default_q)
    assert signed_margin(support_polygon(nao, nao.default_q, "support"), c[:2] - [0.0, 0.1]) > MARGIN
    assert signed_margin(support_polygon(nao, nao.default_q, "single"), c[:2] - [0.0, 0.1]) < -0.05


def test_balance_none_leaves_the_task_as_it_is():
    cfg = dict(plant="nao", task="balance", seed=3)
    _, _, pb, _, desc = build_problem(PlanConfig(**cfg))
    _, _, pb_s, _, desc_s = build_problem(PlanConfig(**cfg, balance="support"))
    assert "balance" not in desc and pb.term_names() == ["via_cog1", "via_cog2", "via_cog3", "r_sole", "control"]
    assert pb_s.term_names() == ["via_cog1", "via_cog2", "via_cog3", "r_sole", "support", "joint_range", "control"]
    assert desc_s["terms"][:1] == desc["terms"][:1]  # the -0.1 m via-point is over the right foot: kept


def _run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.mark.numerics
def test_cli_balance_support_keeps_the_planned_cog_inside(tmp_path):
    res = _run("plan", "--plant", "nao", "--task", "balance-inside", "--balance", "support", "--solver", "raico",
               "--alpha", 1, "--iterations", 6, "--no-record", "--json", "--artifacts", tmp_path)
    assert res.exit_code == 0, res.output
    notes = [ln for ln in res.stderr.splitlines() if ln.startswith("balance ")]
    # seed 0's +0.03 m via-point lies within the 1.5 cm margin of the left sole's outer edge: said, moved
    assert len(notes) == 1 and re.search(r"via_cog2 \(step 200\) is within the margin: its CoG lies 0\.0\d{3} m "
                                         r"inside the support polygon", notes[0]), res.stderr
    line = json.loads(res.stdout.strip().splitlines()[-1])
    m = line["metrics"]
    assert m["balance"]["note"] == notes[0] and m["balance"]["mode"] == "support"
    folder = Path(line["path"])
    d = np.load(folder / "plan.npz")
    desc = json.loads((folder / "problem.json").read_text())
    nao = shared_robot("nao")
    poly = np.array(desc["balance"]["polygon"])
    # the polygon is both soles' hull at the start posture
    q0 = np.array(desc["q0"])
    hull_pts = np.vstack([sole_corners(nao, q0, s)[:, :2] for s in ("l_sole", "r_sole")])
    assert all(signed_margin(poly, p) > -REL for p in hull_pts)   # inside up to rounding (metres)
    margins = cog_margins(nao, d["X"][1:], poly)
    assert margins.min() >= MARGIN - 1e-3, margins.min()  # a soft penalty: to 1 mm
    assert m["balance"]["cog_min_margin"] == pytest.approx(margins.min(), rel=1e-9)
    assert m["via_point_errors"]["r_sole@max"] < 5e-3  # the right sole held at every step
    assert m["final_cost"] < m["initial_cost"]
    # the stored objective (execute and evaluate rebuild it) has the support term and its cost
    obj = objective_from_description(desc)
    support = next(t for t in obj.state_terms if t.name == "support")
    assert isinstance(support, TaskInequality) and support.times.tolist() == list(range(1, 301))
    # a cache hit says it again (never silently)
    again = _run("plan", "--plant", "nao", "--task", "balance-inside", "--balance", "support", "--solver", "raico",
                 "--alpha", 1, "--iterations", 6, "--no-record", "--json", "--artifacts", tmp_path)
    assert again.exit_code == 0 and json.loads(again.stdout.strip().splitlines()[-1])["cached"]
    assert [ln for ln in again.stderr.splitlines() if ln.startswith("balance ")] == notes


@pytest.mark.numerics
def test_cli_balance_single_lifts_the_right_sole(tmp_path):
    res = _run("plan", "--plant", "nao", "--task", "balance", "--balance", "single", "--solver", "raico",
               "--alpha", 1, "--iterations", 6, "--json", "--artifacts", tmp_path)
    assert res.exit_code == 0, res.output
    # recorded: the via-point plots leave the balance's inequality terms out (they have no target)
    assert (Path(json.loads(res.stdout.strip().splitlines()[-1])["path"]) / "recording.rrd").stat().st_size > 0
    notes = [ln for ln in res.stderr.splitlines() if ln.startswith("balance ")]
    assert len(notes) == 1 and notes[0].count("statically infeasible") == 2, res.stderr
    line = json.loads(res.stdout.strip().splitlines()[-1])
    d = np.load(Path(line["path"]) / "plan.npz")
    nao = shared_robot("nao")
    X = d["X"]
    lowest = np.array([sole_corners(nao, X[k, :nao.n_q], "r_sole")[:, 2].min() for k in range(100, 301)])
    assert lowest.min() >= 0.02  # lifted at least 2 cm from T/3 = step 100 on
    margins = cog_margins(nao, X[1:], np.array(line["metrics"]["balance"]["polygon"]))
    assert margins.min() >= MARGIN - 1e-3
    assert "r_sole@max" not in line["metrics"]["via_point_errors"]  # released
    # before the lift: above the ground, or above a start corner the perturbed posture has below it
    desc = json.loads((Path(line["path"]) / "problem.json").read_text())
    clear = next(t for t in desc["terms"] if t["name"] == "r_sole_clear")
    z0 = sole_corners(nao, np.array(desc["q0"]), "r_sole")[:, 2]
    assert z0.min() < 0 and close(clear["b"], -np.minimum(z0, 0.0), scale=1.0)
    assert np.all([sole_corners(nao, X[k, :nao.n_q], "r_sole")[:, 2] >= np.minimum(z0, 0.0) - 1e-3
                   for k in range(1, 100)])


@pytest.mark.parametrize("args, pattern", [
    (["--plant", "nao", "--task", "balance", "--balance", "both"],
     r"unknown balance 'both': choose one of none, support, single"),
    (["--plant", "arm5", "--task", "reach", "--balance", "support"],
     re.escape("--balance support needs a robot that stands on its soles (--plant nao): arm5 has none")),
    (["--plant", "nao", "--task", "balance", "--balance", "single", "--balance-margin", "0.05"],
     re.escape("balance-margin must be in [0, 0.04] m, got 0.05")),
])
def test_bad_balance_option_is_one_line(tmp_path, args, pattern):
    res = _run("plan", *args, "--artifacts", tmp_path)
    assert res.exit_code == 2, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and re.fullmatch("raico: error: " + pattern, lines[0]), res.stderr


@pytest.mark.numerics
def test_balance_margin_option_sets_the_term_and_the_moved_targets():
    descs = {}
    for margin in (0.01, 0.02):
        _, _, _, _, desc = build_problem(PlanConfig(plant="nao", task="balance", balance="single", seed=0,
                                                    balance_margin=margin))
        descs[margin] = desc
        poly = np.array(desc["balance"]["polygon"])
        A, b = halfplanes(poly)
        support = next(t for t in desc["terms"] if t["name"] == "support")
        assert_close(support["b"], b - margin, scale=1.0)
        for m in desc["balance"]["moved"]:
            assert signed_margin(poly, np.array(m["planned"])) == pytest.approx(margin)
    assert PlanConfig(plant="nao", task="balance", balance_margin=0.01).normalized().balance_margin == NO_BALANCE_MARGIN


@pytest.mark.numerics
def test_joint_range_term_bounds_every_joint_inside_its_range():
    """The balance objective's joint-range term: zero inside [lower + margin, upper - margin] at every step 1..T,
    a squared hinge beyond it, its gradient against central finite differences."""
    from raico.planning.objective import build_term
    from raico.stages.plan.balance import JOINT_MARGIN, W_RANGE, apply_balance

    nao = shared_robot("nao")
    T = 4
    terms, _ = apply_balance(nao, nao.default_q, T, [], "support")
    term = build_term(nao, next(t for t in terms if t["name"] == "joint_range"))
    n = nao.n_q
    inside = np.clip(nao.default_q, nao.lower + JOINT_MARGIN + 1e-3, nao.upper - JOINT_MARGIN - 1e-3)  # off the kinks
    assert term.value(np.r_[inside, np.zeros(n)][None], [1])[0] == 0.0
    beyond = inside.copy()
    i = nao.joint_names.index("RAnkleRoll")
    beyond[i] = nao.upper[i]  # at the limit: JOINT_MARGIN past the bound
    xb = np.r_[beyond, 0.1 * np.ones(n)]
    assert term.value(xb[None], [1])[0] == pytest.approx(W_RANGE * JOINT_MARGIN ** 2)
    assert term.value(xb[None], [0])[0] == 0.0  # not at step 0 (the start is given)
    lx, _ = term.derivatives(xb[None], [1])
    eps = 1e-7
    fd = np.array([(term.value((xb + eps * e)[None], [1])[0] - term.value((xb - eps * e)[None], [1])[0]) / (2 * eps)
                   for e in np.eye(2 * n)])
    np.testing.assert_allclose(lx[0], fd, atol=1e-3)
    assert np.count_nonzero(lx[0]) == 1 and lx[0, i] > 0


@pytest.mark.numerics
def test_cog_via_point_margins_against_the_feet():
    """The fig3.4 problem's CoG via-point targets against the feet's polygon: the +0.1 m one 5.5 cm
    outside (as the model says above), the -0.1 m one inside, keys as the via-point errors'."""
    from raico.stages.evaluate.metrics import cog_via_point_margins

    nao, _, pb, q0, _ = build_problem(PlanConfig(plant="nao", task="balance", seed=0))
    poly = support_polygon(nao, q0, "support")
    margins = cog_via_point_margins(pb, poly)
    assert list(margins) == ["via_cog1@100", "via_cog2@200", "via_cog3@300"]
    c = CenterOfMass(nao).value(q0)
    for name, dy in (("via_cog1@100", -0.1), ("via_cog2@200", 0.1), ("via_cog3@300", 0.0)):
        assert margins[name] == pytest.approx(signed_margin(poly, c[:2] + [0.0, dy]), abs=1e-3)
    assert margins["via_cog2@200"] < -0.05 < 0 < margins["via_cog1@100"]


@pytest.mark.numerics
def test_plan_beyond_limits_names_only_the_joints_that_leave_their_range():
    from raico.stages.evaluate.metrics import plan_beyond_limits

    lower, upper = np.array([-1.0, -0.5, 0.0]), np.array([1.0, 0.5, 1.0])
    Q = np.array([[0.0, 0.0, 0.5], [1.2, 0.4, 0.0], [0.9, -0.7, 1.0]])
    assert plan_beyond_limits(Q, lower, upper, ["a", "b", "c"]) == pytest.approx({"a": 0.2, "b": 0.2})
    assert plan_beyond_limits(Q[:1], lower, upper, ["a", "b", "c"]) == {}
