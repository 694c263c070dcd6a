"""The compiled distances of convex meshes (``distance.c`` through ``raico.plants.scene.GJKShapes``): the hull's
support by hill climbing against every vertex, each distance certified by a separating plane (exact, with
no reference to Drake), never above Drake's (whose witness points are on the shapes), and the batch's
gradients against finite differences on a scene with a mesh."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from raico.plants.model_file import shared_model
from raico.plants.numdiff import numdiff_jacobian
from raico.plants.scene import GJKShapes, Shape, gjk_library, hull_graph, obj_text, point_distance, rigid_transform
from tests.plants.scene_robot import SCENE, START, arm_file
from tests.plants.test_model_file import problem_text
from tests.tolerance import REL

pytestmark = [pytest.mark.compiled, pytest.mark.numerics]


@pytest.fixture(autouse=True)
def _library():
    if gjk_library() is None:
        pytest.skip("compiled kernels unavailable")


def _cloud(seed: int = 0, n: int = 400) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.standard_normal((n, 3)) * np.array([0.05, 0.03, 0.08])


SHAPES = [Shape("mesh", "world", "convex", (0,) * 6, vertices=_cloud(), faces=np.zeros((0, 3), int)),
          Shape("box", "world", "box", (0,) * 6, (0.1, 0.06, 0.2)),
          Shape("sphere", "world", "sphere", (0,) * 6, (0.04,)),
          Shape("capsule", "world", "capsule", (0,) * 6, (0.03, 0.12)),
          Shape("cylinder", "world", "cylinder", (0,) * 6, (0.04, 0.1))]


def _support(s: Shape, R: np.ndarray, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The world point of shape ``s`` at pose ``R``, ``p`` farthest along ``n``: every vertex, or the formula."""
    d = R.T @ n
    if s.kind == "convex":
        V = np.asarray(s.vertices)
        x = V[np.argmax(V @ d)]
    elif s.kind == "box":
        x = np.where(d >= 0, 0.5, -0.5) * np.asarray(s.size)
    elif s.kind == "sphere":
        x = s.size[0] * d / np.linalg.norm(d)
    elif s.kind == "capsule":
        x = np.array([0.0, 0.0, np.copysign(0.5 * s.size[1], d[2])]) + s.size[0] * d / np.linalg.norm(d)
    else:
        r = np.hypot(d[0], d[1])
        x = np.array([s.size[0] * d[0] / r, s.size[0] * d[1] / r, np.copysign(0.5 * s.size[1], d[2])])
    return R @ x + p


def _inside(s: Shape, x: np.ndarray) -> float:
    """How far the local point ``x`` lies outside shape ``s`` (m; <= 0 inside)."""
    if s.kind == "convex":
        from scipy.spatial import ConvexHull

        eq = ConvexHull(np.asarray(s.vertices)).equations
        return float(np.max(eq[:, :3] @ x + eq[:, 3]))
    return float(point_distance(s, x[None])[0])


def _random_pose(rng, spread: float) -> tuple[np.ndarray, np.ndarray]:
    X = rigid_transform([*(spread * rng.standard_normal(3)), *rng.uniform(-np.pi, np.pi, 3)])
    return X.rotation().matrix(), X.translation()


def test_hull_support_by_climbing_is_the_largest_vertex():
    """From any start vertex, the climb along the hull's edges ends at a vertex as far along the direction as
    the farthest of all: exact (the same vertices' products), so compared to rounding (``REL`` of the products)."""
    G = GJKShapes(SHAPES)
    V = hull_graph(np.asarray(SHAPES[0].vertices))[0]
    rng = np.random.default_rng(1)
    for _ in range(500):
        d = rng.standard_normal(3)
        s = G.support(0, d, hint=int(rng.integers(len(V))))
        assert s @ d >= (V @ d).max() - REL * np.abs(V @ d).max()
        assert np.min(np.abs(V - s).sum(axis=1)) == 0.0   # a hull vertex


