"""raico's cost terms as crocoddyl residuals and activations.

Terms (:func:`cost_items`, the function the term's row of :mod:`raico.planning.term_kinds` names: crocoddyl
``(residual, activation)`` pairs whose summed cost ``1/2 sum a(r)`` is the raico term's cost divided by 2;
the caller weighs them ``2 w`` on the terminal node and ``2 w / dt`` on running nodes):

- a via-point on a frame's origin or points fixed in it (``frame_points``): a ``ResidualModelFrameTranslation``
  per point, on a Pinocchio frame at that point of the Drake frame (an operational frame where the Drake frame
  is not a link's origin); the diagonal precision as activation weights, 0 on coordinates left out;
- ``frame_rotation``, ``frame_placement``: ``ResidualModelFrameRotation`` /
  ``ResidualModelFramePlacement`` (raico's task maps are exactly their log3/log6 residuals);
- ``roll``: a Python residual with raico's Jacobian;
- ``joints`` (a posture via-point) and ``state``: ``ResidualModelState`` to the target, weights on
  the joints named (0 elsewhere);
- ``cog``: Pinocchio's centre of mass computed by a Python residual (crocoddyl's own CoM residual
  reads a value its free forward dynamics do not compute), its target moved and its weights
  scaled so that it is Drake's centre of mass, which counts the links welded to the world (a fixed
  base) that Pinocchio's universe carries;
- ``control`` (its target, its per-joint weights as activation weights) ``ResidualModelControl``; toward
  gravity (``raico.planning.costs.ControlGravity``) ``ResidualModelControlGrav`` (on a model that damps its joints a
  Python residual on the control, as raico's term: crocoddyl's measures the damped actuation's torque);
  ``control_limit`` the control under ``ActivationModelQuadraticBarrier`` (raico's squared hinge); an
  inequality on joint positions whose rows are +-unit vectors (``joint_limit``) the state under a barrier;
- ``collision``: the pairs' signed distances in Pinocchio's GeometryModel under a quadratic barrier at the
  margin (:mod:`raico.planning.crocoddyl.collision`; crocoddyl's own pair-collision residual is not in this build).

What has no exact counterpart (a non-diagonal precision, a non-zero target of a pose error, an inequality
on another task map or with general rows, the uncertainty term) raises ``NotExpressible`` with one line.
"""

from __future__ import annotations

import math

import numpy as np

from raico.planning.crocoddyl.model import NotExpressible, StateMap, assign, crocoddyl, frame_id, pin

if crocoddyl is not None:
    class _RollResidual(crocoddyl.ResidualModelAbstract):
        """raico's roll angle minus its target: ``atan2(y_E . z_W, z_E . z_W) - target`` (rad).

        Jacobian as ``raico.plants.taskmaps.RollAngle``: ``d(e . z_W) = J_w . (e x z_W)`` with the
        world-frame angular-velocity Jacobian ``J_w`` of the frame."""

        def __init__(self, state, frame_id: int, target: float, nu: int):
            crocoddyl.ResidualModelAbstract.__init__(self, state, 1, nu, True, False, False)
            self.fid, self.target, self.pmodel = frame_id, float(target), state.pinocchio

        def _kin(self, data, x):
            q = np.asarray(x)[:self.state.nq]
            pin.forwardKinematics(self.pmodel, data.pdata, q)
            R = pin.updateFramePlacement(self.pmodel, data.pdata, self.fid).rotation
            return q, R[:, 1], R[:, 2]

        def calc(self, data, x, u=None):
            _, y, z = self._kin(data, x)
            data.r[:] = [math.atan2(y[2], z[2]) - self.target]

        def calcDiff(self, data, x, u=None):
            q, y, z = self._kin(data, x)
            up = np.array([0.0, 0.0, 1.0])
            Jw = pin.computeFrameJacobian(self.pmodel, data.pdata, q, self.fid, pin.LOCAL_WORLD_ALIGNED)[3:]
            a, b = y[2], z[2]
            da, db = np.cross(y, up) @ Jw, np.cross(z, up) @ Jw
            Rx = np.zeros((1, self.state.ndx))
            Rx[0, :self.state.nv] = (b * da - a * db) / (a * a + b * b)
            assign(data.Rx, Rx)

        def createData(self, collector):
            return _OwnKinematicsData(self, collector)

    class _OwnKinematicsData(crocoddyl.ResidualDataAbstract):
        """A Python residual's data with its own Pinocchio data (the action's data is left alone)."""

        def __init__(self, model, collector):
            crocoddyl.ResidualDataAbstract.__init__(self, model, collector)
            self.pdata = model.pmodel.createData()  # own kinematics: the action's data is left alone


