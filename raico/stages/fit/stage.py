"""The fit stage (thesis §4.2): a GP model of ``qddot = f(q, qdot, u)`` from babbled or executed data.

Data. ``--data`` names babble and execute artifacts; the training set is every point of them
(every ``stride``-th sample of each time segment), in the order given: a babble episode's sampled
``(q, qdot, u) -> qddot``, an execution's states and applied torques with Drake's forward dynamics
as the target (an exact sample of the plant's dynamics). Rows with a non-finite value are skipped.
The trailing ``holdout`` fraction of every segment is held out: never trained on, used for the
held-out RMSE and the recording.

Hyperparameter schedule (thesis "1:1" and ">100"). Without ``--prior`` the hyperparameters are
optimized (``fit_gp``). With ``--prior`` (an earlier fit of the same plant, holdout and stride whose
data keys are all among ``--data``): ``every`` re-optimizes on all data, warm-started at the prior's
hyperparameters; ``batch-N`` re-optimizes when ``N`` training points arrived since the prior's last
optimization, else extends the prior's GP at its hyperparameters (``GPModel.update``). The cap
``max_points`` applies to every path; ``n_dropped`` says how many points it dropped.

Residual model (``--residual``): the targets are ``qddot - f_model(q, qdot, u)``, what the planning
model misses (``raico.plants.learned.ResidualDynamics`` plans with model + GP). GP kind (``--gp``):
``exact`` (``raico.plants.gp.GPModel``) or ``sparse`` (FITC with ``--inducing M`` inducing inputs). A prior
must be of the same kind on both counts.

Files: ``model.npz`` (``GPModel.to_arrays()``: what ``make_dynamics("learned", robot, dt, params)``
takes), ``heldout.npz`` (held-out inputs ``X (M, d)``, targets ``Y (M, n_q)``, laid-out ``time (M,)``
s, ``segment (M,)``) and ``fit.json`` (:func:`fit_document`). The rules in detail: docs/learning.md,
"The fit stage".
"""

from __future__ import annotations

import json
import math
import re
import time
from dataclasses import dataclass
from typing import cast

import numpy as np

from raico.plants.gp import AngleInputGP, GPBase, GPModel, SparseGPModel, angle_features
from raico.stages.base import Artifact, Progress, Stage, StageConfig, StageOutput
from raico.stages.fit.gp_fit import fit_gp, fit_sparse_gp, refit_fixed, rmse, subsample_indices
from raico.stages.registry import DESCRIPTIONS

MODEL_FILE = "model.npz"
HELDOUT_FILE = "heldout.npz"
FIT_FILE = "fit.json"
DATA_STAGES = ("babble", "execute")
MIN_BATCH = 100  # batch-N only with N >= 100 (the thesis's ">100")
_BATCH = re.compile(r"batch-(\d+)")
GP_KINDS = ("exact", "sparse", "auto")
AUTO_EXACT_POINTS = 1000  # --gp auto: the exact GP up to this many training points (after the cap), sparse above


