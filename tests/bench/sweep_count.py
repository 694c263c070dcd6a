"""One step of the compiled sweep (``raico/planning/csweep.c`` on ``raico/planning/dense.c``) as scalar Python loops on counted
numbers: the kernels' loops with their index ranges (the triangles they skip, the products they take from the
block form), one scalar at a time instead of in register tiles, each ``+ - * / sqrt`` counted where it happens.

:func:`count` runs a part (forward message, backward message, belief, dynamics relinearization) on random
matrices of the right structure and returns the operations it took and its result, which the tests compare with
numpy's linear algebra (so the counted loops compute the messages) and whose count checks the formulas of
:mod:`bench.flops` (a literal count, not the formula again). The tiles of the kernels compute a few entries more
near the diagonal (a lower-order amount: ``O(n^2)`` per tile width); the count here is of the loops' own
operations, whose cubic term is the kernels'.
"""

from __future__ import annotations

import math

import numpy as np


class Tally:
    """The operations counted so far (``ops``)."""

    ops = 0


def _v(x) -> float:
    return x.v if isinstance(x, F) else float(x)


class F:
    """A float whose ``+ - * /`` each add one to :attr:`Tally.ops`."""

    __slots__ = ("v",)

    def __init__(self, v: float) -> None:
        self.v = float(v)

    @staticmethod
    def _op(r: float) -> F:
        Tally.ops += 1
        return F(r)

    def __add__(self, o) -> F:
        return F._op(self.v + _v(o))

    def __radd__(self, o) -> F:
        return F._op(_v(o) + self.v)

    def __sub__(self, o) -> F:
        return F._op(self.v - _v(o))

    def __rsub__(self, o) -> F:
        return F._op(_v(o) - self.v)

    def __mul__(self, o) -> F:
        return F._op(self.v * _v(o))

    def __rmul__(self, o) -> F:
        return F._op(_v(o) * self.v)

    def __truediv__(self, o) -> F:
        return F._op(self.v / _v(o))

    def __rtruediv__(self, o) -> F:
        return F._op(_v(o) / self.v)


def sqrt(x: F) -> F:
    return F._op(math.sqrt(x.v))


def mat(a) -> list[list[F]]:
    return [[F(v) for v in row] for row in np.atleast_2d(np.asarray(a, float))]


def arr(M) -> np.ndarray:
    return np.array([[_v(x) for x in row] for row in M])


def zeros(r: int, c: int) -> list[list[F]]:
    return [[F(0.0) for _ in range(c)] for _ in range(r)]


# ---------------------------------------------------------------- dense.c's kernels, scalar
def chol_u(A, n: int) -> None:
    """``A = R^T R`` in place, ``R`` upper (left-looking by rows; columns ``j >= i`` of row ``i``)."""
    for i in range(n):
        for p in range(i):
            f = A[p][i]
            for j in range(i, n):
                A[i][j] = A[i][j] - f * A[p][j]
        d = sqrt(A[i][i])
        A[i][i] = d
        inv = 1.0 / d
        for j in range(i + 1, n):
            A[i][j] = A[i][j] * inv


def solve_rt(R, n: int, B, c: int) -> None:
    """``B (n x c) <- R^-T B``, from the top."""
    for i in range(n):
        for p in range(i):
            f = R[p][i]
            for j in range(c):
                B[i][j] = B[i][j] - f * B[p][j]
        inv = 1.0 / R[i][i]
        for j in range(c):
            B[i][j] = B[i][j] * inv


def solve_r(R, n: int, B, c: int) -> None:
    """``B (n x c) <- R^-1 B``, from the bottom."""
    for i in range(n - 1, -1, -1):
        for p in range(i + 1, n):
            f = R[i][p]
            for j in range(c):
                B[i][j] = B[i][j] - f * B[p][j]
        inv = 1.0 / R[i][i]
        for j in range(c):
            B[i][j] = B[i][j] * inv


def trsv_rt(R, n: int, b) -> None:
    for k in range(n):
        v = b[k] / R[k][k]
        b[k] = v
        for i in range(k + 1, n):
            b[i] = b[i] - R[k][i] * v


def trsv_r(R, n: int, b) -> None:
    for i in range(n - 1, -1, -1):
        v = b[i]
        for k in range(i + 1, n):
            v = v - R[i][k] * b[k]
        b[i] = v / R[i][i]


