"""The Nao figures' panels that show the motion, drawn from the plans (thesis Figs. 3.3A, C, D and 3.4A).

Fig. 3.3: (A) snapshots of the inferred reaching movement, (C) the right arm's objectives, (D) the left hand and
the head, which move "to counter balance". Fig. 3.4: (A) snapshots of the balancing movement. The snapshots are
stick figures of Drake's kinematics (body origins joined along the kinematic tree), seen from the front.
"""

from __future__ import annotations

import numpy as np

from raico.pipeline.engine.cache import Cache

# the stick figure: chains of body frames, each drawn as one polyline (legs from the soles, arms and head from the
# torso)
SKELETON = (("l_sole", "l_ankle", "LTibia", "LThigh", "torso"), ("r_sole", "r_ankle", "RTibia", "RThigh", "torso"),
            ("torso", "LShoulder", "LElbow", "l_wrist", "l_gripper"),
            ("torso", "RShoulder", "RElbow", "r_wrist", "r_gripper"), ("torso", "Neck", "Head", "gaze"))
HEAD_JOINTS = ("HeadYaw", "HeadPitch")
SNAPSHOTS = {"reach": 8, "balance": 10}  # Fig. 3.3A: eight snapshots; Fig. 3.4A: ten
LABEL = "R-AICO a=1"  # the plans the thesis's panels show (Fig. 3.4A: "for alpha = 1")


def wants_motion_panels(exp) -> bool:
    """The thesis's Nao figures (reach: Fig. 3.3; balance: Fig. 3.4) have panels of the motion."""
    return exp.plant == "nao" and exp.task in SNAPSHOTS


def _plans_of(cache: Cache, plans: list[dict], label: str) -> list[tuple[int, np.ndarray, dict]]:
    """``(seed, X (T+1, n_x), problem.json)`` of each finite plan of variant ``label``, in seed order."""
    from raico.pipeline.engine.artifacts import as_artifact

    out = []
    for p in sorted((p for p in plans if p["variant"].label == label), key=lambda p: p["seed"]):
        art = as_artifact(cache.require("plan", p["outcome"].key))
        X = art.arrays("plan.npz", ("X",))["X"]
        if np.all(np.isfinite(X)):
            out.append((p["seed"], X, art.document("problem.json")))
    return out


def skeleton(robot, Q: np.ndarray) -> list[np.ndarray]:
    """Per chain of :data:`SKELETON` its points' world positions ``(len(Q), len(chain), 3)`` m at the joint
    positions ``Q (K, n_q)``."""
    from raico.plants.taskmaps import EndEffectorPosition

    pos = {f: EndEffectorPosition(robot, f).values_and_jacobians(Q)[0] for f in {f for c in SKELETON for f in c}}
    return [np.stack([pos[f] for f in chain], axis=1) for chain in SKELETON]


def _snapshot_panel(ax, robot, X: np.ndarray, dt: float, count: int, title: str) -> None:
    """``count`` snapshots of a plan, stick figures seen from the front (world y to the left, z up), side by side
    from the first step to the last, each labelled with its time."""
    import matplotlib

    steps = np.linspace(0, len(X) - 1, count).round().astype(int)
    chains = skeleton(robot, X[steps, :robot.n_q])
    width = max(float(np.ptp(np.concatenate([c[..., 1].ravel() for c in chains]))), 0.2) * 1.15
    cmap = matplotlib.colormaps["viridis"]
    ref = float(np.mean([c[0, :, 1].mean() for c in chains]))  # the first snapshot's middle: each drawn about it
    for i, k in enumerate(steps):
        color = cmap(i / max(count - 1, 1))
        for c in chains:
            # seen from the front (the robot faces world +x): its left, world +y, on the viewer's right
            ax.plot(c[i, :, 1] - ref + i * width, c[i, :, 2], "-o", color=color, lw=1.6, markersize=2)
        ax.text(i * width, -0.03, f"{k * dt:.2f} s", ha="center", va="top", fontsize=7)
    ax.set_aspect("equal")
    ax.set_yticks([])
    ax.set_xticks([])
    ax.set_ylim(-0.08, None)
    ax.set_title(title, fontsize=9)
    for s in ax.spines.values():
        s.set_visible(False)