@dataclass(frozen=True)
class FitConfig(StageConfig):
    """Declared parameters of the fit stage; ``data`` and ``prior`` are its inputs."""

    INPUTS = ("data", "prior")
    INPUT_STAGES = {"data": DATA_STAGES, "prior": "fit"}
    HELP = {"data": "Key of a babble or execute artifact (repeatable: --data A --data B); all their points, in order.",
            "prior": "Key of an earlier fit artifact whose data keys are all among --data (see --schedule).",
            "schedule": "With --prior: 'every' re-optimizes the hyperparameters; 'batch-N' (N >= 100) only once "
                        "N points were added since the prior's last optimization, else adds them at fixed ones.",
            "restarts": "Random restarts of the likelihood optimizer (per output).",
            "seed": "Seed of the optimizer's restarts.",
            "max_points": "Cap on the training points (older ones subsampled).",
            "holdout": "Trailing fraction of every time segment held out for the error and the recording.",
            "stride": "Keep every stride-th sample of each executed trajectory (1: all; babbling keeps all).",
            "gp": "exact (the full GP), auto (exact up to 1000 training points, sparse above: said on stderr) or "
                  "sparse (FITC with --inducing points chosen among the training inputs by "
                  "greedy maximum variance; hyperparameters optimized on that many points).",
            "inducing": "Inducing points of --gp sparse (1 to --max-points, and at most the training points).",
            "residual": "Fit the difference between the data's accelerations and the planning model's (the plant's "
                        "or the model file's analytic dynamics): planning then uses model + GP."}

    data: tuple[str, ...] = ()
    prior: str | None = None
    schedule: str = "every"
    restarts: int = 2
    seed: int = 0
    max_points: int = 1000
    holdout: float = 0.2
    stride: int = 1
    gp: str = "exact"
    inducing: int = 200
    residual: bool = False

    def validate(self) -> None:
        if not self.data:
            raise ValueError("fit needs --data KEY (a babble or execute artifact; repeatable)")
        if len(self.data) > 1000:
            raise ValueError("data: at most 1000 artifacts")
        if any(not isinstance(d, str) or not d.strip() for d in self.data):
            raise ValueError("data: an empty artifact reference")
        if len({d.strip() for d in self.data}) != len(self.data):
            raise ValueError("data: the same artifact given twice")
        if self.prior is not None and not self.prior.strip():
            raise ValueError("prior: an empty artifact reference")
        batch_size(self.schedule)
        checks = [(0 <= self.restarts <= 50, "restarts must be in [0, 50]"),
                  (0 <= self.seed < 2**32, "seed must be in [0, 2^32 - 1]"),
                  (10 <= self.max_points <= 5000, "max-points must be in [10, 5000]"),
                  (0.0 <= self.holdout <= 0.5, "holdout must be in [0, 0.5]"),
                  (1 <= self.stride <= 1000, "stride must be in [1, 1000]"),
                  (self.gp in GP_KINDS, f"gp must be one of {', '.join(GP_KINDS)}, got '{self.gp}'"),
                  (self.inducing >= 1, f"inducing must be >= 1, got {self.inducing}"),
                  (self.gp == "exact" or self.inducing <= self.max_points,
                   f"inducing ({self.inducing}) exceeds max-points ({self.max_points})")]
        for ok, msg in checks:
            if not ok:
                raise ValueError(msg)


def batch_size(schedule: str) -> int | None:
    """None for ``every``, ``N`` for ``batch-N`` (``ValueError`` unless ``N >= 100``)."""
    if schedule == "every":
        return None
    m = _BATCH.fullmatch(schedule or "")
    if m is None or not MIN_BATCH <= int(m.group(1)) <= 10**7:
        raise ValueError(f"schedule must be 'every' or 'batch-N' with N in [{MIN_BATCH}, 1e7], "
                         f"got '{schedule}'")
    return int(m.group(1))


# ----------------------------------------------------------------------------- data
@dataclass
class Segment:
    """One time segment of one data artifact: inputs ``X (K, 2 n_q + n_u)`` = ``(q, qdot, u)``
    (rad, rad/s, N m), targets ``Y (K, n_q)`` (rad/s^2), times ``t (K,)`` s."""

    source: str
    X: np.ndarray
    Y: np.ndarray
    t: np.ndarray


@dataclass
class DataSet:
    """Training and held-out points of all data artifacts, in order (shapes as :class:`Segment`)."""

    plant: str
    joint_names: tuple[str, ...]
    sources: tuple[str, ...]
    X: np.ndarray  # (N, d) training inputs
    Y: np.ndarray  # (N, n_q)
    source: np.ndarray  # (N,) index into sources
    X_test: np.ndarray  # (M, d)
    Y_test: np.ndarray  # (M, n_q)
    t_test: np.ndarray  # (M,) s, held-out segments laid end to end
    seg_test: np.ndarray  # (M,) segment number
    robot: dict | None = None  # the robot as a plan's problem.json states it (plant, robot, robot_true)
    residual: bool = False  # targets are qddot - f_model (the module docstring)
    angle_inputs: tuple[int, ...] = ()  # input columns read as (sin, cos): the continuous joints' angles