# ----------------------------------------------------------------------------- the terms
if crocoddyl is not None:
    class _CoMResidual(crocoddyl.ResidualModelAbstract):
        """Pinocchio's centre of mass minus ``ref`` (3 rows), computed here: crocoddyl's
        ``ResidualModelCoMPosition`` reads ``data.com[0]``, which its free forward dynamics leave
        uncomputed on the ABA route (no crocoddyl armature; crocoddyl 3.2.0), so its value there
        is stale (zero)."""

        def __init__(self, state, ref: np.ndarray, nu: int):
            crocoddyl.ResidualModelAbstract.__init__(self, state, 3, nu, True, False, False)
            self.ref, self.pmodel = np.asarray(ref, float).copy(), state.pinocchio

        def calc(self, data, x, u=None):
            q = np.asarray(x)[:self.state.nq]
            data.r[:] = pin.centerOfMass(self.pmodel, data.pdata, q, False) - self.ref

        def calcDiff(self, data, x, u=None):
            q = np.asarray(x)[:self.state.nq]
            J = pin.jacobianCenterOfMass(self.pmodel, data.pdata, q, False)
            Rx = np.zeros((3, self.state.ndx))
            Rx[:, :self.state.nv] = J
            data.Rx[:, :] = Rx

        def createData(self, collector):
            return _OwnKinematicsData(self, collector)

    class ControlGravityResidual(crocoddyl.ResidualModelAbstract):
        """``u - g(q)`` on the control ``u`` itself (N m, Pinocchio's generalized gravity ``g``): raico's
        ``ControlGravity``. crocoddyl's ``ResidualModelControlGrav`` measures the actuation's torque instead,
        ``u - D v`` under a damped actuation (a model file's ``<dynamics damping>``), so its cost differs
        there from raico's by the damping torque (and its Jacobian leaves out that torque's ``-D``)."""

        def __init__(self, state, nu: int):
            crocoddyl.ResidualModelAbstract.__init__(self, state, state.nv, nu, True, False, True)
            self.pmodel = state.pinocchio

        def calc(self, data, x, u=None):
            q = np.asarray(x)[:self.state.nq]
            g = pin.computeGeneralizedGravity(self.pmodel, data.pdata, q)
            data.r[:] = (-g if u is None else np.asarray(u) - g)

        def calcDiff(self, data, x, u=None):
            q = np.asarray(x)[:self.state.nq]
            Rx = np.zeros((self.state.nv, self.state.ndx))
            Rx[:, :self.state.nv] = -pin.computeGeneralizedGravityDerivatives(self.pmodel, data.pdata, q)
            assign(data.Rx, Rx)
            if u is not None:
                assign(data.Ru, np.eye(self.state.nv))

        def createData(self, collector):
            return _OwnKinematicsData(self, collector)


def _diag(C: np.ndarray, what: str) -> np.ndarray:
    C = np.asarray(C, float)
    if not np.array_equal(C, np.diag(np.diag(C))):
        raise NotExpressible(f"crocoddyl: term {what!r} has a non-diagonal precision")
    return np.diag(C).copy()


def _state_ref(smap: StateMap, model, q: dict[int, float] | np.ndarray | None = None,
               v: np.ndarray | None = None) -> np.ndarray:
    """A Pinocchio state: Pinocchio's neutral posture with raico joint ``i`` at ``q[i]`` (a dict or a
    full vector), velocities ``v`` (raico order) or 0."""
    x = np.zeros(2 * smap.n)
    pin_q = np.asarray(pin.neutral(model), float)
    xp = smap.x_to_pin(x)
    xp[:smap.nq] = pin_q
    items = enumerate(q) if isinstance(q, np.ndarray) else (q or {}).items()
    for i, val in items:
        k = smap.q_index[i]
        if smap.continuous[i]:
            xp[k], xp[k + 1] = math.cos(val), math.sin(val)
        else:
            xp[k] = val
    if v is not None:
        xp[smap.nq + smap.v_index] = v
    return xp


def cost_items(term, state, nu: int, model, smap: StateMap, robot) -> list[tuple[object, object]]:
    """crocoddyl ``(residual, activation)`` pairs of a raico cost term (see the module docstring): the
    function its row of the cost-term table (:mod:`raico.planning.term_kinds`) names."""
    from raico.planning.term_kinds import kind_of_term

    row = kind_of_term(term)
    items = globals().get(row.crocoddyl) if row is not None and row.crocoddyl else None
    if items is None:
        raise NotExpressible(f"crocoddyl: no equivalent of the cost term {term.name!r} ({type(term).__name__})")
    return items(term, state, nu, model, smap, robot)


