
/* ---- driver (raico/plants/fast_analytic.py): the AnalyticDynamics formulas on the generated code ----
 * Accepted shapes (raico/plants/fast_analytic.py: _CompiledStep checks them before any call): 1 <= n <= MP
 * planning coordinates (the work arrays below are sized by MP); x (2 n), u (n), A (2 n, 2 n),
 * aff (2 n), B (2 n, n); the batches T >= 0 steps: X (T, 2 n), U (T, n), A (T, 2 n, 2 n), aff (T, 2 n),
 * B (T, 2 n, n); the rollout x0 (2 n), o (T, n), O (T, n, 2 n), X (T + 1, 2 n), U (T, n). */
typedef struct {
    int n;               /* planning dofs n_q */
    int identity;        /* P is the identity */
    double dt;
    const double *P;     /* (MP, n) row-major */
} dyn_ctx;

/* plant <- planning: out (MP) = P z (n) */
static void to_plant(const dyn_ctx *c, const double *z, double *out)
{
    if (c->identity) { memcpy(out, z, sizeof(double) * MP); return; }
    for (int i = 0; i < MP; i++) {
        double s = 0.0;
        for (int j = 0; j < c->n; j++) s += c->P[i * c->n + j] * z[j];
        out[i] = s;
    }
}

#ifdef TREE_DYN
/* The tree's route: the reductions by P's nonzeros (a selection of the plant's joints, coupled ones
 * summed: one or two per column), O(MP (MP + n)) instead of O(MP^2 n). */

/* the nonzeros of P (MP x n) row by row: rows rk, columns ci, values pv; their count */
static int p_nonzeros(const dyn_ctx *c, int *rk, int *ci, double *pv)
{
    int nz = 0;
    for (int k = 0; k < MP; k++)
        for (int i = 0; i < c->n; i++) {
            double p = c->P[k * c->n + i];
            if (p != 0.0) { rk[nz] = k; ci[nz] = i; pv[nz] = p; nz++; }
        }
    return nz;
}

/* Y (n x cols, row stride ldy) = P^T X (X: MP x cols, row stride ldx) */
static void pt_times(int nz, const int *rk, const int *ci, const double *pv, int n, int cols,
                     const double *X, int ldx, double *Y, int ldy)
{
    for (int i = 0; i < n; i++) for (int j = 0; j < cols; j++) Y[i * ldy + j] = 0.0;
    for (int e = 0; e < nz; e++) {
        const double *x = X + rk[e] * ldx;
        double *y = Y + ci[e] * ldy, p = pv[e];
        for (int j = 0; j < cols; j++) y[j] += p * x[j];
    }
}

/* Y (rows x n, row stride ldy) = X P (X: rows x MP, row stride ldx) */
static void times_p(int nz, const int *rk, const int *ci, const double *pv, int n, int rows,
                    const double *X, int ldx, double *Y, int ldy)
{
    for (int r = 0; r < rows; r++) {
        double *y = Y + r * ldy;
        const double *x = X + r * ldx;
        for (int j = 0; j < n; j++) y[j] = 0.0;
        for (int e = 0; e < nz; e++) y[ci[e]] += pv[e] * x[rk[e]];
    }
}

/* M_r = P^T M P (n x n), h_r = P^T h (n) from the plant's M (MP x MP), h (MP) */
static void reduce_mh(const dyn_ctx *c, const double *M, const double *h, double *Mr, double *hr)
{
    int n = c->n, rk[MP * MP], ci[MP * MP];
    double pv[MP * MP], MPm[MP * MP];   /* M P (MP x n) */
    if (c->identity) { memcpy(Mr, M, sizeof(double) * MP * MP); memcpy(hr, h, sizeof(double) * MP); return; }
    int nz = p_nonzeros(c, rk, ci, pv);
    times_p(nz, rk, ci, pv, n, MP, M, MP, MPm, n);
    pt_times(nz, rk, ci, pv, n, n, MPm, n, Mr, n);
    pt_times(nz, rk, ci, pv, n, 1, h, 1, hr, 1);
}

