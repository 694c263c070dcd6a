"""A collision term on crocoddyl: the same pairs in Pinocchio's GeometryModel (coal) cost and derive as raico's
(Drake's SceneGraph)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.plants.test_scene import AVOID, REACH, _problem

crocoddyl = pytest.importorskip("crocoddyl")


def test_collision_pairs_cost_and_derive_in_crocoddyl_as_in_raico(tmp_path):
    """Pairs with a sphere have closed-form distances on both sides: values and Jacobians agree to rounding. The
    others go through two GJK codes (FCL's in Drake, coal's), each accurate to about 1e-7 m: their values agree to
    1e-5 m; their witness points are not unique on parallel faces, so their Jacobians are left out. The term's
    total over a trajectory (margin 0.2 m: most pairs count) agrees to 1e-6 relative."""
    import raico.planning.crocoddyl.solve as cm
    from raico.planning.costs import Collision
    from raico.planning.crocoddyl.collision import PairDistances, geometry_model
    from tests.planning.test_crocoddyl_model_files import _crocoddyl_term_costs, _trajectory, raico_problem

    path = _problem(tmp_path, costs=REACH + AVOID.format(dmax=1.0).replace("margin = 0.02", "margin = 0.2"))
    robot, problem = raico_problem(path)
    cp = cm.build(problem)
    X, U = _trajectory(problem, 0)
    raico, croc = problem.cost_terms(X, U), _crocoddyl_term_costs(cp, X, U)
    assert raico["avoid"] > 0 and abs(croc["avoid"] - raico["avoid"]) <= 1e-6 * raico["avoid"]
    term = next(t for t in problem.state_terms if isinstance(t, Collision))
    tm = term.taskmap
    gm, ids = geometry_model(cp.pmodel, tm.world, tm.pairs)
    res = PairDistances(crocoddyl.StateMultibody(cp.pmodel), robot.n_q, gm, ids)
    data = res.createData(crocoddyl.DataCollectorMultibody(cp.pmodel.createData()))
    sphere = np.array([any(tm.world.shapes_by_name[n].kind == "sphere" for n in p) for p in tm.pairs])
    assert sphere.any() and (~sphere).any()
    for x in X[:6]:
        xp = cp.to_pin(x[None])[0]
        res.calc(data, xp)
        res.calcDiff(data, xp)
        d, J = tm.value_and_jacobian(x[:robot.n_q])
        r, Rx = np.asarray(data.r), np.asarray(data.Rx)[:, :robot.n_q]
        # sphere pairs: closed forms on both sides, equal up to rounding of the kinematics (metres, m/rad)
        assert np.max(np.abs(r[sphere] - d[sphere])) <= 1e-9 * max(1.0, np.abs(d[sphere]).max())
        assert np.max(np.abs(Rx[sphere] - J[sphere])) <= 1e-9 * max(1.0, np.abs(J).max())
        assert np.max(np.abs(r[~sphere] - d[~sphere])) <= 1e-5