def test_every_distance_is_certified_by_a_separating_plane():
    """For every pair of kinds at random poses: the witness points lie on their shapes (1e-9 m), their distance
    is the one reported (rounding: ``REL`` of 1 m), and the plane normal to the reported normal separates the
    shapes by no less (GJK's stop: a relative 1e-12 of the distance, plus rounding: 1e-9 m) — the distance
    is then the exact one to 1e-9 m. Pairs reported as overlapping or beyond the limit are checked as such; a
    stop short of that (a cylinder's curved side, rounding) is handed on, rarely."""
    G = GJKShapes(SHAPES)
    rng = np.random.default_rng(2)
    checked = overlap = culled = handed = 0
    for _ in range(60):
        for a in range(len(SHAPES)):
            for b in range(len(SHAPES)):
                if SHAPES[a].kind != "convex" and SHAPES[b].kind != "convex":
                    continue
                (RA, pA), (RB, pB) = _random_pose(rng, 0.15), _random_pose(rng, 0.15)
                limit = 0.05 if rng.random() < 0.3 else np.inf
                d, wa, wb, n, status = G.distances([a], [b], RA[None], pA[None], RB[None], pB[None], limit)
                sa, sb = SHAPES[a], SHAPES[b]
                if status[0] == 1:   # overlap: the shapes share a point or come within the kernel's 1e-6 m
                    overlap += 1
                    continue
                if status[0] == 2:   # a stop short of 1e-9 m (rounding on a curved side): handed to Drake
                    assert "cylinder" in (sa.kind, sb.kind)
                    handed += 1
                    continue
                assert status[0] in (0, 3)
                if status[0] == 3:   # beyond the limit: the bound is one, and the true distance no smaller
                    culled += 1
                    assert d[0] >= limit
                    continue
                xa, xb = RA @ wa[0] + pA, RB @ wb[0] + pB
                assert _inside(sa, wa[0]) <= 1e-9 and _inside(sb, wb[0]) <= 1e-9
                assert abs(np.linalg.norm(xa - xb) - d[0]) <= REL
                assert np.linalg.norm(n[0]) == pytest.approx(1.0, abs=REL)
                plane = n[0] @ _support(sa, RA, pA, -n[0]) - n[0] @ _support(sb, RB, pB, n[0])
                assert plane >= d[0] - 1e-9, (sa.kind, sb.kind, d[0], plane)
                checked += 1
    assert checked >= 200 and overlap >= 5 and culled >= 5 and handed <= 0.02 * checked


def test_the_kernel_over_the_corners_of_its_shapes():
    """The corners of ``gjk_batch``'s shapes (run under ASan/UBSan by ``make test-sanitize``): an empty batch; the
    smallest hull (a tetrahedron, 4 vertices) and a hull of 5000 cloud points; one batch of 150 queries with shared
    support hints equal to the same queries one at a time, each certified as above."""
    tet = np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 0.05, 0.0], [0.0, 0.0, 0.05]])
    shapes = [Shape("tet", "world", "convex", (0,) * 6, vertices=tet, faces=np.zeros((0, 3), int)),
              Shape("big", "world", "convex", (0,) * 6, vertices=_cloud(4, 5000), faces=np.zeros((0, 3), int)),
              *SHAPES[1:]]
    G = GJKShapes(shapes)
    e = np.zeros((0, 3))
    d, wa, wb, n, status = G.distances([], [], np.zeros((0, 3, 3)), e, np.zeros((0, 3, 3)), e)
    assert d.shape == (0,) and wa.shape == wb.shape == n.shape == (0, 3) and status.shape == (0,)
    rng = np.random.default_rng(7)
    k = 150
    ga, gb = rng.integers(0, 2, k), rng.integers(0, len(shapes), k)
    poses = [(_random_pose(rng, 0.2), _random_pose(rng, 0.2)) for _ in range(k)]
    RA, pA = np.array([a[0] for a, _ in poses]), np.array([a[1] for a, _ in poses])
    RB, pB = np.array([b[0] for _, b in poses]), np.array([b[1] for _, b in poses])
    hints = np.zeros((3, 2), np.int64)
    batch = G.distances(ga, gb, RA, pA, RB, pB, key=np.arange(k) % 3, hints=hints)
    for i in range(k):
        one = G.distances(ga[i:i + 1], gb[i:i + 1], RA[i:i + 1], pA[i:i + 1], RB[i:i + 1], pB[i:i + 1])
        assert one[4][0] == batch[4][i]
        if batch[4][i] != 0:
            continue
        assert abs(one[0][0] - batch[0][i]) <= 1e-9    # GJK's stop from another start vertex: 1e-9 m
        sa, sb = shapes[ga[i]], shapes[gb[i]]
        assert _inside(sa, batch[1][i]) <= 1e-9 and _inside(sb, batch[2][i]) <= 1e-9
        nn = batch[3][i]
        plane = nn @ _support(sa, RA[i], pA[i], -nn) - nn @ _support(sb, RB[i], pB[i], nn)
        assert plane >= batch[0][i] - 1e-9


