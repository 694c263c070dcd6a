"""Hard collision terms as constraints of AICO's augmented Lagrangian: the constraint's Jacobian against finite
differences, its culling (only rows that can be active are queried, the others exactly inactive), a start
inside the margin given the steps its velocity limits need, and a plan around a ball the unconstrained plan
passes through."""

from __future__ import annotations

import numpy as np
import pytest

from raico.planning.constraints import AugmentedLagrangian, DistanceConstraint
from raico.planning.costs import Collision
from raico.plants.numdiff import numdiff_jacobian
from tests.plants.test_scene import AVOID, REACH, _postures, _problem, _world
from tests.tolerance import assert_close


def _constraint(tmp_path, margin: float, q0=None, T: int = 5, vmax=None):
    robot, world, tm = _world(tmp_path)
    term = Collision(tm, margin, None, 1e6, hard=True, name="avoid")
    q0 = robot.default_q if q0 is None else np.asarray(q0, float)
    return robot, tm, DistanceConstraint(term, robot.n_q, T, q0, 0.01, vmax, 1e-4)


@pytest.mark.numerics
def test_the_distance_constraints_jacobian_matches_finite_differences(tmp_path):
    """Rows ``g = margin - d`` of every step but the start; Jacobian ``-J`` on the positions, zero on the
    velocities. Tolerances as tests/plants/test_scene.py argues them: sphere pairs (closed form in Drake) to
    1e-8 with a step of 1e-6, GJK pairs to 1e-3 with a step of 1e-5 (GJK's 1e-9 m accuracy over the step)."""
    robot, tm, c = _constraint(tmp_path, margin=0.3)
    world = tm.world
    sphere = np.array([any(world.shapes_by_name[n].kind == "sphere" for n in p) for p in tm.pairs])
    Q = _postures(robot, 6, seed=4)
    X = np.hstack([Q, 0.1 * np.ones_like(Q)])
    G, Gx = c._eval(X)
    assert np.all(np.isneginf(G[0])) and not Gx[0].any()           # the start: not constrained
    assert not Gx[:, :, robot.n_q:].any()
    checked = 0
    for t in range(1, 6):
        g = c.bound[t - 1] - tm.values_and_jacobians(Q[t:t + 1])[0][0]   # the margin (or, from a start
        # inside it, the start's distance at step 1)
        live = G[t] > c.bound[t - 1] - tm.max_distance   # queried (culled rows report the cap)
        assert_close(G[t][g > 0], g[g > 0]) and np.all(G[t][g <= 0] <= 0)
        assert_close(G[t][live], g[live])
        fd6 = numdiff_jacobian(lambda q: 0.3 - tm.value(q), Q[t], 1e-6)
        fd5 = numdiff_jacobian(lambda q: 0.3 - tm.value(q), Q[t], 1e-5)
        for k in np.flatnonzero(live & (G[t] > c.bound[t - 1] - 0.95)):   # queried rows away from the cap
            tol, fd = (1e-8, fd6) if sphere[k] else (1e-3, fd5)
            assert np.max(np.abs(Gx[t, k, :robot.n_q] - fd[k])) <= tol, (tm.pairs[k], G[t, k])
            checked += 1
    assert checked >= 20


@pytest.mark.numerics
def test_culled_rows_are_exactly_inactive_and_the_others_exact(tmp_path):
    """With multipliers ``y`` and penalty ``mu`` a row is queried only where its distance bound is below
    ``margin + y / mu``: the AL's ``lam`` and its model equal those of the uncapped distances."""
    robot, tm, c = _constraint(tmp_path, margin=0.05)
    Q = _postures(robot, 6, seed=5)
    X, U = np.hstack([Q, np.zeros_like(Q)]), np.zeros((5, robot.n_q))
    D = tm.values_and_jacobians(Q)[0]
    al = AugmentedLagrangian([c], 5, 10.0)
    rng = np.random.default_rng(0)
    al.y[0] = np.where(rng.random((6, tm.dim)) < 0.3, 0.2, 0.0)
    al._share_slack()
    (G, lam), = al._lams(X, U)
    z = al.y[0][1:] + 10.0 * (c.bound - D[1:])
    assert_close(lam[1:], np.maximum(0.0, z))
    assert np.any(lam[1:] > 0) and np.any(G[1:] == 0.05 - tm.max_distance)


