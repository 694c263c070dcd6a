"""The babble stage's recording: every babbling episode laid end to end on ``sim_time``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from raico.pipeline.recordings import MCAP, RECORDING
from raico.pipeline.recordings import rerun_io as rec_mod
from raico.pipeline.recordings.mcap_io import write_trajectory_mcap


def _episode_times(t: np.ndarray, episodes: int, gap: float) -> np.ndarray:
    """Episodes laid end to end on one ``sim_time`` axis: ``(episodes * K,)`` s."""
    span = t[-1] + gap
    return (np.arange(episodes)[:, None] * span + t[None, :]).reshape(-1)


def record_babble(folder: Path, art, inputs: list, lookup=None) -> None:
    """Every babbling episode laid end to end on ``sim_time``: robot (at most ``MAX_POSES`` poses
    per episode), joints, desired joints and torques by limb."""
    from raico.plants.robots import robot_for
    from raico.stages.babble import robot_description

    cfg = art.config
    data = art.arrays("data.npz")
    robot = robot_for(robot_description(cfg), true=True)
    q, qdot, u, t = data["q"], data["qdot"], data["u"], data["t"]
    E, K, n = q.shape
    times = _episode_times(t, E, gap=t[1] - t[0])
    Q = q.reshape(-1, n)
    poses = (np.arange(E)[:, None] * K + rec_mod.pose_indices(K, rec_mod.n_bodies(robot))[None, :]).reshape(-1)
    sel = rec_mod.plot_indices(E * K)
    groups = rec_mod.joint_groups(robot.joint_names)
    eye = rec_mod.robot_eye(robot, Q[poses])
    plots = [rec_mod.group_views(r, groups, title) for r, title in
             (("joints", "joints (rad)"), ("desired", "desired joints (rad)"), ("torque", "torque (N m)"))]
    blueprint = rec_mod.stage_blueprint(eye, plots)
    with rec_mod.Recording(folder / RECORDING, rec_mod.application_id("babble", cfg["plant"]),
                           properties={"stage": "babble", "key": art.key, **cfg},
                           name=f"babble {cfg['plant']}", blueprint=blueprint) as rec:
        rec_mod.log_robot_geometry(rec, robot)
        rec_mod.log_body_trajectory(rec, robot, times, Q, poses=poses)
        rec_mod.log_joint_series(rec, robot.joint_names, times[sel], data["q_des"].reshape(-1, n)[sel],
                                 root="desired", continuous=rec_mod.continuous_joints(robot))
        rec_mod.log_joint_series(rec, robot.joint_names, times[sel], u.reshape(-1, n)[sel], root="torque")
        rec_mod.log_scalars(rec, "episode_index", "sim_time", times[sel], np.repeat(np.arange(E), K)[sel])
    write_trajectory_mcap(folder / MCAP, robot, times, Q, qdot.reshape(-1, n), u.reshape(-1, n))
