/* iLQG's backward pass (raico/planning/ilqg.py: _backward) in C: the same formulas in the same order per
 * step, without numpy's per-call overhead (at T = 1000 steps of a 10-state arm the numpy loop spends
 * ~57 us a step in a dozen small products). Row-major arrays, numpy's layout:
 * A (T, n, n), B (T, n, m), lx (T+1, n), lxx (T+1, n, n), lu (T, m), luu (T, m, m);
 * out k (T, m), K (T, m, n), dV (2). The regularized Q_uu (with mu: luu + (B^T Vxx + mu B^T) B)
 * is symmetrized and factored by Cholesky; returns 0, or t + 1 when it is not positive definite at
 * step t (the caller raises its regularization). Results equal the numpy code's to rounding
 * (tests/planning/test_solvers_lq.py compares them).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* C (r x c) = X^T (r x s)^T ... helpers on row-major matrices */
static void at_b(int s, int r, int c, const double *X, const double *Y, double *C)   /* C = X^T Y, X (s,r), Y (s,c) */
{
    memset(C, 0, sizeof(double) * r * c);
    for (int k = 0; k < s; k++)
        for (int i = 0; i < r; i++) {
            double x = X[k * r + i];
            for (int j = 0; j < c; j++) C[i * c + j] += x * Y[k * c + j];
        }
}

static void a_b(int r, int s, int c, const double *X, const double *Y, double *C)     /* C = X Y, X (r,s), Y (s,c) */
{
    memset(C, 0, sizeof(double) * r * c);
    for (int i = 0; i < r; i++)
        for (int k = 0; k < s; k++) {
            double x = X[i * s + k];
            for (int j = 0; j < c; j++) C[i * c + j] += x * Y[k * c + j];
        }
}

static void at_v(int s, int r, const double *X, const double *v, double *out)          /* out = X^T v, X (s,r) */
{
    memset(out, 0, sizeof(double) * r);
    for (int k = 0; k < s; k++)
        for (int i = 0; i < r; i++) out[i] += X[k * r + i] * v[k];
}

/* lower Cholesky in place (row-major, lower triangle used): 0, or 1 if not positive definite */
static int chol_l(int m, double *S)
{
    for (int j = 0; j < m; j++) {
        double d = S[j * m + j];
        for (int k = 0; k < j; k++) d -= S[j * m + k] * S[j * m + k];
        if (!(d > 0.0) || !isfinite(d)) return 1;
        d = sqrt(d);
        S[j * m + j] = d;
        for (int i = j + 1; i < m; i++) {
            double v = S[i * m + j];
            for (int k = 0; k < j; k++) v -= S[i * m + k] * S[j * m + k];
            S[i * m + j] = v / d;
        }
    }
    return 0;
}

/* X (m, c) <- S^-1 X with S = L L^T (L from chol_l) */
static void chol_solve(int m, int c, const double *L, double *X)
{
    for (int i = 0; i < m; i++)
        for (int j = 0; j < c; j++) {
            double v = X[i * c + j];
            for (int k = 0; k < i; k++) v -= L[i * m + k] * X[k * c + j];
            X[i * c + j] = v / L[i * m + i];
        }
    for (int i = m - 1; i >= 0; i--)
        for (int j = 0; j < c; j++) {
            double v = X[i * c + j];
            for (int k = i + 1; k < m; k++) v -= L[k * m + i] * X[k * c + j];
            X[i * c + j] = v / L[i * m + i];
        }
}

/* Accepted shapes (raico/planning/ilqg.py: _backward checks them before the call and raises ValueError):
 * T >= 1, n >= 1, m >= 1, every array C-contiguous float64 of the shape above; any m relative to n
 * (more controls than states included). Returns -1 when the work buffer cannot be allocated or a
 * size is out of range. */