def angle_inputs(robot) -> tuple[int, ...]:
    """The GP input columns (joint indices) of ``robot``'s continuous joints: revolute with no position limit
    (a URDF ``continuous`` joint, the cart-pole's pole), whose angle the GP reads as ``(sin, cos)``
    (``raico.plants.gp.AngleInputGP``; PILCO's ``gTrig`` of the cart-pole's angle). A limited revolute joint (the
    pendulum's, +-100 rad; the arms') keeps its raw angle."""
    return tuple(i for i, name in enumerate(robot.joint_names)
                 if robot.plant.GetJointByName(name).type_name() == "revolute"
                 and not np.isfinite(robot.lower[i]) and not np.isfinite(robot.upper[i]))


def _finite_rows(*arrays: np.ndarray) -> np.ndarray:
    """Mask of rows finite in every ``(K, ...)`` array."""
    return np.all(np.hstack([np.isfinite(a).reshape(len(a), -1) for a in arrays]), axis=1)


def babble_segments(art: Artifact) -> tuple[dict, list[Segment]]:
    """The robot (``raico.stages.babble.robot_description``) and one segment per episode of a babble artifact
    (``data.npz``)."""
    from raico.stages.babble import robot_description

    d = art.arrays("data.npz")
    segs = []
    for e in range(d["q"].shape[0]):
        X = np.hstack([d["q"][e], d["qdot"][e], d["u"][e]])
        Y = d["qddot"][e]
        ok = _finite_rows(X, Y)
        segs.append(Segment(art.ref, X[ok], Y[ok], d["t"][ok]))
    return robot_description(art.config), segs


def plan_problem(art: Artifact) -> dict:
    """``problem.json`` of the plan an execute artifact ran (the cache's ``<root>/plan/<key>/``)."""
    refs = [r for r in art.inputs if r.startswith("plan/")]
    path = art.path.parents[1] / "plan" / refs[0].split("/", 1)[1] / "problem.json" if refs else None
    if path is None or not path.is_file():
        raise ValueError(f"{art.ref}: the plan it executed is not in the cache")
    return json.loads(path.read_text(encoding="utf-8"))


def execute_segments(art: Artifact, stride: int = 1) -> tuple[dict, list[Segment]]:
    """The robot (``plant``, ``robot``, ``robot_true`` of its plan's description) and the one segment of an execute artifact: ``(X[k], tau[k]) -> qddot`` by Drake's
    forward dynamics (the analytic model), ``k < T``; non-finite rows skipped, then every
    ``stride``-th row kept. The accelerations are computed only at the kept rows (all rows only if
    one of them is not finite, so the selection is the same as computing everything first)."""
    from raico.plants.dynamics import SemiImplicitEuler
    from raico.plants.dynamics_registry import make_dynamics
    from raico.plants.robots import robot_for

    desc = plan_problem(art)
    r = art.arrays("rollout.npz")
    robot = robot_for(desc, true=True)  # the targets: the executed (true) robot's forward dynamics
    n, tau = robot.n_q, r["tau"]
    T = len(tau)
    X = r["X"][:T]
    dyn = cast(SemiImplicitEuler, make_dynamics("analytic", robot, float(desc["dt"])))   # it has qddot
    ok = _finite_rows(X, tau) & (np.arange(T) < usable_steps(art, float(desc["dt"]), T))
    Y = np.full((T, n), np.nan)
    keep = np.flatnonzero(ok)[::stride]
    for k in keep:
        Y[k] = dyn.qddot(X[k, :n], X[k, n:], tau[k])
    if not np.all(np.isfinite(Y[keep])):
        for k in np.flatnonzero(ok):   # a non-finite acceleration drops its row before the stride
            Y[k] = dyn.qddot(X[k, :n], X[k, n:], tau[k])
        keep = np.flatnonzero(ok & _finite_rows(Y))[::stride]
    robot_desc = {k: desc[k] for k in ("plant", "robot", "robot_true") if desc.get(k) is not None}
    return robot_desc, [Segment(art.ref, np.hstack([X, tau])[keep], Y[keep], r["times"][:T][keep])]


