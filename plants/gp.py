"""Multi-output Gaussian-process posterior for learned dynamics (SPEC §7, thesis §4.2-4.3).

One independent GP per output dimension of ``qddot = f(q, qdot, u)``: inputs ``x = (q, qdot, u)``
of size ``d = 2 D + F``, outputs ``D``. Zero prior mean (in scaled units, see below),
squared-exponential ARD kernel ``k(x, x') = sf2 exp(-1/2 (x - x')^T Lambda^-1 (x - x'))`` with
``Lambda = diag(ell^2)``, plus noise ``sn2`` on the diagonal of the training kernel matrix.
Pure numpy/scipy; hyperparameter fitting lives in ``stages.fit.gp_fit``.

Scaling. Inputs are standardized per dimension, ``z = (x - x_mean) / x_std``; outputs per output,
``y = (Y - y_mean) / y_std`` (a constant dimension gets std 1). All hyperparameters (``ell``,
``sf2``, ``sn2``), the training arrays ``Z``, ``y``, the Cholesky factor ``L`` and ``alpha``, and the
log marginal likelihood are in these scaled units; the zero prior mean in scaled units is the
training mean ``y_mean`` in physical units. Every prediction is returned in physical units
(``qddot`` in rad/s^2, variances in (rad/s^2)^2), gradients with respect to the physical input
``x`` by the chain rule: ``dm/dx = y_std * dm_s/dz / x_std``, ``dvar/dx = y_std^2 * dvar_s/dz / x_std``.
The scaling is fixed when the model is built; ``update`` keeps it.

Noise floor. Simulated data are nearly noise-free and ``K`` gets ill-conditioned; the noise level
is bounded from below, ``sn2 >= noise_floor`` (default ``1e-6`` in standardized output units, i.e.
a noise std of 0.1 % of the output's spread). The fit uses it as the lower bound of sklearn's
``WhiteKernel(noise_level_bounds=(noise_floor, ...))`` with ``GaussianProcessRegressor(alpha=0)``,
and this posterior clips ``sn2`` to the same floor; no other jitter is added anywhere, so the
posterior is exactly the one whose likelihood the fit maximized. With the fit's bound
``sf2 <= 1e3`` this keeps ``cond(K + sn2 I) <= 1 + N sf2 / sn2 <= 1 + 1e9 N``.

Variances. ``var`` is the latent function's variance (without the noise), clipped at 0;
``predict(..., noisy=True)`` adds the noise ``sn2`` (what sklearn's ``return_std`` reports when
the kernel contains a ``WhiteKernel``).

Non-finite query rows give NaN outputs (and NaN gradients), never an exception.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.linalg import cholesky, solve_triangular
from scipy.linalg.blas import dtrsm
from scipy.spatial.distance import cdist

NOISE_FLOOR = 1e-6  # lower bound of sn2 in standardized output units (see the module docstring)

# One query point, every output: the GP mean and its input gradient in C (no per-output numpy
# calls: a planner's relinearization inside the sweeps asks for one point at a time). The same
# formulas as ``mean_with_gradients``; the distance is summed directly (no expansion), so the two
# agree to rounding (tests/test_gp.py).
_POINT_C = r"""
#include <math.h>
/* Zs (D, N, d): training inputs divided by each output's length-scales; alpha (D, N); sf2 (D,);
 * inv_ell (D, d); z (d,) scaled query. out_m (D,), out_g (D, d): scaled mean and gradient. */