/* D_r = [P^T Dq P, P^T Dv P] (n x 2n) from the plant's D = [Dq, Dv] (MP x 2 MP) */
static void reduce_D(const dyn_ctx *c, const double *D, double *Dr)
{
    int n = c->n, rk[MP * MP], ci[MP * MP];
    double pv[MP * MP], DP[MP * 2 * MP];   /* [Dq P, Dv P] (MP x 2n) */
    if (c->identity) { memcpy(Dr, D, sizeof(double) * 2 * MP * MP); return; }
    int nz = p_nonzeros(c, rk, ci, pv);
    times_p(nz, rk, ci, pv, n, MP, D, 2 * MP, DP, 2 * n);
    times_p(nz, rk, ci, pv, n, MP, D + MP, 2 * MP, DP + n, 2 * n);
    pt_times(nz, rk, ci, pv, n, 2 * n, DP, 2 * n, Dr, 2 * n);
}
#else
/* M_r = P^T M P (n x n), h_r = P^T h (n) from the plant's M (MP x MP), h (MP) */
static void reduce_mh(const dyn_ctx *c, const double *M, const double *h, double *Mr, double *hr)
{
    int n = c->n;
    if (c->identity) { memcpy(Mr, M, sizeof(double) * MP * MP); memcpy(hr, h, sizeof(double) * MP); return; }
    double MP_[MP * MP];   /* M P (MP x n) */
    for (int i = 0; i < MP; i++)
        for (int j = 0; j < n; j++) {
            double s = 0.0;
            for (int k = 0; k < MP; k++) s += M[i * MP + k] * c->P[k * n + j];
            MP_[i * n + j] = s;
        }
    for (int i = 0; i < n; i++) {
        for (int j = 0; j < n; j++) {
            double s = 0.0;
            for (int k = 0; k < MP; k++) s += c->P[k * n + i] * MP_[k * n + j];
            Mr[i * n + j] = s;
        }
        double s = 0.0;
        for (int k = 0; k < MP; k++) s += c->P[k * n + i] * h[k];
        hr[i] = s;
    }
}
#endif

/* LU with partial pivoting of the n x n matrix a (overwritten); piv (n). */
static void lu(int n, double *a, int *piv)
{
    for (int k = 0; k < n; k++) {
        int p = k;
        double best = fabs(a[k * n + k]);
        for (int i = k + 1; i < n; i++) if (fabs(a[i * n + k]) > best) { best = fabs(a[i * n + k]); p = i; }
        piv[k] = p;
        if (p != k) for (int j = 0; j < n; j++) { double t = a[k * n + j]; a[k * n + j] = a[p * n + j]; a[p * n + j] = t; }
        double d = a[k * n + k];
        for (int i = k + 1; i < n; i++) {
            double l = a[i * n + k] / d;
            a[i * n + k] = l;
            for (int j = k + 1; j < n; j++) a[i * n + j] -= l * a[k * n + j];
        }
    }
}

/* solve (LU from lu) x = b in place */
static void lu_solve(int n, const double *a, const int *piv, double *b)
{
    for (int k = 0; k < n; k++) if (piv[k] != k) { double t = b[k]; b[k] = b[piv[k]]; b[piv[k]] = t; }
    for (int i = 0; i < n; i++) { double s = b[i]; for (int j = 0; j < i; j++) s -= a[i * n + j] * b[j]; b[i] = s; }
    for (int i = n - 1; i >= 0; i--) { double s = b[i]; for (int j = i + 1; j < n; j++) s -= a[i * n + j] * b[j]; b[i] = s / a[i * n + i]; }
}

/* inverse (n x n) of a (destroyed) */
static void inverse(int n, double *a, double *inv)
{
    int piv[MP];
    double col[MP];
    lu(n, a, piv);
    for (int j = 0; j < n; j++) {
        for (int i = 0; i < n; i++) col[i] = (i == j) ? 1.0 : 0.0;
        lu_solve(n, a, piv, col);
        for (int i = 0; i < n; i++) inv[i * n + j] = col[i];
    }
}

/* qddot (n) at x = (q, v), u: M_r^-1 (u - h_r) */
int dyn_mh(const dyn_ctx *c, const double *x, double *Mr, double *hr);
int dyn_qddot(const dyn_ctx *c, const double *x, const double *u, double *qdd)
{
    int n = c->n, piv[MP];
    double Mr[MP * MP], hr[MP];
    dyn_mh(c, x, Mr, hr);
    for (int i = 0; i < n; i++) qdd[i] = u[i] - hr[i];
    lu(n, Mr, piv);
    lu_solve(n, Mr, piv, qdd);
    return 0;
}

/* one semi-implicit Euler step: xn (2n) */
int dyn_step(const dyn_ctx *c, const double *x, const double *u, double *xn)
{
    int n = c->n;
    double qdd[MP];
    dyn_qddot(c, x, u, qdd);
    for (int i = 0; i < n; i++) {
        double v1 = x[n + i] + c->dt * qdd[i];
        xn[n + i] = v1;
        xn[i] = x[i] + c->dt * v1;
    }
    return 0;
}