FAILED = ("tracking-lost", "fell", "diverged")  # executions whose data end where they failed


def usable_steps(art: Artifact, dt: float, T: int) -> int:
    """Steps of an execution that may join the data: all ``T``, or those before its failure time
    when it lost tracking, fell or diverged (past that point the robot no longer follows a plan: a
    real robot's safety stop; its data would teach the model a runaway)."""
    t_fail = (art.metrics or {}).get("failure_time")
    if art.status not in FAILED or t_fail is None:
        return T
    return max(0, min(T, int(math.floor(float(t_fail) / dt + 1e-9))))


def model_accelerations(robot, X: np.ndarray) -> np.ndarray:
    """The planning model's ``qddot (K, n_q)`` (rad/s^2) at inputs ``X (K, 2 n_q + n_u)`` = ``(q, qdot, u)``:
    the robot's analytic model (its step's ``dt`` does not enter the accelerations)."""
    from raico.plants.dynamics import SemiImplicitEuler
    from raico.plants.dynamics_registry import make_dynamics

    n = robot.n_q
    dyn = cast(SemiImplicitEuler, make_dynamics("analytic", robot, 0.01))   # an analytic model: it has qddot
    return np.array([dyn.qddot(x[:n], x[n:2 * n], x[2 * n:]) for x in X]).reshape(-1, n)


def residual_segment(robot, seg: Segment) -> Segment:
    """``seg`` with targets ``qddot - f_model`` (:func:`model_accelerations`); rows the model cannot
    evaluate (non-finite) are dropped."""
    if len(seg.X) == 0:
        return seg
    Y = seg.Y - model_accelerations(robot, seg.X)
    ok = _finite_rows(Y)
    return Segment(seg.source, seg.X[ok], Y[ok], seg.t[ok])


def split_count(K: int, holdout: float) -> int:
    """Held-out samples at the end of a segment of ``K``: ``round(holdout K)``, leaving one for training."""
    return max(0, min(K - 1, int(round(holdout * K))))


def load_data(arts: tuple[Artifact, ...], holdout: float, stride: int = 1, residual: bool = False) -> DataSet:
    """Training and held-out points of ``arts`` (babble or execute, all of the same plant), every
    ``stride``-th sample of each segment; with ``residual`` the targets less the planning model's
    accelerations (module docstring)."""
    from raico.plants.robots import robot_for

    plant_names, segs, robots = set(), [], {}
    for art in arts:
        # babbling keeps its own sampling rate; an execution every ``stride``-th (finite) sample
        desc, got = babble_segments(art) if art.stage == "babble" else execute_segments(art, stride)
        plant_names.add(desc["plant"])
        robots[desc["plant"]] = desc
        segs += got
    if len(plant_names) != 1:
        raise ValueError(f"data of different plants: {', '.join(sorted(plant_names))}")
    plant = plant_names.pop()
    robot = robot_for(robots[plant])
    if residual:
        segs = [residual_segment(robot, s) for s in segs]
    sources = tuple(a.ref for a in arts)
    tr, te, laid, seg_id, offset = [], [], [], [], 0.0
    for i, s in enumerate(segs):
        h = split_count(len(s.t), holdout)
        cut = len(s.t) - h
        tr.append((s.X[:cut], s.Y[:cut], np.full(cut, sources.index(s.source))))
        if h:
            t = s.t[cut:] - s.t[cut]
            step = float(np.median(np.diff(s.t))) if len(s.t) > 1 else 0.0
            laid.append(offset + t)
            offset += float(t[-1]) + step
            te.append((s.X[cut:], s.Y[cut:]))
            seg_id.append(np.full(h, i))
    X = np.vstack([a for a, _, _ in tr])
    if len(X) == 0:
        raise ValueError("the data artifacts hold no finite points")
    d, n = X.shape[1], segs[0].Y.shape[1]
    return DataSet(plant=plant, joint_names=tuple(robot.joint_names), sources=sources, X=X, robot=robots[plant],
                   residual=residual, angle_inputs=angle_inputs(robot),
                   Y=np.vstack([b for _, b, _ in tr]), source=np.concatenate([c for _, _, c in tr]),
                   X_test=np.vstack([a for a, _ in te]) if te else np.zeros((0, d)),
                   Y_test=np.vstack([b for _, b in te]) if te else np.zeros((0, n)),
                   t_test=np.concatenate(laid) if laid else np.zeros(0),
                   seg_test=np.concatenate(seg_id) if seg_id else np.zeros(0, int))


