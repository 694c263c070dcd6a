"""The frame orientation and pose errors (``FrameRotationError``, ``FramePlacementError``) and the
SO(3) / SE(3) logarithms beneath them.

- ``log3``, ``Jlog3``, ``log6``, ``Jlog6`` equal Pinocchio's on random rotations at every angle
  range its formulas distinguish (0, the Taylor thresholds, generic, near and at pi), and each
  Jacobian is the derivative of its logarithm along a right (LOCAL) perturbation;
- both maps' Jacobians against central differences on arm5, biorob and the Nao at random postures,
  Drake's and the compiled tree kernels' routes the same; the registered examples
  (``TASKMAP_EXAMPLES``) are checked by ``tests/plants/test_derivatives.py`` as every other map;
- residual and Jacobian equal crocoddyl's ``ResidualModelFrameRotation`` and
  ``ResidualModelFramePlacement`` on the same robot (arm5, biorob);
- the batched logarithms (``log3_angle_rows``, ...) and the maps' batches (compiled and Drake's)
  equal the scalar functions row by row, each branch's rows mixed in one batch;
- the JSON descriptions of ``raico.planning.objective`` build them.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from raico.planning import objective
from raico.plants.numdiff import check_taskmap, numdiff_jacobian
from raico.plants.robots import shared_robot
from raico.plants.taskmaps import (
    FramePlacementError,
    FrameRotationError,
    Jlog3,
    Jlog6,
    jlog3,
    jlog3_rows,
    jlog6,
    jlog6_rows,
    log3,
    log3_angle,
    log3_angle_rows,
    log6,
    log6_parts,
    log6_parts_rows,
)
from tests.tolerance import REL, assert_close, bound, scale_of

with warnings.catch_warnings():   # pinocchio imports its collision library by its old name
    warnings.simplefilter("ignore")
    try:
        import pinocchio as pin
    except ImportError:
        pin = None
# only the comparisons with Pinocchio's own functions need it; rotations here come from numpy
needs_pin = pytest.mark.skipif(pin is None, reason="pinocchio is not installed (pip extra baseline)")

# angles (rad) at and around every branch of Pinocchio's formulas: 0, the Taylor thresholds
# (6.1e-6 and 1.2e-4), generic, the explicit near-pi branch (1 - cos < 6.1e-6, pi - theta < 3.5e-3)
ANGLES = [0.0, 1e-12, 1e-9, 1e-7, 5e-6, 6.1e-6, 1e-5, 1.2e-4, 1.3e-4, 1e-3, 0.1, 1.0, 2.0, 3.0,
          np.pi - 1e-2, np.pi - 4e-3, np.pi - 3e-3, np.pi - 1e-3, np.pi - 1e-5, np.pi - 1e-8, np.pi]


def _skew3(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _exp3(w) -> np.ndarray:
    """Rodrigues' formula: the rotation ``(3, 3)`` of the rotation vector ``w (3,)`` (rad)."""
    w = np.asarray(w, float)
    th = float(np.linalg.norm(w))
    K = _skew3(w)
    if th < 1e-4:   # Taylor series: the closed form loses digits in 1 - cos
        a, b = 1.0 - th**2 / 6.0, 0.5 - th**2 / 24.0
    else:
        a, b = np.sin(th) / th, (1.0 - np.cos(th)) / th**2
    return np.eye(3) + a * K + b * K @ K


def _rotation(axis, angle) -> np.ndarray:
    return _exp3(np.asarray(axis, float) / np.linalg.norm(axis) * angle)


def _random_cases(seed: int = 0, per_angle: int = 12):
    """``(R, p)``: per angle the three coordinate axes and random axes, random translations."""
    rng = np.random.default_rng(seed)
    for angle in ANGLES:
        for k in range(per_angle):
            axis = np.eye(3)[k] if k < 3 else rng.standard_normal(3)
            yield _rotation(axis, angle), 2.0 * rng.standard_normal(3)


