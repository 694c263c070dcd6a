"""Recording of a fit artifact: the GP's prediction against the held-out data (SPEC §9).

The held-out segments (``heldout.npz``) are laid end to end on ``sim_time``. Per joint, four
scalar series under ``fit/<joint>/``: ``mean`` (GP predictive mean of qddot, rad/s^2),
``upper`` and ``lower`` (mean +- 2 predictive std, the noise included: where a new
measurement should fall) and ``measured`` (the held-out target); each joint gets its own plot.
The robot moves through the held-out states in the 3D view. ``fit/summary`` (static text) and
the recording properties hold the config, the key, the training points' count (used and
dropped by the cap) and how the hyperparameters were obtained.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline import recording as rec_mod

RECORDING = "recording.rrd"  # = pipeline.recorders.RECORDING (that module imports this one)


def predicted_band(model, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, lower and upper (mean -+ 2 predictive std) ``(M, D)`` at ``X (M, d)``, physical units."""
    mean, var = model.predict(X, noisy=True)
    sd = np.sqrt(np.maximum(var, 0.0))
    return mean, mean - 2.0 * sd, mean + 2.0 * sd


def summary_text(doc: dict) -> str:
    """Markdown summary of a ``fit.json``."""
    rows = "\n".join(f"| {j} | {doc['heldout_rmse'][j]:.4g} | {doc['heldout_nrmse'][j]:.3g} | "
                     f"{doc['log_marginal_likelihood'][j]:.5g} |" for j in doc["joint_names"])
    return (f"**{doc['plant']}**: {doc['n_points']} training points ({doc['n_dropped']} dropped by the cap "
            f"of {doc['max_points']}), {doc['n_heldout']} held out; hyperparameters {doc['mode']} "
            f"in {doc['fit_time_s']:.2f} s.\n\n| joint | held-out RMSE (rad/s^2) | / std | log ML |\n"
            f"|---|---|---|---|\n{rows}\n")


def record_fit(folder: Path, art, inputs: list) -> None:
    """Predicted mean with a +-2 sigma band against the held-out data, per joint, on ``sim_time``."""
    import rerun as rr

    from plants.gp import GPModel
    from plants.robots import shared_robot

    doc = art.document("fit.json")
    h = art.arrays("heldout.npz")
    model = GPModel.from_arrays(art.arrays("model.npz"))
    robot = shared_robot(doc["plant"])
    joints = [rec_mod.entity_name(j) for j in doc["joint_names"]]
    times, X, Y = h["time"], h["X"], h["Y"]
    props = {"stage": "fit", "key": art.key, **art.config, "n_points": doc["n_points"],
             "n_dropped": doc["n_dropped"], "mode": doc["mode"]}
    with rec_mod.Recording(folder / RECORDING, properties=props, name=f"fit {doc['plant']} ({doc['mode']})",
                           time_series=[f"fit/{j}" for j in joints], eye=rec_mod.robot_eye(robot)) as rec:
        rec.rec.log("fit/summary", rr.TextDocument(summary_text(doc), media_type="text/markdown"), static=True)
        rec_mod.log_robot_geometry(rec, robot)
        if len(times):
            rec_mod.log_body_trajectory(rec, robot, times, X[:, :robot.n_q])
            mean, lower, upper = predicted_band(model, X)
            for i, j in enumerate(joints):
                for name, values in (("mean", mean), ("upper", upper), ("lower", lower), ("measured", Y)):
                    rec_mod.log_scalars(rec, f"fit/{j}/{name}", "sim_time", times, values[:, i])
