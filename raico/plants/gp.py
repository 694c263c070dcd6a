"""Multi-output Gaussian-process posterior for learned dynamics (thesis §4.2-4.3).

One independent GP per output dimension of ``qddot = f(q, qdot, u)``: inputs ``x = (q, qdot, u)``
of size ``d = 2 D + F``, outputs ``D``. Zero prior mean (in scaled units, see below),
squared-exponential ARD kernel ``k(x, x') = sf2 exp(-1/2 (x - x')^T Lambda^-1 (x - x'))`` with
``Lambda = diag(ell^2)``, plus noise ``sn2`` on the diagonal of the training kernel matrix.
Pure numpy/scipy; hyperparameter fitting lives in ``raico.stages.fit.gp_fit``.

Scaling. Inputs are standardized per dimension, ``z = (x - x_mean) / x_std``; outputs per output,
``y = (Y - y_mean) / y_std`` (a constant dimension gets std 1). All hyperparameters (``ell``,
``sf2``, ``sn2``), the training arrays ``Z``, ``y``, the Cholesky factor ``L``, the weights
``weights`` (stored as ``alpha``) and the log marginal likelihood are in these scaled units; the
zero prior mean in scaled units is the training mean ``y_mean`` in physical units. Every prediction is returned in physical units
(``qddot`` in rad/s^2, variances in (rad/s^2)^2), gradients with respect to the physical input
``x`` by the chain rule: ``dm/dx = y_std * dm_s/dz / x_std``, ``dvar/dx = y_std^2 * dvar_s/dz / x_std``.
The scaling is fixed when the model is built; ``update`` keeps it.

Noise floor. Simulated data are nearly noise-free and ``K`` gets ill-conditioned; the noise level
is bounded from below, ``sn2 >= noise_floor`` (default ``1e-6`` in standardized output units), the
same bound the fit keeps, and no other jitter is added anywhere: the posterior is exactly the one
whose likelihood the fit maximized (docs/learning.md, "The GP's noise floor").

Variances. ``var`` is the latent function's variance (without the noise), clipped at 0;
``predict(..., noisy=True)`` adds the noise ``sn2`` (what sklearn's ``return_std`` reports when
the kernel contains a ``WhiteKernel``).

Non-finite query rows give NaN outputs (and NaN gradients), never an exception.
"""

from __future__ import annotations

import ctypes
from collections.abc import Mapping
from typing import cast

import numpy as np

from raico.plants.codegen import c_backend
from raico.plants.lazy import LazyModule

# scipy, imported at first use (see raico.plants.lazy)
_linalg, _blas, _distance = (LazyModule("scipy.linalg"), LazyModule("scipy.linalg.blas"),
                             LazyModule("scipy.spatial.distance"))

NOISE_FLOOR = 1e-6  # lower bound of sn2 in standardized output units (see the module docstring)

# One query point, every output: the GP mean and its input gradient in C (no per-output numpy
# calls: a planner's relinearization inside the sweeps asks for one point at a time). The same
# formulas as ``mean_with_gradients``; the distance is summed directly (no expansion), so the two
# agree to rounding (tests/plants/test_gp.py). The source: gp_point.c beside this module.
# The point kernels' stack buffers (gp_point.c): at most this many inputs, and for the compiled
# relinearization this many outputs; larger models run the numpy code.
POINT_MAX_INPUTS = 256
POINT_MAX_OUTPUTS = 128


#: The compiled ``gp_point`` (``None`` without a C compiler or with ``RAICO_NO_C``).
_point_lib = c_backend.CompiledLibrary("gp_point", lambda: c_backend.c_source(__file__, "gp_point.c"), {
    "gp_point": ([ctypes.c_long] * 3 + [ctypes.c_void_p] * 7, None),
    "gp_point_var": ([ctypes.c_long] * 3 + [ctypes.c_void_p] * 11, None),
    "gp_rollout": ([ctypes.c_long] * 4 + [ctypes.c_void_p] * 8 + [ctypes.c_double] + [ctypes.c_void_p] * 4, None),
    "gp_linearize_address": (None, ctypes.c_void_p)}, flags=(*c_backend.CFLAGS, "-O3"))

_GP_DYN = None


def _gp_dyn_struct():
    """``gp_dyn_t`` of gp_point.c as a ``ctypes.Structure`` (made once)."""
    global _GP_DYN
    if _GP_DYN is None:
        import ctypes

        class GPDyn(ctypes.Structure):
            _fields_ = [("N", ctypes.c_long), ("d", ctypes.c_long), ("D", ctypes.c_long),
                        *((k, ctypes.c_void_p) for k in ("Zs", "weights", "sf2", "inv_ell", "x_mean", "x_std",
                                                         "y_mean", "y_std")), ("dt", ctypes.c_double)]
        _GP_DYN = GPDyn
    return _GP_DYN


_LOG_2PI = float(np.log(2.0 * np.pi))


def column_std(A: np.ndarray) -> np.ndarray:
    """Column standard deviations, 1 where a column is (numerically) constant."""
    s = A.std(axis=0)
    return np.where(s > 1e-12 * np.maximum(1.0, np.abs(A).max(axis=0, initial=0.0)), s, 1.0)


def se_kernel(A: np.ndarray, B: np.ndarray, ell: np.ndarray, sf2: float) -> np.ndarray:
    """Exact SE-ARD kernel matrix ``(n_A, n_B)`` (pairwise differences, as sklearn's ``RBF``)."""
    return sf2 * np.exp(-0.5 * _distance.cdist(A / ell, B / ell, "sqeuclidean"))


def _se_kernel_fast(P: np.ndarray, Q: np.ndarray, qq: np.ndarray, sf2: float) -> np.ndarray:
    """SE kernel ``(M, N)`` (C order) of pre-divided inputs ``P = Zq/ell``, ``Q = Z/ell`` (``qq = |Q|^2``).

    The exponent ``-|p - q|^2 / 2 = p.q - |p|^2/2 - |q|^2/2`` comes out of one matmul of the
    augmented ``[P, -|p|^2/2, 1]`` and ``[Q, 1, -|q|^2/2]``, then a clamp at 0, an in-place ``exp``
    and the factor ``sf2``: four passes over the ``(M, N)`` array. (Folding ``log sf2`` into the
    exponent would save one pass but costs ~10 ulp of kernel accuracy at ``sf2 = 1e3``, which the
    ill-conditioned ``K`` of fitted models amplifies.)"""
    M, d = P.shape
    Pa = np.empty((M, d + 2))
    Pa[:, :d] = P
    Pa[:, d] = -0.5 * (P * P).sum(1)
    Pa[:, d + 1] = 1.0
    Qa = np.empty((d + 2, Q.shape[0]))
    Qa[:d] = Q.T
    Qa[d] = 1.0
    Qa[d + 1] = -0.5 * qq
    S = Pa @ Qa
    np.minimum(S, 0.0, out=S)
    np.exp(S, out=S)
    S *= sf2
    return S


