"""Recording of a fit artifact: the GP's prediction against the held-out data.

The held-out segments (``heldout.npz``) are laid end to end on ``sim_time``. Per joint, four
scalar series under ``fit/<joint>/``: ``mean`` (GP predictive mean of qddot, rad/s^2),
``upper`` and ``lower`` (mean +- 2 predictive std, the noise included: where a new
measurement should fall) and ``measured`` (the held-out target); each joint gets its own plot
(the Nao's in a tab per limb, ``raico.pipeline.recordings.rerun_io.joint_groups``). The robot moves through the
held-out states in the 3D view (poses decimated as in ``raico.pipeline.recordings.rerun_io``), above
``fit/summary`` (static text); that and the recording properties hold the config, the key, the
training points' count (used and dropped by the cap) and how the hyperparameters were obtained.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from raico.pipeline.recordings import RECORDING
from raico.pipeline.recordings import rerun_io as rec_mod


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


def record_fit(folder: Path, art, inputs: list, lookup=None) -> None:
    """Predicted mean with a +-2 sigma band against the held-out data, per joint, on ``sim_time``."""
    import rerun as rr

    from raico.plants.gp import GPModel
    from raico.plants.robots import robot_for

    doc = art.document("fit.json")
    h = art.arrays("heldout.npz")
    model = GPModel.from_arrays(art.arrays("model.npz"))
    robot = robot_for({"plant": doc["plant"], "robot": doc.get("robot")})
    joints = [rec_mod.entity_name(j) for j in doc["joint_names"]]
    times, X, Y = h["time"], h["X"], h["Y"]
    props = {"stage": "fit", "key": art.key, **art.config, "n_points": doc["n_points"],
             "n_dropped": doc["n_dropped"], "mode": doc["mode"]}
    eye = rec_mod.robot_eye(robot, X[:, :robot.n_q] if len(times) else None)
    with rec_mod.Recording(folder / RECORDING, rec_mod.application_id("fit", doc["plant"]), properties=props,
                           name=f"fit {doc['plant']} ({doc['mode']})", blueprint=fit_blueprint(joints, eye)) as rec:
        rec.rec.log("fit/summary", rr.TextDocument(summary_text(doc), media_type="text/markdown"), static=True)
        rec_mod.log_robot_geometry(rec, robot)
        if len(times):
            rec_mod.log_body_trajectory(rec, robot, times, X[:, :robot.n_q], joints=False)
            mean, lower, upper = predicted_band(model, X)
            sel = rec_mod.plot_indices(len(times))
            for i, j in enumerate(joints):
                for name, values in (("mean", mean), ("upper", upper), ("lower", lower), ("measured", Y)):
                    rec_mod.log_scalars(rec, f"fit/{j}/{name}", "sim_time", times[sel], values[sel, i],
                                        names=[f"{j} {name}"], colors=[BAND_COLORS[name]])


BAND_COLORS = {"mean": (80, 145, 245), "upper": (120, 120, 150), "lower": (120, 120, 150),
               "measured": (240, 175, 40)}


def fit_blueprint(joints: list[str], eye):
    """The robot above the summary; per joint a plot of ``fit/<joint>`` (a tab per limb if the
    joints have limbs)."""
    import rerun.blueprint as rrb

    def view(j: str):
        return rrb.TimeSeriesView(origin=f"/fit/{j}", name=f"{j}: qddot (rad/s^2)")

    groups = rec_mod.joint_groups(joints)
    if "" in groups:
        plots = [view(j) for j in joints]
    else:
        plots = [rrb.Tabs(*[rrb.Vertical(*[view(joints[i]) for i in idx], name=g) for g, idx in groups.items()],
                          active_tab=0)]
    return rec_mod.stage_blueprint(eye, plots, [rrb.TextDocumentView(origin="/fit/summary", name="summary")])