def test_a_start_inside_the_margin_is_given_the_steps_its_velocity_limits_need(tmp_path):
    """The pairs closer than the margin at ``q0`` start at their distance and rise, first order, at the speed
    the velocity limits allow (``|J(q0)| vmax``); the others hold the margin from step 1; without velocity
    limits the margin holds from step 2."""
    start = np.array([0.0, 1.2, 1.5])   # the forearm's tip in the table
    robot, tm, c = _constraint(tmp_path, margin=0.02, q0=start, T=10, vmax=np.full(3, 2.0))
    d0, J0 = tm.value_and_jacobian(start)
    inside = d0 < 0.02
    assert inside.any() and c.start_inside == inside.sum()
    rate = np.abs(J0[inside]) @ np.full(3, 2.0)
    t = np.arange(1, 11)[:, None]
    assert_close(c.bound[:, inside], np.minimum(0.02, d0[inside] + (t - 1) * 0.01 * rate))
    assert np.all(c.bound[:, ~inside] == 0.02)
    _, _, free = _constraint(tmp_path, margin=0.02, q0=start, T=10, vmax=None)
    assert_close(free.bound[0, inside], d0[inside]) and np.all(free.bound[1:] == 0.02)


AROUND = REACH.replace("target = [0.0, 0.0, -0.1]", "target = [-0.15, 0.245, -0.05]") + AVOID.format(
    dmax=0.1).replace('pairs = [["robot", "scene"]]', 'pairs = [["fore", "scene"]]').replace("self = true", "self = false")


@pytest.mark.slow
@pytest.mark.numerics
def test_the_constrained_plan_keeps_the_margin_where_the_unconstrained_one_passes_through(tmp_path):
    """The tip swings over a ball at a height the straight reach passes through: R-AICO without the term goes
    into it (the premise), with the hard term it keeps the margin to 1 mm (the constraints' stopping tolerance
    is 0.1 mm; a plan 1 mm inside is out-of-bounds)."""
    from raico.stages.plan.stage import PlanConfig, plan

    smallest = {}
    for hard in (False, True):
        costs = AROUND if hard else AROUND.replace("margin = 0.02", "margin = 0.02\nhard = false\nweight = 0.0")
        out = plan(PlanConfig(problem=str(_problem(tmp_path / str(hard), costs=costs, T=50)), solver="raico",
                              iterations=150).normalized())
        term = next(t for t in out.problem.state_terms if isinstance(t, Collision))
        smallest[hard] = term.smallest(out.result.X)[0]
        if hard:
            assert out.metrics()["status"] != "out-of-bounds", out.metrics()["message"]
    assert smallest[False] < 0.0
    assert smallest[True] >= 0.02 - 1e-3


# ------------------------------------------------------------------ culling bounds
@pytest.mark.numerics
def test_segment_distances_are_the_closest_points_of_two_segments():
    """Against a grid of 801 points on each segment (the grid's distance is above the exact one by at most
    half a grid step times the segments' lengths, ~1e-2 here): never below it by more than rounding, and the
    closest-point formula exact on points and parallel segments."""
    from raico.plants.scene import segment_distances

    rng = np.random.default_rng(1)
    n = 600
    P0, P1, Q0, Q1 = (rng.standard_normal((n, 3)) for _ in range(4))
    P1[:100] = P0[:100]
    Q1[100:200] = Q0[100:200]
    P1[200:250], Q1[200:250] = P0[200:250], Q0[200:250]
    Q1[250:300] = Q0[250:300] + 0.7 * (P1 - P0)[250:300]
    s = np.linspace(0.0, 1.0, 801)
    A = P0[:, None] + s[None, :, None] * (P1 - P0)[:, None]
    B = Q0[:, None] + s[None, :, None] * (Q1 - Q0)[:, None]
    grid = np.array([np.min(np.linalg.norm(A[i][:, None] - B[i][None], axis=-1)) for i in range(n)])
    d = segment_distances(P0, P1, Q0, Q1)
    assert np.all(d <= grid + 1e-9 * (1.0 + grid)) and np.all(grid - d <= 1e-2)
    assert_close(d[200:250], np.linalg.norm(P0 - Q0, axis=1)[200:250])