class GPBase:
    """What the exact GP (:class:`GPModel`) and the sparse one (:class:`SparseGPModel`) do the same way:
    independent SE-ARD GPs, one per output, whose mean is ``m(z) = k(z, Z)^T w`` over a set of
    inputs ``Z`` (the training inputs of the exact GP, the inducing inputs of the sparse one).

    Held here: the scaling (``x_mean, x_std (d,)``, ``y_mean, y_std (D,)``, physical units), the
    hyperparameters (scaled units: ``ell (D, d)``, ``sf2 (D,)``, ``sn2 (D,)``, clipped at
    ``noise_floor``), the scaled targets ``y (N, D)``, the mean and its gradient (batch and one point,
    compiled where a C compiler is available), the compiled linearization and rollout, and the loop of
    the batch predictions. A subclass holds ``Z`` and ``weights (D, len(Z))`` and gives the latent
    variance (``_latent_variance``) and the weights of its gradient (``_variance_weights``), its
    factorization, update, likelihood and stored arrays.
    """

    Z: np.ndarray        # (M, d) scaled inputs of the mean (set by the subclass)
    weights: np.ndarray  # (D, M) the mean's weights over Z (set by the subclass)

    # -- what each subclass gives --------------------------------------------------------
    @property
    def N(self) -> int:
        """Number of training points."""
        raise NotImplementedError

    @property
    def X(self) -> np.ndarray:
        """Training inputs ``(N, d)`` in physical units."""
        raise NotImplementedError

    def update(self, X_new: np.ndarray, Y_new: np.ndarray) -> GPBase:
        """Add data at fixed hyperparameters and scaling, in place."""
        raise NotImplementedError

    def log_marginal_likelihood(self) -> np.ndarray:
        """``log p(y | theta)`` per output ``(D,)``."""
        raise NotImplementedError

    def to_arrays(self, *, include_factor: bool = True) -> dict[str, np.ndarray]:
        """Plain arrays for ``np.savez``."""
        raise NotImplementedError

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> GPBase:
        """Inverse of ``to_arrays``."""
        raise NotImplementedError

    def _set_data(self, X: np.ndarray, Y: np.ndarray, ell: np.ndarray, sf2: np.ndarray, sn2: np.ndarray,
                  x_mean: np.ndarray | None, x_std: np.ndarray | None, y_mean: np.ndarray | None,
                  y_std: np.ndarray | None, noise_floor: float) -> np.ndarray:
        """Check physical data ``X (N, d)``, ``Y (N, D)``; set the scaling (default: the standardization
        of ``X`` and ``Y``), the hyperparameters (``ell`` ``(D, d)`` or ``(d,)`` shared, ``sf2`` and
        ``sn2`` ``(D,)`` or scalars) and the scaled targets ``y``. Returns the scaled inputs ``(N, d)``."""
        X, Y = _as_2d(X, "X"), _as_2d(Y, "Y")
        if X.shape[0] != Y.shape[0]:
            raise ValueError(f"X has {X.shape[0]} rows but Y has {Y.shape[0]}")
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
            raise ValueError("training data must be finite")
        self.x_mean = X.mean(0) if x_mean is None else np.asarray(x_mean, float).copy()
        self.x_std = column_std(X) if x_std is None else np.asarray(x_std, float).copy()
        self.y_mean = Y.mean(0) if y_mean is None else np.asarray(y_mean, float).copy()
        self.y_std = column_std(Y) if y_std is None else np.asarray(y_std, float).copy()
        D, d = Y.shape[1], X.shape[1]
        self.noise_floor = float(noise_floor)
        self.ell = np.broadcast_to(np.asarray(ell, float), (D, d)).copy()
        self.sf2 = np.broadcast_to(np.asarray(sf2, float), (D,)).copy()
        self.sn2 = np.maximum(np.broadcast_to(np.asarray(sn2, float), (D,)), self.noise_floor)
        Z = self.scale_x(X)
        self.y = (Y - self.y_mean) / self.y_std
        return Z

    def _new_data(self, X_new: np.ndarray, Y_new: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``update``'s data checked: ``X_new (n, d)``, ``Y_new (n, D)`` (physical), finite."""
        Xn, Yn = _as_2d(X_new, "X_new"), _as_2d(Y_new, "Y_new")
        if Xn.shape[0] != Yn.shape[0] or Xn.shape[1] != self.d or Yn.shape[1] != self.D:
            raise ValueError(f"update expects X_new (n, {self.d}) and Y_new (n, {self.D}), got {Xn.shape}, {Yn.shape}")
        if not (np.all(np.isfinite(Xn)) and np.all(np.isfinite(Yn))):
            raise ValueError("training data must be finite")
        return Xn, Yn

    # -- shapes and scaling ------------------------------------------------------------
    @property
    def d(self) -> int:
        """Input dimension ``2 D + F``."""
        return self.Z.shape[1]

    @property
    def D(self) -> int:
        """Number of outputs."""
        return self.y.shape[1]

    @property
    def Y(self) -> np.ndarray:
        """Training targets ``(N, D)`` in physical units."""
        return self.y * self.y_std + self.y_mean

    def scale_x(self, X: np.ndarray) -> np.ndarray:
        """Physical inputs ``(M, d)`` -> standardized ``(M, d)``."""
        return (X - self.x_mean) / self.x_std

    def unscale_x(self, Z: np.ndarray) -> np.ndarray:
        """Standardized inputs ``(M, d)`` -> physical ``(M, d)``."""
        return Z * self.x_std + self.x_mean

    # -- what a subclass gives -----------------------------------------------------------
    def _latent_variance(self, j: int, Ks: np.ndarray) -> np.ndarray:
        """Scaled latent variance ``(M,)`` of output ``j`` (not clipped) at the queries whose cross-kernel
        with ``Z`` is ``Ks (M, len(Z))``; ``Ks`` may be overwritten."""
        raise NotImplementedError

    def _variance_weights(self, j: int, Ks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scaled latent variance ``(M,)`` (not clipped) and ``W (M, len(Z))``, the weights of the variance
        gradient ``dvar/dz = -2 sum_i W_i k_i Lambda^-1 (z_i - z)`` (``Ks`` is left as it is)."""
        raise NotImplementedError

    # -- prediction ----------------------------------------------------------------------
    def _query(self, Xq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scaled finite query rows and the mask of finite rows."""
        Xq = _as_2d(Xq, "Xq")
        if Xq.shape[1] != self.d:
            raise ValueError(f"queries must have {self.d} columns, got {Xq.shape[1]}")
        ok = np.all(np.isfinite(Xq), axis=1)
        return self.scale_x(Xq[ok]), ok

    def _kstar(self, j: int, Zq: np.ndarray) -> np.ndarray:
        """Cross-kernel ``(M, len(Z))`` between scaled queries and ``Z`` of output ``j``."""
        ell = self.ell[j]
        Q = self.Z / ell
        return _se_kernel_fast(Zq / ell, Q, (Q * Q).sum(1), self.sf2[j])

    def _mean_grad(self, j: int, Ks: np.ndarray, Zq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scaled mean ``(M,)`` and its gradient ``(M, d)``: ``sum_i w_i k_i Lambda^-1 (z_i - z*)``
        as ``(Ks (w Z) - z* (Ks w)) / ell^2`` (one ``(M, N) x (N, d)`` matmul, no ``(M, N)`` temporary)."""
        a = self.weights[j]
        m = Ks @ a
        return m, (Ks @ (a[:, None] * self.Z) - Zq * m[:, None]) / self.ell[j] ** 2

    def predict(self, Xq: np.ndarray, *, noisy: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(M, D)`` and latent variance ``(M, D)`` at physical inputs ``Xq (M, d)``, physical units.

        ``noisy=True`` adds the noise variance ``sn2 y_std^2`` (the variance of a new observation)."""
        Zq, ok = self._query(Xq)
        mean, var = _nan((len(ok), self.D)), _nan((len(ok), self.D))
        for j in range(self.D if len(Zq) else 0):
            Ks = self._kstar(j, Zq)
            mean[ok, j] = Ks @ self.weights[j]
            v = np.maximum(self._latent_variance(j, Ks), 0.0)  # Ks is not needed after this
            var[ok, j] = v + self.sn2[j] if noisy else v
        return mean * self.y_std + self.y_mean, var * self.y_std**2

    def predict_mean(self, Xq: np.ndarray) -> np.ndarray:
        """Mean ``(M, D)`` at physical inputs ``Xq (M, d)`` (physical units), ``O(D M N d)``."""
        Zq, ok = self._query(Xq)
        mean = _nan((len(ok), self.D))
        for j in range(self.D if len(Zq) else 0):
            mean[ok, j] = self._kstar(j, Zq) @ self.weights[j]
        return mean * self.y_std + self.y_mean

    def mean_with_gradients(self, Xq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(M, D)`` and its input gradient ``(M, D, d)`` (physical units), ``O(D M N d)``.

        ``dm/dx* = sum_i w_i k(x_i, x*) Lambda^-1 (x_i - x*)`` (thesis eq. 4.1 without its factor -2)."""
        Zq, ok = self._query(Xq)
        mean, dmean = _nan((len(ok), self.D)), _nan((len(ok), self.D, self.d))
        for j in range(self.D if len(Zq) else 0):
            mean[ok, j], dmean[ok, j] = self._mean_grad(j, self._kstar(j, Zq), Zq)
        scale = self.y_std[:, None] / self.x_std[None, :]
        return mean * self.y_std + self.y_mean, dmean * scale

    def predict_with_gradients(self, Xq: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Mean ``(M, D)``, latent variance ``(M, D)``, ``dmean (M, D, d)``, ``dvar (M, D, d)`` (physical
        units). ``dvar/dx* = -2 (dk*/dx*)^T W`` (thesis eq. 4.2) with the subclass's weights
        ``W`` (``_variance_weights``); one ``exp`` of the ``(M, N)`` cross-kernel and matmuls
        ``(M, N) x (N, <= d + 1)`` for the mean, its gradient and the variance gradient."""
        Zq, ok = self._query(Xq)
        M, D, d = len(ok), self.D, self.d
        mean, var = _nan((M, D)), _nan((M, D))
        dmean, dvar = _nan((M, D, d)), _nan((M, D, d))
        Z1 = np.hstack([self.Z, np.ones((self.Z.shape[0], 1))])
        for j in range(D if len(Zq) else 0):
            Ks = self._kstar(j, Zq)
            mean[ok, j], dmean[ok, j] = self._mean_grad(j, Ks, Zq)
            v, W = self._variance_weights(j, Ks)
            var[ok, j] = np.maximum(v, 0.0)
            W *= Ks  # W[m, i] = k*_i(x_m) W_i(x_m)
            G = W @ Z1  # (M, d + 1): sum_i W z_i and sum_i W
            dvar[ok, j] = -2.0 * (G[:, :d] - Zq * G[:, d:]) / self.ell[j] ** 2
        scale = self.y_std[:, None] / self.x_std[None, :]
        return (mean * self.y_std + self.y_mean, var * self.y_std**2,
                dmean * scale, dvar * (scale * self.y_std[:, None]))

    # -- one point, compiled ---------------------------------------------------------------
    def point_mean_with_gradients(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(D,)`` and its input gradient ``(D, d)`` at one physical input ``x (d,)`` (physical
        units): ``mean_with_gradients`` for one point, every output in one compiled call (numpy
        where no C compiler is available). NaN where ``x`` is not finite."""
        x = self._point_query(x)
        if not np.all(np.isfinite(x)):
            return np.full(self.D, np.nan), np.full((self.D, self.d), np.nan)
        lib = _point_lib() if self.d <= POINT_MAX_INPUTS else None
        if lib is None:
            m, g = self.mean_with_gradients(x[None, :])
            return m[0], g[0]
        pc = self._point_arrays(x)
        m, g = pc["m"], pc["g"]
        lib.gp_point(self.Z.shape[0], self.d, self.D, *pc["ptrs"])
        return m * self.y_std + self.y_mean, g * pc["gscale"]

    def _point_query(self, x: np.ndarray) -> np.ndarray:
        """One physical query ``x (d,)`` as floats (a wrong length raises ``ValueError``)."""
        x = np.asarray(x, dtype=float).reshape(-1)
        if x.shape != (self.d,):
            raise ValueError(f"a query has {self.d} entries, got {x.shape}")
        return x

    def _point_arrays(self, x: np.ndarray | None = None) -> dict:
        """The compiled point calls' contiguous inputs and output buffers, made once per model state
        (rebuilt when ``update`` or a refit replaced an array): ``Zs (D, N, d)`` (inputs over each
        output's length-scales), weights, ``sf2``, ``1 / ell`` (``ptrs``, with the query ``z (d,)`` and
        the outputs), the scaling ``x_mean, x_std, y_mean, y_std`` (``stat_ptrs``); with ``x`` (physical)
        the query ``z`` set to its scaled value."""
        key = (self.Z, self.weights, self.ell, self.sf2, self.x_mean, self.x_std, self.y_mean, self.y_std,
               getattr(self, "L", None))
        pc = getattr(self, "_point_cache", None)
        if pc is None or not all(a is b for a, b in zip(pc["key"], key)):
            Zs = np.ascontiguousarray(self.Z[None, :, :] / self.ell[:, None, :])
            keep = (Zs, np.ascontiguousarray(self.weights), np.ascontiguousarray(self.sf2),
                    np.ascontiguousarray(1.0 / self.ell))
            stats = tuple(np.ascontiguousarray(a, dtype=float) for a in (self.x_mean, self.x_std, self.y_mean,
                                                                          self.y_std))
            z, m, g = np.empty(self.d), np.empty(self.D), np.empty((self.D, self.d))
            pc = self._point_cache = {
                "key": key, "keep": keep, "stats": stats, "z": z, "m": m, "g": g,
                "ptrs": [a.ctypes.data for a in (*keep, z, m, g)],
                "stat_ptrs": [a.ctypes.data for a in stats],
                "gscale": self.y_std[:, None] / self.x_std[None, :]}
        if x is not None:
            np.subtract(x, self.x_mean, out=pc["z"])
            pc["z"] /= self.x_std
        return pc

    def _compiled_point_predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """``point_predict_with_gradients`` at a finite ``x (d,)`` by the compiled kernel, or ``None``
        where there is none for this model (the batch call on one row then)."""
        return None

    def point_predict_with_gradients(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``predict_with_gradients`` at one physical input ``x (d,)``: mean ``(D,)``, latent variance
        ``(D,)``, ``dmean (D, d)``, ``dvar (D, d)`` (physical units); compiled where the model has a
        compiled variance (``_compiled_point_predict``), else the batch call on one row. NaN where
        ``x`` is not finite."""
        x = self._point_query(x)
        out = self._compiled_point_predict(x) if np.all(np.isfinite(x)) else None
        if out is None:
            m, v, dm, dv = self.predict_with_gradients(x[None, :])
            return m[0], v[0], dm[0], dv[0]
        return out

    def point_linearizer(self, dt: float) -> tuple[int, int, object] | None:
        """``(address of gp_linearize, address of its context, keep-alive)``: the compiled linearization of
        the dynamics ``qddot = mean(q, qdot, u)`` with semi-implicit Euler of step ``dt`` s at one state
        (``raico.plants.learned.LearnedDynamics.linearize``'s formulas; the AICO sweep kernel calls it), or
        ``None`` without a C compiler."""
        lib = (_point_lib() if self.d <= POINT_MAX_INPUTS and self.D <= POINT_MAX_OUTPUTS and self.d >= 2 * self.D
               else None)
        if lib is None:
            return None
        import ctypes

        pc = self._point_arrays()
        ctx = _gp_dyn_struct()(self.Z.shape[0], self.d, self.D, *pc["ptrs"][:4], *pc["stat_ptrs"], float(dt))
        return lib.gp_linearize_address(), ctypes.addressof(ctx), (ctx, pc, lib)

    def controller_rollout(self, x0: np.ndarray, o: np.ndarray, O: np.ndarray, dt: float
                           ) -> tuple[np.ndarray, np.ndarray] | None:
        """Compiled rollout of ``u_t = o_t + O_t x_t`` on ``qddot = mean(q, qdot, u)`` (the outputs
        are ``n_q`` accelerations, the inputs ``(q, qdot, u)``) with semi-implicit Euler of step
        ``dt`` s from ``x0``: ``X (T+1, 2 D)``, ``U (T, d - 2 D)``; the point mean's formulas, so
        the same numbers as stepping ``point_mean_with_gradients`` up to the rounding of ``O_t x_t``.
        ``None`` without a C compiler (the caller steps in Python)."""
        lib = _point_lib() if self.d <= POINT_MAX_INPUTS else None
        if lib is None:
            return None
        T, nx = o.shape[0], 2 * self.D
        pc = self._point_arrays()
        o, O = np.ascontiguousarray(o, dtype=float), np.ascontiguousarray(O, dtype=float)
        if o.shape != (T, self.d - nx) or O.shape != (T, self.d - nx, nx) or np.shape(x0) != (nx,):
            raise ValueError(f"rollout expects x0 ({nx},), o (T, {self.d - nx}), O (T, {self.d - nx}, {nx})")
        X, U = np.empty((T + 1, nx)), np.empty((T, self.d - nx))
        X[0] = x0
        lib.gp_rollout(T, self.Z.shape[0], self.d, self.D, *pc["ptrs"][:4], *pc["stat_ptrs"],
                       float(dt), o.ctypes.data, O.ctypes.data, X.ctypes.data, U.ctypes.data)
        return X, U

    # -- storage -------------------------------------------------------------------------
    def _hyper_arrays(self) -> dict[str, np.ndarray]:
        """The hyperparameters, the scaling and the noise floor as stored arrays."""
        return {"ell": self.ell, "sf2": self.sf2, "sn2": self.sn2, "x_mean": self.x_mean, "x_std": self.x_std,
                "y_mean": self.y_mean, "y_std": self.y_std, "noise_floor": np.array(self.noise_floor)}

    @staticmethod
    def _stored(arrays: Mapping[str, np.ndarray], required: set[str], what: str) -> dict[str, np.ndarray]:
        """``arrays`` as floats, checked to hold every ``required`` name (``what`` names the model)."""
        missing = required - set(arrays)
        if missing:
            raise ValueError(f"{what} arrays lack {sorted(missing)}")
        return {k: np.asarray(arrays[k], float) for k in arrays}

    def _restore_hypers(self, g: Mapping[str, np.ndarray]) -> None:
        """The hyperparameters, scaling, noise floor and scaled targets ``y`` from stored arrays ``g``."""
        self.y = g["y"].copy()
        self.ell, self.sf2, self.sn2 = g["ell"].copy(), g["sf2"].copy(), g["sn2"].copy()
        self.x_mean, self.x_std = g["x_mean"].copy(), g["x_std"].copy()
        self.y_mean, self.y_std = g["y_mean"].copy(), g["y_std"].copy()
        self.noise_floor = float(g.get("noise_floor", NOISE_FLOOR))

    def _hypers_consistent(self) -> bool:
        """Whether ``ell (D, d)``, ``sf2 (D,)``, ``sn2 (D,)`` match ``Z`` and ``y``."""
        D, d = self.y.shape[1], self.Z.shape[1]
        return self.ell.shape == (D, d) and self.sf2.shape == (D,) and self.sn2.shape == (D,)

    def copy(self) -> GPBase:
        """Deep copy."""
        return type(self).from_arrays(self.to_arrays())


class GPModel(GPBase):
    """The exact GP: independent SE-ARD GPs, one per output, sharing the training inputs (scaled units inside).

    Attributes (scaled units): ``Z (N, d)`` training inputs, ``y (N, D)`` targets,
    ``ell (D, d)`` length-scales, ``sf2 (D,)``, ``sn2 (D,)``, ``L (D, N, N)`` lower Cholesky
    factors of ``K + sn2 I``, ``weights (D, N) = (K + sn2 I)^-1 y`` (``alpha`` in the stored arrays);
    scaling ``x_mean, x_std (d,)``, ``y_mean, y_std (D,)`` (physical units).
    """

    def __init__(self, X: np.ndarray, Y: np.ndarray, ell: np.ndarray, sf2: np.ndarray, sn2: np.ndarray,
                 *, x_mean: np.ndarray | None = None, x_std: np.ndarray | None = None,
                 y_mean: np.ndarray | None = None, y_std: np.ndarray | None = None,
                 noise_floor: float = NOISE_FLOOR):
        """Build and factorize from physical data ``X (N, d)``, ``Y (N, D)`` and scaled hyperparameters.

        The scaling defaults to the standardization of ``X`` and ``Y``; ``ell`` is ``(D, d)``
        (or ``(d,)`` shared), ``sf2`` and ``sn2`` are ``(D,)`` or scalars."""
        self.Z = self._set_data(X, Y, ell, sf2, sn2, x_mean, x_std, y_mean, y_std, noise_floor)
        self._factorize()

    @property
    def N(self) -> int:
        """Number of training points."""
        return self.Z.shape[0]

    @property
    def X(self) -> np.ndarray:
        """Training inputs ``(N, d)`` in physical units."""
        return self.unscale_x(self.Z)

    # -- factorization -----------------------------------------------------------------
    def kernel_matrix(self, j: int) -> np.ndarray:
        """``K + sn2 I`` ``(N, N)`` of output ``j`` (scaled units)."""
        K = se_kernel(self.Z, self.Z, self.ell[j], self.sf2[j])
        K[np.diag_indices_from(K)] += self.sn2[j]
        return K

    def _factorize(self) -> None:
        """Cholesky factors and ``weights`` of every output from scratch (``O(D N^3)``)."""
        N, D = self.N, self.D
        self.L = np.empty((D, N, N))
        self.weights = np.empty((D, N))
        for j in range(D):
            self.L[j] = _linalg.cholesky(self.kernel_matrix(j), lower=True, check_finite=False)
            self.weights[j] = self._solve(self.L[j], self.y[:, j])

    @staticmethod
    def _solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``(L L^T)^-1 b`` by two triangular solves."""
        v = _linalg.solve_triangular(L, b, lower=True, check_finite=False)
        return _linalg.solve_triangular(L, v, lower=True, trans="T", check_finite=False)

    def update(self, X_new: np.ndarray, Y_new: np.ndarray) -> GPModel:
        """Add data ``X_new (n, d)``, ``Y_new (n, D)`` (physical) at fixed hyperparameters and scaling, in place.

        Exact block-Cholesky extension, the old block is not refactorized:
        ``L21 = (L11^-1 K12)^T``, ``L22 = chol(K22 + sn2 I - L21 L21^T)``; ``weights`` by two
        triangular solves. ``O(D (N^2 n + N n^2 + n^3))``. Returns ``self``; on an error
        (non-finite data, a failed Cholesky) the model is left unchanged."""
        Xn, Yn = self._new_data(X_new, Y_new)
        n = Xn.shape[0]
        if n == 0:
            return self
        Zn, yn = self.scale_x(Xn), (Yn - self.y_mean) / self.y_std
        N = self.N
        Z = np.vstack([self.Z, Zn])
        y = np.vstack([self.y, yn])
        L = np.zeros((self.D, N + n, N + n))
        weights = np.empty((self.D, N + n))
        for j in range(self.D):
            K12 = se_kernel(self.Z, Zn, self.ell[j], self.sf2[j])
            K22 = se_kernel(Zn, Zn, self.ell[j], self.sf2[j])
            K22[np.diag_indices_from(K22)] += self.sn2[j]
            L21T = _linalg.solve_triangular(self.L[j], K12, lower=True, check_finite=False)  # (N, n)
            L[j, :N, :N] = self.L[j]
            L[j, N:, :N] = L21T.T
            L[j, N:, N:] = _linalg.cholesky(K22 - L21T.T @ L21T, lower=True, check_finite=False)
            weights[j] = self._solve(L[j], y[:, j])
        self.Z, self.y, self.L, self.weights = Z, y, L, weights
        return self

    def log_marginal_likelihood(self) -> np.ndarray:
        """``log p(y | theta)`` per output ``(D,)`` in scaled units (sklearn's ``log_marginal_likelihood_value_``).

        In physical units subtract ``N log(y_std)``."""
        logdet = np.log(np.diagonal(self.L, axis1=1, axis2=2)).sum(1)
        return -0.5 * np.einsum("nj,jn->j", self.y, self.weights) - logdet - 0.5 * self.N * _LOG_2PI

    # -- the variance ----------------------------------------------------------------------
    def _solve_fwd(self, j: int, Ks: np.ndarray, *, overwrite: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Scaled latent variance ``(M,)`` (not clipped) and ``Vt = (L^-1 k*)^T`` ``(M, N)``, C order.

        One BLAS ``dtrsm`` in place on ``Ks (M, N)`` (C order, i.e. ``Ks^T`` in Fortran order), on
        a copy unless ``overwrite``; ``var = sf2 - |L^-1 k*|^2``, a sum of squares (accurate also
        for an ill-conditioned ``K``, unlike an explicit inverse)."""
        # L.T is L^T in Fortran order (no copy), op(L^T) = L; Ks.T is Fortran order, solved in place
        B = Ks.T if overwrite else Ks.T.copy(order="F")
        Vt = _blas.dtrsm(1.0, self.L[j].T, B, lower=0, trans_a=1, overwrite_b=1).T
        return self.sf2[j] - np.einsum("mn,mn->m", Vt, Vt), Vt

    def _solve_bwd(self, j: int, Vt: np.ndarray) -> np.ndarray:
        """``((K + sn2 I)^-1 k*)^T = (L^-T L^-1 k*)^T`` ``(M, N)`` in place on ``Vt`` from ``_solve_fwd``."""
        return _blas.dtrsm(1.0, self.L[j].T, Vt.T, lower=0, trans_a=0, overwrite_b=1).T  # op(L^T) = L^T

    def _latent_variance(self, j: int, Ks: np.ndarray) -> np.ndarray:
        """``sf2 - k*^T (K + sn2 I)^-1 k*`` ``(M,)``, solved in place on ``Ks``."""
        return self._solve_fwd(j, Ks, overwrite=True)[0]

    def _variance_weights(self, j: int, Ks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The variance ``(M,)`` and ``W = ((K + sn2 I)^-1 k*)^T`` ``(M, N)``: two in-place triangular
        solves (BLAS ``dtrsm``) with ``M`` right-hand sides against the Cholesky factor (``2 M N^2``
        flops, the bulk of ``predict_with_gradients``). No explicit inverse: with the noise floor,
        ``cond(K + sn2 I)`` reaches ``1e11`` on fitted models and ``k*^T K^-1 k*`` from an explicit
        ``K^-1`` then loses the variance near the data entirely (``bench/gp_bench.py`` docstring)."""
        v, Vt = self._solve_fwd(j, Ks)
        return v, self._solve_bwd(j, Vt)

    def _compiled_point_predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """One point, every output in one compiled call: forward and back substitution against each
        Cholesky factor, ``2 N^2`` flops per output (the planner's sweeps ask for one point at a time).
        The same formulas as the batch call; the solves run in a different order than BLAS's, so the
        two agree to rounding (tests/plants/test_gp.py). ``None`` without a C compiler."""
        lib = _point_lib() if self.d <= POINT_MAX_INPUTS else None
        if lib is None:
            return None
        pc = self._point_arrays(x)
        if "var" not in pc:
            pc["L"] = np.ascontiguousarray(self.L)
            pc["var"], pc["gv"], pc["work"] = np.empty(self.D), np.empty((self.D, self.d)), np.empty(2 * self.N)
            pc["ptrs_var"] = [*pc["ptrs"][:4], pc["L"].ctypes.data,
                              *(pc[k].ctypes.data for k in ("z", "m", "g", "var", "gv", "work"))]
        lib.gp_point_var(self.N, self.d, self.D, *pc["ptrs_var"])
        gscale = pc["gscale"]
        return (pc["m"] * self.y_std + self.y_mean, np.maximum(pc["var"], 0.0) * self.y_std ** 2,
                pc["g"] * gscale, pc["gv"] * (gscale * self.y_std[:, None]))

    # -- storage -------------------------------------------------------------------------
    def to_arrays(self, *, include_factor: bool = True) -> dict[str, np.ndarray]:
        """Plain arrays for ``np.savez`` (no pickle); with the factor ``L`` and the weights (key
        ``alpha``, the stored format's name) unless told not to.

        Without the factor (``D N^2`` doubles), ``from_arrays`` refactorizes: same predictions to
        rounding, not bit for bit."""
        out = {"Z": self.Z, "y": self.y, **self._hyper_arrays()}
        if include_factor:
            out |= {"L": self.L, "alpha": self.weights}
        return {k: np.array(v, copy=True) for k, v in out.items()}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> GPBase:
        """Inverse of ``to_arrays`` (uses the stored factor when present, else refactorizes); the
        arrays of a :class:`SparseGPModel` (they hold ``Z_train``) give a ``SparseGPModel``."""
        if cls is GPModel and ANGLE_KEY in arrays:   # answers every query of a GPBase (in the raw inputs)
            return cast(GPBase, AngleInputGP.from_arrays(arrays))
        if cls is GPModel and "Z_train" in arrays:
            return SparseGPModel.from_arrays(arrays)
        g = cls._stored(arrays, {"Z", "y", "ell", "sf2", "sn2", "x_mean", "x_std", "y_mean", "y_std"}, "GP")
        self = cls.__new__(cls)
        self.Z = g["Z"].copy()
        self._restore_hypers(g)
        N, D = self.Z.shape[0], self.y.shape[1]
        if self.y.shape[0] != N or not self._hypers_consistent():
            raise ValueError("inconsistent GP array shapes")
        if "L" in g and "alpha" in g:
            if g["L"].shape != (D, N, N) or g["alpha"].shape != (D, N):
                raise ValueError("inconsistent GP factor shapes")
            self.L, self.weights = g["L"].copy(), g["alpha"].copy()
        else:
            self._factorize()
        return self


SELECT_TOL = 1e-12  # greedy inducing selection: smallest conditional prior variance (over sf2) of a new inducing point


def select_inducing(Z: np.ndarray, ell: np.ndarray, sf2: np.ndarray, m: int, *, tol: float = SELECT_TOL) -> np.ndarray:
    """Indices ``(<= m,)`` of ``Z (N, d)`` (scaled inputs) chosen as inducing inputs, in selection order.

    Greedy maximum-variance selection (a pivoted Cholesky factorization of the prior kernel
    matrices, shared by all ``D`` outputs; Fine & Scheinberg 2001, Burt et al. 2020): each step adds
    the training input whose conditional prior variance given the inputs chosen so far, summed over
    the outputs and each divided by its ``sf2``, is largest (ties: lowest index). A point is eligible
    only while its conditional variance is above ``tol sf2`` in every output, so the Cholesky
    pivots of every ``K_mm`` (in this order) are ``>= tol sf2`` and no jitter is needed; the
    selection stops early, with fewer than ``m`` points, when no point is eligible (the rest are
    then determined by the chosen ones to ``sqrt(tol)`` of their prior std). Deterministic, no seed.
    ``ell (D, d)``, ``sf2 (D,)``; cost ``O(D N m (d + m))``."""
    N = Z.shape[0]
    D = ell.shape[0]
    m = min(int(m), N)
    Zs = Z[None, :, :] / ell[:, None, :]  # (D, N, d)
    G = np.zeros((D, m, N))  # rows of the pivoted Cholesky factors of K / sf2
    r = np.ones((D, N))  # conditional prior variance / sf2
    chosen: list[int] = []
    for k in range(m):
        score = r.sum(0)
        score[r.min(0) <= tol] = -np.inf
        p = int(np.argmax(score))
        if not np.isfinite(score[p]):
            break
        kc = np.exp(-0.5 * ((Zs - Zs[:, p:p + 1, :]) ** 2).sum(-1))  # (D, N) correlation with point p
        if k:
            kc -= np.matmul(G[:, None, :k, p], G[:, :k, :])[:, 0, :]
        col = kc / np.sqrt(r[:, p])[:, None]
        G[:, k] = col
        r -= col * col
        r[:, p] = 0.0
        chosen.append(p)
    return np.asarray(chosen, dtype=int)


class SparseGPModel(GPBase):
    """Sparse GP (FITC, Snelson & Ghahramani 2006; Quinonero-Candela & Rasmussen 2005) with ``M``
    inducing inputs, one per output with the exact model's SE-ARD kernel, scaling and noise.

    Inducing inputs ``U``: a subset of the training inputs (``select_inducing``) or given. With
    ``Q_ab = K_aU K_UU^-1 K_Ub`` and ``Lam = diag(K_nn - Q_nn) + sn2 I`` (per output, scaled units):
    mean ``m(z) = k_U(z)^T w`` with ``w = Sigma K_Un Lam^-1 y``, ``Sigma = (K_UU + K_Un Lam^-1 K_nU)^-1``;
    latent variance ``sf2 - k_U^T K_UU^-1 k_U + k_U^T Sigma k_U``. Numerically: ``L_U = chol(K_UU)``
    (no jitter: the selection bounds its pivots below by ``1e-12 sf2``, ``SELECT_TOL``; with the
    fit's bounds ``sf2 <= 1e3``, ``sn2 >= 1e-6`` that is below 1e-3 of the noise variance),
    ``A = L_U^-1 K_Un Lam^-1/2``, ``L_B = chol(I + A A^T)``; a prediction needs the triangular
    solves ``V1 = L_U^-1 k_U``, ``V2 = L_B^-1 V1`` (variance ``sf2 - |V1|^2 + |V2|^2``) and, for the
    variance gradient, ``L_U^-T (V1 - L_B^-T V2)``: four ``M x M`` solves per output instead of two
    ``N x N``. With the inducing inputs equal to all training inputs this is the exact GP
    (``Q_nn = K_nn``), tested.

    Layout: ``Z (M, d)`` and ``weights (D, M)`` are the inducing inputs and weights (so the mean, its
    gradient and the compiled one-point path are :class:`GPBase`'s), the training data are
    ``Z_train (N, d)`` and ``y (N, D)`` (scaled), ``L_U``, ``L_B (D, M, M)``, ``lam (D, N)``.
    ``m_requested``: the inducing count asked for (``update`` selects again up to it). The compiled
    one-point variance is the exact GP's: here the batch call on one row.
    """

    _online: tuple[np.ndarray, ...] | None = None   # add_points' sums (None: from the data at the next call)

    def __init__(self, X: np.ndarray, Y: np.ndarray, ell: np.ndarray, sf2: np.ndarray, sn2: np.ndarray,
                 *, inducing: int | np.ndarray, x_mean: np.ndarray | None = None, x_std: np.ndarray | None = None,
                 y_mean: np.ndarray | None = None, y_std: np.ndarray | None = None,
                 noise_floor: float = NOISE_FLOOR):
        """Physical data ``X (N, d)``, ``Y (N, D)``, scaled hyperparameters as :class:`GPModel`;
        ``inducing``: a count ``1 <= M <= N`` (greedy selection among the training inputs) or
        physical inducing inputs ``(M, d)``."""
        self.Z_train = self._set_data(X, Y, ell, sf2, sn2, x_mean, x_std, y_mean, y_std, noise_floor)
        N, d = self.Z_train.shape
        if np.ndim(inducing) == 0:
            M = int(inducing)
            if not 1 <= M <= N:
                raise ValueError(f"inducing points must be in [1, {N}] (the training points), got {M}")
            self.m_requested = M
            self.Z = self.Z_train[select_inducing(self.Z_train, self.ell, self.sf2, M)]
        else:
            U = _as_2d(np.asarray(inducing), "inducing")
            if U.shape[1] != d or len(U) == 0 or not np.all(np.isfinite(U)):
                raise ValueError(f"inducing inputs must be finite, (M >= 1, {d}), got shape {U.shape}")
            self.m_requested = len(U)
            self.Z = self.scale_x(U)
        self._factorize()

    @property
    def N(self) -> int:
        """Number of training points."""
        return self.Z_train.shape[0]

    @property
    def M(self) -> int:
        """Number of inducing points."""
        return self.Z.shape[0]

    @property
    def X(self) -> np.ndarray:
        """Training inputs ``(N, d)`` in physical units."""
        return self.unscale_x(self.Z_train)

    @property
    def U(self) -> np.ndarray:
        """Inducing inputs ``(M, d)`` in physical units."""
        return self.unscale_x(self.Z)

    def kernel_matrix(self, j: int) -> np.ndarray:
        """``K_UU`` ``(M, M)`` of output ``j`` (scaled units, no noise, no jitter)."""
        return se_kernel(self.Z, self.Z, self.ell[j], self.sf2[j])

    def _factorize(self) -> None:
        """``L_U``, ``L_B``, ``lam`` and the weights ``weights`` of every output (``O(D N M^2)``)."""
        M, N, D = self.M, self.N, self.D
        self.L_U, self.L_B = np.empty((D, M, M)), np.empty((D, M, M))
        self.lam, self.weights = np.empty((D, N)), np.empty((D, M))
        self._lml = np.empty(D)
        for j in range(D):
            try:
                LU = _linalg.cholesky(self.kernel_matrix(j), lower=True, check_finite=False)
            except np.linalg.LinAlgError:
                raise ValueError(f"output {j}: the inducing inputs' kernel matrix is singular "
                                 "(inducing inputs too close at these length-scales)") from None
            A = _linalg.solve_triangular(LU, se_kernel(self.Z, self.Z_train, self.ell[j], self.sf2[j]), lower=True,
                                 check_finite=False)  # (M, N) L_U^-1 K_Un
            lam = self.sn2[j] + np.maximum(self.sf2[j] - np.einsum("mn,mn->n", A, A), 0.0)
            s = 1.0 / np.sqrt(lam)
            A *= s
            B = A @ A.T
            B[np.diag_indices_from(B)] += 1.0
            LB = _linalg.cholesky(B, lower=True, check_finite=False)
            ys = self.y[:, j] * s
            c = _linalg.solve_triangular(LB, A @ ys, lower=True, check_finite=False)
            self.weights[j] = _linalg.solve_triangular(LU, _linalg.solve_triangular(LB, c, lower=True, trans="T", check_finite=False),
                                             lower=True, trans="T", check_finite=False)
            self.L_U[j], self.L_B[j], self.lam[j] = LU, LB, lam
            # FITC log marginal likelihood log N(y | 0, Q_nn + Lam) by Woodbury and the determinant lemma
            self._lml[j] = (-0.5 * (ys @ ys - c @ c) - 0.5 * np.log(lam).sum() - np.log(np.diagonal(LB)).sum()
                            - 0.5 * N * _LOG_2PI)

    def log_marginal_likelihood(self) -> np.ndarray:
        """FITC's approximate ``log p(y | theta)`` per output ``(D,)`` in scaled units (the exact
        GP's when the inducing inputs are all training inputs)."""
        return self._lml.copy()

    def update(self, X_new: np.ndarray, Y_new: np.ndarray) -> SparseGPModel:
        """Add data ``X_new (n, d)``, ``Y_new (n, D)`` (physical) at fixed hyperparameters and scaling,
        in place: the inducing inputs are selected again among all training inputs (up to
        ``m_requested``; the new data may lie where the old inducing inputs do not reach) and the
        posterior is refactorized, ``O(D N M (d + M))``. Returns ``self``; unchanged on an error."""
        Xn, Yn = self._new_data(X_new, Y_new)
        if Xn.shape[0] == 0:
            return self
        new = SparseGPModel(np.vstack([self.X, Xn]), np.vstack([self.Y, Yn]), self.ell, self.sf2, self.sn2,
                            inducing=self.m_requested, x_mean=self.x_mean, x_std=self.x_std, y_mean=self.y_mean,
                            y_std=self.y_std, noise_floor=self.noise_floor)
        self.__dict__.update(new.__dict__)
        self._online = None   # add_points' sums start again from these data
        return self

    def add_points(self, X_new: np.ndarray, Y_new: np.ndarray) -> SparseGPModel:
        """Add data ``X_new (k, d)``, ``Y_new (k, D)`` (physical) at fixed hyperparameters, scaling and inducing
        inputs, in place: FITC's posterior over the inducing outputs takes a rank-``k`` update. Each new point
        ``z`` adds the column ``a = L_U^-1 k_U(z) / sqrt(lam(z))`` to ``A`` (its ``lam`` is its own: the inducing
        inputs are fixed), so ``B = I + A A^T`` gains ``a a^T`` and ``A ys`` gains ``a y / sqrt(lam)``; ``L_B`` is
        refactorized from ``B`` (``O(D M^3)``, no pass over the old data) and the weights solved again. Equal to
        the batch posterior of all the data at these inducing inputs (``SparseGPModel(..., inducing=self.U)``, the
        same scaling). Returns ``self``; unchanged on an error."""
        Xn, Yn = self._new_data(X_new, Y_new)
        if Xn.shape[0] == 0:
            return self
        if self._online is None:
            self._online = self._posterior_stats(self.Z_train, self.y)[:4]
        Zn, yn = self.scale_x(Xn), (Yn - self.y_mean) / self.y_std
        Bs, rs, ss, add = self._online
        new = self._posterior_stats(Zn, yn)
        B, r, s2 = Bs + new[0], rs + new[1], ss + new[2]
        L_B, weights, lml = np.empty_like(self.L_B), np.empty_like(self.weights), np.empty(self.D)
        N = self.N + Zn.shape[0]
        for j in range(self.D):
            LB = _linalg.cholesky(B[j], lower=True, check_finite=False)
            c = _linalg.solve_triangular(LB, r[j], lower=True, check_finite=False)
            weights[j] = _linalg.solve_triangular(self.L_U[j], _linalg.solve_triangular(
                LB, c, lower=True, trans="T", check_finite=False), lower=True, trans="T", check_finite=False)
            L_B[j] = LB
            lml[j] = (-0.5 * (s2[j] - c @ c) - 0.5 * (add[j] + new[3][j]) - np.log(np.diagonal(LB)).sum()
                      - 0.5 * N * _LOG_2PI)
        self.Z_train, self.y = np.vstack([self.Z_train, Zn]), np.vstack([self.y, yn])
        self.lam = np.hstack([self.lam, new[4]])
        self.L_B, self.weights, self._lml = L_B, weights, lml
        self._online = (B, r, s2, add + new[3])
        return self

    def _posterior_stats(self, Z: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, ...]:
        """FITC's sums over the points ``Z (n, d)``, ``y (n, D)`` (scaled) at the fixed inducing inputs, per
        output: ``I + A A^T`` for the first call's data (``A A^T`` else: pass the old data once), ``A ys``,
        ``ys . ys``, ``sum log lam`` and ``lam (D, n)``, with ``A = L_U^-1 K_Un Lam^-1/2``, ``ys = y Lam^-1/2``."""
        D, M, n = self.D, self.M, Z.shape[0]
        first = self._online is None
        B, r, s2, logs, lam = np.empty((D, M, M)), np.empty((D, M)), np.empty(D), np.empty(D), np.empty((D, n))
        for j in range(D):
            A = _linalg.solve_triangular(self.L_U[j], se_kernel(self.Z, Z, self.ell[j], self.sf2[j]), lower=True,
                                         check_finite=False)
            lam[j] = self.sn2[j] + np.maximum(self.sf2[j] - np.einsum("mn,mn->n", A, A), 0.0)
            w = 1.0 / np.sqrt(lam[j])
            A *= w
            B[j] = A @ A.T
            if first:
                B[j][np.diag_indices(M)] += 1.0
            ys = y[:, j] * w
            r[j], s2[j], logs[j] = A @ ys, ys @ ys, np.log(lam[j]).sum()
        return B, r, s2, logs, lam

    # -- the variance ----------------------------------------------------------------------
    def _var_solves(self, j: int, Ks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Scaled latent variance ``(T,)`` (not clipped), ``V1 = L_U^-1 k_U`` and ``V2 = L_B^-1 V1``, both ``(M, T)``."""
        V1 = _linalg.solve_triangular(self.L_U[j], Ks.T, lower=True, check_finite=False)
        V2 = _linalg.solve_triangular(self.L_B[j], V1, lower=True, check_finite=False)
        return self.sf2[j] - np.einsum("mt,mt->t", V1, V1) + np.einsum("mt,mt->t", V2, V2), V1, V2

    def _latent_variance(self, j: int, Ks: np.ndarray) -> np.ndarray:
        """``sf2 - k_U^T K_UU^-1 k_U + k_U^T Sigma k_U`` ``(T,)``."""
        return self._var_solves(j, Ks)[0]

    def _variance_weights(self, j: int, Ks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The variance ``(T,)`` and ``W = ((K_UU^-1 - Sigma) k_U)^T = (L_U^-T (V1 - L_B^-T V2))^T`` ``(T, M)``."""
        v, V1, V2 = self._var_solves(j, Ks)
        V1 -= _linalg.solve_triangular(self.L_B[j], V2, lower=True, trans="T", check_finite=False)
        return v, _linalg.solve_triangular(self.L_U[j], V1, lower=True, trans="T", check_finite=False).T

    # -- storage -------------------------------------------------------------------------
    def to_arrays(self, *, include_factor: bool = True) -> dict[str, np.ndarray]:
        """Plain arrays for ``np.savez``: inducing inputs ``Z``, training data ``Z_train``, ``y``,
        hyperparameters, scaling, ``m_requested``; with the factors ``L_U``, ``L_B``, ``lam``,
        the weights and the likelihood ``lml`` unless told not to (``from_arrays`` then refactorizes
        at the stored inducing inputs)."""
        out = {"Z": self.Z, "Z_train": self.Z_train, "y": self.y, **self._hyper_arrays(),
               "m_requested": np.array(self.m_requested)}
        if include_factor:
            out |= {"L_U": self.L_U, "L_B": self.L_B, "lam": self.lam, "alpha": self.weights, "lml": self._lml}
        return {k: np.array(v, copy=True) for k, v in out.items()}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> SparseGPModel:
        """Inverse of ``to_arrays``."""
        g = cls._stored(arrays, {"Z", "Z_train", "y", "ell", "sf2", "sn2", "x_mean", "x_std", "y_mean", "y_std"},
                        "sparse GP")
        self = cls.__new__(cls)
        self.Z, self.Z_train = g["Z"].copy(), g["Z_train"].copy()
        self._restore_hypers(g)
        self.m_requested = int(g.get("m_requested", len(self.Z)))
        M, N, d, D = self.Z.shape[0], self.Z_train.shape[0], self.Z.shape[1], self.y.shape[1]
        if self.Z_train.shape[1] != d or self.y.shape[0] != N or not self._hypers_consistent():
            raise ValueError("inconsistent sparse GP array shapes")
        if all(k in g for k in ("L_U", "L_B", "lam", "alpha", "lml")):
            if (g["L_U"].shape != (D, M, M) or g["L_B"].shape != (D, M, M) or g["lam"].shape != (D, N)
                    or g["alpha"].shape != (D, M) or g["lml"].shape != (D,)):
                raise ValueError("inconsistent sparse GP factor shapes")
            self.L_U, self.L_B, self.lam = g["L_U"].copy(), g["L_B"].copy(), g["lam"].copy()
            self.weights, self._lml = g["alpha"].copy(), g["lml"].copy()
        else:
            self._factorize()
        return self


ANGLE_KEY = "angle_inputs"  # in a GP's stored arrays: the raw input columns it reads as (sin, cos)


def angle_features(X: np.ndarray, wrap: np.ndarray) -> np.ndarray:
    """Inputs ``X (M, d)`` with each column of ``wrap`` (an angle, rad) replaced by its sine and its cosine
    appended: ``(M, d + len(wrap))``, the GP inputs of a continuous joint (PILCO's ``gTrig``): the angles
    ``theta`` and ``theta + 2 pi k`` are the same input. NaN stays NaN."""
    X = np.asarray(X, float)
    F = np.concatenate([X, np.cos(X[..., wrap])], axis=-1)
    F[..., wrap] = np.sin(X[..., wrap])
    return F


def angle_jacobian(X: np.ndarray, wrap: np.ndarray) -> np.ndarray:
    """``d angle_features / dX`` ``(M, d + len(wrap), d)`` at ``X (M, d)``: the identity, but
    ``d sin/d theta = cos`` in the angle's row and ``d cos / d theta = -sin`` in its appended row."""
    X = np.asarray(X, float)
    M, d = X.shape
    J = np.zeros((M, d + len(wrap), d))
    J[:, np.arange(d), np.arange(d)] = 1.0
    for i, c in enumerate(np.asarray(wrap, int)):
        J[:, c, c] = np.cos(X[:, c])
        J[:, d + i, c] = -np.sin(X[:, c])
    return J


class AngleInputGP:
    """A GP (``inner``, exact or sparse) over :func:`angle_features` of its physical inputs: the raw inputs'
    columns ``wrap`` (the angles of continuous joints, rad) enter as ``(sin, cos)``, so a pole that spun turns
    gives data at the same GP inputs as one that did not. Queries take the raw inputs ``(M, d)``; the
    gradients are the inner GP's through the chain rule (``angle_jacobian``), exact at the point. No
    compiled linearization or rollout (``point_linearizer`` and ``controller_rollout`` are None: the
    callers step in Python); everything else (hyperparameters, scaling, likelihood) is the inner GP's."""

    def __init__(self, inner: GPBase, wrap: np.ndarray):
        self.inner = inner
        self.wrap = np.asarray(wrap, int).reshape(-1)
        if len(self.wrap) == 0 or inner.d <= 2 * len(self.wrap) or np.any(self.wrap >= inner.d - len(self.wrap)):
            raise ValueError(f"angle inputs {self.wrap.tolist()} do not fit a GP of {inner.d} feature inputs")

    def __getattr__(self, name: str):
        if name in ("inner", "wrap"):
            raise AttributeError(name)
        return getattr(self.inner, name)

    @property
    def d(self) -> int:
        """Raw inputs."""
        return self.inner.d - len(self.wrap)

    @property
    def D(self) -> int:
        return self.inner.D

    def _features(self, Xq: np.ndarray) -> np.ndarray:
        Xq = _as_2d(np.asarray(Xq, float), "Xq")
        if Xq.shape[1] != self.d:
            raise ValueError(f"a query has {self.d} entries, got {Xq.shape[1]}")
        return angle_features(Xq, self.wrap)

    def predict(self, Xq: np.ndarray, *, noisy: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """``GPBase.predict`` at raw inputs ``Xq (M, d)``."""
        return self.inner.predict(self._features(Xq), noisy=noisy)

    def predict_mean(self, Xq: np.ndarray) -> np.ndarray:
        """``GPBase.predict_mean`` at raw inputs ``Xq (M, d)``."""
        return self.inner.predict_mean(self._features(Xq))

    def mean_with_gradients(self, Xq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(M, D)`` and its gradient ``(M, D, d)`` in the raw inputs (chain rule)."""
        Xq = _as_2d(np.asarray(Xq, float), "Xq")
        m, g = self.inner.mean_with_gradients(self._features(Xq))
        return m, g @ angle_jacobian(Xq, self.wrap)

    def predict_with_gradients(self, Xq: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Mean, latent variance ``(M, D)`` and their gradients ``(M, D, d)`` in the raw inputs."""
        Xq = _as_2d(np.asarray(Xq, float), "Xq")
        m, v, dm, dv = self.inner.predict_with_gradients(self._features(Xq))
        J = angle_jacobian(Xq, self.wrap)
        return m, v, dm @ J, dv @ J

    def point_mean_with_gradients(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(D,)`` and gradient ``(D, d)`` at one raw input ``x (d,)`` (the inner GP's compiled point call)."""
        x = np.asarray(x, float).reshape(-1)
        if x.shape != (self.d,):
            raise ValueError(f"a query has {self.d} entries, got {x.shape}")
        m, g = self.inner.point_mean_with_gradients(angle_features(x[None, :], self.wrap)[0])
        return m, g @ angle_jacobian(x[None, :], self.wrap)[0]

    def point_predict_with_gradients(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``predict_with_gradients`` at one raw input ``x (d,)``."""
        x = np.asarray(x, float).reshape(-1)
        if x.shape != (self.d,):
            raise ValueError(f"a query has {self.d} entries, got {x.shape}")
        m, v, dm, dv = self.inner.point_predict_with_gradients(angle_features(x[None, :], self.wrap)[0])
        J = angle_jacobian(x[None, :], self.wrap)[0]
        return m, v, dm @ J, dv @ J

    def point_linearizer(self, dt: float) -> None:
        """No compiled linearization through the features (the sweeps call ``linearize``)."""
        return None

    def controller_rollout(self, x0: np.ndarray, o: np.ndarray, O: np.ndarray, dt: float) -> None:
        """No compiled rollout through the features (the caller steps in Python)."""
        return None

    def to_arrays(self, *, include_factor: bool = True) -> dict[str, np.ndarray]:
        """The inner GP's arrays and ``ANGLE_KEY``."""
        return {**self.inner.to_arrays(include_factor=include_factor), ANGLE_KEY: self.wrap.astype(float)}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> AngleInputGP:
        """Inverse of :meth:`to_arrays`."""
        wrap = np.asarray(arrays[ANGLE_KEY], float).reshape(-1).astype(int)
        return cls(GPModel.from_arrays({k: v for k, v in arrays.items() if k != ANGLE_KEY}), wrap)

    def copy(self) -> AngleInputGP:
        return AngleInputGP.from_arrays(self.to_arrays())


def _as_2d(A: np.ndarray, name: str) -> np.ndarray:
    A = np.asarray(A, dtype=float)
    if A.ndim != 2:
        raise ValueError(f"{name} must be 2-D, got shape {A.shape}")
    return A


def _nan(shape: tuple[int, ...]) -> np.ndarray:
    return np.full(shape, np.nan)