@pytest.mark.numerics
@needs_pin
def test_logs_and_their_jacobians_equal_pinocchios():
    worst = np.zeros(4)
    for R, p in _random_cases():
        M = pin.SE3(R, p)
        errs = [np.max(np.abs(log3(R) - pin.log3(R))), np.max(np.abs(Jlog3(R) - pin.Jlog3(R))),
                np.max(np.abs(log6(R, p) - pin.log6(M).vector)), np.max(np.abs(Jlog6(R, p) - pin.Jlog6(M)))]
        worst = np.maximum(worst, errs)
    assert np.all(worst <= 1e-9), f"log3, Jlog3, log6, Jlog6 differ from Pinocchio's by {worst}"


@pytest.mark.numerics
def test_log3_inverts_exp_and_is_continuous_below_pi():
    rng = np.random.default_rng(1)
    for angle in ANGLES[:-1]:   # at pi itself r and -r are both logarithms
        r = rng.standard_normal(3)
        r *= angle / np.linalg.norm(r)
        got = log3(_rotation(r, np.linalg.norm(r)) if angle else np.eye(3))
        assert np.max(np.abs(got - r)) <= 1e-7 * max(1.0, angle), (angle, got, r)
    # exactly pi about x: rotation angle pi, axis +-x
    r = log3(np.diag([1.0, -1.0, -1.0]))
    assert np.isclose(np.linalg.norm(r), np.pi) and np.allclose(np.abs(r), [np.pi, 0, 0])


def _exp6(d: np.ndarray) -> np.ndarray:
    """The pose ``(4, 4)`` of the twist ``d = (v, w) (6,)`` (Pinocchio's ``exp6`` of ``Motion(v, w)``)."""
    v, w = d[:3], d[3:]
    th = float(np.linalg.norm(w))
    K = _skew3(w)
    if th < 1e-4:
        b, c = 0.5 - th**2 / 24.0, 1.0 / 6.0 - th**2 / 120.0
    else:
        b, c = (1.0 - np.cos(th)) / th**2, (th - np.sin(th)) / th**3
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = _exp3(w), (np.eye(3) + b * K + c * K @ K) @ v
    return M


@pytest.mark.numerics
@pytest.mark.parametrize("angle", [0.0, 1e-5, 0.3, 2.0, np.pi - 1e-2])
def test_jlog_is_the_derivative_along_a_local_perturbation(angle):
    """``d log3(R exp(d)) / dd = Jlog3(R)`` and ``d log6(M exp6(d)) / dd = Jlog6(M)`` by central
    differences (independent of Pinocchio's Jlog functions). Step 1e-4: near pi the logarithm
    itself loses digits (``theta / sin theta`` amplifies rounding), which smaller steps magnify."""
    rng = np.random.default_rng(int(angle * 1000))
    R = _rotation(rng.standard_normal(3), angle) if angle else np.eye(3)
    p = rng.standard_normal(3)
    fd3 = numdiff_jacobian(lambda d: log3(R @ _exp3(d)), np.zeros(3), eps=1e-4)
    np.testing.assert_allclose(Jlog3(R), fd3, rtol=0, atol=1e-7)
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, p

    def f6(d):
        X = M @ _exp6(d)
        return log6(X[:3, :3], X[:3, 3])

    np.testing.assert_allclose(Jlog6(R, p), numdiff_jacobian(f6, np.zeros(6), eps=1e-4), rtol=0, atol=1e-7)
    # a wrong derivative is seen: the transposed Jlog3 (the left Jacobian's inverse) differs
    if angle > 0.1:
        assert np.max(np.abs(Jlog3(R).T - fd3)) > 1e-3