def gemm(X, Y, a: int, r: int, c: int, C=None, transpose_x: bool = False):
    """``C (a x c) (+)= X Y`` (``X^T Y`` with ``transpose_x``), ``r`` the inner dimension: ``2 a r c``."""
    out = zeros(a, c) if C is None else C
    for i in range(a):
        for j in range(c):
            s = out[i][j]
            for k in range(r):
                s = s + (X[k][i] if transpose_x else X[i][k]) * Y[k][j]
            out[i][j] = s
    return out


def upper_tn(X, Y, n: int, r: int, C=None, k_from_diagonal: bool = False):
    """The upper triangle of ``C (n x n) (+)= X^T Y`` (``X``, ``Y``: ``r x n``), mirrored; ``k_from_diagonal``: the
    sum from ``k = j`` (``X``, ``Y`` lower triangular: ``spd_inverse``'s ``Y^T Y``)."""
    out = zeros(n, n) if C is None else C
    for i in range(n):
        for j in range(i, n):
            s = out[i][j]
            for k in range(j if k_from_diagonal else 0, r):
                s = s + X[k][i] * Y[k][j]
            out[i][j] = s
    for i in range(n):
        for j in range(i):
            out[i][j] = out[j][i]
    return out


def spd_inverse(R, n: int):
    """``A^-1 = R^-1 R^-T`` from ``A = R^T R``: ``Y = R^-T`` (lower, its zeros skipped), then ``Y^T Y``."""
    Y = zeros(n, n)
    for i in range(n):
        Y[i][i] = F(1.0)
        for p in range(i):
            f = R[p][i]
            for j in range(p + 1):
                Y[i][j] = Y[i][j] - f * Y[p][j]
        inv = 1.0 / R[i][i]
        for j in range(i + 1):
            Y[i][j] = Y[i][j] * inv
    return upper_tn(Y, Y, n, n, k_from_diagonal=True)


# ---------------------------------------------------------------- csweep.c's messages, scalar
def forward(SA0, RA0, A, Qbar, ae, n: int):
    """csweep.c ``forward`` (a dense ``C``): ``[S_t^-1 | S_t^-1 s_t]`` from ``[S^-1 | S^-1 s] + [R | r]``."""
    Pa = [[SA0[i][j] + RA0[i][j] if j >= i else F(0.0) for j in range(n + 1)] for i in range(n)]
    chol_u(Pa, n)
    W = [[A[j][i] for j in range(n)] for i in range(n)]          # A^T
    solve_rt(Pa, n, W, n)
    y = [Pa[i][n] for i in range(n)]
    trsv_rt(Pa, n, y)
    S = upper_tn(W, W, n, n, C=[list(r) for r in Qbar])
    tmp = [F(0.0) for _ in range(n)]
    for i in range(n):
        for j in range(n):
            tmp[j] = tmp[j] + y[i] * W[i][j]
    tmp = [tmp[j] + ae[j] for j in range(n)]
    chol_u(S, n)
    out = spd_inverse(S, n)
    for i in range(n):
        v = F(0.0)
        for j in range(n):
            v = v + out[i][j] * tmp[j]
        out[i].append(v)
    return out


def vstar(Pa, n: int, q: float):
    """``[V* | V* m']`` by the Cholesky route: ``(I + q P') V = [P' | p']``."""
    ss = F(0.0)
    for row in Pa:
        for x in row:
            ss = ss + x * x
    E = [[q * Pa[i][j] + (1.0 if i == j else 0.0) for j in range(n)] for i in range(n)]
    chol_u(E, n)
    Vs = [list(r) for r in Pa]
    solve_rt(E, n, Vs, n + 1)
    solve_r(E, n, Vs, n + 1)
    return Vs


