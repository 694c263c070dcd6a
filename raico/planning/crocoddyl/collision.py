"""raico's collision terms on crocoddyl: the same geometry pairs in Pinocchio's GeometryModel (coal).

crocoddyl's own pair-collision residual (``ResidualModelPairCollision``: the witness points' difference
``p_1 - p_2`` under a 2-norm barrier, the first body's Jacobian only) is not in the crocoddyl this
environment installs (built without hpp-fcl: ``crocoddyl.ResidualModelPairCollision`` is missing), and its
``||p_1 - p_2||`` is the distance's magnitude, which grows again inside a penetration. The residual here
keeps its style and raico's cost exactly: one row per pair, the signed distance ``d`` (m, coal's, negative
in penetration) of the pair's geometries placed by Pinocchio's kinematics, under
``ActivationModelQuadraticBarrier`` with lower bound the margin (``w max(0, margin - d)^2`` with the
caller's weight ``2 w``), and its Jacobian ``n^T (J_2(p_2) - J_1(p_1))`` (``n`` from the first geometry
to the second, both bodies' Jacobians at the witness points).

The geometry is raico's own (``raico.plants.scene``): primitives as they are, meshes as coal's convex hulls of
the same vertices (Drake's ``Convex``), the scene on the universe joint. A world file's geometry
(``type = "file"``) has no shape here: ``NotExpressible`` says so in one line.
"""

from __future__ import annotations

import numpy as np

from raico.planning.crocoddyl.model import NotExpressible, assign, crocoddyl, pin


def _coal_shape(shape):
    """coal's geometry of a ``raico.plants.scene.Shape``."""
    import coal

    if shape.kind == "box":
        return coal.Box(*shape.size)
    if shape.kind == "sphere":
        return coal.Sphere(shape.size[0])
    if shape.kind == "cylinder":
        return coal.Cylinder(*shape.size)
    if shape.kind == "capsule":
        return coal.Capsule(*shape.size)
    pts = coal.StdVec_Vec3s()
    for p in np.asarray(shape.vertices, float):
        pts.append(p)
    return coal.Convex.convexHull(pts, False, "")


def _se3(pose) -> pin.SE3:
    from raico.plants.model_file import rpy_matrix

    return pin.SE3(rpy_matrix(pose[3:]), np.asarray(pose[:3], float))


def geometry_model(model, world, pairs: list[tuple[str, str]]):
    """Pinocchio's ``GeometryModel`` of the pairs' geometries (raico's collision world ``world``) on
    ``model``, and the pairs' indices in it."""
    gm = pin.GeometryModel()
    index: dict[str, int] = {}
    for name in dict.fromkeys(n for p in pairs for n in p):
        shape = world.shapes_by_name.get(name)
        if shape is None:
            raise NotExpressible(f"crocoddyl: the collision geometry '{name}' (a world file's) has no shape here")
        if shape.body == "world":
            joint, frame, placement = 0, 0, _se3(shape.pose)
        else:
            if not model.existFrame(shape.body, pin.BODY):
                raise NotExpressible(f"crocoddyl: link '{shape.body}' is not a body of Pinocchio's model")
            frame = model.getFrameId(shape.body, pin.BODY)
            f = model.frames[frame]
            joint, placement = f.parentJoint, f.placement * _se3(shape.pose)
        index[name] = gm.addGeometryObject(pin.GeometryObject(name, joint, frame, placement, _coal_shape(shape)))
    ids = []
    for a, b in pairs:
        gm.addCollisionPair(pin.CollisionPair(index[a], index[b]))
        ids.append(gm.findCollisionPair(pin.CollisionPair(index[a], index[b])))
    return gm, ids


if crocoddyl is not None:
    class PairDistances(crocoddyl.ResidualModelAbstract):
        """The signed distances ``(m,)`` (m) of geometry pairs and their Jacobian (module docstring)."""

        def __init__(self, state, nu: int, gmodel, pair_ids: list[int]):
            crocoddyl.ResidualModelAbstract.__init__(self, state, len(pair_ids), nu, True, False, False)
            self.pmodel, self.gmodel, self.pair_ids = state.pinocchio, gmodel, list(pair_ids)

        def _distances(self, data, x, jacobians: bool):
            q = np.asarray(x)[:self.state.nq]
            pm, pd, gd = self.pmodel, data.pdata, data.gdata
            if jacobians:
                pin.computeJointJacobians(pm, pd, q)
            else:
                pin.forwardKinematics(pm, pd, q)
            pin.updateGeometryPlacements(pm, pd, self.gmodel, gd)
            d = np.empty(len(self.pair_ids))
            J = np.zeros((len(self.pair_ids), self.state.nv)) if jacobians else None
            for k, pid in enumerate(self.pair_ids):
                pin.computeDistance(self.gmodel, gd, pid)
                res = gd.distanceResults[pid]
                d[k] = res.min_distance
                if jacobians:
                    pair = self.gmodel.collisionPairs[pid]
                    n = np.asarray(res.normal)
                    for sign, g, p in ((-1.0, pair.first, res.getNearestPoint1()),
                                       (1.0, pair.second, res.getNearestPoint2())):
                        jid = self.gmodel.geometryObjects[g].parentJoint
                        if jid == 0:
                            continue
                        Jj = pin.getJointJacobian(pm, pd, jid, pin.LOCAL_WORLD_ALIGNED)
                        r = np.asarray(p) - pd.oMi[jid].translation
                        J[k] += sign * (n @ (Jj[:3] - pin.skew(r) @ Jj[3:]))
            return d, J

        def calc(self, data, x, u=None):
            data.r[:] = self._distances(data, x, False)[0]

        def calcDiff(self, data, x, u=None):
            d, J = self._distances(data, x, True)
            Rx = np.zeros((self.nr, self.state.ndx))
            Rx[:, :self.state.nv] = J
            assign(data.Rx, Rx)

        def createData(self, collector):
            return _PairData(self, collector)

    class _PairData(crocoddyl.ResidualDataAbstract):
        def __init__(self, model, collector):
            crocoddyl.ResidualDataAbstract.__init__(self, model, collector)
            self.pdata = model.pmodel.createData()
            self.gdata = pin.GeometryData(model.gmodel)


def items_collision(term, state, nu, model, smap, robot):
    """A collision term's crocoddyl items: :class:`PairDistances` under a quadratic barrier at its margin."""
    tm = term.taskmap
    gm, ids = geometry_model(model, tm.world, tm.pairs)
    m = len(ids)
    bounds = crocoddyl.ActivationBounds(np.full(m, term.margin), np.full(m, np.inf))
    return [(PairDistances(state, nu, gm, ids), crocoddyl.ActivationModelQuadraticBarrier(bounds))]