/* M_r (n x n), h_r (n) at x = (q, v) */
int dyn_mh(const dyn_ctx *c, const double *x, double *Mr, double *hr)
{
    double xs[2 * MP], out[MP * MP + MP];
    to_plant(c, x, xs);
    to_plant(c, x + c->n, xs + MP);
    gen_mh(xs, out);
    reduce_mh(c, out, out + MP * MP, Mr, hr);
    return 0;
}

#ifdef TREE_DYN
/* The kinematic tree's route (raico/plants/codegen/rbd_kernels.c): M and h by the first pass of the analytical
 * inverse-dynamics derivatives, M_r^-1 from the Cholesky factor of M_r (LU where M_r is not positive
 * definite), dID/d(q, v) at a = qddot by the second pass. */

/* the Cholesky factor L (lower triangle of a, in place) of the n x n matrix a: 0, or -1 where a pivot
 * is not positive. Right-looking: after column j, the rows below take its outer product off their
 * trailing part (row-wise updates that vectorize, no dependent sums). */
static int chol(int n, double *a)
{
    double col[MP];
    for (int j = 0; j < n; j++) {
        double d = a[j * n + j];
        if (!(d > 0.0)) return -1;
        d = sqrt(d);
        a[j * n + j] = d;
        for (int i = j + 1; i < n; i++) col[i] = a[i * n + j] /= d;
        for (int i = j + 1; i < n; i++) {
            double l = col[i], *row = a + i * n;
            for (int k = j + 1; k <= i; k++) row[k] -= l * col[k];
        }
    }
    return 0;
}

/* C (r x c, row stride ldc) = sum over k < K of A_ik B_kj, with A_ik = A[i lda + k] (trans = 0) or
 * A[k lda + i] (trans = 1), B (K x c, row stride ldb); from k = k0(i) = (lower ? i : 0) on (lower:
 * A_ik = 0 for k < i). Every entry is summed in the order of k, as the scalar loop does; two rows at a
 * time, the columns in blocks of 16 and 4 (vectors of 4 doubles) with a scalar tail. */
typedef double v4d __attribute__((vector_size(32)));
static inline v4d ld4(const double *p) { v4d v; memcpy(&v, p, sizeof v); return v; }
static inline void st4(double *p, v4d v) { memcpy(p, &v, sizeof v); }

static void gemm_rows(int r, int c, int K, const double *A, int lda, int trans, int lower,
                      const double *B, int ldb, double *C, int ldc)
{
#define A_(i, k) (trans ? A[(long)(k) * lda + (i)] : A[(long)(i) * lda + (k)])
    int i = 0;
    for (; i + 2 <= r; i += 2) {   /* two rows at once: 8 independent sums of 4 */
        double *C0 = C + (long)i * ldc, *C1 = C0 + ldc;
        int k0 = lower ? i : 0, j = 0;   /* lower: row i + 1 adds A_(i+1, i) = 0 first, exactly */
        for (; j + 16 <= c; j += 16) {
            v4d z = {0.0, 0.0, 0.0, 0.0}, a0 = z, a1 = z, a2 = z, a3 = z, b0 = z, b1 = z, b2 = z, b3 = z;
            for (int k = k0; k < K; k++) {
                double x = A_(i, k), y = A_(i + 1, k);
                v4d xv = {x, x, x, x}, yv = {y, y, y, y};
                const double *Bk = B + (long)k * ldb + j;
                v4d B0 = ld4(Bk), B1 = ld4(Bk + 4), B2 = ld4(Bk + 8), B3 = ld4(Bk + 12);
                a0 += xv * B0; a1 += xv * B1; a2 += xv * B2; a3 += xv * B3;
                b0 += yv * B0; b1 += yv * B1; b2 += yv * B2; b3 += yv * B3;
            }
            st4(C0 + j, a0); st4(C0 + j + 4, a1); st4(C0 + j + 8, a2); st4(C0 + j + 12, a3);
            st4(C1 + j, b0); st4(C1 + j + 4, b1); st4(C1 + j + 8, b2); st4(C1 + j + 12, b3);
        }
        for (; j + 4 <= c; j += 4) {
            v4d a0 = {0.0, 0.0, 0.0, 0.0}, b0 = a0;
            for (int k = k0; k < K; k++) {
                double x = A_(i, k), y = A_(i + 1, k);
                v4d xv = {x, x, x, x}, yv = {y, y, y, y}, Bv = ld4(B + (long)k * ldb + j);
                a0 += xv * Bv; b0 += yv * Bv;
            }
            st4(C0 + j, a0); st4(C1 + j, b0);
        }
        for (; j < c; j++) {
            double s0 = 0.0, s1 = 0.0;
            for (int k = k0; k < K; k++) { double b = B[(long)k * ldb + j]; s0 += A_(i, k) * b; s1 += A_(i + 1, k) * b; }
            C0[j] = s0; C1[j] = s1;
        }
    }
    for (; i < r; i++) {
        double *Ci = C + (long)i * ldc;
        int k0 = lower ? i : 0, j = 0;
        for (; j + 4 <= c; j += 4) {
            v4d a0 = {0.0, 0.0, 0.0, 0.0};
            for (int k = k0; k < K; k++) {
                double x = A_(i, k);
                v4d xv = {x, x, x, x};
                a0 += xv * ld4(B + (long)k * ldb + j);
            }
            st4(Ci + j, a0);
        }
        for (; j < c; j++) {
            double s0 = 0.0;
            for (int k = k0; k < K; k++) s0 += A_(i, k) * B[(long)k * ldb + j];
            Ci[j] = s0;
        }
    }
#undef A_
}

