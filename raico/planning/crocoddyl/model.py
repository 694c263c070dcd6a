"""raico's robots in crocoddyl's terms: the optional import of crocoddyl and Pinocchio (``AVAILABLE``),
``NotExpressible``, the Pinocchio model of a robot and the coordinates between raico and Pinocchio.

The model (:func:`pinocchio_robot`) comes from the model file the robot was loaded from (a built-in
plant's too): Pinocchio reads the SAME repaired URDF text Drake reads (``raico.plants.model_file.repair_urdf``:
locked joints fixed, mimic tags dropped) with a fixed base, where Drake puts a robot whose free root is
welded at the world origin; a robot welded on another frame (a humanoid on a sole) re-roots Drake's tree,
which Pinocchio's cannot: ``NotExpressible``. MJCF goes through Pinocchio's MJCF reader, SDF through
Drake's reading of it (:func:`model_from_drake`). The spec's armature is ``model.armature``; Drake's joint
damping, which Pinocchio's forward dynamics ignores, enters as ``tau = u - D v`` (:class:`DampedActuation`).

Continuous joints (``continuous``): raico's angle is a real number with plain differences ``q - q*``;
Pinocchio reads a URDF continuous joint as ``(cos q, sin q)`` whose differences wrap to (-pi, pi].
``"angle"`` (the default, raico's problem exactly) gives Pinocchio a revolute joint without limits;
``"cos-sin"`` keeps Pinocchio's reading, crocoddyl's own problem (its examples), whose costs agree with
raico's only within pi of each term's reference (crocoddyl's Kinova example leaves it: raico's cost of
its solution is 8.179 where crocoddyl's is 8.125).

Coordinates (:class:`StateMap`): raico's state ``(q, v)`` over its planning joints (Drake's order),
Pinocchio's in its own joint order; controls and tangent vectors are permutations; a ``"cos-sin"``
angle comes back as ``atan2(sin, cos)`` unwrapped along the trajectory (each step's nearest to the
previous angle plus ``dt`` times the new velocity: exact on a semi-implicit Euler rollout).
"""

from __future__ import annotations

import re
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from raico.planning.problem import Problem

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


def assign(target: np.ndarray, value: np.ndarray) -> None:
    """Write ``value`` into a crocoddyl data matrix in place (eigenpy maps a 1 x n matrix to ``(n,)``)."""
    target[...] = np.reshape(value, np.shape(target))



def require() -> None:
    """Raise ``RuntimeError`` (what to install) where crocoddyl or Pinocchio does not import."""
    if not AVAILABLE:
        raise RuntimeError(UNAVAILABLE_REASON)


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


@dataclass(frozen=True)
class ActuatedMap(StateMap):
    """A :class:`StateMap` whose controls are an underactuated robot's motor commands ``u (n_act,)`` (raico's
    actuated joints in order, ``raico.plants.robot.Robot.S``), which are crocoddyl's controls as they are: its
    actuation model (:class:`SelectedActuation`) puts them on their joints."""

    sel: np.ndarray = None  # (nv, n_act): Pinocchio's generalized force of each motor command

    @classmethod
    def of(cls, smap: StateMap, S: np.ndarray) -> ActuatedMap:
        """``smap`` with the motors of the selection ``S (n_q, n_act)`` (raico's joints)."""
        sel = np.zeros((smap.nv, S.shape[1]))
        sel[smap.v_index] = S
        return cls(smap.nq, smap.nv, smap.q_index, smap.v_index, smap.continuous, sel)

    @property
    def n_u(self) -> int:
        return self.sel.shape[1]

    @property
    def is_identity(self) -> bool:
        return False   # the controls are not the joints'

    def u_to_pin(self, U: np.ndarray) -> np.ndarray:
        return np.asarray(U, float)

    def u_to_raico(self, Up: np.ndarray) -> np.ndarray:
        return np.asarray(Up, float)

    def gains_to_raico(self, K: np.ndarray) -> np.ndarray:
        """crocoddyl's gains ``(T, n_act, 2 nv)`` -> raico's ``(T, n_act, 2 n)``."""
        return np.asarray(K, float)[:, :, self.tangent_index]


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


# ----------------------------------------------------------------------------- the model
def _root_links(text: str) -> list[str]:
    root = ET.fromstring(text)
    children = {j.find("child").get("link") for j in root.findall("joint") if j.find("child") is not None}
    return [link.get("name") for link in root.findall("link") if link.get("name") not in children]


CONTINUOUS = ("angle", "cos-sin")


