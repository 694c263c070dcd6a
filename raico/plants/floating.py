"""A floating robot: the execution model of a robot that stands on its own feet (``execution = "floating"``).

Plans are made on the fixed-base model (its stance sole welded to the world, ``raico.plants.robots``); they are
executed on this one, built from the robot's facts (its ``feet``, ``sole`` outline and ``stand`` table,
``raico.plants.stand``):

- the same model file with a floating base (Drake's quaternion floating joint on its root body);
- a DISCRETE ``MultibodyPlant`` (the spec's ``time_step``) with Drake's SAP solver in its ``lagged``
  approximation and the contact model ``hydroelastic_with_fallback``: each sole a compliant-hydroelastic box
  (``stand.sole_box``; modulus and Hunt-Crossley dissipation of ``stand.contact``) on a rigid ground (the
  half space z <= 0) with Coulomb friction; the ``stand.bumpers`` spheres (rigid, point contact) let a fallen
  robot lie on the floor. The robot's geometries collide with the ground only;
- joint position limits (from the model file) enforced by the plant (SAP limit constraints); every actuator
  PD-controlled by Drake (``stand.gains``, implicit in SAP), its total ``Kp (q_d - q) + Kd (v_d - v) + u_ff``
  clamped at its effort limit; reflected motor inertia as in the planning model (``armature``).

Coordinates: planning ``q (n_q,)`` -> the tree joints by ``Robot.P`` (coupled joints copy their driver);
the free plant's positions are the floating base's ``(qw, qx, qy, qz, x, y, z)`` followed by the joints.
The Nao's numbers: docs/execution.md.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import numpy as np

from raico.plants.model_file import RobotSpec, shared_model
from raico.plants.robots import Robot, shared_robot

DISCRETE_CONTACT_APPROXIMATION = "lagged"  # SAP with lagged friction (Drake's default)


def sole_corners_local(spec: RobotSpec) -> np.ndarray:
    """The corners ``(k, 3)`` of a sole in its sole frame (m, z = 0: the contact face): the spec's outline."""
    sole = np.array(spec.sole)
    return np.c_[sole, np.zeros(len(sole))]


STANCE_MARGIN = 0.02  # m, the standing start's CoG margin inside the support polygon
STANCE_COG_WEIGHT = 1e4  # 1/m^2 (joints: 1/rad^2): the stance's CoG ground projection held at the posture's
MAX_TIP = 0.5  # rad: a posture that finds no rest within this tilt cannot stand on flat ground


