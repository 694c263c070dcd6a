"""raico's problems in crocoddyl's terms: the Pinocchio model of a robot, its coordinates, its cost terms.

:mod:`planning.crocoddyl_model` builds the ``ShootingProblem`` and runs FDDP; this module says
how a raico robot and each raico cost term become Pinocchio and crocoddyl objects, for the
built-in plants and for robots loaded from model files (:mod:`plants.model_file`). It holds the
optional import of crocoddyl and Pinocchio (``AVAILABLE``) and ``NotExpressible``, which
crocoddyl_model re-exports.

The model of a model-file robot (:func:`pinocchio_robot`): Pinocchio reads the SAME repaired URDF
text Drake reads (``plants.model_file.repair_urdf``: locked joints are fixed joints there, mimic
tags dropped), with a fixed base, which is where Drake puts the robot when its free root is welded
at the world origin (or the file attaches it to a ``world`` link). A robot welded on another frame
(a humanoid standing on a sole) re-roots the tree in Drake: Pinocchio's URDF tree is rooted at the
file's root link, so that is ``NotExpressible``. An MJCF file is read by Pinocchio's own MJCF reader
(``buildModelFromMJCF``), as Drake reads the file itself; an SDF file through Drake's reading of it
(:func:`model_from_drake`: Pinocchio's model built joint by joint from Drake's plant; Pinocchio's own
SDFormat reader is an option of its build, absent here). The armature of the spec is Pinocchio's
``model.armature`` (Drake's rotor inertia with gear ratio 1: both add it to the mass matrix's
diagonal); Drake's joint damping (the file's ``<dynamics damping>``), which Pinocchio's forward
dynamics ignores, enters through an actuation model ``tau = u - D v`` (crocoddyl_model's).

Continuous joints (``continuous``): raico's angle of a continuous joint is a real number, and its
costs take plain differences ``q - q*``. Pinocchio reads a URDF continuous joint as a unit complex
number ``(cos q, sin q)`` (nq 2, nv 1) and crocoddyl's state difference is then the angle
difference wrapped to (-pi, pi]: the same cost only while the joint stays within pi of each term's
reference. ``"angle"`` (the default: raico's problem exactly) gives Pinocchio the joint as a revolute
joint without position limits (nq 1, the same dynamics); ``"cos-sin"`` keeps Pinocchio's own
reading, crocoddyl's own problem (its examples), whose costs agree with raico's only within that
range (crocoddyl's Kinova example leaves it: its solution turns the base joint 3.65 rad from the
start, so raico's cost of it is 8.179 where crocoddyl's is 8.125).

Coordinates (:class:`StateMap`): raico's state is ``(q, v)`` over its planning joints (Drake's
position order); Pinocchio's is ``(q_pin, v_pin)`` in its own joint order, a ``"cos-sin"`` continuous
joint stored as ``(cos q, sin q)``. Controls and tangent vectors (``v``, state differences, gains)
are permutations. Back from Pinocchio such an angle is ``atan2(sin, cos)`` unwrapped along the
trajectory, each step's nearest to the previous angle plus ``dt`` times the new velocity (the
semi-implicit Euler step: exact on a rollout, however fast the joint turns).

Terms (:func:`cost_items`, each a list of crocoddyl ``(residual, activation)`` pairs whose summed
crocoddyl cost ``1/2 sum a(r)`` is the raico term's cost divided by 2; the caller weighs them
``2 w`` on the terminal node and ``2 w / dt`` on running nodes, see crocoddyl_model):

- a via-point on a frame's origin or on points fixed in it (``frame_points``): one
  ``ResidualModelFrameTranslation`` per point, on a Pinocchio frame placed at that point of the
  Drake frame (an operational frame is added where the Drake frame is not a link's origin); the
  diagonal precision as activation weights, 0 on coordinates left out;
- ``frame_rotation``, ``frame_placement``: ``ResidualModelFrameRotation`` /
  ``ResidualModelFramePlacement`` (raico's task maps are exactly their log3/log6 residuals);
- ``roll``: a Python residual with raico's Jacobian;
- ``joints`` (a posture via-point) and ``state``: ``ResidualModelState`` to the target, weights on
  the joints named (0 elsewhere);
- ``cog``: Pinocchio's centre of mass computed by a Python residual (crocoddyl's own CoM residual
  reads a value its free forward dynamics do not compute), its target moved and its weights
  scaled so that it is Drake's centre of mass, which counts the links welded to the world (a fixed
  base) that Pinocchio's universe carries;
- ``control`` (with its target, its per-joint weights as activation weights) ``ResidualModelControl``;
  toward gravity (``planning.costs.ControlGravity``) ``ResidualModelControlGrav``; ``control_limit`` the control under
  ``ActivationModelQuadraticBarrier`` (raico's squared hinge); an inequality on joint positions
  whose rows are +-unit vectors (``joint_limit``) the state under a quadratic barrier.

What has no exact counterpart (a non-diagonal precision, a non-zero target of a pose error, an
inequality on another task map or with general rows, the uncertainty term) raises
``NotExpressible`` with one line.
"""