@pytest.mark.numerics
def test_the_culling_bounds_never_exceed_the_distances_and_the_last_batch_bounds_the_next(tmp_path):
    """The spheres', capsules' and point bounds at random postures lie below Drake's distances; a batch after
    another (the last batch's distances moved by the joints' reach bounds) gives what a fresh map gives."""
    robot, world, tm = _world(tmp_path)
    Q = _postures(robot, 40, seed=6)
    lb = tm.lower_bounds(tm._frames(Q @ robot.P.T), len(Q))
    tm._known = None
    D = tm.evaluate(Q, jacobians=False)[0]
    live = D < tm.max_distance
    assert live.sum() > 100 and np.all(lb[live] <= D[live])
    rng = np.random.default_rng(7)
    for k in range(6):
        Q2 = Q + (0.02 * k) * rng.standard_normal(Q.shape)
        for cull in (None, 0.05):
            D1, J1, _ = tm.evaluate(Q2, cull=cull)
            tm._known = None
            D2, J2, _ = tm.evaluate(Q2, cull=cull)
            c = tm.max_distance if cull is None else cull
            assert np.array_equal(D1 < c, D2 < c) and np.array_equal(D1[D1 < c], D2[D2 < c])
            assert np.array_equal(J1[D1 < c], J2[D2 < c])


# ------------------------------------------------------------------ bad input
ROBOT_MESH = ('<collision><origin xyz="0 0 0.12"/><geometry><capsule radius="0.025" length="0.14"/></geometry>'
              '</collision>')
BAD = [
    ("scene_not_tables", '[scene]\nname = "table"\n', AVOID, r"\[\[scene\]\] must be an array of tables"),
    ("scene_mesh_missing", '[[scene]]\nname = "m"\ntype = "mesh"\nfile = "nowhere.obj"\n', AVOID,
     r"mesh .*nowhere.obj: cannot be read \(No such file"),
    ("allow_link", None, AVOID.replace("self = true", 'self = true\nallow = [["base", "elbo"]]'),
     r"\[costs.avoid\] allow: unknown link 'elbo'"),
    ("group_link", None, AVOID.replace('[["robot", "scene"]]', '[["arm", "scene"]]\ngroups = {{ arm = ["fore", "uper"] }}'),
     r"\[costs.avoid\] groups.arm: unknown link 'uper'"),
    ("robot_mesh", None, AVOID, r"mesh broken.stl: cannot be read"),
]


@pytest.mark.parametrize("case, scene, avoid, pattern", BAD, ids=[b[0] for b in BAD])
def test_more_bad_collision_input_is_one_line_exit_2_nothing_cached(tmp_path, case, scene, avoid, pattern):
    """Beyond tests/plants/test_scene.py's cases: a scene that is no array of tables, a scene mesh that is not
    there, an unknown link in an allow list or a group, a robot collision mesh that cannot be read."""
    import re

    from typer.testing import CliRunner

    from raico.pipeline.interface.cli import app
    from tests.plants.scene_robot import SCENE

    problem = _problem(tmp_path, costs=REACH + avoid.format(dmax=1.0), scene=SCENE if scene is None else scene)
    if case == "robot_mesh":
        (tmp_path / "broken.stl").write_bytes(b"\x00" * 90)
        urdf = tmp_path / "three_link.urdf"
        urdf.write_text(urdf.read_text().replace(ROBOT_MESH, '<collision><geometry><mesh filename="broken.stl"/>'
                                                             '</geometry></collision>'))
        assert "broken.stl" in urdf.read_text()
    arts = tmp_path / "artifacts"
    r = CliRunner().invoke(app, ["plan", "--problem", str(problem), "--iterations", "1", "--artifacts", str(arts)])
    assert r.exit_code == 2, (r.exit_code, r.output)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and "note:" not in ln]
    assert len(lines) == 1 and re.search(pattern, lines[0]), r.stderr
    assert not list(arts.glob("plan/*")), "nothing cached"