# -- the batched logarithms --------------------------------------------------------------------------
def _mixed_batch(seed: int = 5):
    """``(R (K, 3, 3), p (K, 3))``: every angle of ``ANGLES`` and pi - 1e-7 about coordinate and
    random axes, slightly non-orthonormal copies of some, and random rotations, shuffled so that
    each branch's rows sit between the others'."""
    rng = np.random.default_rng(seed)
    Rs = [R for R, _ in _random_cases(seed, per_angle=5)]
    Rs += [_rotation(rng.standard_normal(3), np.pi - 1e-7) for _ in range(4)]
    Rs += [_exp3(rng.standard_normal(3)) for _ in range(20)]
    Rs += [R + 1e-9 * rng.standard_normal((3, 3)) for R in Rs[::7]]   # renormalized first
    R = np.array(Rs)[rng.permutation(len(Rs))]
    return R, 2.0 * rng.standard_normal((len(R), 3))


@pytest.mark.numerics
def test_batched_logarithms_equal_the_scalar_ones_row_by_row():
    R, p = _mixed_batch()
    angles = np.array([log3_angle(Rk)[0] for Rk in R])
    for a in (0.0, 1e-7, 1e-5, np.pi - 1e-7, np.pi):   # each branch has rows in the batch
        assert np.any(np.abs(angles - a) <= REL + 0.05 * min(a, np.pi - a)), a
    theta, r = log3_angle_rows(R)
    J3 = jlog3_rows(theta, r)
    theta6, w6, l6 = log6_parts_rows(R, p)
    J6 = jlog6_rows(theta6, w6, p)
    assert theta.shape == (len(R),) and r.shape == (len(R), 3) and J3.shape == (len(R), 3, 3)
    assert l6.shape == (len(R), 6) and J6.shape == (len(R), 6, 6)
    for k in range(len(R)):
        th, rk = log3_angle(R[k])
        th6, wk, lk = log6_parts(R[k], p[k])
        # the inputs' scale: a rotation's entries (1) and the translation's (|p|)
        s6 = max(1.0, scale_of(p[k]))
        assert_close([theta[k], theta6[k]], [th, th6], scale=1.0, err_msg=str(k))
        assert_close(r[k], rk, scale=1.0, err_msg=str(k))
        assert_close(J3[k], jlog3(th, rk), scale=1.0, err_msg=str(k))
        assert_close(w6[k], wk, scale=1.0, err_msg=str(k))
        assert_close(l6[k], lk, scale=s6, err_msg=str(k))
        assert_close(J6[k], jlog6(th6, wk, p[k]), scale=s6, err_msg=str(k))


def test_batched_logarithms_raise_no_warning_on_the_branches_they_do_not_take():
    """The generic formulas are evaluated on every row with safe arguments (no division by
    sin 0 or 1 - cos 0 left for np.where to discard)."""
    R, p = _mixed_batch(6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        theta, w, _ = log6_parts_rows(R, p)
        jlog6_rows(theta, w, p)
        jlog3_rows(*log3_angle_rows(R))


# -- the task maps on the robots --------------------------------------------------------------------
def _pose(robot, frame: str, q: np.ndarray):
    plant = robot.plant
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, robot.P @ q)
    X = plant.CalcRelativeTransform(ctx, plant.world_frame(), plant.GetFrameByName(frame))
    return X.rotation().matrix(), X.translation()


def _random_postures(robot, rng, K: int) -> np.ndarray:
    lo = np.where(np.isfinite(robot.lower), robot.lower, -np.pi)
    hi = np.where(np.isfinite(robot.upper), robot.upper, np.pi)
    return lo + (hi - lo) * rng.uniform(0.1, 0.9, (K, robot.n_q))


def _maps(robot, frame: str, rng):
    """Both maps on ``frame``, targeted at the pose of another random posture turned by 1 rad."""
    R, p = _pose(robot, frame, _random_postures(robot, rng, 1)[0])
    R_t = R @ _rotation(rng.standard_normal(3), 1.0)
    return [FrameRotationError(robot, frame, R_t, name="rot"),
            FramePlacementError(robot, frame, R_t, p + 0.1 * rng.standard_normal(3), name="place")]