MESH = """
[[scene]]
name = "blob"
type = "mesh"
file = "blob.obj"
pose = [0.25, -0.12, 0.45, 0.3, 0.2, 0.1]
"""
AVOID = """
[costs.avoid]
type = "collision"
pairs = [["robot", "scene"]]
margin = 0.02
max_distance = 1.0
"""


def _mesh_world(tmp_path: Path):
    from scipy.spatial import ConvexHull

    from raico.planning.problem_file import read_problem
    from raico.plants.scene import CollisionWorld, SignedDistances, resolve_pairs

    tmp_path.mkdir(exist_ok=True)
    arm_file(tmp_path)
    V = _cloud(3, 300)
    (tmp_path / "blob.obj").write_text(obj_text(V, ConvexHull(V).simplices))
    path = tmp_path / "arm_mesh.toml"
    path.write_text(problem_text("three_link.urdf", {"start": START}, SCENE + MESH + AVOID, T=10,
                                 dynamics="analytic"))
    pf = read_problem(path)
    robot = shared_model(pf.robot_spec())
    world = CollisionWorld(pf.robot_spec(), pf.doc["scene"])
    pairs = [p for p in resolve_pairs(world, [["robot", "scene"]], {}, False, [], "test") if "blob" in p[1]]
    return robot, world, SignedDistances(robot, world, pairs, 1.0)


def test_mesh_pairs_by_gjk_never_exceed_drakes_and_their_gradients_match_finite_differences(tmp_path):
    """The arm's capsules, spheres and cylinder against a convex mesh: the compiled distances are exact (above),
    Drake's are a pair of points on the shapes, so never below (rounding and the hull's text form, 1e-9 m);
    they agree to Drake's accuracy (1e-4 m here). Central differences (step 1e-6) of the exact distance: its
    third derivative (1/r^2 at these radii, about 1e3) times the step squared, 1e-9, and rounding, 1e-16 / 1e-6:
    atol 1e-7, where a wrong frame, sign or body changes an entry by its size (0.05-0.5 m/rad)."""
    robot, world, tm = _mesh_world(tmp_path)
    assert tm.compiled and tm._gjk_pair.all() and tm.dim >= 5
    rng = np.random.default_rng(4)
    Q = robot.default_q + 0.4 * rng.standard_normal((6, robot.n_q))
    D, J = tm.values_and_jacobians(Q)
    tm.compiled = False
    D0, _ = tm.values_and_jacobians(Q)
    tm.compiled = True
    live = (D < 1.0) & (D > 0.0)
    assert live.sum() >= 20
    assert np.all(D[live] <= D0[live] + 1e-9)
    assert np.max(np.abs(D[live] - D0[live])) <= 1e-4
    checked = 0
    for k, q in enumerate(Q):
        fd = numdiff_jacobian(tm.value, q, 1e-6)
        for p in np.flatnonzero(live[k]):
            assert np.max(np.abs(J[k, p] - fd[p])) <= 1e-7, (tm.pairs[p], D[k, p], J[k, p], fd[p])
            checked += 1
    assert checked >= 20