def _objectives_panel(ax, robot, runs: list, dt: float) -> None:
    """Fig. 3.3C: the right hand's planned coordinates that its via-point objectives constrain (mean and standard
    deviation over the plans, each thin) against their targets (large circles at their times)."""
    from raico.plants.taskmaps import FramePoints

    terms = [t for t in runs[0][2]["terms"] if t.get("term") == "via" and t["name"].startswith("via_hand")
             and (t.get("map") or {}).get("map") == "frame_points"]
    if not terms:
        ax.text(0.5, 0.5, "no hand objectives", ha="center", va="center", transform=ax.transAxes)
        return
    colors = ("tab:blue", "tab:orange", "tab:green")
    for term in terms:
        m = term["map"]
        fp = FramePoints(robot, m["frame"], m.get("points"), m.get("axes") or (0, 1, 2))
        Y = np.array([fp.values_and_jacobians(X[:, :robot.n_q])[0] for _, X, _ in runs])  # (plans, T+1, dim)
        t = np.arange(Y.shape[1]) * dt
        for a, axis in enumerate(m.get("axes") or (0, 1, 2)):
            c = colors[a % len(colors)]
            name = "xyz"[axis]
            for y in Y[:, :, a]:
                ax.plot(t, y, color=c, lw=0.4, alpha=0.35)
            mean, sd = Y[:, :, a].mean(axis=0), Y[:, :, a].std(axis=0)
            ax.fill_between(t, mean - sd, mean + sd, color=c, alpha=0.2, lw=0)
            ax.plot(t, mean, color=c, lw=1.8, label=f"{m['frame']} {name} (world)")
            for tt in term.get("times") or []:
                ax.plot(tt * dt, term["target"][a], "o", color=c, markersize=9, mfc="none", mew=1.5)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("position (m)")
    ax.set_title(f"(C) the right arm's objectives, {LABEL} ({len(runs)} plans):\nmean and standard deviation, each "
                 "plan thin; circles: the targets", fontsize=9)
    ax.legend(fontsize=7, loc="best")
    ax.grid(True, alpha=0.3)


def _counterbalance_panels(ax_hand, ax_head, robot, runs: list, dt: float) -> None:
    """Fig. 3.3D: the left hand's displacement from its start (world x, y, z) and the head joints' angles from
    their start, mean and standard deviation over the plans (each thin)."""
    from raico.plants.taskmaps import EndEffectorPosition

    hand = EndEffectorPosition(robot, "l_gripper")
    P = np.array([hand.values_and_jacobians(X[:, :robot.n_q])[0] for _, X, _ in runs])
    P = P - P[:, :1]
    idx = [robot.joint_names.index(j) for j in HEAD_JOINTS]
    H = np.array([X[:, idx] - X[0, idx] for _, X, _ in runs])
    t = np.arange(P.shape[1]) * dt
    for ax, V, names, unit in ((ax_hand, P, ("x", "y", "z"), "m"), (ax_head, H, HEAD_JOINTS, "rad")):
        for a, name in enumerate(names):
            c = f"C{a}"
            for v in V[:, :, a]:
                ax.plot(t, v, color=c, lw=0.4, alpha=0.35)
            mean, sd = V[:, :, a].mean(axis=0), V[:, :, a].std(axis=0)
            ax.fill_between(t, mean - sd, mean + sd, color=c, alpha=0.2, lw=0)
            ax.plot(t, mean, color=c, lw=1.8, label=name)
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_xlabel("time (s)")
        ax.set_ylabel(f"change from the start ({unit})")
        ax.legend(fontsize=7, loc="best")
        ax.grid(True, alpha=0.3)
    ax_hand.set_title(f"(D) the left hand (no objective names it), {LABEL}:\ndisplacement from the start (world "
                      "axes), mean and sd, each plan thin", fontsize=9)
    ax_head.set_title(f"(D) the head joints (no objective names them), {LABEL}:\nangle from the start", fontsize=9)


def motion_figure(cache: Cache, exp, plans: list[dict]):
    """The thesis's panels of the Nao's motion from the ``LABEL`` plans, a matplotlib figure: Fig. 3.3A, C, D (reach)
    or Fig. 3.4A (balance). The snapshots show the first initial state's plan. None where the figure has none or no
    finite plan."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from raico.plants.robots import shared_robot

    if not wants_motion_panels(exp):
        return None
    runs = _plans_of(cache, plans, LABEL)
    if not runs:
        return None
    robot = shared_robot("nao")
    seed, X, desc = runs[0]
    dt = float(desc["dt"])
    count = SNAPSHOTS[exp.task]
    if exp.task == "reach":
        fig = plt.figure(figsize=(15, 8.6), layout="constrained")
        grid = fig.add_gridspec(2, 3, height_ratios=(1.0, 1.1))
        ax_a = fig.add_subplot(grid[0, :])
        _snapshot_panel(ax_a, robot, X, dt, count, f"(A) {count} snapshots of the inferred movement, {LABEL}, initial "
                                                   f"state {seed} (front view: the robot's left on the right; colour: "
                                                   "time)")
        _objectives_panel(fig.add_subplot(grid[1, 0]), robot, runs, dt)
        _counterbalance_panels(fig.add_subplot(grid[1, 1]), fig.add_subplot(grid[1, 2]), robot, runs, dt)
    else:
        fig, ax = plt.subplots(figsize=(15, 2.6), layout="constrained")
        _snapshot_panel(ax, robot, X, dt, count, f"(A) {count} snapshots of the balancing movement, {LABEL}, initial "
                                                 f"state {seed} (front view: the robot's left on the right; colour: "
                                                 "time)")
    return fig