/* Mi (n x n) = (L L^T)^-1 = L^-T L^-1 from the factor L (lower triangle of a) */
static void chol_inverse(int n, const double *a, double *Mi)
{
    double Li[MP * MP];   /* L^-1, lower (zeros above), row by row: row i = (e_i - sum_k<i L_ik row k) / L_ii */
    for (int i = 0; i < n; i++) {
        double *row = Li + i * n;
        for (int j = 0; j < n; j++) row[j] = 0.0;
        row[i] = 1.0;
        for (int k = 0; k < i; k++) {
            double l = a[i * n + k];
            const double *rk = Li + k * n;
            for (int j = 0; j <= k; j++) row[j] -= l * rk[j];
        }
        double d = a[i * n + i];
        for (int j = 0; j <= i; j++) row[j] /= d;
    }
    gemm_rows(n, n, n, Li, n, 1, 1, Li, n, Mi, n);   /* Mi_ij = sum_k>=i (L^-1)_ki (L^-1)_kj */
}

int dyn_derivatives(const dyn_ctx *c, const double *x, const double *u, double *a, double *F, double *Mi)
{
    int n = c->n, N = 2 * n;
    double xs[2 * MP], M[MP * MP], h[MP], Mr[MP * MP], hr[MP], ap[MP], D[2 * MP * MP], Dr[MP * 2 * MP];
    to_plant(c, x, xs);
    to_plant(c, x + n, xs + MP);
    tree_pass1(xs, xs + MP, 1, &TREE_W, M, h);
    reduce_mh(c, M, h, Mr, hr);
    if (chol(n, Mr) == 0) chol_inverse(n, Mr, Mi);
    else {
        reduce_mh(c, M, h, Mr, hr);
        inverse(n, Mr, Mi);
    }
    for (int i = 0; i < n; i++) {
        double s = 0.0;
        for (int j = 0; j < n; j++) s += Mi[i * n + j] * (u[j] - hr[j]);
        a[i] = s;
    }
    to_plant(c, a, ap);
    tree_pass2(&TREE_W, xs + MP, ap, NULL, D);
    reduce_D(c, D, Dr);
    gemm_rows(n, N, n, Mi, n, 0, 0, Dr, N, F, N);   /* F = -M_r^-1 D_r */
    for (int i = 0; i < n * N; i++) F[i] = -F[i];
    return 0;
}
#else
/* D_r = [P^T Dq P, P^T Dv P] (n x 2n) from the plant's D = [Dq, Dv] (MP x 2 MP) */
static void reduce_D(const dyn_ctx *c, const double *D, double *Dr)
{
    int n = c->n, N = 2 * n;
    if (c->identity) { memcpy(Dr, D, sizeof(double) * 2 * MP * MP); return; }
    for (int i = 0; i < n; i++)
        for (int half = 0; half < 2; half++)
            for (int j = 0; j < n; j++) {
                double s = 0.0;
                for (int k = 0; k < MP; k++) {
                    double pk = c->P[k * n + i];
                    if (pk == 0.0) continue;
                    for (int l = 0; l < MP; l++) s += pk * D[k * 2 * MP + half * MP + l] * c->P[l * n + j];
                }
                Dr[i * N + half * n + j] = s;
            }
}