# ----------------------------------------------------------------------------- fit
@dataclass
class FitResult:
    """The model and how it was made (``mode``: ``optimized``, ``incremental`` or ``refactorized``,
    the last = the prior's hyperparameters on a capped set, factorized anew)."""

    model: GPBase | AngleInputGP
    mode: str
    fit_time_s: float
    n_at_optimization: int  # training points (before the cap) at the last hyperparameter optimization
    since_optimization: int  # training points added since then (before this fit)
    warnings: list


def check_prior(prior: Artifact, data: DataSet, cfg: FitConfig) -> dict:
    """The prior's ``fit.json``, checked against this fit's data (same plant, holdout and stride;
    its data keys among this fit's)."""
    doc = prior.document(FIT_FILE)
    if doc["plant"] != data.plant:
        raise ValueError(f"prior {prior.ref} is a model of {doc['plant']}, the data are of {data.plant}")
    if not math.isclose(float(doc["holdout"]), cfg.holdout) or int(doc["stride"]) != cfg.stride:
        raise ValueError(f"prior {prior.ref} was fit with holdout {doc['holdout']} and stride {doc['stride']}: "
                         "use the same")
    if bool(doc.get("residual", False)) != cfg.residual:
        raise ValueError(f"prior {prior.ref} is {'a residual' if doc.get('residual') else 'a full'} model, this fit "
                         f"asks for {'--residual' if cfg.residual else '--no-residual'}: use the same")
    if doc.get("gp", "exact") != cfg.gp:
        raise ValueError(f"prior {prior.ref} is a {doc.get('gp', 'exact')} GP, this fit asks for --gp {cfg.gp}: "
                         "use the same")
    missing = [k for k in doc["data_keys"] if k not in data.sources]
    if missing:
        raise ValueError(f"--data lacks {missing[0]}, a data artifact of prior {prior.ref}: give all of them")
    return doc


def _inner(model) -> GPBase:
    """The GP over the features of an :class:`raico.plants.gp.AngleInputGP`, else the model itself."""
    return model.inner if isinstance(model, AngleInputGP) else model


def fit_model(cfg: FitConfig, data: DataSet, prior: Artifact | None) -> FitResult:
    """Optimize the hyperparameters or update the prior's GP (rule in the module docstring); a robot with
    continuous joints gets an :class:`raico.plants.gp.AngleInputGP` (the GP fit on ``angle_features``)."""
    wrap = np.array(data.angle_inputs, int)
    if len(wrap) == 0:
        return _fit_features(cfg, data.X, data, prior)
    res = _fit_features(cfg, angle_features(data.X, wrap), data, prior)
    res.model = AngleInputGP(_inner(res.model), wrap)
    return res