FRAMES = [("arm5", "ee"), ("biorob", "ee"), ("nao", "r_gripper"), ("nao", "r_sole")]


@pytest.mark.numerics
@pytest.mark.compiled
@pytest.mark.parametrize("plant,frame", FRAMES, ids=lambda x: x)
def test_jacobians_against_finite_differences_at_random_postures(plant, frame):
    robot = shared_robot(plant)
    rng = np.random.default_rng(7)
    for tm in _maps(robot, frame, rng):
        Q = _random_postures(robot, rng, 6)
        V = tm.values_and_jacobians(Q)[0]
        angle = np.linalg.norm(V[:, -3:], axis=1)
        Q = Q[angle < np.pi - 0.05]   # log3 jumps at pi: differences across it are no derivative
        assert len(Q) >= 3
        check_taskmap(tm, Q, atol=1e-6).assert_passed()
        assert np.max(np.abs(tm.values_and_jacobians(Q)[0])) > 0.1   # a non-trivial error


@pytest.mark.numerics
@pytest.mark.compiled
@pytest.mark.parametrize("plant,frame", FRAMES[:3], ids=lambda x: x)
def test_compiled_and_drake_routes_agree(plant, frame):
    robot = shared_robot(plant)
    rng = np.random.default_rng(11)
    for tm in _maps(robot, frame, rng):
        assert tm.tree_kernels() is not None
        for qp in _random_postures(robot, rng, 3) @ robot.P.T:
            v_c, J_c = tm._compiled_in_plant(tm.tree_kernels(), qp)
            v_d, J_d = tm._in_plant(qp)
            assert_close(v_c, v_d, scale=1.0)   # radians and metres of a robot of about 1 m
            assert_close(J_c, J_d, scale=1.0)


@pytest.mark.numerics
@pytest.mark.parametrize("cls", [FrameRotationError, FramePlacementError])
def test_batched_residuals_equal_the_scalar_residual_row_by_row(cls):
    """``_residuals`` on a batch of world poses and Jacobians (errors at every branch's angle,
    random Jacobians) equals ``_residual`` row by row."""
    robot = shared_robot("arm5")
    rng = np.random.default_rng(12)
    R_err, p = _mixed_batch(7)
    R_t = _rotation(rng.standard_normal(3), 0.7)
    R = R_t @ R_err   # the error rotation R_t^T R is R_err
    m = robot.n_q
    Jv, Jw = rng.standard_normal((len(R), 3, m)), rng.standard_normal((len(R), 3, m))
    tm = (FrameRotationError(robot, "ee", R_t) if cls is FrameRotationError
          else FramePlacementError(robot, "ee", R_t, rng.standard_normal(3)))
    V, J = tm._residuals(R, p, Jv, Jw)
    assert V.shape == (len(R), tm.dim) and J.shape == (len(R), tm.dim, m)
    for k in range(len(R)):
        v, Jk = tm._residual(R[k], p[k], Jv[k], Jw[k])
        assert_close(V[k], v, scale=max(1.0, scale_of(p[k])))
        assert_close(J[k], Jk, scale=max(1.0, scale_of(p[k])) * scale_of(Jv[k], Jw[k]))


@pytest.mark.numerics
@pytest.mark.compiled
@pytest.mark.parametrize("route", ["compiled", "drake"])
def test_batches_evaluate_the_logarithms_once_for_all_rows(route, monkeypatch):
    """``values_and_jacobians`` (the tree kernels' route and Drake's) never calls the per-row
    ``_residual``, and equals the points' ``value_and_jacobian`` (which does) row by row; a
    non-finite row gives NaN."""
    robot = shared_robot("arm5")
    rng = np.random.default_rng(13)
    Q = _random_postures(robot, rng, 9)
    Q[4] = np.nan
    for tm in _maps(robot, "ee", rng):
        if route == "drake":
            tm._kernels = False
        points = [tm.value_and_jacobian(q) for q in np.delete(Q, 4, axis=0)]
        with monkeypatch.context() as mp:
            mp.setattr(type(tm), "_residual", lambda *a: pytest.fail("per-row _residual in a batch"))
            V, J = tm.values_and_jacobians(Q)
        assert np.all(np.isnan(V[4])) and np.all(np.isnan(J[4]))
        V, J = np.delete(V, 4, axis=0), np.delete(J, 4, axis=0)
        assert_close(V, [v for v, _ in points], scale=1.0)
        assert_close(J, [Jk for _, Jk in points], scale=1.0)