from __future__ import annotations

import math
import re
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

try:  # the optional baseline: the extra ``raico[baseline]`` (``make install`` installs it)
    with warnings.catch_warnings():  # pinocchio imports its collision library by its old name
        warnings.simplefilter("ignore", DeprecationWarning)
        import crocoddyl
        import pinocchio as pin

    AVAILABLE = True
    UNAVAILABLE_REASON = ""
except ImportError as _e:  # pragma: no cover - depends on the environment
    crocoddyl = pin = None
    AVAILABLE = False
    UNAVAILABLE_REASON = (f"crocoddyl/pinocchio not installed ({_e}); `make install` installs the "
                          "pinned pair (the extra raico[baseline]) into .venv")


class NotExpressible(ValueError):
    """A raico problem crocoddyl cannot express exactly (the message says what and why)."""


def _assign(target: np.ndarray, value: np.ndarray) -> None:
    """Write ``value`` into a crocoddyl data matrix in place (eigenpy maps a 1 x n matrix to ``(n,)``)."""
    target[...] = np.reshape(value, np.shape(target))


if crocoddyl is not None:
    class _RollResidual(crocoddyl.ResidualModelAbstract):
        """raico's roll angle minus its target: ``atan2(y_E . z_W, z_E . z_W) - target`` (rad).

        Jacobian as ``plants.taskmaps.RollAngle``: ``d(e . z_W) = J_w . (e x z_W)`` with the
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
            _assign(data.Rx, Rx)

        def createData(self, collector):
            return _OwnKinematicsData(self, collector)

    class _OwnKinematicsData(crocoddyl.ResidualDataAbstract):
        """A Python residual's data with its own Pinocchio data (the action's data is left alone)."""

        def __init__(self, model, collector):
            crocoddyl.ResidualDataAbstract.__init__(self, model, collector)
            self.pdata = model.pmodel.createData()  # own kinematics: the action's data is left alone




# ----------------------------------------------------------------------------- coordinates
@dataclass(frozen=True)
class StateMap:
    """raico's planning coordinates <-> Pinocchio's. Per raico joint ``i``: ``q_index[i]`` (start in
    Pinocchio's ``q``), ``v_index[i]`` (in its ``v``), ``continuous[i]`` (stored as cos, sin)."""

    nq: int
    nv: int
    q_index: np.ndarray
    v_index: np.ndarray
    continuous: np.ndarray

    @classmethod
    def identity(cls, n: int) -> StateMap:
        r = np.arange(n)
        return cls(n, n, r, r.copy(), np.zeros(n, bool))

    @property
    def n(self) -> int:
        return len(self.v_index)

    @property
    def is_identity(self) -> bool:
        r = np.arange(self.n)
        return (self.nq == self.nv == self.n and not self.continuous.any()
                and np.array_equal(self.q_index, r) and np.array_equal(self.v_index, r))

    @property
    def tangent_index(self) -> np.ndarray:
        """``(2 n,)``: the Pinocchio tangent (``ndx = 2 nv``) coordinate of each raico state coordinate."""
        return np.concatenate([self.v_index, self.nv + self.v_index])

    # -- states
    def x_to_pin(self, X: np.ndarray) -> np.ndarray:
        """raico states ``(..., 2 n)`` -> Pinocchio states ``(..., nq + nv)``."""
        X = np.asarray(X, float)
        n = self.n
        out = np.zeros((*X.shape[:-1], self.nq + self.nv))
        q, v = X[..., :n], X[..., n:]
        c = self.continuous
        out[..., self.q_index[~c]] = q[..., ~c]
        out[..., self.q_index[c]] = np.cos(q[..., c])
        out[..., self.q_index[c] + 1] = np.sin(q[..., c])
        out[..., self.nq + self.v_index] = v
        return out

    def x_to_raico(self, Xp: np.ndarray, q_start: np.ndarray | None = None, dt: float = 0.0) -> np.ndarray:
        """Pinocchio states ``(K, nq + nv)`` (a trajectory) -> raico states ``(K, 2 n)``: cos/sin
        joints' angles ``atan2(sin, cos)`` unwrapped along the rows, the first row's nearest to
        ``q_start`` (raico angles of the start; ``None``: in (-pi, pi]), each next one nearest to the
        previous angle plus ``dt`` times its velocity."""
        Xp = np.atleast_2d(np.asarray(Xp, float))
        n, c = self.n, self.continuous
        out = np.empty((Xp.shape[0], 2 * n))
        out[:, np.flatnonzero(~c)] = Xp[:, self.q_index[~c]]
        out[:, n:] = Xp[:, self.nq + self.v_index]
        if c.any():
            ang = np.arctan2(Xp[:, self.q_index[c] + 1], Xp[:, self.q_index[c]])
            vel = out[:, n + np.flatnonzero(c)]
            prev = ang[0] if q_start is None else np.asarray(q_start, float)[c]
            for k in range(len(ang)):  # nearest to the semi-implicit Euler step from the previous row
                guess = prev + (dt * vel[k] if k else 0.0)
                ang[k] = guess + _wrap(ang[k] - guess)
                prev = ang[k]
            out[:, np.flatnonzero(c)] = ang
        return out

    # -- controls and tangent vectors
    def u_to_pin(self, U: np.ndarray) -> np.ndarray:
        U = np.asarray(U, float)
        out = np.zeros((*U.shape[:-1], self.nv))
        out[..., self.v_index] = U
        return out

    def u_to_raico(self, Up: np.ndarray) -> np.ndarray:
        return np.asarray(Up, float)[..., self.v_index]

    def gains_to_raico(self, K: np.ndarray) -> np.ndarray:
        """crocoddyl's gains ``(T, nv, 2 nv)`` (``u = us - K (x - xs)``, tangent) -> raico's ``(T, n, 2 n)``."""
        K = np.asarray(K, float)
        return K[:, self.v_index][:, :, self.tangent_index]


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


# ----------------------------------------------------------------------------- the model
def _root_links(text: str) -> list[str]:
    root = ET.fromstring(text)
    children = {j.find("child").get("link") for j in root.findall("joint") if j.find("child") is not None}
    return [link.get("name") for link in root.findall("link") if link.get("name") not in children]


CONTINUOUS = ("angle", "cos-sin")


def _continuous_as_revolute(text: str) -> str:
    """The URDF text with every continuous joint a revolute joint without position limits (Pinocchio
    then stores its angle, nq 1; effort and velocity limits kept)."""
    root = ET.fromstring(text)
    for j in root.findall("joint"):
        if j.get("type") == "continuous":
            j.set("type", "revolute")
            lim = j.find("limit")
            if lim is None:
                lim = ET.SubElement(j, "limit", {"effort": "0", "velocity": "0"})
            lim.set("lower", "-1e30")
            lim.set("upper", "1e30")
    return ET.tostring(root, encoding="unicode")


def _other_format_roots(path: Path, fmt: str) -> list[str]:
    """The roots of an MJCF (the bodies of its ``<worldbody>``) or SDF file's tree (its first link)."""
    if fmt == "mjcf":
        world = ET.parse(path).getroot().find("worldbody")
        return [b.get("name") for b in ([] if world is None else world.findall("body"))]
    m = re.search(r"<link\s+name=\"([^\"]+)\"", path.read_text(errors="replace"))
    return [m.group(1)] if m else []


def _other_format_model(robot, path: Path, fmt: str):
    """Pinocchio's model of an MJCF file (its own reader, ``buildModelFromMJCF``: hinge and slide
    joints, bodies without a joint fixed to their parent) or of an SDF file (:func:`model_from_drake`:
    Drake's reading of it, joint by joint; the SDFormat reader is an option of Pinocchio's build)."""
    if fmt == "sdf":
        return model_from_drake(robot)
    try:
        return pin.buildModelFromMJCF(str(path))
    except (RuntimeError, ValueError) as e:
        raise NotExpressible(f"crocoddyl: Pinocchio cannot read {path.name}: {str(e).splitlines()[0]}") from None


def _se3(X) -> pin.SE3:
    """Drake's RigidTransform as Pinocchio's SE3."""
    return pin.SE3(X.rotation().matrix(), X.translation())


def model_from_drake(robot):
    """Pinocchio's model of ``robot``'s Drake plant, joint by joint from the world: each revolute or
    prismatic joint a Pinocchio joint about its axis at the parent side's joint frame, each weld
    merged into its parent (the child's inertia and a frame of its name on the parent's joint), each
    body's spatial inertia and a BODY frame of its name, joint damping and position limits; the
    joint names are Drake's. ``NotExpressible`` for another joint type (a floating joint inside)."""
    from pydrake.multibody.tree import JointIndex

    plant = robot.plant
    model = pin.Model()
    world = plant.world_body().index()
    at = {world: (0, pin.SE3.Identity())}   # body -> (Pinocchio joint, body origin in its joint frame)
    joints = [plant.get_joint(JointIndex(i)) for i in range(plant.num_joints())]
    pending = list(joints)
    while pending:
        ready = [j for j in pending if j.parent_body().index() in at]
        if not ready:
            raise NotExpressible(f"crocoddyl: {robot.name}'s tree does not reach every joint from the world")
        for j in ready:
            pending.remove(j)
            parent, X_JP = at[j.parent_body().index()]
            X_JF = X_JP * _se3(j.frame_on_parent().GetFixedPoseInBodyFrame())   # the joint frame on the parent
            X_CM = _se3(j.frame_on_child().GetFixedPoseInBodyFrame()).inverse()  # the child in its joint frame
            kind = j.type_name()
            if kind == "weld":
                X_FM = _se3(j.X_FM()) if hasattr(j, "X_FM") else pin.SE3.Identity()
                jid, X_JC = parent, X_JF * X_FM * X_CM
            elif kind in ("revolute", "prismatic"):
                axis = np.asarray(j.revolute_axis() if kind == "revolute" else j.translation_axis(), float)
                jm = (pin.JointModelRevoluteUnaligned if kind == "revolute" else pin.JointModelPrismaticUnaligned)(
                    *axis)
                jid = model.addJoint(parent, jm, X_JF, j.name())
                model.damping[model.joints[jid].idx_v] = float(j.default_damping())
                model.lowerPositionLimit[model.joints[jid].idx_q] = float(j.position_lower_limits()[0])
                model.upperPositionLimit[model.joints[jid].idx_q] = float(j.position_upper_limits()[0])
                X_JC = X_CM
            else:
                raise NotExpressible(f"crocoddyl: joint '{j.name()}' of {robot.name} is a {kind} joint in Drake")
            body = j.child_body()
            M = body.default_spatial_inertia()
            com = np.asarray(M.get_com(), float)
            I_com = M.Shift(com).CalcRotationalInertia().CopyToFullMatrix3()
            model.appendBodyToJoint(jid, pin.Inertia(float(M.get_mass()), com, I_com), X_JC)
            model.addFrame(pin.Frame(body.name(), jid, X_JC, pin.FrameType.BODY))
            at[body.index()] = (jid, X_JC)
    return model


def pinocchio_robot(robot, continuous: str = "angle"):
    """``(model, StateMap)`` of a model-file robot (``robot.spec``), see the module docstring;
    ``continuous``: ``"angle"`` or ``"cos-sin"``."""
    from plants.model_file import _model_text

    spec = robot.spec
    if spec is None:
        raise ValueError(f"{robot.name} is a built-in plant, not a model-file robot")
    if continuous not in CONTINUOUS:
        raise ValueError(f"continuous must be one of {CONTINUOUS}, got {continuous!r}")
    path, fmt, text, _, _ = _model_text(spec)
    if fmt == "urdf":
        roots = [r for r in _root_links(text) if r != "world"] or _root_links(text)
    else:
        roots = _other_format_roots(path, fmt)
    if spec.weld is not None and not (len(roots) == 1 and spec.weld == roots[0]):
        raise NotExpressible(
            f"crocoddyl cannot express {path.name} welded on '{spec.weld}': Drake re-roots the tree there, "
            f"Pinocchio's tree is rooted at '{roots[0] if roots else '?'}' (a fixed base at the root only)")
    if fmt == "urdf":
        model = pin.buildModelFromXML(_continuous_as_revolute(text) if continuous == "angle" else text)
    else:
        model = _other_format_model(robot, path, fmt)
    names = [model.names[i] for i in range(1, model.njoints)]
    if sorted(names) != sorted(robot.joint_names):
        raise NotExpressible(f"crocoddyl: Pinocchio's joints {names} of {path.name} are not raico's planning "
                             f"joints {list(robot.joint_names)}")
    if not np.array_equal(robot.P, np.eye(robot.n_q)):
        raise NotExpressible(f"crocoddyl: {robot.name} has coupled joints (P is not the identity)")
    qi, vi, cont = [], [], []
    for name in robot.joint_names:
        j = model.joints[model.getJointId(name)]
        if j.nv != 1 or j.nq not in (1, 2):
            raise NotExpressible(f"crocoddyl: joint '{name}' is a {j.shortname()} in Pinocchio (nq {j.nq}, nv {j.nv})")
        qi.append(j.idx_q)
        vi.append(j.idx_v)
        cont.append(j.nq == 2)
    smap = StateMap(model.nq, model.nv, np.array(qi), np.array(vi), np.array(cont, bool))
    from plants.model_file import _per_joint

    armature = _per_joint(spec.armature, list(robot.joint_names), "armature")
    arm = np.zeros(model.nv)
    arm[smap.v_index] = armature
    model.armature = arm
    return model, smap


def frame_id(model, robot, frame_name: str, point=None) -> int:
    """Pinocchio's frame at Drake's frame ``frame_name`` of ``robot`` (moved to ``point``, m, in
    it): the link's own frame where it is one, else an operational frame added to ``model``."""
    f = robot.plant.GetFrameByName(frame_name)
    body = f.body().name()
    X = f.GetFixedPoseInBodyFrame()
    R, p = X.rotation().matrix(), X.translation()
    if point is not None:
        p = p + R @ np.asarray(point, float)
    if not model.existFrame(body, pin.BODY):
        raise NotExpressible(f"crocoddyl: frame '{frame_name}' is on body '{body}', which Pinocchio's model lacks")
    fb = model.getFrameId(body, pin.BODY)
    if np.array_equal(R, np.eye(3)) and not np.any(p):
        return fb
    parent = model.frames[fb]
    M = parent.placement * pin.SE3(R, p)
    name = f"{frame_name}@{','.join(repr(float(x)) for x in p)}"
    if model.existFrame(name):
        return model.getFrameId(name)
    return model.addFrame(pin.Frame(name, parent.parentJoint, fb, M, pin.OP_FRAME), False)


def add_frames(terms, model, robot) -> None:
    """Add to ``model`` the operational frames the via-points of ``terms`` need (:func:`frame_id`)."""
    from planning.costs import ViaPoint
    from plants.taskmaps import FramePoints

    for term in terms:
        tm = getattr(term, "taskmap", None)
        frame = getattr(tm, "frame", None)
        if not isinstance(term, ViaPoint) or frame is None:
            continue
        for point in (tm.points if isinstance(tm, FramePoints) else [None]):
            frame_id(model, robot, frame.name(), point)


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
    function its row of the cost-term table (:mod:`planning.term_kinds`) names."""
    from planning.term_kinds import kind_of_term

    row = kind_of_term(term)
    items = globals().get(row.crocoddyl) if row is not None and row.crocoddyl else None
    if items is None:
        raise NotExpressible(f"crocoddyl: no equivalent of the cost term {term.name!r} ({type(term).__name__})")
    return items(term, state, nu, model, smap, robot)


def _items_state(term, state, nu, model, smap, robot):
    w = np.zeros(state.ndx)
    w[smap.tangent_index] = _diag(term.C, term.name)
    n = smap.n
    xref = _state_ref(smap, model, term.target[:n], term.target[n:])
    return [(crocoddyl.ResidualModelState(state, xref, nu), crocoddyl.ActivationModelWeightedQuad(w))]


def _items_control(term, state, nu, model, smap, robot):
    act = (crocoddyl.ActivationModelQuad(nu) if term.c is None
           else crocoddyl.ActivationModelWeightedQuad(smap.u_to_pin(term.c)))
    if term.target is None:
        return [(crocoddyl.ResidualModelControl(state, nu), act)]
    return [(crocoddyl.ResidualModelControl(state, smap.u_to_pin(term.target)), act)]


def _items_control_gravity(term, state, nu, model, smap, robot):
    """u - g(q), Pinocchio's generalized gravity."""
    return [(crocoddyl.ResidualModelControlGrav(state, nu), crocoddyl.ActivationModelWeightedQuad(smap.u_to_pin(term.c)))]


def _items_control_limit(term, state, nu, model, smap, robot):
    n = smap.n
    lo = smap.u_to_pin(np.broadcast_to(term.lower, (n,)).astype(float))
    hi = smap.u_to_pin(np.broadcast_to(term.upper, (n,)).astype(float))
    return [(crocoddyl.ResidualModelControl(state, nu),
             crocoddyl.ActivationModelQuadraticBarrier(crocoddyl.ActivationBounds(lo, hi)))]


def _via(term, state, nu, model, smap, robot):
    """A via-point's crocoddyl residuals and activations: the function its task map's row of the
    task-map table (:mod:`planning.term_kinds`) names."""
    from planning.term_kinds import kind_of_map

    tm = term.taskmap
    row = kind_of_map(tm)
    build = globals().get(row.crocoddyl) if row is not None and row.crocoddyl else None
    if build is None:
        raise NotExpressible(f"crocoddyl: no equivalent of the task map {tm.name!r} ({type(tm).__name__})")
    return build(term, tm, _diag(term.C, term.name), state, nu, model, smap, robot)


def _via_frame_points(term, tm, w, state, nu, model, smap, robot):
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


def _via_roll(term, tm, w, state, nu, model, smap, robot):
    fid = frame_id(model, robot, tm.frame.name())
    return [(_RollResidual(state, fid, float(term.target[0]), nu), crocoddyl.ActivationModelWeightedQuad(w))]


def _via_com(term, tm, w, state, nu, model, smap, robot):
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


def _via_frame_pose(term, tm, w, state, nu, model, smap, robot):
    from plants.taskmaps import FrameRotationError

    if np.any(term.target != 0):
        raise NotExpressible(f"crocoddyl: via-point {term.name!r} asks a pose error of {term.target.tolist()}, "
                             "crocoddyl's frame residuals are zero at their reference")
    fid = frame_id(model, robot, tm.frame.name())
    if isinstance(tm, FrameRotationError):
        res = crocoddyl.ResidualModelFrameRotation(state, fid, tm.R_target, nu)
    else:
        res = crocoddyl.ResidualModelFramePlacement(state, fid, pin.SE3(tm.R_target, tm.p_target), nu)
    return [(res, crocoddyl.ActivationModelWeightedQuad(w))]


def _via_joints(term, tm, w, state, nu, model, smap, robot):
    idx = [int(np.flatnonzero(row)[0]) for row in tm.S]
    if len(set(idx)) != len(idx):
        raise NotExpressible(f"crocoddyl: via-point {term.name!r} names a joint twice")
    ws = np.zeros(state.ndx)
    ws[smap.v_index[idx]] = w
    xref = _state_ref(smap, model, dict(zip(idx, term.target)))
    return [(crocoddyl.ResidualModelState(state, xref, nu), crocoddyl.ActivationModelWeightedQuad(ws))]


def _joint_bounds(term, state, nu, model, smap, robot=None):
    """``A q[idx] <= b`` with +-unit rows: the state difference to a reference under a quadratic
    barrier (reference 0 for revolute and prismatic joints, where the difference is ``q`` itself;
    the bounds' middle, or the bound, for a continuous joint)."""
    from plants.taskmaps import JointPositions

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