def _fit_features(cfg: FitConfig, X: np.ndarray, data: DataSet, prior: Artifact | None) -> FitResult:
    """:func:`fit_model` on the GP inputs ``X (N, d')`` (the data's, or their angle features)."""
    n_train = len(data.X)
    if prior is not None:
        doc = check_prior(prior, data, cfg)
        since = n_train - int(doc["n_train_at_optimization"])
        N = batch_size(cfg.schedule)
        if N is not None and since < N:
            t0 = time.perf_counter()
            model = _inner(GPModel.from_arrays(prior.arrays(MODEL_FILE)))
            new = ~np.isin(np.array(data.sources)[data.source], doc["data_keys"])
            model, mode = _add_points(model, X[new], data.Y[new], cfg.max_points)
            return FitResult(model, mode, time.perf_counter() - t0, int(doc["n_train_at_optimization"]),
                             since, [])
    else:
        since = n_train
    start = _inner(GPModel.from_arrays(prior.arrays(MODEL_FILE))) if prior is not None else None
    if start is not None and start.d != X.shape[1]:
        raise ValueError(f"prior {prior.ref} has {start.d} GP inputs, this fit {X.shape[1]}: use a prior of the same "
                         "inputs")
    t0 = time.perf_counter()
    if gp_kind(cfg, n_train) == "sparse":
        model, info = fit_sparse_gp(X, data.Y, inducing=cfg.inducing, restarts=cfg.restarts, seed=cfg.seed,
                                    max_points=cfg.max_points, start=start)
    else:
        model, info = fit_gp(X, data.Y, restarts=cfg.restarts, seed=cfg.seed, max_points=cfg.max_points,
                             start=start)
    return FitResult(model, "optimized", time.perf_counter() - t0, n_train, since, info["warnings"])


def gp_kind(cfg: FitConfig, n_train: int) -> str:
    """The GP a fit makes: ``cfg.gp``, or for ``auto`` the exact GP up to ``AUTO_EXACT_POINTS`` training points
    (after the ``max_points`` cap) and the sparse GP (``cfg.inducing`` points) above, said on stderr."""
    if cfg.gp != "auto":
        return cfg.gp
    n = min(n_train, cfg.max_points)
    if n <= AUTO_EXACT_POINTS:
        return "exact"
    import sys

    print(f"raico: note: fit: {n} training points are too many for the exact GP (more than {AUTO_EXACT_POINTS}): "
          f"the sparse GP with {min(cfg.inducing, n)} inducing points", file=sys.stderr, flush=True)
    return "sparse"


def _add_points(model: GPBase, X: np.ndarray, Y: np.ndarray, max_points: int) -> tuple[GPBase, str]:
    """``model`` plus ``X (n, d)``, ``Y (n, D)`` at fixed hyperparameters: the Cholesky factor
    extended, or, past ``max_points``, the capped union factorized anew (a sparse GP: always
    factorized anew, its inducing inputs selected again among all points, ``SparseGPModel.update``)."""
    if isinstance(model, SparseGPModel) and model.N + len(X) <= max_points:
        return model.update(X, Y), "refactorized"
    if model.N + len(X) <= max_points:
        return model.update(X, Y), "incremental"
    Xa, Ya = np.vstack([model.X, X]), np.vstack([model.Y, Y])
    kept = subsample_indices(Xa, max_points)
    return refit_fixed(model, Xa[kept], Ya[kept]), "refactorized"


def heldout_errors(model: GPBase | AngleInputGP, data: DataSet) -> tuple[np.ndarray, np.ndarray]:
    """Held-out RMSE ``(D,)`` (rad/s^2) and RMSE over the held-out targets' std ``(D,)``; NaN without held-out points."""
    if len(data.X_test) == 0:
        nan = np.full(model.D, np.nan)
        return nan, nan
    e = rmse(model, data.X_test, data.Y_test)
    return e, e / np.maximum(data.Y_test.std(axis=0), 1e-300)