def _without_visuals(text: str) -> str:
    """The URDF text without its ``<visual>`` elements: the dynamics need none, and urdfdom refuses
    geometry it does not know (a capsule), with an error line per link."""
    root = ET.fromstring(text)
    for link in root.findall("link"):
        for vis in link.findall("visual"):
            link.remove(vis)
    return ET.tostring(root, encoding="unicode")


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
    """``(model, StateMap)`` of a robot from the model file it was loaded from (``robot.spec``: a built-in
    plant's too), see the module docstring; ``continuous``: ``"angle"`` or ``"cos-sin"``."""
    from raico.plants.model_file import model_text

    spec = robot.spec
    if spec is None:
        raise ValueError(f"{robot.name} was not loaded from a model file (raico.plants.model_file.load_model)")
    if continuous not in CONTINUOUS:
        raise ValueError(f"continuous must be one of {CONTINUOUS}, got {continuous!r}")
    path, fmt, text, _, _ = model_text(spec)
    if fmt == "urdf":
        roots = [r for r in _root_links(text) if r != "world"] or _root_links(text)
    else:
        roots = _other_format_roots(path, fmt)
    if spec.weld is not None and not (len(roots) == 1 and spec.weld == roots[0]):
        raise NotExpressible(
            f"crocoddyl cannot express {path.name} welded on '{spec.weld}': Drake re-roots the tree there, "
            f"Pinocchio's tree is rooted at '{roots[0] if roots else '?'}' (a fixed base at the root only)")
    if fmt == "urdf":
        text = _without_visuals(text)
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
    from raico.plants.model_file import per_joint

    armature = per_joint(spec.armature, list(robot.joint_names), "armature")
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
    from raico.planning.costs import ViaPoint
    from raico.plants.taskmaps import FramePoints

    for term in terms:
        tm = getattr(term, "taskmap", None)
        frame = getattr(tm, "frame", None)
        if not isinstance(term, ViaPoint) or frame is None:
            continue
        for point in (tm.points if isinstance(tm, FramePoints) else [None]):
            frame_id(model, robot, frame.name(), point)


def problem_robot(problem: Problem):
    """The robot of ``problem``'s analytic dynamics (``NotExpressible`` for other dynamics)."""
    from raico.plants.dynamics import ActuatedDynamics, AnalyticDynamics, PseudoDynamics, SubstepDynamics
    from raico.plants.fast_analytic import FastAnalyticDynamics

    dyn = problem.dynamics
    if isinstance(dyn, ActuatedDynamics):   # an underactuated robot: crocoddyl's actuation selects its motors
        dyn = dyn.inner
    if isinstance(dyn, SubstepDynamics):
        raise NotExpressible("solver fddp: crocoddyl steps its model once per node; the problem's model takes "
                             f"{dyn.k} substeps per control step")
    if isinstance(dyn, PseudoDynamics):
        raise NotExpressible(
            "solver fddp: crocoddyl cannot express the pseudo-dynamics exactly (controls are accelerations; "
            "its forward-dynamics models take torques): use --dynamics analytic")
    robot = getattr(dyn, "robot", None)
    if robot is None or not isinstance(dyn, (FastAnalyticDynamics, AnalyticDynamics)):
        raise NotExpressible(f"solver fddp: crocoddyl can express only the analytic dynamics, not "
                             f"{type(dyn).__name__}")
    return robot


if AVAILABLE:
    class DampedActuation(crocoddyl.ActuationModelAbstract):
        """Full actuation with viscous joint damping: ``tau = u - D qdot`` (Drake's joint damping)."""

        def __init__(self, state, damping: np.ndarray):
            crocoddyl.ActuationModelAbstract.__init__(self, state, state.nv)
            self.D = np.asarray(damping, float)
            self.nq = state.nq

        def calc(self, data, x, u=None):
            v = np.asarray(x)[self.nq:]
            data.tau[:] = (np.zeros(self.nu) if u is None else np.asarray(u)) - self.D * v

        def calcDiff(self, data, x, u=None):
            nv = self.state.nv
            dx = np.zeros((nv, self.state.ndx))
            dx[:, nv:] = -np.diag(self.D)
            assign(data.dtau_dx, dx)
            assign(data.dtau_du, np.eye(nv))

        def commands(self, data, x, tau):
            data.u[:] = np.asarray(tau) + self.D * np.asarray(x)[self.nq:]

        def torqueTransform(self, data, x, u):
            assign(data.Mtau, np.eye(self.nu))

    class SelectedActuation(crocoddyl.ActuationModelAbstract):
        """An underactuated robot's motors with viscous joint damping: ``tau = Sel u - D qdot`` with
        ``Sel (nv, n_act)`` putting each motor command on its joint (:class:`ActuatedMap`)."""

        def __init__(self, state, sel: np.ndarray, damping: np.ndarray):
            crocoddyl.ActuationModelAbstract.__init__(self, state, sel.shape[1])
            self.sel = np.asarray(sel, float)
            self.D = np.asarray(damping, float)
            self.nq = state.nq

        def calc(self, data, x, u=None):
            v = np.asarray(x)[self.nq:]
            data.tau[:] = (np.zeros(self.state.nv) if u is None else self.sel @ np.asarray(u)) - self.D * v

        def calcDiff(self, data, x, u=None):
            nv = self.state.nv
            dx = np.zeros((nv, self.state.ndx))
            dx[:, nv:] = -np.diag(self.D)
            assign(data.dtau_dx, dx)
            assign(data.dtau_du, self.sel)

        def commands(self, data, x, tau):
            data.u[:] = self.sel.T @ (np.asarray(tau) + self.D * np.asarray(x)[self.nq:])

        def torqueTransform(self, data, x, u):
            assign(data.Mtau, self.sel.T)


def pinocchio_of(robot, continuous: str):
    """``(model, StateMap)`` of any robot, from the model file it was loaded from (a fresh model: frames
    may be added to it)."""
    return pinocchio_robot(robot, continuous)
