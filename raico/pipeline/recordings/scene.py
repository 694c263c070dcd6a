"""A plan's or an execution's scene in its recording (plans with collision terms, :mod:`raico.plants.scene`).

- ``world/scene/<object>``: the scene's objects, static, in their colour (default grey-blue); a world
  file's geometry by Drake's shapes;
- ``world/robot/<body>/collision/<geometry>``: the robot's own collision geometry (primitives, meshes as
  their convex hulls' vertices and triangles), translucent orange, moving with its body;
- ``world/distances``: on ``sim_time``, the closest-distance segments (witness point to witness point) of
  every pair within its term's ``max_distance``, red below the margin, orange within twice it, green else;
- ``collision/min_distance``: the smallest distance over the pairs per step (m), with the margin.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import rerun as rr

from raico.pipeline.recordings import rerun_io as rec_mod

SCENE_COLOR = (120, 140, 190, 255)
COLLISION_COLOR = (255, 150, 40, 90)
NEAR, CLOSE, FAR = (230, 40, 40), (250, 160, 30), (60, 200, 90)


def collision_terms(objective) -> list:
    from raico.planning.costs import Collision

    return [t for t in objective.state_terms if isinstance(t, Collision)]


def _archetype(shape, color) -> Any:
    """A ``raico.plants.scene.Shape`` as a solid Rerun archetype in its own frame."""
    kw = {"colors": [color], "fill_mode": "solid"}
    if shape.kind == "box":
        return rr.Boxes3D(sizes=[list(shape.size)], **kw)
    if shape.kind == "sphere":
        return rr.Ellipsoids3D(radii=[shape.size[0]], **kw)
    if shape.kind == "cylinder":
        return rr.Cylinders3D(lengths=[shape.size[1]], radii=[shape.size[0]], **kw)
    if shape.kind == "capsule":   # Rerun's runs from z = 0 to z = length, the shape's is centred
        return rr.Capsules3D(lengths=[shape.size[1]], radii=[shape.size[0]],
                             translations=[[0.0, 0.0, -shape.size[1] / 2]], **kw)
    from scipy.spatial import ConvexHull

    V = np.asarray(shape.vertices, float)
    hull = ConvexHull(V)
    return rr.Mesh3D(vertex_positions=V[hull.vertices],
                     triangle_indices=np.searchsorted(hull.vertices, hull.simplices).astype(np.uint32),
                     albedo_factor=color)


def _pose(pose) -> rr.Transform3D:
    from raico.plants.scene import rigid_transform

    X = rigid_transform(pose)
    return rr.Transform3D(translation=X.translation(),
                          quaternion=rec_mod._wxyz_to_xyzw(X.rotation().ToQuaternion().wxyz()))


def log_scene_geometry(rec, world) -> None:
    """The scene's objects and the robot's collision geometry of a ``raico.plants.scene.CollisionWorld``, static."""

    from raico.plants.scene import ROBOT_PREFIX

    stream = rec_mod._stream(rec)
    drawn = set()
    for s in world.shapes:
        if s.body == "world":
            color = tuple(int(round(255 * c)) for c in s.color) if s.color else SCENE_COLOR
            color = color if len(color) == 4 else (*color, 255)
            stream.log(f"world/scene/{rec_mod.entity_name(s.name)}", _pose(s.pose), _archetype(s, color), static=True)
        else:
            name = rec_mod.entity_name(s.name.removeprefix(ROBOT_PREFIX).replace("/", "_"))
            stream.log(f"{rec_mod.ROBOT_PREFIX}/{rec_mod.entity_name(s.body)}/collision/{name}", _pose(s.pose),
                       _archetype(s, COLLISION_COLOR), static=True)
        drawn.add(s.name)
    inspector = world.inspector
    for name, gid in world.geometries.items():   # a world file's geometry: Drake's shapes
        if name in drawn or name.startswith(ROBOT_PREFIX):
            continue
        archetype = rec_mod._primitive(inspector.GetShape(gid), np.asarray(SCENE_COLOR, np.uint8))
        if archetype is None:
            continue
        world.set_positions(np.zeros(world.plant.num_positions()))
        X = world.scene_graph.get_query_output_port().Eval(world.sg_context).GetPoseInWorld(gid)
        stream.log(f"world/scene/{rec_mod.entity_name(name)}",
                   rr.Transform3D(translation=X.translation(),
                                  quaternion=rec_mod._wxyz_to_xyzw(X.rotation().ToQuaternion().wxyz())),
                   archetype, static=True)


def log_scene(rec, objective, times: np.ndarray, X: np.ndarray, sel: np.ndarray) -> None:
    """The scene, the robot's collision geometry, the closest-distance segments at the samples ``sel`` of
    ``times (K,)`` s along ``X (K, n_x)`` and the smallest distance per sample (module docstring); nothing
    without collision terms."""
    terms = collision_terms(objective)
    if not terms:
        return
    stream = rec_mod._stream(rec)
    log_scene_geometry(rec, terms[0].taskmap.world)
    n = X.shape[1] // 2
    Q = np.nan_to_num(X[sel, :n])
    smallest = np.full(len(sel), np.inf)
    segments: list[list] = [[] for _ in sel]
    colors: list[list] = [[] for _ in sel]
    for term in terms:
        D, _, W = term.taskmap.evaluate(Q, jacobians=False)
        smallest = np.minimum(smallest, np.nanmin(D, axis=1))
        for k in range(len(sel)):
            for p in np.flatnonzero(np.isfinite(W[k, :, 0, 0])):
                segments[k].append(W[k, p])
                d = D[k, p]
                colors[k].append(NEAR if d < term.margin else CLOSE if d < 2 * term.margin else FAR)
    for k, s in enumerate(sel):
        stream.set_time("sim_time", duration=float(times[s]))
        stream.log("world/distances", rr.LineStrips3D(segments[k], colors=colors[k] or None, radii=0.002))
    margin = min(t.margin for t in terms)
    rec_mod.log_scalars(rec, "collision/min_distance", "sim_time", times[sel],
                        np.c_[smallest, np.full(len(sel), margin)],
                        names=["smallest distance (m)", "margin (m)"], colors=[NEAR, (150, 150, 150)])


def scene_views(objective) -> list:
    """The smallest-distance plot (``collision``) where the objective has collision terms."""
    import rerun.blueprint as rrb

    return [rrb.TimeSeriesView(origin="/collision", name="smallest distance (m)")] if collision_terms(objective) else []
