"""A learner that is not raico: PETS-style model-based RL (Chua et al., NeurIPS 2018) on scikit-learn.

The dynamics model is a bootstrap ensemble of scikit-learn ``MLPRegressor`` networks (:class:`Ensemble`: each
member fit on its own resample of the transitions, inputs and outputs standardized), predicting the change of
the state over one control step; the controller is model-predictive control by the cross-entropy method over
the ensemble (:func:`cem`): candidate action sequences are rolled out through every member (trajectory sampling
with one particle per member, each particle keeping its member, PETS's TS-inf), scored by the mean cost over the
particles, the sampling distribution refit to the elites. The members predict a mean only (a deterministic
ensemble, PETS's "DE"; scikit-learn has no network with a variance head): the ensemble's spread is the model's
uncertainty. The rollout of a candidate is a numpy forward pass through the members' fitted weights
(:meth:`Ensemble.predict_all`, equal to ``MLPRegressor.predict``).

Why not torch (mbrl-lib's PETS, stable-baselines3's SAC): on this project's package index ``pip install torch``
resolves to the CUDA build (nvidia-* wheels, about 3 GB); the 190 MB CPU wheel needs PyTorch's own index,
which a pyproject extra cannot name. scikit-learn is already a dependency (raico's GP fit uses its kernels).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


class Ensemble:
    """``members`` scikit-learn MLPs, each fit on a bootstrap resample of ``(Z, Y)`` (standardized)."""

    def __init__(self, members: int = 5, hidden: tuple[int, ...] = (64, 64), seed: int = 0, max_iter: int = 400,
                 l2: float = 1e-4):
        self.members, self.hidden, self.seed, self.max_iter, self.l2 = members, hidden, seed, max_iter, l2
        self.nets: list = []
        self.n_points = 0

    def fit(self, Z: np.ndarray, Y: np.ndarray) -> Ensemble:
        """Fit every member on its own resample (with replacement, ``len(Z)`` rows) of all the data."""
        from sklearn.neural_network import MLPRegressor

        Z, Y = np.asarray(Z, float), np.asarray(Y, float)
        self.z_mu, self.z_sd = Z.mean(0), Z.std(0) + 1e-8
        self.y_mu, self.y_sd = Y.mean(0), Y.std(0) + 1e-8
        Zs, Ys = (Z - self.z_mu) / self.z_sd, (Y - self.y_mu) / self.y_sd
        rng = np.random.default_rng(self.seed)
        self.nets = []
        for b in range(self.members):
            idx = rng.integers(0, len(Z), len(Z))
            net = MLPRegressor(hidden_layer_sizes=self.hidden, activation="tanh", solver="lbfgs", alpha=self.l2, max_iter=self.max_iter,
                               random_state=self.seed * 100 + b)
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")   # lbfgs's iteration cap: the cap is the setting
                net.fit(Zs[idx], Ys[idx])
            self.nets.append(net)
        self.n_points = len(Z)
        self.W = [np.stack([n.coefs_[i] for n in self.nets]) for i in range(len(self.hidden) + 1)]
        self.c = [np.stack([n.intercepts_[i] for n in self.nets])[:, None, :] for i in range(len(self.hidden) + 1)]
        return self

    def predict_all(self, Z: np.ndarray) -> np.ndarray:
        """Every member's prediction ``(members, N, dy)`` at inputs ``Z (N, dz)`` or per member ``(members, N, dz)``."""
        H = (np.asarray(Z, float) - self.z_mu) / self.z_sd
        H = np.broadcast_to(H, (self.members, *H.shape[-2:])) if H.ndim == 2 else H
        for i, (W, c) in enumerate(zip(self.W, self.c)):
            H = H @ W + c
            if i < len(self.hidden):
                H = np.tanh(H)
        return H * self.y_sd + self.y_mu


def cem(cost: Callable[[np.ndarray], np.ndarray], mean: np.ndarray, std: np.ndarray, lower: np.ndarray,
        upper: np.ndarray, rng: np.random.Generator, population: int = 400, elites: int = 40, iterations: int = 5,
        smoothing: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """The cross-entropy method: ``iterations`` rounds of ``population`` samples of ``N(mean, std^2)`` clipped to
    ``[lower, upper]``, scored by ``cost (population, *shape) -> (population,)``, the mean and std refit to the
    ``elites`` best (``smoothing``: the weight kept of the previous ones). Returns the final ``(mean, std)``."""
    mean, std = np.array(mean, float), np.array(std, float)
    for _ in range(iterations):
        S = np.clip(mean + std * rng.standard_normal((population, *mean.shape)), lower, upper)
        best = S[np.argsort(cost(S))[:elites]]
        mean = smoothing * mean + (1 - smoothing) * best.mean(0)
        std = smoothing * std + (1 - smoothing) * best.std(0)
    return mean, std


@dataclass
class Task:
    """What the learner is given of a task: the state's model ``features(X)``, the cost of states and actions per
    step ``cost(X (..., nx), U (..., nu)) -> (...)``, the action box, the control step and the episode's steps."""

    features: Callable[[np.ndarray], np.ndarray]
    cost: Callable[[np.ndarray, np.ndarray], np.ndarray]
    lower: np.ndarray
    upper: np.ndarray
    dt: float
    steps: int


@dataclass
class Controller:
    """PETS's MPC: CEM over ``horizon`` actions through the ensemble, the first action applied, the rest shifted."""

    task: Task
    model: Ensemble
    horizon: int = 20
    population: int = 400
    elites: int = 40
    iterations: int = 5
    seed: int = 0

    def __post_init__(self):
        self.rng = np.random.default_rng(self.seed)
        nu = len(self.task.lower)
        self.mean = np.tile((self.task.lower + self.task.upper) / 2, (self.horizon, 1)).reshape(self.horizon, nu)

    def rollout_cost(self, x: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Mean over the particles (one per member) of the summed cost of action sequences ``U (N, H, nu)``."""
        B, N = self.model.members, len(U)
        X = np.broadcast_to(x, (B, N, len(x))).copy()
        total = np.zeros((B, N))
        for h in range(U.shape[1]):
            u = np.broadcast_to(U[:, h], (B, N, U.shape[2]))
            Z = np.concatenate([self.task.features(X), u], axis=-1)
            X = X + self.model.predict_all(Z)
            total += self.task.cost(X, u)
        total = np.where(np.isfinite(total), total, np.inf)
        return total.mean(0)

    def act(self, x: np.ndarray) -> np.ndarray:
        """The first action of the CEM's plan from state ``x``; the plan shifted by one step for the next call."""
        lo, hi = self.task.lower, self.task.upper
        std = np.tile((hi - lo) / 4, (self.horizon, 1))
        self.mean, _ = cem(lambda S: self.rollout_cost(x, S), self.mean, std, lo, hi, self.rng, self.population,
                           self.elites, self.iterations)
        u = self.mean[0].copy()
        self.mean = np.concatenate([self.mean[1:], self.mean[-1:]])
        return u


def transitions(X: np.ndarray, U: np.ndarray, features) -> tuple[np.ndarray, np.ndarray]:
    """Model data of one episode: inputs ``[features(x_k), u_k]`` and targets ``x_{k+1} - x_k``, the rows with a
    finite next state (``len(U)`` rows at most: an episode of K actions gives K transitions)."""
    Z = np.concatenate([features(X[:-1]), U], axis=1)
    Y = X[1:] - X[:-1]
    ok = np.all(np.isfinite(Z), 1) & np.all(np.isfinite(Y), 1)
    return Z[ok], Y[ok]