/* qddot a (n), d qddot / d(q, v) F (n x 2n), M_r^-1 Mi (n x n) at (x, u) */
int dyn_derivatives(const dyn_ctx *c, const double *x, const double *u, double *a, double *F, double *Mi)
{
    int n = c->n, N = 2 * n;
    double xs[2 * MP], out[MP * MP + MP], carry[NCARRY > 0 ? NCARRY : 1], Mr[MP * MP], hr[MP];
    double ys[MP + (NCARRY > 0 ? NCARRY : 1)], D[2 * MP * MP], Dr[MP * 2 * MP];
    to_plant(c, x, xs);
    to_plant(c, x + n, xs + MP);
    gen_first(xs, out, carry);
    reduce_mh(c, out, out + MP * MP, Mr, hr);
    inverse(n, Mr, Mi);
    for (int i = 0; i < n; i++) {
        double s = 0.0;
        for (int j = 0; j < n; j++) s += Mi[i * n + j] * (u[j] - hr[j]);
        a[i] = s;
    }
    to_plant(c, a, ys);
    for (int k = 0; k < NCARRY; k++) ys[MP + k] = carry[k];
    gen_second(ys, D);
    reduce_D(c, D, Dr);
    for (int i = 0; i < n; i++)
        for (int j = 0; j < N; j++) {
            double s = 0.0;
            for (int k = 0; k < n; k++) s += Mi[i * n + k] * Dr[k * N + j];
            F[i * N + j] = -s;
        }
    return 0;
}

#endif

/* A (2n x 2n), aff (2n), B (2n x n) of the step at (x, u) (AnalyticDynamics.linearize) */
int dyn_linearize(const void *cv, const double *x, const double *u, double *A, double *aff, double *B)
{
    const dyn_ctx *c = (const dyn_ctx *)cv;
    int n = c->n, N = 2 * n;
    double dt = c->dt;
    double Mi[MP * MP], a[MP], F[MP * 2 * MP];
    dyn_derivatives(c, x, u, a, F, Mi);
    for (int i = 0; i < n; i++) {
        for (int j = 0; j < N; j++) A[(n + i) * N + j] = F[i * N + j] * dt;
        A[(n + i) * N + n + i] += 1.0;
    }
    for (int i = 0; i < n; i++) {
        for (int j = 0; j < N; j++) A[i * N + j] = A[(n + i) * N + j] * dt;
        A[i * N + i] += 1.0;
    }
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            double b = Mi[i * n + j] * dt;
            B[(n + i) * n + j] = b;
            B[i * n + j] = b * dt;
        }
    for (int i = 0; i < n; i++) {
        double s = a[i], fx = 0.0, mu = 0.0;
        for (int j = 0; j < N; j++) fx += F[i * N + j] * x[j];
        for (int j = 0; j < n; j++) mu += Mi[i * n + j] * u[j];
        s = s - fx - mu;
        aff[i] = (dt * dt) * s;
        aff[n + i] = dt * s;
    }
    return 0;
}

int dyn_linearize_batch(const dyn_ctx *c, int T, const double *X, const double *U, double *A, double *aff, double *B)
{
    int n = c->n, N = 2 * n;
    for (int t = 0; t < T; t++)
        dyn_linearize(c, X + (long)t * N, U + (long)t * n, A + (long)t * N * N, aff + (long)t * N, B + (long)t * N * n);
    return 0;
}

/* X (T+1, 2n), U (T, n) of u_t = o_t + O_t x_t rolled out from x0 */
int dyn_controller_rollout(const dyn_ctx *c, int T, const double *x0, const double *o, const double *O, double *X, double *U)
{
    int n = c->n, N = 2 * n;
    memcpy(X, x0, sizeof(double) * N);
    for (int t = 0; t < T; t++) {
        const double *x = X + (long)t * N;
        double *u = U + (long)t * n;
        for (int i = 0; i < n; i++) {
            double s = 0.0;
            const double *row = O + ((long)t * n + i) * N;
            for (int j = 0; j < N; j++) s += row[j] * x[j];
            u[i] = o[(long)t * n + i] + s;
        }
        dyn_step(c, x, u, X + (long)(t + 1) * N);
    }
    return 0;
}

/* the function pointer the AICO sweep kernel calls */
void *dyn_linearize_address(void) { return (void *)&dyn_linearize; }