def test_a_batch_asked_again_is_the_kept_one_and_a_larger_cull_queries_anew(tmp_path):
    """The kept batches: the same rows at cull distances no larger give the same arrays (copies); a larger
    cull distance queries again (more pairs within it)."""
    robot, world, tm = _mesh_world(tmp_path)
    Q = robot.default_q + 0.3 * np.random.default_rng(5).standard_normal((4, robot.n_q))
    D1, J1, _ = tm.evaluate(Q, cull=0.05)
    n = tm.queries
    D2, J2, _ = tm.evaluate(Q, cull=0.03)
    assert tm.queries == n and np.array_equal(D1, D2) and np.array_equal(J1, J2) and D2 is not D1
    D3, _, _ = tm.evaluate(Q, cull=0.5)
    assert tm.queries > n and np.sum(D3 < 0.5) >= np.sum(D1 < 0.05)


def test_every_bodys_frame_in_one_batch_is_each_bodys_own(tmp_path):
    """``body_frames_batch`` (the kinematics once per row) against ``frame_points_batch`` body by body: the same
    arithmetic, so equal to rounding (``REL`` of the frames' 1 m scale)."""
    robot, world, tm = _mesh_world(tmp_path)
    k = tm.tree_kernels()
    assert k is not None
    Qp = (robot.default_q + 0.3 * np.random.default_rng(6).standard_normal((5, robot.n_q))) @ robot.P.T
    bodies = [k.tree.body(b) for b in tm._bodies]
    pos, J = k.body_frames_batch(Qp, bodies)
    pts = np.vstack([np.zeros(3), np.eye(3)])
    for i, b in enumerate(bodies):
        p1, J1 = k.frame_points_batch(Qp, b, np.eye(3), np.zeros(3), pts)
        np.testing.assert_allclose(pos[:, i], p1, rtol=0, atol=REL)
        np.testing.assert_allclose(J[:, i], J1, rtol=0, atol=REL)
    with pytest.raises(ValueError, match="out of range"):
        k.body_frames_batch(Qp, [len(k.tree.names)])


def test_pairs_gjk_hands_on_are_drakes(tmp_path, monkeypatch):
    """Cores closer than the kernel's threshold (penetration) go to Drake: with the threshold at 1 m every pair
    does, and the batch is Drake's exactly (the same queries)."""
    import raico.plants.scene as scene

    robot, world, tm = _mesh_world(tmp_path)
    Q = robot.default_q + 0.3 * np.random.default_rng(8).standard_normal((3, robot.n_q))
    tm.compiled = False
    D0, J0 = tm.values_and_jacobians(Q)
    tm.compiled, tm._known = True, None
    monkeypatch.setattr(scene, "GJK_TINY", 1.0)
    D1, J1 = tm.values_and_jacobians(Q)
    assert np.any(D0 < 1.0)
    assert np.array_equal(D0, D1) and np.array_equal(J0, J1)