def fit_document(cfg: FitConfig, data: DataSet, res: FitResult, prior: Artifact | None) -> dict:
    """``fit.json``: hyperparameters (standardized units) and log marginal likelihood per output,
    timing, how the model was made, point counts, data keys, held-out errors."""
    m, names = res.model, list(data.joint_names)
    err, nerr = heldout_errors(m, data)
    lml = m.log_marginal_likelihood()
    return {
        "plant": data.plant, "joint_names": names, "data_keys": list(data.sources),
        "prior": prior.ref if prior else None, "schedule": cfg.schedule, "holdout": cfg.holdout,
        "stride": cfg.stride, "gp": cfg.gp, "residual": cfg.residual,
        **{k: data.robot[k] for k in ("robot", "robot_true") if data.robot and k in data.robot},
        "n_inducing": inner.M if isinstance(inner := _inner(m), SparseGPModel) else None,
        "angle_inputs": [names[i] for i in data.angle_inputs],
        "mode": res.mode, "optimized": res.mode == "optimized", "fit_time_s": res.fit_time_s,
        "hyperparameters": {j: {"length_scales": m.ell[i].tolist(), "sf2": float(m.sf2[i]),
                                "sn2": float(m.sn2[i])} for i, j in enumerate(names)},
        "hyperparameter_units": "standardized inputs and outputs (raico.plants.gp)",
        "log_marginal_likelihood": {j: float(lml[i]) for i, j in enumerate(names)},
        "n_points": m.N, "n_train": len(data.X), "n_dropped": len(data.X) - m.N, "n_heldout": len(data.X_test),
        "n_train_at_optimization": res.n_at_optimization,
        "points_since_optimization": res.since_optimization, "max_points": cfg.max_points,
        "heldout_rmse": {j: float(err[i]) for i, j in enumerate(names)},
        "heldout_rmse_overall": float(np.sqrt(np.mean(err**2))),
        "heldout_nrmse": {j: float(nerr[i]) for i, j in enumerate(names)},
        "warnings": res.warnings,
    }


def fit_metrics(doc: dict) -> dict:
    """Headline metrics of a ``fit.json``."""
    keys = ("n_points", "n_train", "n_dropped", "n_heldout", "optimized", "mode", "fit_time_s",
            "points_since_optimization", "heldout_rmse", "heldout_rmse_overall")
    return {**{k: doc[k] for k in keys}, "lml": doc["log_marginal_likelihood"]}


def run(cfg: FitConfig, inputs: dict, progress: Progress | None = None) -> StageOutput:
    """The fit stage: ``model.npz``, ``heldout.npz`` and ``fit.json`` (module docstring)."""
    arts = tuple(inputs.get("data", ()))
    if len({a.ref for a in arts}) != len(arts):
        raise ValueError("data: the same artifact given twice")
    data = load_data(arts, cfg.holdout, cfg.stride, cfg.residual)
    if cfg.holdout > 0 and len(data.X_test) == 0:
        raise ValueError(f"holdout {cfg.holdout} leaves no held-out point (round(holdout x samples) is 0 in every "
                         "segment): give a larger --holdout, or --holdout 0 for none")
    res = fit_model(cfg, data, inputs.get("prior"))
    doc = fit_document(cfg, data, res, inputs.get("prior"))
    heldout = {"X": data.X_test, "Y": data.Y_test, "time": data.t_test, "segment": data.seg_test}
    arrays = res.model.to_arrays()
    if cfg.residual:
        from raico.plants.learned import RESIDUAL_KEY

        arrays[RESIDUAL_KEY] = np.array(1.0)
    return StageOutput(status="ok", metrics=fit_metrics(doc), arrays={MODEL_FILE: arrays,
                                                                     HELDOUT_FILE: heldout},
                       documents={FIT_FILE: doc}, payload=res)


STAGE = Stage(name="fit", config_cls=FitConfig, run=run,
              sources=("raico.plants", "raico.stages.fit", "raico.stages.base", "raico.stages.babble", "raico.planning.problem_file",
                       "raico.planning.problem_terms", "raico.planning.term_kinds"),
              data_files=(MODEL_FILE, HELDOUT_FILE, FIT_FILE),
              description=DESCRIPTIONS["fit"])