def products_block(Vs, Ct, n: int, m: int, dt: float):
    """csweep.c ``backward_block``: ``FB = B^T [V* B | V* A | g]`` and ``FA = [A^T V* A | A^T g]`` from the velocity
    rows ``A_b``, ``B_b`` of ``C = [[B, A, -a]]`` (``A = J + e A_b``, ``B = e B_b``)."""
    K, h = m + n + 1, n // 2
    Bb = [Ct[h + k][:m] for k in range(h)]
    Ab = [Ct[h + k][m:m + n] for k in range(h)]
    Ve = [[dt * Vs[i][j] + Vs[i][h + j] for j in range(h)] for i in range(n)]
    g = []
    for i in range(n):
        v = Vs[i][n]
        for j in range(n):
            v = v + Vs[i][j] * Ct[j][m + n]
        g.append(v)
    E1 = [[dt * Ve[i][j] + Ve[h + i][j] for j in range(h)] for i in range(h)]
    Y = [EB + EZ + [F(0.0)] for EB, EZ in zip(gemm(E1, Bb, h, h, m), gemm(E1, Ab, h, h, n))]
    FA = upper_tn(Ab, [r[m:m + n] for r in Y], n, h)                       # A_b^T Z1
    T2 = gemm(Ve[:h], Ab, h, h, n)
    for i in range(h):
        for j in range(h):
            Y[i][m + j] = Y[i][m + j] + Ve[j][i]
        Y[i][m + n] = dt * g[i] + g[h + i]
    FB = gemm(Bb, Y, m, h, K, transpose_x=True)
    for i in range(n):
        if i < h:
            for j in range(i, h):
                FA[i][j] = FA[i][j] + (Vs[i][j] + T2[i][j] + T2[j][i])
            for j in range(h, n):
                FA[i][j] = FA[i][j] + T2[i][j]
        v = g[i] if i < h else F(0.0)
        for k in range(h):
            v = v + Ab[k][i] * Y[k][m + n]
        FA[i].append(v)
    for i in range(n):
        for j in range(i):
            FA[i][j] = FA[j][i]
    return FB, FA


def products_dense(Vs, Ct, n: int, m: int):
    """csweep.c ``backward``'s dense route: ``G = V* C``, ``FB = B^T G``, ``FA = A^T G[:, m:]``."""
    K = m + n + 1
    G = gemm(Vs, Ct, n, n + 1, K)
    FB = gemm(Ct, G, m, n, K, transpose_x=True)
    FA = gemm([r[m:m + n] for r in Ct], [r[m:] for r in G], n, n, n + 1, transpose_x=True)
    return FB, FA


def control(FB, FA, H, hv, n: int, m: int):
    """csweep.c ``backward`` after the products: the ``m x m`` factor, its two solves, ``Kmat^T Kmat``: the
    controller ``Z = [-O_t | o_t]`` and the message ``[V_t^-1 | V_t^-1 v_t]``."""
    for i in range(m):
        for j in range(m):
            FB[i][j] = FB[i][j] + H[i][j]
        FB[i][m + n] = FB[i][m + n] + hv[i]
    chol_u(FB, m)
    Kmat = [r[m:] for r in FB]
    solve_rt(FB, m, Kmat, n + 1)
    Z = [list(r) for r in Kmat]
    solve_r(FB, m, Z, n + 1)
    KK = upper_tn(Kmat, Kmat, n, m)
    kc = [F(0.0) for _ in range(n)]
    for k in range(m):
        for i in range(n):
            kc[i] = kc[i] + Kmat[k][n] * Kmat[k][i]
    out = [[0.5 * (FA[i][j] + FA[j][i]) - KK[i][j] for j in range(n)] + [FA[i][n] - kc[i]] for i in range(n)]
    return out, Z


def belief(SA, VA, RA, n: int):
    """csweep.c ``belief``: the mean ``b_t`` of ``S^-1 + V^-1 + R`` by its factor and two triangular solves."""
    Ba = [[SA[i][j] + VA[i][j] + RA[i][j] if j >= i else F(0.0) for j in range(n + 1)] for i in range(n)]
    b = [Ba[i][n] for i in range(n)]
    chol_u(Ba, n)
    trsv_rt(Ba, n, b)
    trsv_r(Ba, n, b)
    return b


def relin_block(Ct, Hinv, hv, a, n: int, m: int, dt: float, q: float):
    """csweep.c ``relin_dyn``'s block form: ``Qbar = e D e^T + q I`` with ``D = B_b H^-1 B_b^T`` (its upper
    triangle), ``a_eff = a + e (B_b H^-1 h)``."""
    h = n // 2
    Bb = [Ct[h + k][:m] for k in range(h)]
    BHi = gemm(Bb, Hinv, h, m, m)
    Bt = [[Bb[k][j] for k in range(h)] for j in range(m)]
    D = upper_tn([[BHi[i][k] for i in range(h)] for k in range(m)], Bt, h, m)
    Qb = zeros(n, n)
    bh = []
    for i in range(h):
        for j in range(h):
            d = D[i][j]
            dd = dt * d
            Qb[i][j], Qb[i][h + j], Qb[h + i][j], Qb[h + i][h + j] = dt * dd, dd, dd, d
        u = F(0.0)
        for k in range(m):
            u = u + BHi[i][k] * hv[k]
        bh.append(u)
    ae = [a[i] + dt * bh[i] for i in range(h)] + [a[h + i] + bh[i] for i in range(h)]
    for i in range(n):
        Qb[i][i] = Qb[i][i] + q
    return Qb, ae