def items_state(term, state, nu, model, smap, robot):
    if term.target.ndim == 2:
        raise NotExpressible(f"crocoddyl: state term {term.name!r} has a target per step (one residual per node)")
    w = np.zeros(state.ndx)
    w[smap.tangent_index] = _diag(term.C, term.name)
    n = smap.n
    xref = _state_ref(smap, model, term.target[:n], term.target[n:])
    return [(crocoddyl.ResidualModelState(state, xref, nu), crocoddyl.ActivationModelWeightedQuad(w))]


def items_control(term, state, nu, model, smap, robot):
    act = (crocoddyl.ActivationModelQuad(nu) if term.c is None
           else crocoddyl.ActivationModelWeightedQuad(smap.u_to_pin(term.c)))
    if term.target is None:
        return [(crocoddyl.ResidualModelControl(state, nu), act)]
    return [(crocoddyl.ResidualModelControl(state, smap.u_to_pin(term.target)), act)]


def items_control_gravity(term, state, nu, model, smap, robot):
    """u - g(q), Pinocchio's generalized gravity: crocoddyl's ``ResidualModelControlGrav`` on an undamped
    model, raico's own residual on the control where the model damps its joints (crocoddyl's would
    measure the damped actuation's torque ``u - D v``, see ``ControlGravityResidual``)."""
    act = crocoddyl.ActivationModelWeightedQuad(smap.u_to_pin(term.c))
    if np.any(np.asarray(model.damping) != 0):
        return [(ControlGravityResidual(state, nu), act)]
    return [(crocoddyl.ResidualModelControlGrav(state, nu), act)]


def items_control_limit(term, state, nu, model, smap, robot):
    n = getattr(smap, "n_u", smap.n)   # an underactuated robot's motors (ActuatedMap)
    lo = smap.u_to_pin(np.broadcast_to(term.lower, (n,)).astype(float))
    hi = smap.u_to_pin(np.broadcast_to(term.upper, (n,)).astype(float))
    return [(crocoddyl.ResidualModelControl(state, nu),
             crocoddyl.ActivationModelQuadraticBarrier(crocoddyl.ActivationBounds(lo, hi)))]


def items_via(term, state, nu, model, smap, robot):
    """A via-point's crocoddyl residuals and activations: the function its task map's row of the
    task-map table (:mod:`raico.planning.term_kinds`) names."""
    from raico.planning.term_kinds import kind_of_map

    tm = term.taskmap
    row = kind_of_map(tm)
    build = globals().get(row.crocoddyl) if row is not None and row.crocoddyl else None
    if build is None:
        raise NotExpressible(f"crocoddyl: no equivalent of the task map {tm.name!r} ({type(tm).__name__})")
    return build(term, tm, _diag(term.C, term.name), state, nu, model, smap, robot)