@pytest.mark.numerics
def test_value_is_zero_at_the_target_and_the_jacobian_is_the_local_one():
    """At the target pose the error is 0 and ``Jlog = I``: the Jacobian is the LOCAL frame Jacobian
    (linear rows first), which Drake gives as the world spatial Jacobian rotated into F."""
    from pydrake.multibody.tree import JacobianWrtVariable

    robot = shared_robot("arm5")
    q = robot.default_q + 0.2
    R, p = _pose(robot, "ee", q)
    place = FramePlacementError(robot, "ee", R, p)
    rot = FrameRotationError(robot, "ee", R)
    v, J = place.value_and_jacobian(q)
    pose_scale = max(1.0, scale_of(p))   # zero up to the rounding of the pose's entries
    assert_close(v, np.zeros_like(v), scale=pose_scale)
    assert_close(rot.value_and_jacobian(q)[0], np.zeros(3), scale=1.0)
    plant, ctx = robot.plant, robot.plant.CreateDefaultContext()
    plant.SetPositions(ctx, robot.P @ q)
    Js = plant.CalcJacobianSpatialVelocity(ctx, JacobianWrtVariable.kV, plant.GetFrameByName("ee"),
                                           np.zeros(3), plant.world_frame(), plant.world_frame())
    J_local = np.vstack([R.T @ Js[3:], R.T @ Js[:3]]) @ robot.P
    assert_close(J, J_local, scale=pose_scale)
    assert_close(rot.value_and_jacobian(q)[1], J_local[3:], scale=1.0)
    # a translated target moves the linear part only (by R^T dp, at zero rotation error)
    place2 = FramePlacementError(robot, "ee", R, p - np.array([0.0, 0.0, 0.1]))
    assert_close(place2.value_and_jacobian(q)[0], np.r_[R.T @ [0.0, 0.0, 0.1], 0, 0, 0], scale=pose_scale)


# -- the same residuals as crocoddyl's ---------------------------------------------------------------
@pytest.mark.numerics
@needs_pin
@pytest.mark.compiled
@pytest.mark.parametrize("plant", ["arm5", "biorob"])
def test_equal_to_crocoddyls_frame_residuals(plant, crocoddyl_baseline):
    import crocoddyl

    cm = crocoddyl_baseline
    model = cm.pinocchio_robot(shared_robot(plant))[0]
    robot = shared_robot(plant)
    state = crocoddyl.StateMultibody(model)
    fid = model.getFrameId("ee")
    rng = np.random.default_rng(3)
    rot, place = _maps(robot, "ee", rng)
    res_rot = crocoddyl.ResidualModelFrameRotation(state, fid, rot.R_target, model.nv)
    res_place = crocoddyl.ResidualModelFramePlacement(
        state, fid, pin.SE3(place.R_target, place.p_target), model.nv)
    pdata = model.createData()
    collector = crocoddyl.DataCollectorMultibody(pdata)
    datas = [(res_rot, res_rot.createData(collector), rot), (res_place, res_place.createData(collector), place)]
    for q in _random_postures(robot, rng, 4):
        x = np.concatenate([q, np.zeros(model.nv)])
        pin.forwardKinematics(model, pdata, q)
        pin.updateFramePlacements(model, pdata)
        pin.computeJointJacobians(model, pdata, q)
        for res, data, tm in datas:
            res.calc(data, x)
            res.calcDiff(data, x)
            v, J = tm.value_and_jacobian(q)
            assert_close(v, data.r, scale=1.0)   # radians and metres of a robot of about 1 m
            assert_close(J, data.Rx[:, :model.nv], scale=1.0)