void gp_point(long N, long d, long D, const double *Zs, const double *alpha, const double *sf2,
              const double *inv_ell, const double *z, double *out_m, double *out_g)
{
    double zs[256], g[256];
    for (long j = 0; j < D; j++) {
        const double *Zj = Zs + j * N * d, *aj = alpha + j * N, *ie = inv_ell + j * d;
        for (long k = 0; k < d; k++) { zs[k] = z[k] * ie[k]; g[k] = 0.0; }
        double m = 0.0;
        for (long i = 0; i < N; i++) {
            const double *zi = Zj + i * d;
            double s = 0.0;
            for (long k = 0; k < d; k++) { double e = zi[k] - zs[k]; s += e * e; }
            double w = aj[i] * sf2[j] * exp(-0.5 * s);
            m += w;
            for (long k = 0; k < d; k++) g[k] += w * (zi[k] - zs[k]);
        }
        out_m[j] = m;
        for (long k = 0; k < d; k++) out_g[j * d + k] = g[k] * ie[k];
    }
}
"""
_POINT_LIB: object = None


def _point_lib():
    """The compiled ``gp_point`` (``None`` without a C compiler or with ``RAICO_NO_C``)."""
    global _POINT_LIB
    if _POINT_LIB is None:
        import ctypes

        from plants.codegen import c_backend
        try:
            if not c_backend.enabled():
                raise c_backend.CompileUnavailable("disabled")
            lib = c_backend.load_library(_POINT_C, "gp_point", flags=(*c_backend.CFLAGS, "-O3"))
            lib.gp_point.argtypes = [ctypes.c_long] * 3 + [ctypes.c_void_p] * 7
            lib.gp_point.restype = None
            _POINT_LIB = lib
        except (c_backend.CompileUnavailable, OSError):
            _POINT_LIB = False
    return _POINT_LIB or None

_LOG_2PI = float(np.log(2.0 * np.pi))


def column_std(A: np.ndarray) -> np.ndarray:
    """Column standard deviations, 1 where a column is (numerically) constant."""
    s = A.std(axis=0)
    return np.where(s > 1e-12 * np.maximum(1.0, np.abs(A).max(axis=0, initial=0.0)), s, 1.0)


def se_kernel(A: np.ndarray, B: np.ndarray, ell: np.ndarray, sf2: float) -> np.ndarray:
    """Exact SE-ARD kernel matrix ``(n_A, n_B)`` (pairwise differences, as sklearn's ``RBF``)."""
    return sf2 * np.exp(-0.5 * cdist(A / ell, B / ell, "sqeuclidean"))


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


class GPModel:
    """Independent SE-ARD GPs, one per output, sharing the training inputs (scaled units inside).

    Attributes (scaled units): ``Z (N, d)`` training inputs, ``y (N, D)`` targets,
    ``ell (D, d)`` length-scales, ``sf2 (D,)``, ``sn2 (D,)``, ``L (D, N, N)`` lower Cholesky
    factors of ``K + sn2 I``, ``alpha (D, N) = (K + sn2 I)^-1 y``; scaling ``x_mean, x_std (d,)``,
    ``y_mean, y_std (D,)`` (physical units).
    """

    def __init__(self, X: np.ndarray, Y: np.ndarray, ell: np.ndarray, sf2: np.ndarray, sn2: np.ndarray,
                 *, x_mean: np.ndarray | None = None, x_std: np.ndarray | None = None,
                 y_mean: np.ndarray | None = None, y_std: np.ndarray | None = None,
                 noise_floor: float = NOISE_FLOOR):
        """Build and factorize from physical data ``X (N, d)``, ``Y (N, D)`` and scaled hyperparameters.

        The scaling defaults to the standardization of ``X`` and ``Y``; ``ell`` is ``(D, d)``
        (or ``(d,)`` shared), ``sf2`` and ``sn2`` are ``(D,)`` or scalars."""
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
        self.Z = self.scale_x(X)
        self.y = (Y - self.y_mean) / self.y_std
        self._factorize()

    # -- shapes and scaling ------------------------------------------------------------
    @property
    def N(self) -> int:
        """Number of training points."""
        return self.Z.shape[0]

    @property
    def d(self) -> int:
        """Input dimension ``2 D + F``."""
        return self.Z.shape[1]

    @property
    def D(self) -> int:
        """Number of outputs."""
        return self.y.shape[1]

    @property
    def X(self) -> np.ndarray:
        """Training inputs ``(N, d)`` in physical units."""
        return self.Z * self.x_std + self.x_mean

    @property
    def Y(self) -> np.ndarray:
        """Training targets ``(N, D)`` in physical units."""
        return self.y * self.y_std + self.y_mean

    def scale_x(self, X: np.ndarray) -> np.ndarray:
        """Physical inputs ``(M, d)`` -> standardized ``(M, d)``."""
        return (X - self.x_mean) / self.x_std

    # -- factorization -----------------------------------------------------------------
    def kernel_matrix(self, j: int) -> np.ndarray:
        """``K + sn2 I`` ``(N, N)`` of output ``j`` (scaled units)."""
        K = se_kernel(self.Z, self.Z, self.ell[j], self.sf2[j])
        K[np.diag_indices_from(K)] += self.sn2[j]
        return K

    def _factorize(self) -> None:
        """Cholesky factors and ``alpha`` of every output from scratch (``O(D N^3)``)."""
        N, D = self.N, self.D
        self.L = np.empty((D, N, N))
        self.alpha = np.empty((D, N))
        for j in range(D):
            self.L[j] = cholesky(self.kernel_matrix(j), lower=True, check_finite=False)
            self.alpha[j] = self._solve(self.L[j], self.y[:, j])

    @staticmethod
    def _solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``(L L^T)^-1 b`` by two triangular solves."""
        v = solve_triangular(L, b, lower=True, check_finite=False)
        return solve_triangular(L, v, lower=True, trans="T", check_finite=False)

    def update(self, X_new: np.ndarray, Y_new: np.ndarray) -> GPModel:
        """Add data ``X_new (n, d)``, ``Y_new (n, D)`` (physical) at fixed hyperparameters and scaling, in place.

        Exact block-Cholesky extension, the old block is not refactorized:
        ``L21 = (L11^-1 K12)^T``, ``L22 = chol(K22 + sn2 I - L21 L21^T)``; ``alpha`` by two
        triangular solves. ``O(D (N^2 n + N n^2 + n^3))``. Returns ``self``; on an error
        (non-finite data, a failed Cholesky) the model is left unchanged."""
        Xn, Yn = _as_2d(X_new, "X_new"), _as_2d(Y_new, "Y_new")
        if Xn.shape[0] != Yn.shape[0] or Xn.shape[1] != self.d or Yn.shape[1] != self.D:
            raise ValueError(f"update expects X_new (n, {self.d}) and Y_new (n, {self.D}), got {Xn.shape}, {Yn.shape}")
        if not (np.all(np.isfinite(Xn)) and np.all(np.isfinite(Yn))):
            raise ValueError("training data must be finite")
        n = Xn.shape[0]
        if n == 0:
            return self
        Zn, yn = self.scale_x(Xn), (Yn - self.y_mean) / self.y_std
        N = self.N
        Z = np.vstack([self.Z, Zn])
        y = np.vstack([self.y, yn])
        L = np.zeros((self.D, N + n, N + n))
        alpha = np.empty((self.D, N + n))
        for j in range(self.D):
            K12 = se_kernel(self.Z, Zn, self.ell[j], self.sf2[j])
            K22 = se_kernel(Zn, Zn, self.ell[j], self.sf2[j])
            K22[np.diag_indices_from(K22)] += self.sn2[j]
            L21T = solve_triangular(self.L[j], K12, lower=True, check_finite=False)  # (N, n)
            L[j, :N, :N] = self.L[j]
            L[j, N:, :N] = L21T.T
            L[j, N:, N:] = cholesky(K22 - L21T.T @ L21T, lower=True, check_finite=False)
            alpha[j] = self._solve(L[j], y[:, j])
        self.Z, self.y, self.L, self.alpha = Z, y, L, alpha
        return self

    def log_marginal_likelihood(self) -> np.ndarray:
        """``log p(y | theta)`` per output ``(D,)`` in scaled units (sklearn's ``log_marginal_likelihood_value_``).

        In physical units subtract ``N log(y_std)``."""
        logdet = np.log(np.diagonal(self.L, axis1=1, axis2=2)).sum(1)
        return -0.5 * np.einsum("nj,jn->j", self.y, self.alpha) - logdet - 0.5 * self.N * _LOG_2PI

    # -- prediction ----------------------------------------------------------------------
    def _query(self, Xq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scaled finite query rows and the mask of finite rows."""
        Xq = _as_2d(Xq, "Xq")
        if Xq.shape[1] != self.d:
            raise ValueError(f"queries must have {self.d} columns, got {Xq.shape[1]}")
        ok = np.all(np.isfinite(Xq), axis=1)
        return self.scale_x(Xq[ok]), ok

    def _kstar(self, j: int, Zq: np.ndarray) -> np.ndarray:
        """Cross-kernel ``(M, N)`` between scaled queries and training inputs of output ``j``."""
        ell = self.ell[j]
        Q = self.Z / ell
        return _se_kernel_fast(Zq / ell, Q, (Q * Q).sum(1), self.sf2[j])

    def _solve_fwd(self, j: int, Ks: np.ndarray, *, overwrite: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Scaled latent variance ``(M,)`` (not clipped) and ``Vt = (L^-1 k*)^T`` ``(M, N)``, C order.

        One BLAS ``dtrsm`` in place on ``Ks (M, N)`` (C order, i.e. ``Ks^T`` in Fortran order), on
        a copy unless ``overwrite``; ``var = sf2 - |L^-1 k*|^2``, a sum of squares (accurate also
        for an ill-conditioned ``K``, unlike an explicit inverse)."""
        # L.T is L^T in Fortran order (no copy), op(L^T) = L; Ks.T is Fortran order, solved in place
        B = Ks.T if overwrite else Ks.T.copy(order="F")
        Vt = dtrsm(1.0, self.L[j].T, B, lower=0, trans_a=1, overwrite_b=1).T
        return self.sf2[j] - np.einsum("mn,mn->m", Vt, Vt), Vt

    def _solve_bwd(self, j: int, Vt: np.ndarray) -> np.ndarray:
        """``((K + sn2 I)^-1 k*)^T = (L^-T L^-1 k*)^T`` ``(M, N)`` in place on ``Vt`` from ``_solve_fwd``."""
        return dtrsm(1.0, self.L[j].T, Vt.T, lower=0, trans_a=0, overwrite_b=1).T  # op(L^T) = L^T

    def _mean_grad(self, j: int, Ks: np.ndarray, Zq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scaled mean ``(M,)`` and its gradient ``(M, d)``: ``sum_i alpha_i k_i Lambda^-1 (z_i - z*)``
        as ``(Ks (alpha Z) - z* (Ks alpha)) / ell^2`` (one ``(M, N) x (N, d)`` matmul, no ``(M, N)`` temporary)."""
        a = self.alpha[j]
        m = Ks @ a
        return m, (Ks @ (a[:, None] * self.Z) - Zq * m[:, None]) / self.ell[j] ** 2

    def predict(self, Xq: np.ndarray, *, noisy: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(M, D)`` and latent variance ``(M, D)`` at physical inputs ``Xq (M, d)``, physical units.

        ``noisy=True`` adds the noise variance ``sn2 y_std^2`` (the variance of a new observation)."""
        Zq, ok = self._query(Xq)
        mean, var = _nan((len(ok), self.D)), _nan((len(ok), self.D))
        for j in range(self.D if len(Zq) else 0):
            Ks = self._kstar(j, Zq)
            mean[ok, j] = Ks @ self.alpha[j]
            v = np.maximum(self._solve_fwd(j, Ks, overwrite=True)[0], 0.0)  # Ks is not needed after this
            var[ok, j] = v + self.sn2[j] if noisy else v
        return mean * self.y_std + self.y_mean, var * self.y_std**2

    def predict_mean(self, Xq: np.ndarray) -> np.ndarray:
        """Mean ``(M, D)`` at physical inputs ``Xq (M, d)`` (physical units), ``O(D M N d)``."""
        Zq, ok = self._query(Xq)
        mean = _nan((len(ok), self.D))
        for j in range(self.D if len(Zq) else 0):
            mean[ok, j] = self._kstar(j, Zq) @ self.alpha[j]
        return mean * self.y_std + self.y_mean

    def mean_with_gradients(self, Xq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(M, D)`` and its input gradient ``(M, D, d)`` (physical units), ``O(D M N d)``.

        ``dm/dx* = sum_i alpha_i k(x_i, x*) Lambda^-1 (x_i - x*)`` (thesis eq. 4.1 without its factor -2)."""
        Zq, ok = self._query(Xq)
        mean, dmean = _nan((len(ok), self.D)), _nan((len(ok), self.D, self.d))
        for j in range(self.D if len(Zq) else 0):
            mean[ok, j], dmean[ok, j] = self._mean_grad(j, self._kstar(j, Zq), Zq)
        scale = self.y_std[:, None] / self.x_std[None, :]
        return mean * self.y_std + self.y_mean, dmean * scale

    def point_mean_with_gradients(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(D,)`` and its input gradient ``(D, d)`` at one physical input ``x (d,)`` (physical
        units): ``mean_with_gradients`` for one point, every output in one compiled call (numpy
        where no C compiler is available). NaN where ``x`` is not finite."""
        x = np.asarray(x, dtype=float).reshape(-1)
        if x.shape != (self.d,):
            raise ValueError(f"a query has {self.d} entries, got {x.shape}")
        if not np.all(np.isfinite(x)):
            return np.full(self.D, np.nan), np.full((self.D, self.d), np.nan)
        lib = _point_lib() if self.d <= 256 else None
        if lib is None:
            m, g = self.mean_with_gradients(x[None, :])
            return m[0], g[0]
        key = (self.Z, self.alpha, self.ell, self.sf2, self.x_mean, self.x_std, self.y_mean, self.y_std)
        pc = getattr(self, "_point_cache", None)
        if pc is None or not all(a is b for a, b in zip(pc[0], key)):
            Zs = np.ascontiguousarray(self.Z[None, :, :] / self.ell[:, None, :])
            keep = (Zs, np.ascontiguousarray(self.alpha), np.ascontiguousarray(self.sf2),
                    np.ascontiguousarray(1.0 / self.ell))
            z, m, g = np.empty(self.d), np.empty(self.D), np.empty((self.D, self.d))
            ptrs = [a.ctypes.data for a in (*keep, z, m, g)]
            pc = self._point_cache = (key, keep, z, m, g, ptrs, self.y_std[:, None] / self.x_std[None, :])
        _, _, z, m, g, ptrs, gscale = pc
        np.subtract(x, self.x_mean, out=z)
        z /= self.x_std
        lib.gp_point(self.N, self.d, self.D, *ptrs)
        return m * self.y_std + self.y_mean, g * gscale

    def predict_with_gradients(self, Xq: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Mean ``(M, D)``, latent variance ``(M, D)``, ``dmean (M, D, d)``, ``dvar (M, D, d)`` (physical units).

        ``dvar/dx* = -2 (dk*/dx*)^T (K + sn2 I)^-1 k*`` (thesis eq. 4.2). Cost per output: two
        in-place triangular solves (BLAS ``dtrsm``) with ``M`` right-hand sides against the
        Cholesky factor (``2 M N^2`` flops, the bulk), one ``exp`` of the ``(M, N)`` cross-kernel,
        matmuls ``(M, d + 2) x (d + 2, N)`` (kernel) and ``(M, N) x (N, <= d + 1)`` (mean, its
        gradient, the variance gradient). No explicit inverse: with the noise floor,
        ``cond(K + sn2 I)`` reaches ``1e11`` on fitted models and ``k*^T K^-1 k*`` from an explicit
        ``K^-1`` then loses the variance near the data entirely (``bench/gp_bench.py`` docstring)."""
        Zq, ok = self._query(Xq)
        M, D, d = len(ok), self.D, self.d
        mean, var = _nan((M, D)), _nan((M, D))
        dmean, dvar = _nan((M, D, d)), _nan((M, D, d))
        Z1 = np.hstack([self.Z, np.ones((self.N, 1))])
        for j in range(D if len(Zq) else 0):
            Ks = self._kstar(j, Zq)
            mean[ok, j], dmean[ok, j] = self._mean_grad(j, Ks, Zq)
            v, Vt = self._solve_fwd(j, Ks)
            var[ok, j] = np.maximum(v, 0.0)
            W = self._solve_bwd(j, Vt)
            W *= Ks  # W[m, i] = k*_i(x_m) ((K + sn2 I)^-1 k*(x_m))_i
            G = W @ Z1  # (M, d + 1): sum_i W z_i and sum_i W
            dvar[ok, j] = -2.0 * (G[:, :d] - Zq * G[:, d:]) / self.ell[j] ** 2
        scale = self.y_std[:, None] / self.x_std[None, :]
        return (mean * self.y_std + self.y_mean, var * self.y_std**2,
                dmean * scale, dvar * (scale * self.y_std[:, None]))

    # -- storage -------------------------------------------------------------------------
    def to_arrays(self, *, include_factor: bool = True) -> dict[str, np.ndarray]:
        """Plain arrays for ``np.savez`` (no pickle); with the factor ``L`` and ``alpha`` unless told not to.

        Without the factor (``D N^2`` doubles), ``from_arrays`` refactorizes: same predictions to
        rounding, not bit for bit."""
        out = {"Z": self.Z, "y": self.y, "ell": self.ell, "sf2": self.sf2, "sn2": self.sn2,
               "x_mean": self.x_mean, "x_std": self.x_std, "y_mean": self.y_mean, "y_std": self.y_std,
               "noise_floor": np.array(self.noise_floor)}
        if include_factor:
            out |= {"L": self.L, "alpha": self.alpha}
        return {k: np.array(v, copy=True) for k, v in out.items()}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> GPModel:
        """Inverse of ``to_arrays`` (uses the stored factor when present, else refactorizes)."""
        missing = {"Z", "y", "ell", "sf2", "sn2", "x_mean", "x_std", "y_mean", "y_std"} - set(arrays)
        if missing:
            raise ValueError(f"GP arrays lack {sorted(missing)}")
        g = {k: np.asarray(arrays[k], float) for k in arrays}
        self = cls.__new__(cls)
        self.Z, self.y = g["Z"].copy(), g["y"].copy()
        self.ell, self.sf2, self.sn2 = g["ell"].copy(), g["sf2"].copy(), g["sn2"].copy()
        self.x_mean, self.x_std = g["x_mean"].copy(), g["x_std"].copy()
        self.y_mean, self.y_std = g["y_mean"].copy(), g["y_std"].copy()
        self.noise_floor = float(g.get("noise_floor", NOISE_FLOOR))
        N, d, D = self.Z.shape[0], self.Z.shape[1], self.y.shape[1]
        if self.y.shape[0] != N or self.ell.shape != (D, d) or self.sf2.shape != (D,) or self.sn2.shape != (D,):
            raise ValueError("inconsistent GP array shapes")
        if "L" in g and "alpha" in g:
            if g["L"].shape != (D, N, N) or g["alpha"].shape != (D, N):
                raise ValueError("inconsistent GP factor shapes")
            self.L, self.alpha = g["L"].copy(), g["alpha"].copy()
        else:
            self._factorize()
        return self

    def copy(self) -> GPModel:
        """Deep copy."""
        return GPModel.from_arrays(self.to_arrays())


def _as_2d(A: np.ndarray, name: str) -> np.ndarray:
    A = np.asarray(A, dtype=float)
    if A.ndim != 2:
        raise ValueError(f"{name} must be 2-D, got shape {A.shape}")
    return A


def _nan(shape: tuple[int, ...]) -> np.ndarray:
    return np.full(shape, np.nan)