def via_frame_points(term, tm, w, state, nu, model, smap, robot):
    axes = [int(r) for r in tm.rows[:len(tm.rows) // len(tm.points)]]
    k = len(axes)
    target = term.target.reshape(len(tm.points), k)
    out = []
    for j, point in enumerate(tm.points):
        fid = frame_id(model, robot, tm.frame.name(), point)
        ref, wj = np.zeros(3), np.zeros(3)
        ref[axes], wj[axes] = target[j], w[j * k:(j + 1) * k]
        out.append((crocoddyl.ResidualModelFrameTranslation(state, fid, ref, nu),
                    crocoddyl.ActivationModelWeightedQuad(wj)))
    return out


def via_roll(term, tm, w, state, nu, model, smap, robot):
    fid = frame_id(model, robot, tm.frame.name())
    return [(_RollResidual(state, fid, float(term.target[0]), nu), crocoddyl.ActivationModelWeightedQuad(w))]


def via_com(term, tm, w, state, nu, model, smap, robot):
    # Drake's centre of mass counts the links welded to the world (a fixed base), Pinocchio's
    # leaves out what its universe carries (m0 at c0): c_drake - ref = k (c_pin - ref') with
    # k = M / (M + m0), ref' = ((M + m0) ref - m0 c0) / M, exactly
    M, m0 = float(pin.computeTotalMass(model)), float(model.inertias[0].mass)
    c0 = np.asarray(model.inertias[0].lever, float)
    drake_mass = robot.plant.CalcTotalMass(robot.context)
    if not math.isclose(M + m0, drake_mass, rel_tol=1e-12):
        raise NotExpressible(f"crocoddyl: via-point {term.name!r} on the centre of mass: Drake's robot weighs "
                             f"{drake_mass:g} kg, Pinocchio's {M + m0:g} kg")
    k = M / (M + m0)
    ref, wc = np.zeros(3), np.zeros(3)
    ref[tm.axes], wc[tm.axes] = term.target, w
    ref = ((M + m0) * ref - m0 * c0) / M
    return [(_CoMResidual(state, ref, nu), crocoddyl.ActivationModelWeightedQuad(k * k * wc))]


def via_frame_pose(term, tm, w, state, nu, model, smap, robot):
    from raico.plants.taskmaps import FrameRotationError

    if np.any(term.target != 0):
        raise NotExpressible(f"crocoddyl: via-point {term.name!r} asks a pose error of {term.target.tolist()}, "
                             "crocoddyl's frame residuals are zero at their reference")
    fid = frame_id(model, robot, tm.frame.name())
    if isinstance(tm, FrameRotationError):
        res = crocoddyl.ResidualModelFrameRotation(state, fid, tm.R_target, nu)
    else:
        res = crocoddyl.ResidualModelFramePlacement(state, fid, pin.SE3(tm.R_target, tm.p_target), nu)
    return [(res, crocoddyl.ActivationModelWeightedQuad(w))]


def via_joints(term, tm, w, state, nu, model, smap, robot):
    idx = [int(np.flatnonzero(row)[0]) for row in tm.S]
    if len(set(idx)) != len(idx):
        raise NotExpressible(f"crocoddyl: via-point {term.name!r} names a joint twice")
    ws = np.zeros(state.ndx)
    ws[smap.v_index[idx]] = w
    xref = _state_ref(smap, model, dict(zip(idx, term.target)))
    return [(crocoddyl.ResidualModelState(state, xref, nu), crocoddyl.ActivationModelWeightedQuad(ws))]


def items_joint_bounds(term, state, nu, model, smap, robot=None):
    """``A q[idx] <= b`` with +-unit rows: the state difference to a reference under a quadratic
    barrier (reference 0 for revolute and prismatic joints, where the difference is ``q`` itself;
    the bounds' middle, or the bound, for a continuous joint)."""
    from raico.plants.taskmaps import JointPositions

    tm = term.taskmap
    if not isinstance(tm, JointPositions):
        raise NotExpressible(f"crocoddyl: the inequality {term.name!r} is on {type(tm).__name__}, not on joint "
                             "positions (only joint bounds have a crocoddyl counterpart)")
    idx = [int(np.flatnonzero(row)[0]) for row in tm.S]
    lo = np.full(len(idx), -np.inf)
    hi = np.full(len(idx), np.inf)
    for a, b in zip(term.A, term.b):
        nz = np.flatnonzero(a)
        if len(nz) != 1 or abs(a[nz[0]]) != 1.0:
            raise NotExpressible(f"crocoddyl: the inequality {term.name!r} has a row {a.tolist()} that is not a "
                                 "bound on one joint")
        k = int(nz[0])
        bound, upper = (b, True) if a[k] > 0 else (-b, False)
        if (hi if upper else lo)[k] != (np.inf if upper else -np.inf):
            raise NotExpressible(f"crocoddyl: the inequality {term.name!r} bounds joint {idx[k]} twice on one side")
        (hi if upper else lo)[k] = bound
    ref = {}
    for k, i in enumerate(idx):
        if smap.continuous[i]:
            ref[i] = (0.5 * (lo[k] + hi[k]) if np.isfinite(lo[k]) and np.isfinite(hi[k])
                      else lo[k] if np.isfinite(lo[k]) else hi[k] if np.isfinite(hi[k]) else 0.0)
        else:
            ref[i] = 0.0
    lb = np.full(state.ndx, -np.inf)
    ub = np.full(state.ndx, np.inf)
    for k, i in enumerate(idx):
        j = smap.v_index[i]
        lb[j], ub[j] = lo[k] - ref[i], hi[k] - ref[i]
    xref = _state_ref(smap, model, ref)
    return [(crocoddyl.ResidualModelState(state, xref, nu),
             crocoddyl.ActivationModelQuadraticBarrier(crocoddyl.ActivationBounds(lb, ub)))]


def items_collision(term, state, nu, model, smap, robot):
    """A collision term: the signed distances of its pairs in Pinocchio's GeometryModel under a quadratic
    barrier at its margin (:mod:`raico.planning.crocoddyl.collision`)."""
    from raico.planning.crocoddyl.collision import items_collision as items

    return items(term, state, nu, model, smap, robot)
