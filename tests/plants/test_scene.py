"""Scenes and collision terms: signed distances and their gradients from Drake's SceneGraph against finite
differences, the culled batch against the pairwise query, pairs resolved from names, meshes read, a scene's
round trip through a problem file and its stored description, and bad input refused in one line."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from raico.pipeline.interface.cli import app
from raico.planning.costs import Collision, ControlCost, hard_inequalities
from raico.planning.objective import build_terms as build_objective
from raico.planning.objective import objective_from_description
from raico.planning.problem_file import ProblemFile, build_terms, read_problem
from raico.plants.model_file import shared_model
from raico.plants.numdiff import check_cost_term, numdiff_jacobian
from raico.plants.scene import CollisionWorld, SignedDistances, read_mesh, resolve_pairs
from tests.plants.scene_robot import SCENE, START, arm_file
from tests.plants.test_model_file import problem_text
from tests.tolerance import assert_close

REACH = """
[costs.reach]
type = "frame_position"
frame = "tip"
target = [0.0, 0.0, -0.1]
relative = "start"
times = "last"
weight = 1e4

[costs.control]
type = "control"
weight = 1e-3
"""
AVOID = """
[costs.avoid]
type = "collision"
pairs = [["robot", "scene"]]
self = true
margin = 0.02
max_distance = {dmax}
"""


def _problem(tmp_path: Path, costs: str = REACH + AVOID.format(dmax=1.0), scene: str = SCENE,
             start: dict | None = None, T: int = 20) -> Path:
    tmp_path.mkdir(exist_ok=True)
    arm_file(tmp_path)
    path = tmp_path / "arm_scene.toml"
    path.write_text(problem_text("three_link.urdf", {"start": start or START}, scene + costs, T=T,
                                 dynamics="analytic"))
    return path


def _world(tmp_path: Path, dmax: float = 1.0):
    pf = read_problem(_problem(tmp_path / "world"))
    robot = shared_model(pf.robot_spec())
    world = CollisionWorld(pf.robot_spec(), pf.doc["scene"])
    pairs = resolve_pairs(world, [["robot", "scene"]], {}, True, [], "test")
    return robot, world, SignedDistances(robot, world, pairs, dmax)


def _postures(robot, k: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return robot.default_q + 0.4 * rng.standard_normal((k, robot.n_q))


# ------------------------------------------------------------------ distances and gradients
def test_signed_distance_gradients_match_finite_differences(tmp_path):
    """Sphere pairs have closed-form distances in Drake: central differences (step 1e-6) are exact up to their
    truncation, eps^2 |d'''| <= 1e-12 * 1/r^2 (r >= 0.035 m: about 1e-9), and rounding, 1e-16 / 1e-6 = 1e-10: atol
    1e-8. Other pairs (capsules, boxes, cylinders) go through GJK, whose distances are accurate to about its
    tolerance (1e-9 m here), which a step of 1e-5 amplifies to 1e-4: atol 1e-3 there, while a wrong sign, frame
    or missing body changes an entry by its whole size (0.05-0.6 m/rad at these postures)."""
    robot, world, tm = _world(tmp_path)
    sphere = np.array([any(world.shapes_by_name[n].kind == "sphere" for n in p) for p in tm.pairs])
    assert sphere.sum() >= 8 and (~sphere).sum() >= 8
    checked = 0
    for q in _postures(robot, 4):
        d, J = tm.value_and_jacobian(q)
        live = d < tm.max_distance
        fd6, fd5 = numdiff_jacobian(tm.value, q, 1e-6), numdiff_jacobian(tm.value, q, 1e-5)
        for k in np.flatnonzero(live):
            tol, fd = (1e-8, fd6) if sphere[k] else (1e-3, fd5)
            assert np.max(np.abs(J[k] - fd[k])) <= tol, (tm.pairs[k], d[k], J[k], fd[k])
            checked += 1
        assert np.abs(J[~live]).max(initial=0.0) == 0.0    # capped pairs: no gradient
    assert checked >= 40


def test_culled_batch_equals_the_pairwise_query(tmp_path):
    """The batch (bounding spheres, compiled kinematics, one pair query each) and the pairwise query with
    max-distance culling and Drake's Jacobians: the same distances and gradients up to rounding."""
    robot, world, tm = _world(tmp_path, dmax=0.15)
    Q = _postures(robot, 6, seed=1)
    D, J = tm.values_and_jacobians(Q)
    assert np.any(D < 0.15) and np.any(D == 0.15)
    for k, q in enumerate(Q):
        d, G, W = world.distances(robot.P @ q, tm.pairs, 0.15)
        assert_close(D[k], d)
        assert_close(J[k], G @ robot.P, scale=1.0)
        _, W_batch = tm.witnesses(q)
        live = d < 0.15
        assert_close(W_batch[live], W[live], scale=1.0)


def test_collision_term_is_the_squared_hinge_below_the_margin_and_its_constraint(tmp_path):
    robot, world, tm = _world(tmp_path)
    Q = _postures(robot, 5, seed=2)
    d = tm.values_and_jacobians(Q)[0]
    margin = float(np.quantile(d, 0.2))   # about a fifth of the pairs below it
    term = Collision(tm, margin, [1, 3], 10.0, hard=True, name="avoid")
    X = np.hstack([Q, np.zeros_like(Q)])
    idx = np.arange(5)
    expect = 10.0 * np.sum(np.maximum(margin - d, 0.0) ** 2, axis=1) * np.isin(idx, [1, 3])
    assert_close(term.value(X, idx), expect)
    check_cost_term(lambda Z: term.value(Z, idx), lambda Z: term.derivatives(Z, idx), X, eps=1e-6,
                    atol=1e-3, rtol=1e-5, subject="collision").assert_passed()
    g, G = term.constraints(X, idx)
    assert np.all(np.isneginf(g[[0, 2, 4]])) and not np.any(G[[0, 2, 4]])
    J = tm.values_and_jacobians(Q)[1]
    assert_close(g[[1, 3]], margin - d[[1, 3]])
    assert_close(G[[1, 3], :, :robot.n_q], -J[[1, 3]], scale=1.0)
    assert not np.any(G[:, :, robot.n_q:])
    dmin, step, pair = term.smallest(X)
    assert dmin == d[[1, 3]].min() and step in (1, 3)
    soft = Collision(tm, margin, [1, 3], 10.0, hard=False, name="soft")
    assert hard_inequalities([term, soft, ControlCost(1.0)]) == [term]


def test_self_pairs_leave_out_adjacent_and_welded_links_and_the_allow_list(tmp_path):
    robot, world, tm = _world(tmp_path)
    links = {(world.body_of[a], world.body_of[b]) for a, b in tm.pairs if world.body_of[b] != "world"}
    # base-post, post-upper, upper-fore are joined by joints; base-upper, base-fore, post-fore are not
    assert links == {("base", "upper"), ("base", "fore"), ("post", "fore")}
    allowed = resolve_pairs(world, [], {}, True, [["post", "fore"]], "test")
    assert {(world.body_of[a], world.body_of[b]) for a, b in allowed} == {("base", "upper"), ("base", "fore")}


# ------------------------------------------------------------------ meshes
def _cube(h: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    V = np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)])
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return V, F


def test_meshes_read_from_obj_and_binary_and_ascii_stl_alike(tmp_path):
    V, F = _cube()
    (tmp_path / "c.obj").write_text("".join(f"v {a} {b} {c}\n" for a, b, c in V)
                                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F))
    tri = V[F]
    (tmp_path / "c.stl").write_bytes(b"\0" * 80 + struct.pack("<I", len(F)) + b"".join(
        struct.pack("<12fH", 0, 0, 0, *t.reshape(-1), 0) for t in tri))
    (tmp_path / "a.stl").write_text("solid c\n" + "".join(
        "facet normal 0 0 0\nouter loop\n" + "".join(f"vertex {a} {b} {c}\n" for a, b, c in t) + "endloop\nendfacet\n"
        for t in tri) + "endsolid c\n")
    for name in ("c.obj", "c.stl", "a.stl"):
        Vr, Fr = read_mesh(tmp_path / name)
        # binary STL stores float32: its vertices agree to float32's resolution, 2^-24 relative
        assert_close(np.sort(np.unique(Vr.round(6), axis=0), axis=0), np.sort(V, axis=0), rel=1e-7)
        assert len(Fr) == 12
    (tmp_path / "bad.stl").write_bytes(b"\x01\x02garbage")
    with pytest.raises(ValueError, match=r"^mesh bad.stl: cannot be read"):
        read_mesh(tmp_path / "bad.stl")
    with pytest.raises(ValueError, match=r"format '.ply'"):
        read_mesh(tmp_path / "x.ply")


# ------------------------------------------------------------------ problem files
def test_a_scene_round_trips_through_the_problem_file_and_the_stored_description(tmp_path):
    """The problem file's canonical content survives JSON; the terms built from it and the objective rebuilt
    from the stored descriptions (execute's route) give the same distances."""
    pf = read_problem(_problem(tmp_path, costs=REACH + AVOID.format(dmax=0.3)))
    assert [o["name"] for o in pf.doc["scene"]] == ["table", "ball", "pole"]
    again = ProblemFile(json.loads(pf.canonical()))
    assert again.digest() == pf.digest()
    robot = shared_model(pf.robot_spec())
    descs = build_terms(again, robot, robot.default_q, pf.T)
    stored = json.loads(json.dumps(descs))
    col = next(d for d in stored if d["term"] == "collision")
    assert col["map"]["scene"] == pf.doc["scene"] and col["margin"] == 0.02 and col["map"]["max_distance"] == 0.3
    a = next(t for t in build_objective(robot, descs, pf.T).state_terms if isinstance(t, Collision))
    desc = {"terms": stored, "T": pf.T, "control_kind": "torque", "robot": pf.robot_spec().to_dict()}
    b = next(t for t in objective_from_description(desc, robot).state_terms if isinstance(t, Collision))
    Q = _postures(robot, 3)
    assert a.taskmap.pairs == b.taskmap.pairs
    assert_close(a.taskmap.values_and_jacobians(Q)[0], b.taskmap.values_and_jacobians(Q)[0])


BAD = [
    ("scene_type", REACH + AVOID.format(dmax=1.0), '[[scene]]\nname = "x"\ntype = "cone"\n',
     r"\[\[scene\]\] 'x': unknown type 'cone': choose one of box, sphere"),
    ("scene_size", REACH + AVOID.format(dmax=1.0), '[[scene]]\nname = "x"\ntype = "box"\nsize = [0.1, -1, 0.1]\n',
     r"\[\[scene\]\] 'x' size must be a number > 0 \(m\), got -1"),
    ("world_file", REACH + AVOID.format(dmax=1.0), '[[scene]]\nname = "w"\ntype = "file"\nfile = "world.urdf"\n',
     r"\[\[scene\]\] 'w': world file world.urdf does not parse"),
    ("mesh", REACH + AVOID.format(dmax=1.0), '[[scene]]\nname = "m"\ntype = "mesh"\nfile = "rock.stl"\n',
     r"mesh rock.stl: cannot be read"),
    ("link", REACH + AVOID.format(dmax=1.0).replace('[["robot", "scene"]]', '[["elbo", "scene"]]'), SCENE,
     r"\[costs.avoid\]: unknown link or group 'elbo': closest"),
    ("object", REACH + AVOID.format(dmax=1.0).replace('[["robot", "scene"]]', '[["fore", "tabel"]]'), SCENE,
     r"\[costs.avoid\]: unknown scene object 'tabel': closest table"),
    ("margin", REACH + AVOID.format(dmax=1.0).replace("margin = 0.02", "margin = -0.01"), SCENE,
     r"\[costs.avoid\] margin must be >= 0 \(m\), got -0.01"),
]


@pytest.mark.parametrize("case, costs, scene, pattern", BAD, ids=[b[0] for b in BAD])
def test_bad_scene_or_collision_term_is_one_line_exit_2_nothing_cached(tmp_path, case, costs, scene, pattern):
    (tmp_path / "world.urdf").write_text("<robot name='w'><link name='a'><collision><geometry><box size='1 1'/>"
                                         "</geometry></collision></link>")   # not even XML
    (tmp_path / "rock.stl").write_bytes(b"\x00" * 90)
    problem = _problem(tmp_path, costs=costs, scene=scene)
    arts = tmp_path / "artifacts"
    r = CliRunner().invoke(app, ["plan", "--problem", str(problem), "--iterations", "1", "--artifacts", str(arts)])
    assert r.exit_code == 2, (r.exit_code, r.output)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and "note:" not in ln]
    assert len(lines) == 1 and __import__("re").search(pattern, lines[0]), r.stderr
    assert not list(arts.glob("plan/*")), "nothing cached"


def test_a_start_in_collision_is_said_and_planned_anyway(tmp_path):
    """The arm bent down over the table puts the forearm's tip into it: the hard term's start is said, the plan
    runs."""
    start = {"yaw": 0.0, "shoulder": 1.2, "elbow": 1.5}
    problem = _problem(tmp_path, start=start, T=10)
    robot = shared_model(read_problem(problem).robot_spec())
    _, _, tm = _world(tmp_path)
    d = tm.value(np.array(list(start.values())))
    assert d.min() < 0   # the premise: in collision
    r = CliRunner().invoke(app, ["plan", "--problem", str(problem), "--iterations", "2", "--no-record",
                                 "--artifacts", str(tmp_path / "a")])
    assert r.exit_code == 0, r.output
    notes = [ln for ln in r.stderr.splitlines() if "the start is in collision" in ln]
    assert len(notes) == 1 and "'avoid'" in notes[0] and "planned anyway (hard)" in notes[0], r.stderr
    assert robot.n_q == 3 and list(Path(tmp_path / "a").glob("plan/*"))


def test_a_world_files_geometry_is_the_object_it_describes(tmp_path):
    """A URDF world file holding one board, welded at its pose: its distances are those of the same board given as
    a box (two routes to one geometry: equal up to rounding)."""
    (tmp_path / "shelf.urdf").write_text('<robot name="shelf"><link name="board"><collision><origin xyz="0 0 0.1"/>'
                                         '<geometry><box size="0.4 0.6 0.02"/></geometry></collision></link></robot>')
    scene = """
[[scene]]
name = "shelf"
type = "file"
file = "shelf.urdf"
pose = [0.45, 0.0, 0.5, 0.0, 0.0, 0.0]

[[scene]]
name = "board"
type = "box"
size = [0.4, 0.6, 0.02]
pose = [0.45, 0.0, 0.6, 0.0, 0.0, 0.0]
"""
    pf = read_problem(_problem(tmp_path, scene=scene))
    world = CollisionWorld(pf.robot_spec(), pf.doc["scene"])
    robot = shared_model(pf.robot_spec())
    assert sorted(world.scene_objects()) == ["board", "shelf"]
    a = SignedDistances(robot, world, resolve_pairs(world, [["robot", "shelf"]], {}, False, [], "t"), 1.0)
    b = SignedDistances(robot, world, resolve_pairs(world, [["robot", "board"]], {}, False, [], "t"), 1.0)
    Q = _postures(robot, 5, seed=3)
    (Da, Ja), (Db, Jb) = a.values_and_jacobians(Q), b.values_and_jacobians(Q)
    assert np.any(Da < 1.0)
    assert_close(Da, Db)
    assert_close(Ja, Jb, scale=1.0)