int ilqg_backward(long T, long n_, long m_, const double *A, const double *B, const double *lx, const double *lxx,
                  const double *lu, const double *luu, double mu, double *k, double *K, double *dV)
{
    if (T < 1 || n_ < 1 || m_ < 1 || n_ > 4096 || m_ > 4096) return -1;
    int n = (int)n_, m = (int)m_;
    /* Vx, Qx (n); Qu (m); Vxx, VA, Qxx, Vn (n n); BtV, Qux, BtVr, Quxr, Bt (m n); Quu, QuuF, S (m m);
     * rhs (m (n + 1)); KtQuu (n m); tmp (m) */
    size_t need = (size_t)(2 * n + m + 4 * n * n + 5 * m * n + 3 * m * m + m * (n + 1) + n * m + m);
    double *w = (double *)malloc(sizeof(double) * need);
    if (!w) return -1;
    double *Vx = w, *Qx = Vx + n, *Qu = Qx + n, *Vxx = Qu + m, *VA = Vxx + n * n, *Qxx = VA + n * n,
           *Vn = Qxx + n * n, *BtV = Vn + n * n, *Qux = BtV + m * n, *BtVr = Qux + m * n, *Quxr = BtVr + m * n,
           *Bt = Quxr + m * n, *Quu = Bt + m * n, *QuuF = Quu + m * m, *S = QuuF + m * m, *rhs = S + m * m,
           *KtQuu = rhs + m * (n + 1), *tmp = KtQuu + n * m;
    int rc = 0;
    dV[0] = dV[1] = 0.0;
    memcpy(Vx, lx + (long)T * n, sizeof(double) * n);
    memcpy(Vxx, lxx + (long)T * n * n, sizeof(double) * n * n);
    for (long t = T - 1; t >= 0; t--) {
        const double *At = A + t * n * n, *Btn = B + t * n * m;
        at_v(n, n, At, Vx, Qx);
        for (int i = 0; i < n; i++) Qx[i] += lx[t * n + i];
        at_v(n, m, Btn, Vx, Qu);
        for (int i = 0; i < m; i++) Qu[i] += lu[t * m + i];
        a_b(n, n, n, Vxx, At, VA);
        at_b(n, n, n, At, VA, Qxx);
        for (int i = 0; i < n * n; i++) Qxx[i] += lxx[t * n * n + i];
        at_b(n, m, n, Btn, Vxx, BtV);                   /* B^T Vxx (m, n) */
        a_b(m, n, m, BtV, Btn, Quu);
        for (int i = 0; i < m * m; i++) Quu[i] += luu[t * m * m + i];
        a_b(m, n, n, BtV, At, Qux);
        if (mu != 0.0) {
            for (int i = 0; i < m; i++)
                for (int j = 0; j < n; j++) { Bt[i * n + j] = Btn[j * m + i]; BtVr[i * n + j] = BtV[i * n + j] + mu * Bt[i * n + j]; }
            a_b(m, n, m, BtVr, Btn, QuuF);
            for (int i = 0; i < m * m; i++) QuuF[i] += luu[t * m * m + i];
            a_b(m, n, n, Bt, At, Quxr);
            for (int i = 0; i < m * n; i++) Quxr[i] = Qux[i] + mu * Quxr[i];
        } else {
            a_b(m, n, m, BtV, Btn, QuuF);
            for (int i = 0; i < m * m; i++) QuuF[i] += luu[t * m * m + i];
            memcpy(Quxr, Qux, sizeof(double) * m * n);
        }
        for (int i = 0; i < m; i++)
            for (int j = 0; j < m; j++) S[i * m + j] = 0.5 * (QuuF[i * m + j] + QuuF[j * m + i]);
        if (chol_l(m, S)) { rc = (int)t + 1; break; }
        for (int i = 0; i < m; i++) {
            rhs[i * (n + 1)] = Qu[i];
            for (int j = 0; j < n; j++) rhs[i * (n + 1) + 1 + j] = Quxr[i * n + j];
        }
        chol_solve(m, n + 1, S, rhs);
        double *kt = k + t * m, *Kt = K + t * m * n;
        for (int i = 0; i < m; i++) {
            kt[i] = -rhs[i * (n + 1)];
            for (int j = 0; j < n; j++) Kt[i * n + j] = -rhs[i * (n + 1) + 1 + j];
        }
        /* dV += (kt . Qu, 0.5 kt^T Quu kt) */
        double d0 = 0.0, d1 = 0.0;
        for (int i = 0; i < m; i++) d0 += kt[i] * Qu[i];
        for (int i = 0; i < m; i++) { double s = 0.0; for (int j = 0; j < m; j++) s += Quu[i * m + j] * kt[j]; tmp[i] = s; }
        for (int i = 0; i < m; i++) d1 += kt[i] * tmp[i];
        dV[0] += d0; dV[1] += 0.5 * d1;
        at_b(m, n, m, Kt, Quu, KtQuu);                  /* Kt^T Quu (n, m) */
        /* Vx = Qx + KtQuu kt + Kt^T Qu + Qux^T kt */
        for (int i = 0; i < n; i++) {
            double s = Qx[i];
            for (int j = 0; j < m; j++) s += KtQuu[i * m + j] * kt[j];
            double s2 = 0.0, s3 = 0.0;
            for (int j = 0; j < m; j++) { s2 += Kt[j * n + i] * Qu[j]; s3 += Qux[j * n + i] * kt[j]; }
            Vx[i] = s + s2 + s3;
        }
        /* Vxx = Qxx + KtQuu Kt + Kt^T Qux + Qux^T Kt, symmetrized */
        a_b(n, m, n, KtQuu, Kt, Vn);
        at_b(m, n, n, Kt, Qux, VA);                     /* reuse VA: Kt^T Qux */
        for (int i = 0; i < n * n; i++) Vn[i] += Qxx[i] + VA[i];
        at_b(m, n, n, Qux, Kt, VA);                     /* Qux^T Kt */
        for (int i = 0; i < n * n; i++) Vn[i] += VA[i];
        for (int i = 0; i < n; i++)
            for (int j = 0; j < n; j++) Vxx[i * n + j] = 0.5 * (Vn[i * n + j] + Vn[j * n + i]);
    }
    free(w);
    return rc;
}