def relin_dense(B, Hinv, hv, a, n: int, m: int, q: float):
    """csweep.c ``relin_dyn`` for other models: ``B H^-1`` and the whole ``B H^-1 B^T`` by loops."""
    BHi = gemm(B, Hinv, n, m, m)
    Qb = zeros(n, n)
    ae = []
    for i in range(n):
        for j in range(n):
            v = F(0.0)
            for k in range(m):
                v = v + BHi[i][k] * B[j][k]
            Qb[i][j] = v + (q if i == j else 0.0)
        v = F(0.0)
        for k in range(m):
            v = v + BHi[i][k] * hv[k]
        ae.append(a[i] + v)
    return Qb, ae


# ---------------------------------------------------------------- a step on random numbers
def _spd(rng: np.random.Generator, n: int) -> np.ndarray:
    G = rng.standard_normal((n, n))
    return G @ G.T / n + np.eye(n)


def step_data(n_joints: int, seed: int = 0) -> dict:
    """Random matrices of one step: ``N = 2 n`` states, ``m = n`` controls, a block-form ``C`` (``dt = 0.01``), SPD
    messages and costs, the process noise ``q`` of R-AICO's default."""
    rng = np.random.default_rng(seed)
    n, m, h, dt = 2 * n_joints, n_joints, n_joints, 0.01
    Ab, Bb = 0.3 * rng.standard_normal((h, n)), 0.3 * rng.standard_normal((h, m))
    e = np.vstack([dt * np.eye(h), np.eye(h)])
    J = np.zeros((n, n))
    J[:h, :h] = np.eye(h)
    A, B, a = J + e @ Ab, e @ Bb, rng.standard_normal(n)
    Ct = np.vstack([np.hstack([B, A, -a[:, None]]), np.eye(1, n + m + 1, n + m)])   # [[B, A, -a], [0, 0, 1]]
    msg = [np.hstack([_spd(rng, n), rng.standard_normal((n, 1))]) for _ in range(4)]
    H = _spd(rng, m)
    return {"n": n, "m": m, "dt": dt, "q": 1e-3, "A": A, "B": B, "a": a, "Ct": Ct, "SA": msg[0], "VA": msg[1],
            "RA": msg[2], "P1": msg[3], "H": H, "Hinv": np.linalg.inv(H), "hv": rng.standard_normal(m),
            "Qbar": _spd(rng, n), "ae": rng.standard_normal(n)}


def count(part: str, d: dict, block: bool = True) -> tuple[int, object]:
    """The operations of ``part`` (``forward``, ``backward``, ``belief``, ``relinearization``) on step data ``d``
    (:func:`step_data`) and its result (numpy arrays); ``block``: the block form's products (else the dense)."""
    n, m = d["n"], d["m"]
    args = {k: mat(v) for k, v in d.items() if isinstance(v, np.ndarray) and v.ndim == 2}
    vec = {k: [F(x) for x in v] for k, v in d.items() if isinstance(v, np.ndarray) and v.ndim == 1}
    Tally.ops = 0
    if part == "forward":
        out = arr(forward(args["SA"], args["RA"], args["A"], args["Qbar"], vec["ae"], n))
    elif part == "backward":
        Vs = vstar(args["P1"], n, d["q"])
        FB, FA = (products_block(Vs, args["Ct"], n, m, d["dt"]) if block
                  else products_dense(Vs, args["Ct"], n, m))
        V, Z = control(FB, FA, args["H"], vec["hv"], n, m)
        out = (arr(V), arr(Z))
    elif part == "belief":
        out = np.array([x.v for x in belief(args["SA"], args["VA"], args["RA"], n)])
    elif part == "relinearization":
        Qb, ae = (relin_block(args["Ct"], args["Hinv"], vec["hv"], vec["a"], n, m, d["dt"], d["q"]) if block
                  else relin_dense(args["B"], args["Hinv"], vec["hv"], vec["a"], n, m, d["q"]))
        out = (arr(Qb), np.array([x.v for x in ae]))
    else:
        raise ValueError(part)
    return Tally.ops, out