def _tip(C: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Roll and pitch (rad) at which the rigid point set ``C (k, 3)`` with centre of mass
    ``c (3,)`` comes to rest when tipped about the origin from zero: a local minimum of the CoG
    height above the lowest point, by a compass search (8 directions, halving steps)."""

    def height(x):
        cr, sr, cp, sp = np.cos(x[0]), np.sin(x[0]), np.cos(x[1]), np.sin(x[1])
        row = np.array([-sp, sr * cp, cr * cp])  # z row of R = Ry(pitch) Rx(roll)
        return c @ row - (C @ row).min()

    x, h, step = np.zeros(2), height(np.zeros(2)), 2e-3  # small steps: the descent cannot jump a ridge
    dirs = np.array([[np.cos(a), np.sin(a)] for a in np.arange(8) * np.pi / 4])
    while step > 1e-7:
        trials = [np.clip(x + step * d, -MAX_TIP, MAX_TIP) for d in dirs]
        hs = [height(t) for t in trials]
        i = int(np.argmin(hs))
        if hs[i] < h - 1e-12:
            x, h = trials[i], hs[i]
        else:
            step /= 2
    return x


@dataclass
class FloatingRobot:
    """A floating robot's plant with the maps to and from the planning coordinates."""

    plant: Any
    scene_graph: Any
    builder: Any
    model: Any  # ModelInstanceIndex of the robot
    fixed: Robot  # the planning (fixed-base) robot: joint names, P, limits, efforts
    base: Any  # the floating base body
    A: np.ndarray  # (n_act, n_q): actuator values = A @ planning values (actuator order)
    act_fixed_idx: np.ndarray  # (n_act,): each actuator's joint in the fixed plant's q (= v) order
    joint_idx: np.ndarray  # (n_fixed_positions,): free-plant position index of each fixed-plant position
    joint_vidx: np.ndarray  # (n_fixed_velocities,): free-plant velocity index of each fixed-plant velocity
    effort: np.ndarray  # (n_act,) N m
    spec: RobotSpec | None = None  # its facts: feet (the stance sole first), sole outline, stand
    sole_geometries: dict = field(default_factory=dict)  # GeometryId -> sole index (0 stance, 1 other)
    name: str = ""
    _context: Any = field(default=None, repr=False)

    @property
    def soles(self) -> tuple[str, ...]:
        """The sole frames, the stance one first (the spec's ``feet``)."""
        return self.spec.feet

    @property
    def time_step(self) -> float:
        return self.plant.time_step()

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.fixed.joint_names

    @property
    def n_q(self) -> int:
        return self.fixed.n_q

    @property
    def default_q(self) -> np.ndarray:
        return self.fixed.default_q

    @property
    def context(self):
        if self._context is None:
            self._context = self.plant.CreateDefaultContext()
        return self._context

    def to_plant_q(self, Q: np.ndarray) -> np.ndarray:
        """Free-plant positions pass through unchanged (``body_poses`` of the recorders take
        the stored free-plant positions ``(K, n_positions)``)."""
        return np.asarray(Q, float)

    def free_positions(self, q: np.ndarray, base_q: np.ndarray) -> np.ndarray:
        """Free-plant positions from planning ``q (n_q,)`` and the base's 7 positions."""
        qp = np.zeros(self.plant.num_positions())
        qp[self.joint_idx] = self.fixed.to_plant_q(q)
        qp[self.base_positions] = base_q
        return qp

    @property
    def base_positions(self) -> np.ndarray:
        """Indices of the floating base's ``(qw, qx, qy, qz, x, y, z)`` in the free positions."""
        start = self.base.floating_positions_start()
        return np.arange(start, start + 7)

    def planning_q(self, qp: np.ndarray) -> np.ndarray:
        """Planning ``q (n_q,)`` from free-plant positions (least squares for coupled joints)."""
        return self.fixed.from_plant_q(np.asarray(qp)[..., self.joint_idx])

    def planning_v(self, vp: np.ndarray) -> np.ndarray:
        """Planning ``v (n_q,)`` from free-plant velocities."""
        return self.fixed.from_plant_q(np.asarray(vp)[..., self.joint_vidx])

    def standing_positions(self, q: np.ndarray) -> tuple[np.ndarray, float]:
        """Free-plant positions of a robot at rest on the ground with joints at planning ``q``.

        First the stance sole flat on the ground at the fixed-base model's pose (the world frame).
        When the other sole then reaches under the ground (the plan's posture has the feet at
        different heights), the robot, rigid at ``q``, is tipped about the world origin onto its
        lowest sole corners: the roll and pitch that locally minimize the CoG height over the
        lowest corner, found by a pattern search from zero (quasi-static tipping: the CoG ends
        over the corners it rests on; at most ``MAX_TIP`` rad); then it is moved up or down so
        that its lowest corner is at z = 0. Returns the positions and the tilt applied (rad, 0 for a flat stance)."""
        from pydrake.math import RigidTransform, RollPitchYaw

        plant, ctx = self.plant, self.context
        identity = np.r_[1.0, 0, 0, 0, 0, 0, 0]
        plant.SetPositions(ctx, self.free_positions(q, identity))
        X_WS = plant.GetFrameByName(self.soles[0]).CalcPoseInWorld(ctx)
        X_WB = plant.EvalBodyPoseInWorld(ctx, self.base)
        plant.SetFreeBodyPose(ctx, self.base, X_WS.inverse() @ X_WB)
        C = self.sole_corners(ctx).reshape(-1, 3)
        c = plant.CalcCenterOfMassPositionInWorld(ctx)
        rpy = np.zeros(3)
        if C[:, 2].min() < -1e-9:
            rpy[:2] = _tip(C, c)
        R = RollPitchYaw(rpy).ToRotationMatrix()
        X_WB = RigidTransform(R, np.zeros(3)) @ plant.EvalBodyPoseInWorld(ctx, self.base)
        plant.SetFreeBodyPose(ctx, self.base, X_WB)
        dz = -float(self.sole_corners(ctx)[..., 2].min())
        plant.SetFreeBodyPose(ctx, self.base, RigidTransform([0.0, 0.0, dz]) @ X_WB)
        tilt = float(np.arccos(np.clip((np.trace(R.matrix()) - 1) / 2, -1.0, 1.0)))
        return plant.GetPositions(ctx).copy(), tilt

    def stance_positions(self, q: np.ndarray, margin: float = STANCE_MARGIN) -> tuple[np.ndarray, dict]:
        """Free-plant positions of a double-support stance near planning ``q (n_q,)`` (rad).

        Drake's ``InverseKinematics`` (SNOPT) finds the free-plant positions closest to ``q`` in the
        joints (least squares over the tree joints, coupled joints kept equal as on the robot, the
        joint limits respected) such that the stance sole lies flat at the world
        origin (the fixed-base model's pose, so that the plan's world frame stays the robot's), the
        other sole lies flat on the ground (z = 0, its z axis vertical; its x, y and yaw free), and
        the CoG's ground projection, held near where ``q`` puts it on the fixed-base model (a cost
        ``STANCE_COG_WEIGHT``: the plan's CoG via-points stay where the plan has them), is at least
        ``margin`` m inside the support polygon (the convex
        hull of both soles' corners with the other sole at its pose under ``q``, projected flat).
        Returns the positions and ``{"projection_norm", "projection_max"}`` (rad: the joint-space
        norm and largest absolute change in planning coordinates), ``"sole_height"`` (m, the largest
        |z| of a sole corner), ``"cog_margin"`` (m, against the hull of the projected stance's
        corners) and ``"solver"``. Raises ``ValueError`` when no stance is found.
        """
        from pydrake.math import RotationMatrix
        from pydrake.multibody.inverse_kinematics import ComPositionConstraint, InverseKinematics
        from pydrake.solvers import Solve
        from scipy.spatial import ConvexHull

        from raico.plants.polygons import signed_margin

        plant = self.plant
        q = np.asarray(q, float)
        guess, _ = self.standing_positions(q)
        # the support polygon: the stance sole at the origin, the other where q puts it, laid flat
        fp, fctx = self.fixed.plant, self.fixed.plant.CreateDefaultContext()
        fp.SetPositions(fctx, self.fixed.to_plant_q(q))
        X_LR = fp.GetFrameByName(self.soles[0]).CalcPoseInWorld(fctx).inverse() @ \
            fp.GetFrameByName(self.soles[1]).CalcPoseInWorld(fctx)
        yaw = float(np.arctan2(X_LR.rotation().matrix()[1, 0], X_LR.rotation().matrix()[0, 0]))
        Rz = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
        local = sole_corners_local(self.spec)[:, :2]
        pts = np.vstack([local, local @ Rz.T + X_LR.translation()[:2]])
        hull = ConvexHull(pts)
        A = np.c_[hull.equations[:, :2], np.zeros(len(hull.equations))]  # a . p + b <= 0 inside
        ub = -hull.equations[:, 2] - margin

        ik = InverseKinematics(plant, with_joint_limits=True)
        qv, prog = ik.q(), ik.get_mutable_prog()
        world = plant.world_frame()
        lsole, rsole = plant.GetFrameByName(self.soles[0]), plant.GetFrameByName(self.soles[1])
        ik.AddPositionConstraint(lsole, np.zeros(3), world, np.zeros(3), np.zeros(3))
        ik.AddOrientationConstraint(lsole, RotationMatrix(), world, RotationMatrix(), 0.0)
        ik.AddPositionConstraint(rsole, np.zeros(3), world, [-1.0, -1.0, 0.0], [1.0, 1.0, 0.0])
        ik.AddAngleBetweenVectorsConstraint(world, [0.0, 0.0, 1.0], rsole, [0.0, 0.0, 1.0], 0.0, 0.0)
        # the CoG r = com(q): inside the polygon (margin), its ground projection kept where q puts it on the
        # fixed-base model (the plan's world frame: its CoG via-points stay the robot's), at a cost
        r = prog.NewContinuousVariables(3, "com")
        prog.AddConstraint(ComPositionConstraint(plant, None, world, ik.context()), np.r_[qv, r])
        prog.AddLinearConstraint(A, np.full(len(ub), -np.inf), ub, r)
        c_q = fp.CalcCenterOfMassPositionInWorld(fctx)
        prog.AddQuadraticErrorCost(STANCE_COG_WEIGHT * np.eye(2), c_q[:2], r[:2])
        for joint, driver in self.spec.coupled:  # coupled joints kept equal, as one motor drives them
            hd = plant.GetJointByName(driver).position_start()
            hj = plant.GetJointByName(joint).position_start()
            prog.AddLinearEqualityConstraint(qv[hd] - qv[hj] == 0)
        target = self.free_positions(q, guess[self.base_positions])
        W = np.zeros((plant.num_positions(), plant.num_positions()))
        W[self.joint_idx, self.joint_idx] = 1.0
        prog.AddQuadraticErrorCost(W, target, qv)
        plant.SetPositions(self.context, guess)
        x0 = np.zeros(prog.num_vars())
        prog.SetDecisionVariableValueInVector(qv, guess, x0)
        prog.SetDecisionVariableValueInVector(r, plant.CalcCenterOfMassPositionInWorld(self.context), x0)
        result = Solve(prog, x0)
        if not result.is_success():
            raise ValueError(f"no double-support stance found near the start posture ({result.get_solution_result()})")
        qp = result.GetSolution(qv)
        qp[self.base_positions[:4]] /= np.linalg.norm(qp[self.base_positions[:4]])
        ctx = self.context
        plant.SetPositions(ctx, qp)
        corners = self.sole_corners(ctx)
        c = plant.CalcCenterOfMassPositionInWorld(ctx)
        poly = corners[..., :2].reshape(-1, 2)
        poly = poly[ConvexHull(poly).vertices]
        dq = self.planning_q(qp) - q
        return qp, {"projection_norm": float(np.linalg.norm(dq)), "projection_max": float(np.abs(dq).max()),
                    "sole_height": float(np.abs(corners[..., 2]).max()),
                    "cog_margin": float(signed_margin(poly, c[:2])), "solver": result.get_solver_id().name()}

    def sole_corners(self, ctx) -> np.ndarray:
        """World positions ``(2, k, 3)`` (m) of the stance and the other sole's corners."""
        local = sole_corners_local(self.spec)
        out = np.empty((2, len(local), 3))
        for i, s in enumerate(self.soles):
            X = self.plant.GetFrameByName(s).CalcPoseInWorld(ctx)
            out[i] = local @ X.rotation().matrix().T + X.translation()
        return out

    def contacts(self, ctx) -> tuple[np.ndarray, np.ndarray]:
        """From Drake's contact results (of the last plant step): the normal force ``(2,)`` N from
        the ground on the stance and the other sole, and every contact point ``(k, 3)`` m (centroids of
        the soles' hydroelastic contact surfaces, point contacts of the bumpers)."""
        results = self.plant.get_contact_results_output_port().Eval(ctx)
        force = np.zeros(2)
        points = []
        for i in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(i)
            s = info.contact_surface()
            for gid in (s.id_M(), s.id_N()):
                if gid in self.sole_geometries:
                    force[self.sole_geometries[gid]] += abs(info.F_Ac_W().translational()[2])
            points.append(np.asarray(s.centroid()))
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            pair = info.point_pair()
            for gid in (pair.id_A, pair.id_B):
                if gid in self.sole_geometries:
                    force[self.sole_geometries[gid]] += abs(info.contact_force()[2])
            points.append(np.asarray(info.contact_point()))
        return force, (np.array(points) if points else np.zeros((0, 3)))

    def zmp(self, ctx) -> np.ndarray:
        """The zero-moment point ``(2,)`` (m, world xy) of the ground's reaction on the robot (Drake's
        contact results of the last plant step): the point of the ground plane z = 0 about which the
        total contact wrench has no horizontal moment, ``p_x = -M_y / F_z``, ``p_y = M_x / F_z``
        (moments about the world origin; on flat ground the centre of pressure). NaN without a
        normal force. Each contact's wrench is taken as the one on the robot (normal force up)."""
        results = self.plant.get_contact_results_output_port().Eval(ctx)
        F, M = np.zeros(3), np.zeros(3)

        def add(f: np.ndarray, m_about_p: np.ndarray, p: np.ndarray) -> None:
            nonlocal F, M
            sign = 1.0 if f[2] >= 0 else -1.0   # the wrench on the robot: the ground pushes up
            F += sign * f
            M += sign * (m_about_p + np.cross(p, f))

        for i in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(i)
            w = info.F_Ac_W()   # at the contact surface's centroid
            add(np.asarray(w.translational()), np.asarray(w.rotational()), np.asarray(info.contact_surface().centroid()))
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            add(np.asarray(info.contact_force()), np.zeros(3), np.asarray(info.contact_point()))
        if F[2] <= 1e-9:
            return np.full(2, np.nan)
        return np.array([-M[1] / F[2], M[0] / F[2]])

    def torso_pose(self, ctx):
        return self.plant.EvalBodyPoseInWorld(ctx, self.plant.GetBodyByName(self.spec.stand.torso))


class _DropDrakeMessage(logging.Filter):
    """Drops the ``drake`` logger's records whose message contains ``text``."""

    def __init__(self, text: str):
        super().__init__()
        self.text = text

    def filter(self, record: logging.LogRecord) -> bool:
        return self.text not in record.getMessage()


def _drop_drake_message(text: str) -> None:
    """Drop Drake's log records that contain ``text`` from now on, in this process (pydrake logs through
    Python's ``drake`` logger); idempotent."""
    logger = logging.getLogger("drake")
    if not any(isinstance(f, _DropDrakeMessage) and f.text == text for f in logger.filters):
        logger.addFilter(_DropDrakeMessage(text))


def load_floating(spec: RobotSpec, builder=None, time_step: float | None = None, pd: bool = True) -> FloatingRobot:
    """A fresh floating robot of ``spec`` (its own plant and scene graph, optionally inside ``builder``; the
    step: the spec's ``time_step``). ``pd`` False: the actuators have no PD gains (pure torque control, the
    stabilizer's plant)."""
    from pydrake.geometry import (
        AddCompliantHydroelasticProperties,
        AddContactMaterial,
        AddRigidHydroelasticProperties,
        Box,
        CollisionFilterDeclaration,
        GeometrySet,
        HalfSpace,
        ProximityProperties,
        Sphere,
    )
    from pydrake.math import RigidTransform
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import (
        AddMultibodyPlantSceneGraph,
        ContactModel,
        CoulombFriction,
        DiscreteContactApproximation,
    )
    from pydrake.multibody.tree import PdControllerGains
    from pydrake.systems.framework import DiagramBuilder

    time_step = spec.time_step if time_step is None else time_step
    if time_step <= 0:
        raise ValueError("a floating robot is a discrete plant: time_step must be > 0")
    stand = spec.stand
    friction_c, dissipation, stiffness = (stand.value("contact", k) for k in ("friction", "dissipation",
                                                                               "bumper_stiffness"))
    builder = builder or DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step)
    plant.set_contact_model(ContactModel.kHydroelasticWithFallback)
    plant.set_discrete_contact_approximation(DiscreteContactApproximation.kLagged)
    model, = Parser(plant).AddModels(spec.file)
    for i in plant.GetJointActuatorIndices():
        act = plant.get_joint_actuator(i)
        act.set_default_gear_ratio(1.0)
        act.set_default_rotor_inertia(spec.armature)
        if pd:
            act.set_controller_gains(PdControllerGains(p=stand.value("gains", "kp"), d=stand.value("gains", "kd")))
    friction = CoulombFriction(friction_c, friction_c)
    sole_props = ProximityProperties()
    AddCompliantHydroelasticProperties(0.02, stand.value("contact", "modulus"), sole_props)
    AddContactMaterial(dissipation=dissipation, point_stiffness=stiffness, friction=friction,
                       properties=sole_props)
    robot_geoms = []
    soles = {}
    for k, s in enumerate(spec.feet):
        gid = plant.RegisterCollisionGeometry(plant.GetBodyByName(s), RigidTransform(list(stand.box_center)),
                                              Box(*stand.box_size), f"{s}_box", sole_props)
        robot_geoms.append(gid)
        soles[gid] = k
    bumper_props = ProximityProperties()
    AddContactMaterial(dissipation=dissipation, point_stiffness=stiffness, friction=friction,
                       properties=bumper_props)
    for j, (body, centre, r) in enumerate(stand.bumpers):
        robot_geoms.append(plant.RegisterCollisionGeometry(plant.GetBodyByName(body), RigidTransform(list(centre)),
                                                           Sphere(r), f"bumper_{j}_{body}", bumper_props))
    ground_props = ProximityProperties()
    AddRigidHydroelasticProperties(ground_props)
    AddContactMaterial(dissipation=dissipation, point_stiffness=stiffness, friction=friction,
                       properties=ground_props)
    # the ground: the rigid half space z <= 0. Drake clips the soles' pressure fields against a plane,
    # not a box's triangles: the same contact, about a quarter less compute for the floating executions
    # (measured over a reproduce). Its one-line warning that a rigid half space has no deformable
    # contact (raico has no deformable bodies; Drake logs it at the first contact query) is dropped
    _drop_drake_message("half spaces are not currently supported for deformable contact")
    plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform(), HalfSpace(), "ground", ground_props)
    plant.RegisterVisualGeometry(plant.world_body(), RigidTransform([0.0, 0.0, -0.001]), Box(1.0, 1.0, 0.002),
                                 "floor", np.array([0.75, 0.75, 0.72, 1.0]))
    plant.Finalize()
    scene_graph.collision_filter_manager().Apply(
        CollisionFilterDeclaration().ExcludeWithin(GeometrySet(robot_geoms)))

    fixed = shared_robot(spec.plant) if spec.plant else shared_model(spec.planning)
    fp = fixed.plant
    joint_idx = np.empty(fp.num_positions(), dtype=int)
    joint_vidx = np.empty(fp.num_velocities(), dtype=int)
    col = {}
    for jf in (fp.get_joint(i) for i in fp.GetJointIndices()):
        if jf.num_positions() == 1:
            free = plant.GetJointByName(jf.name())
            joint_idx[jf.position_start()] = free.position_start()
            joint_vidx[jf.velocity_start()] = free.velocity_start()
            col[jf.name()] = jf.position_start()
    acts = [plant.get_joint_actuator(i) for i in plant.GetJointActuatorIndices(model)]
    act_fixed_idx = np.array([col[a.joint().name()] for a in acts])
    effort = np.array([a.effort_limit() for a in acts])
    bases = [plant.get_body(b) for b in plant.GetFloatingBaseBodies()]
    return FloatingRobot(plant=plant, scene_graph=scene_graph, builder=builder, model=model, fixed=fixed,
                         base=bases[0], A=fixed.P[act_fixed_idx], act_fixed_idx=act_fixed_idx, joint_idx=joint_idx,
                         joint_vidx=joint_vidx, effort=effort, spec=spec, sole_geometries=soles,
                         name=spec.plant or fixed.name)


@cache
def shared_floating(spec: RobotSpec) -> FloatingRobot:
    """One floating robot per spec and process for kinematics queries and recordings (not for diagrams)."""
    return load_floating(spec)