@pytest.mark.parametrize("carried", [False, True])
def test_poses_witness_points_and_gradient_rows_in_c_are_the_python_routes(tmp_path, carried):
    """``GJKShapes.frames_distances`` (the geometries' poses from the bodies' frames, the witness points in the
    world and ``n . (J_A - J_B)`` in C) against ``distances`` on poses built in numpy with the witness points and
    rows assembled as before: the same GJK from the same start, so equal to rounding (the frames' scale, 1 m,
    times ``REL``), statuses alike; a row without frames and a body column out of range are refused or handed on.
    ``carried``: the mesh on the first body instead of the world (both sides moving, as the robot against itself)."""
    robot, world, tm = _mesh_world(tmp_path)
    Q = robot.default_q + 0.4 * np.random.default_rng(9).standard_normal((6, robot.n_q))
    Qp = Q @ robot.P.T
    K, m = Qp.shape
    names, fr, Jf, rowmap = tm._frame_arrays(Qp)
    frames = tm._frames_of((names, fr, Jf, rowmap), K, m)
    O, R, Jo, Je = tm._stacked(frames, K, m)
    G = GJKShapes([world.shapes_by_name.get(n) for n in tm._names])
    tq, pq = np.nonzero(np.ones((K, tm.dim), bool))
    sa, sb = tm._ia[pq], tm._ib[pq]
    body_index = np.where(tm._body_index == len(tm._bodies), 0, tm._body_index) if carried else tm._body_index
    ba, bb = body_index[sa], body_index[sb]
    RA, RB = R[ba, tq] @ tm._R_BG[sa], R[bb, tq] @ tm._R_BG[sb]
    pA = O[ba, tq] + np.einsum("kij,kj->ki", R[ba, tq], tm._p_BG[sa])
    pB = O[bb, tq] + np.einsum("kij,kj->ki", R[bb, tq], tm._p_BG[sb])
    limit = np.where(np.arange(len(tq)) % 3 == 0, 0.05, np.inf)
    d0, wa, wb, n0, s0 = G.distances(sa, sb, RA, pA, RB, pB, limit, pq, np.zeros((tm.dim, 2), np.int64))
    col = {b: i for i, b in enumerate(names)}
    gbody = np.array([(0 if carried else -1) if world.body_of[n] == "world" else col[world.body_of[n]]
                      for n in tm._names])
    d1, W1, n1, J1, s1 = G.frames_distances(tq, pq, tm._ia, tm._ib, gbody, tm._R_BG, tm._p_BG, rowmap, fr, Jf,
                                            limit, np.zeros((tm.dim, 2), np.int64))
    assert np.array_equal(s0, s1) and np.sum(s0 == 0) >= 20 and np.sum(s0 == 3) >= 3
    done = (s0 == 0) | (s0 == 3)
    np.testing.assert_allclose(d1[done], d0[done], rtol=0, atol=REL)
    ok = s0 == 0
    np.testing.assert_allclose(n1[ok], n0[ok], rtol=0, atol=REL)
    Jd = 0.0
    for side, (slots, pts) in enumerate(((sa, wa), (sb, wb))):
        p_B = np.einsum("kij,kj->ki", tm._R_BG[slots], pts) + tm._p_BG[slots]
        b = body_index[slots]
        Wp = O[b, tq] + np.einsum("kij,kj->ki", R[b, tq], p_B)
        np.testing.assert_allclose(W1[ok, side], Wp[ok], rtol=0, atol=REL)
        nJ = np.einsum("kc,kcm->km", n0, Jo[b, tq]) + np.einsum("ki,kc,kicm->km", p_B, n0, Je[b, tq])
        Jd = Jd + (nJ if side == 0 else -nJ)
    np.testing.assert_allclose(J1[ok], Jd[ok], rtol=0, atol=REL)
    none = np.full(K, -1, np.int64)   # no frames at any row: handed on (status 2), nothing read
    s2 = G.frames_distances(tq, pq, tm._ia, tm._ib, gbody, tm._R_BG, tm._p_BG, none, fr, Jf, limit,
                            np.zeros((tm.dim, 2), np.int64))[4]
    assert np.all(s2 == 2)
    with pytest.raises(ValueError, match="out of range"):
        G.frames_distances(tq, pq + tm.dim, tm._ia, tm._ib, gbody, tm._R_BG, tm._p_BG, rowmap, fr, Jf, limit,
                           np.zeros((tm.dim, 2), np.int64))