# -- the JSON descriptions --------------------------------------------------------------------------
@pytest.mark.numerics
@pytest.mark.compiled
def test_descriptions_build_the_maps():
    robot = shared_robot("arm5")
    q = robot.default_q + 0.1
    R, p = _pose(robot, "ee", robot.default_q)
    descs = [objective.frame_rotation("ee", R, "ee_rot"), objective.frame_placement("ee", R, p, "ee_pose")]
    assert descs[0] == {"map": "frame_rotation", "frame": "ee", "rotation": R.tolist(), "name": "ee_rot"}
    assert descs[1]["map"] == "frame_placement" and descs[1]["translation"] == p.tolist()
    built = [objective.build_taskmap(robot, json.loads(json.dumps(d))) for d in descs]
    assert [type(m) for m in built] == [FrameRotationError, FramePlacementError]
    assert [m.dim for m in built] == [3, 6] and [m.name for m in built] == ["ee_rot", "ee_pose"]
    direct = [FrameRotationError(robot, "ee", R), FramePlacementError(robot, "ee", R, p)]
    for m, d in zip(built, direct):
        np.testing.assert_array_equal(m.value_and_jacobian(q)[0], d.value_and_jacobian(q)[0])
    # a via-point on them has the target zeros(dim): zero cost at the target posture, positive off it
    terms = objective.build_terms(robot, [objective.via("v", desc, np.zeros(m.dim), [1], 1e2)
                                          for desc, m in zip(descs, built)], T=2)
    X = np.zeros((3, 2 * robot.n_q))
    X[:, :robot.n_q] = robot.default_q
    for term in terms.state_terms:
        # zero up to the rounding of the residual (REL of its unit scale), squared and weighted
        assert 0.0 <= term.value(X, np.arange(3))[1] <= 1e2 * 6 * REL**2
    X[1, :robot.n_q] = q
    assert all(term.value(X, np.arange(3))[1] > 1e-3 for term in terms.state_terms)


@pytest.mark.numerics
def test_without_pinocchio_only_the_comparisons_with_it_skip():
    """With Pinocchio hidden, the tests on Drake's maps and the numpy rotations still run: a pytest of
    one of them passes, not skips; ``_exp3`` and ``_exp6`` are Pinocchio's exponentials where it is."""
    import subprocess
    import sys
    from pathlib import Path

    code = ("import sys, pytest; sys.modules['pinocchio'] = None; "
            "sys.exit(pytest.main(['-q', '-p', 'no:cacheprovider', '-rs', sys.argv[1]]))")
    test = f"{Path(__file__).resolve()}::test_batched_residuals_equal_the_scalar_residual_row_by_row"
    res = subprocess.run([sys.executable, "-c", code, test], capture_output=True, text=True, timeout=300,
                         cwd=Path(__file__).resolve().parents[2])
    assert res.returncode == 0 and "2 passed" in res.stdout and "skipped" not in res.stdout, res.stdout[-2000:]
    if pin is not None:
        rng = np.random.default_rng(2)
        for scale in (1e-6, 0.5, 3.0):
            d = scale * rng.standard_normal(6)
            # Rodrigues' formula: entries of size <= 1 from sin, cos and four products (libm's sin and
            # cos within a few units in the last place: c = 8 covers them)
            np.testing.assert_allclose(_exp3(d[3:]), pin.exp3(d[3:]), rtol=0, atol=bound(4))
            np.testing.assert_allclose(_exp6(d), pin.exp6(pin.Motion(d[:3], d[3:])).homogeneous,
                                       rtol=0, atol=bound(4) * max(1.0, np.abs(d).max()))
