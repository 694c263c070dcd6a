/* AICO / R-AICO sweeps of planning/aico.py (_Sweeps) in C: the same formulas, the same order of
 * steps, relinearizations and repeats (thesis Algorithm 1), without per-step Python overhead.
 *
 * Arrays are numpy's, row-major. The dense algebra (Cholesky factors, triangular solves, products)
 * is the register-tiled loops below, no BLAS. The message layout is _Sweeps's:
 * SA[t], VA[t], RA[t] = [P | p] (n x (n+1)), C[t] = [[B, A, -a], [0, 0, 1]] ((n+1) x (m+n+1)),
 * Z[t] = [-O_t | o_t] (m x (n+1)).
 *
 * The kernel is resumable: where a relinearization needs Python (a task term costs the step, or
 * the dynamics have no compiled linearization) sweep_run returns a request (bit 1: dynamics,
 * bit 2: task message) with the step's point already moved; the caller fills C[t], Qbar[t],
 * a_eff[t] and/or RA[t] and calls sweep_run again, which continues where it stopped.
 * Build: gcc -O3 with fused multiply-adds where the CPU has them (kernels.FLAGS, Makefile target
 * `kernels`); the results equal the numpy code's to rounding (tests/test_kernels.py), not bit for bit.
 */
#include <math.h>
#include <string.h>

typedef int (*lin_t)(const void *, const double *, const double *, double *, double *, double *);
typedef int (*task_t)(const void *, long, const double *, double *, double *);

enum { ERR_CHOL = -1, ERR_LIN = -2 };
enum { PH_FWD = 0, PH_BWD = 1, PH_DONE = 2 };
enum { SUB_STEP = 0, SUB_CHECK = 1, SUB_AFTER = 2 };
enum { DYN_NONE = 0, DYN_C = 1, DYN_PY = 2 };

typedef struct {
    /* sizes and options */
    long T, n, m;
    long relocate, max_repeats, dyn_mode;
    double q, theta, rate, start_unused;
    /* arrays (row-major); *_s: stride between steps in doubles (0: one matrix shared by all) */
    double *SA, *VA, *RA, *C, *Qbar, *a_eff, *H, *h, *Hinv, *X, *U, *b, *Z;
    long C_s, Qbar_s, H_s, Hinv_s;
    const unsigned char *active;
    /* compiled dynamics */
    void *lin_fn, *lin_ctx;
    /* work: see sweep_work_size; iw: int work (sparsity of a shared C) */
    double *w;
    int *iw;
    long sp_state;       /* shared C: 0 unknown, 1 sparse lists ready, 2 dense */
    /* compiled task messages (NULL: the caller's); R-AICO's alpha and the previous trajectory */
    void *task_fn, *task_ctx;
    double alpha;
    const double *Xprev;
    /* resumable state */
    long phase, t, r, sub, dyn_flag, task_flag, repeats, err_info, err_code;
} sweep_t;

/* work doubles needed for sizes n, m */
long sweep_iwork_size(long n, long m) { return 3 * (n + 1) * (m + n + 1) + 2 * (m + n + 2); }

long sweep_work_size(long n, long m)
{
    long N1 = n + 1, K = m + n + 1;
    return 8 * n * N1 + 3 * n * n + 2 * n * K + m * K + 5 * n + n * m * 3 + 64;
}

/* work layout */
typedef struct { double *Pa, *Vs, *Ba, *Y0, *Y1, *FA, *W, *S, *G, *GT, *FB, *y, *tmp, *rhs, *Ad, *ad, *Bd, *BHi, *E, *lx, *lxx; } work_t;

static work_t layout(const sweep_t *s)
{
    long n = s->n, m = s->m, N1 = n + 1, K = m + n + 1;
    work_t w;
    double *p = s->w;
    w.Pa = p; p += n * N1;
    w.Vs = p; p += n * N1;
    w.Ba = p; p += n * N1;
    w.Y0 = p; p += n * N1;
    w.Y1 = p; p += n * N1;
    w.FA = p; p += n * N1;
    w.E = p; p += 2 * n * N1;   /* I + q P' (vstar), column n of V* (mul_sparse_C); 2nd half: Ad */
    w.W = p; p += n * n;
    w.S = p; p += n * n;
    w.G = p; p += n * K;
    w.GT = p; p += n * K;
    w.FB = p; p += m * K;
    w.y = p; p += n;
    w.tmp = p; p += n;
    w.rhs = p; p += n;
    w.ad = p; p += n;
    w.Ad = p; p += n * m;   /* reused: A (n x n) needs n*n: placed in E's second half below */
    w.Bd = p; p += n * m;
    w.BHi = p; p += n * m;
    w.lx = p; p += n;
    w.lxx = p; p += n * n;
    w.Ad = w.E + n * N1;    /* n * (n+1) >= n * n */
    return w;
}

/* -- small dense kernels (row-major) ----------------------------------------------------------
 * Every product, factorization and solve below is built on one register-tiled update (upd): a
 * 4 x 8 block of the result kept in eight 4-wide vector accumulators over the whole inner
 * dimension, with 4 x 4 and 4 x (1..3) edge tiles. For the sweeps' sizes (n <= ~100: everything
 * in L1/L2) this beats OpenBLAS, whose calls cost 0.3-0.5 us each and whose small-size LAPACK
 * runs at level-2 speed. Measured at n = 50, cycles per call, hot cache, best of 2000, this box:
 * Cholesky 12.8k -> 8.6k (the previous rank-4 loops), SPD inverse 29k -> 16.7k, V* series
 * (OpenBLAS syrk + gemm) 53.6k -> 36.0k, syrk 50 x 25 (OpenBLAS) 10.3k -> 5.3k; in the sweeps,
 * where each step's messages come from memory, the gain is smaller: the Nao balancing run (25
 * iterations) took 0.76-0.81x the previous kernel's time, interleaved A/B. The vectors are GCC vector extensions:
 * with -mavx2 -mfma one ymm register each, without them the compiler splits them.
 * A Cholesky factor R is upper, row-major, A = R^T R; only A's upper triangle is read. */
typedef double v4d __attribute__((vector_size(32)));
static inline v4d ldv(const double *p) { v4d v; memcpy(&v, p, sizeof v); return v; }
static inline void stv(double *p, v4d v) { memcpy(p, &v, sizeof v); }

/* tile of nr (<= 4) rows x 8 columns: c[r][j] += scale sum_{k=kb}^{ke-1} X(r, k) y[k][j],
 * X(r, k) = x[r xr + k xk] */
static inline __attribute__((always_inline)) void mk8(int nr, int kb, int ke, const double *x, long xr, long xk,
                                                     const double *y, long ldy, double *c, long ldc, double scale,
                                                     int set)
{
    v4d a0 = {0}, a1 = {0}, b0 = {0}, b1 = {0}, c0 = {0}, c1 = {0}, d0 = {0}, d1 = {0};
    for (int k = kb; k < ke; k++) {
        const double *yk = y + (long)k * ldy, *xk_ = x + (long)k * xk;
        v4d y0 = ldv(yk), y1 = ldv(yk + 4);
        double f = xk_[0];
        a0 += f * y0; a1 += f * y1;
        if (nr > 1) { f = xk_[xr]; b0 += f * y0; b1 += f * y1; }
        if (nr > 2) { f = xk_[2 * xr]; c0 += f * y0; c1 += f * y1; }
        if (nr > 3) { f = xk_[3 * xr]; d0 += f * y0; d1 += f * y1; }
    }
    if (set) {
        stv(c, scale * a0); stv(c + 4, scale * a1);
        if (nr > 1) { c += ldc; stv(c, scale * b0); stv(c + 4, scale * b1); }
        if (nr > 2) { c += ldc; stv(c, scale * c0); stv(c + 4, scale * c1); }
        if (nr > 3) { c += ldc; stv(c, scale * d0); stv(c + 4, scale * d1); }
        return;
    }
    stv(c, ldv(c) + scale * a0); stv(c + 4, ldv(c + 4) + scale * a1);
    if (nr > 1) { c += ldc; stv(c, ldv(c) + scale * b0); stv(c + 4, ldv(c + 4) + scale * b1); }
    if (nr > 2) { c += ldc; stv(c, ldv(c) + scale * c0); stv(c + 4, ldv(c + 4) + scale * c1); }
    if (nr > 3) { c += ldc; stv(c, ldv(c) + scale * d0); stv(c + 4, ldv(c + 4) + scale * d1); }
}

/* nr rows x 4 columns */
static inline __attribute__((always_inline)) void mk4(int nr, int kb, int ke, const double *x, long xr, long xk,
                                                     const double *y, long ldy, double *c, long ldc, double scale,
                                                     int set)
{
    v4d a0 = {0}, b0 = {0}, c0 = {0}, d0 = {0};
    for (int k = kb; k < ke; k++) {
        const double *xk_ = x + (long)k * xk;
        v4d y0 = ldv(y + (long)k * ldy);
        a0 += xk_[0] * y0;
        if (nr > 1) b0 += xk_[xr] * y0;
        if (nr > 2) c0 += xk_[2 * xr] * y0;
        if (nr > 3) d0 += xk_[3 * xr] * y0;
    }
    v4d z = {0};
    stv(c, (set ? z : ldv(c)) + scale * a0);
    if (nr > 1) { c += ldc; stv(c, (set ? z : ldv(c)) + scale * b0); }
    if (nr > 2) { c += ldc; stv(c, (set ? z : ldv(c)) + scale * c0); }
    if (nr > 3) { c += ldc; stv(c, (set ? z : ldv(c)) + scale * d0); }
}

/* 4 rows x nc (< 4) columns with X(r, k) contiguous in r (xr = 1): vectors across the rows */
static inline __attribute__((always_inline)) void mke(int nc, int kb, int ke, const double *x, long xk,
                                                     const double *y, long ldy, double *c, long ldc, double scale,
                                                     int set)
{
    v4d a0 = {0}, a1 = {0}, a2 = {0};
    for (int k = kb; k < ke; k++) {
        v4d xv = ldv(x + (long)k * xk);
        const double *yk = y + (long)k * ldy;
        a0 += xv * yk[0];
        if (nc > 1) a1 += xv * yk[1];
        if (nc > 2) a2 += xv * yk[2];
    }
    for (int r = 0; r < 4; r++) {
        double *cr = c + r * ldc;
        cr[0] = (set ? 0.0 : cr[0]) + scale * a0[r];
        if (nc > 1) cr[1] = (set ? 0.0 : cr[1]) + scale * a1[r];
        if (nc > 2) cr[2] = (set ? 0.0 : cr[2]) + scale * a2[r];
    }
}

/* nr rows x nc (< 4) columns, scalar (the rare edge: fewer than 4 rows or X strided in r) */
static void mks(int nr, int nc, int kb, int ke, const double *x, long xr, long xk,
                const double *y, long ldy, double *c, long ldc, double scale, int set)
{
    for (int r = 0; r < nr; r++)
        for (int j = 0; j < nc; j++) {
            double v = 0.0;
            for (int k = kb; k < ke; k++) v += x[r * xr + (long)k * xk] * y[(long)k * ldy + j];
            c[r * ldc + j] = (set ? 0.0 : c[r * ldc + j]) + scale * v;
        }
}

enum { UP_KCOL = 1, UP_KROW = 2, UP_UPPER = 4, UP_SET = 8 };

/* C (R x Cn, ld ldc) += scale sum_{k=kb}^{ke-1} X(r, k) Y[k][c], X(r, k) = X[r xr + k xk] (xr = 1,
 * xk = ld: X^T of a row-major block; xr = ld, xk = 1: X itself), Y row-major (ld ldy).
 * flags: UP_KCOL: a tile's k starts at its first column (Y lower triangular, zeros stored);
 * UP_KROW: at its first row (X(r, k) = 0 for k < r); UP_UPPER: only tiles reaching the upper
 * triangle (C's upper triangle wanted; the few lower entries of a tile across the diagonal get
 * the same update); UP_SET: C = scale X Y (C not read: no zeroing before). */
static void upd(int R, int Cn, int kb, int ke, int flags, const double *X, long xr, long xk,
                const double *Y, long ldy, double *C, long ldc, double scale)
{
    int set = (flags & UP_SET) != 0;
    for (int i0 = 0; i0 < R; i0 += 4) {
        int nr = R - i0 < 4 ? R - i0 : 4;
        const double *x = X + i0 * xr;
        double *c = C + (long)i0 * ldc;
        for (int j0 = (flags & UP_UPPER) ? i0 : 0; j0 < Cn;) {
            int k0 = kb;
            if ((flags & UP_KCOL) && j0 > k0) k0 = j0;
            if ((flags & UP_KROW) && i0 > k0) k0 = i0;
            int w = Cn - j0 >= 8 ? 8 : (Cn - j0 >= 4 ? 4 : Cn - j0);
            const double *y = Y + j0;
            double *cc = c + j0;
            if (k0 >= ke && !set) { j0 += w; continue; }
            if (k0 > ke) k0 = ke;
            if (w == 8) {
                switch (nr) {
                case 4: mk8(4, k0, ke, x, xr, xk, y, ldy, cc, ldc, scale, set); break;
                case 3: mk8(3, k0, ke, x, xr, xk, y, ldy, cc, ldc, scale, set); break;
                case 2: mk8(2, k0, ke, x, xr, xk, y, ldy, cc, ldc, scale, set); break;
                default: mk8(1, k0, ke, x, xr, xk, y, ldy, cc, ldc, scale, set);
                }
            } else if (w == 4) {
                switch (nr) {
                case 4: mk4(4, k0, ke, x, xr, xk, y, ldy, cc, ldc, scale, set); break;
                case 3: mk4(3, k0, ke, x, xr, xk, y, ldy, cc, ldc, scale, set); break;
                case 2: mk4(2, k0, ke, x, xr, xk, y, ldy, cc, ldc, scale, set); break;
                default: mk4(1, k0, ke, x, xr, xk, y, ldy, cc, ldc, scale, set);
                }
            } else if (nr == 4 && xr == 1) {
                switch (w) {
                case 3: mke(3, k0, ke, x, xk, y, ldy, cc, ldc, scale, set); break;
                case 2: mke(2, k0, ke, x, xk, y, ldy, cc, ldc, scale, set); break;
                default: mke(1, k0, ke, x, xk, y, ldy, cc, ldc, scale, set);
                }
            } else mks(nr, w, k0, ke, x, xr, xk, y, ldy, cc, ldc, scale, set);
            j0 += w;
        }
    }
}

/* Rows i0..i0+3 of B (ld ldb), columns c0..c1-1 <- R_d^-T times them, R_d = R[i0:i0+4, i0:i0+4]
 * (upper; inv: the inverses of its diagonal): forward substitution in one pass over the columns,
 * 4 at a time in vectors (the same operations, in the same order, as row by row) */
static void block4_rt(const double *R, int ld, int i0, const double *inv, double *B, long ldb, int c0, int c1)
{
    const double *r0 = R + (long)i0 * ld + i0, *r1 = r0 + ld, *r2 = r1 + ld;
    double a01 = r0[1], a02 = r0[2], a03 = r0[3], a12 = r1[2], a13 = r1[3], a23 = r2[3];
    double *b0 = B + (long)i0 * ldb, *b1 = b0 + ldb, *b2 = b1 + ldb, *b3 = b2 + ldb;
    int j = c0;
    for (; j + 4 <= c1; j += 4) {
        v4d x0 = ldv(b0 + j) * inv[0];
        v4d x1 = (ldv(b1 + j) - a01 * x0) * inv[1];
        v4d x2 = (ldv(b2 + j) - a02 * x0 - a12 * x1) * inv[2];
        v4d x3 = (ldv(b3 + j) - a03 * x0 - a13 * x1 - a23 * x2) * inv[3];
        stv(b0 + j, x0); stv(b1 + j, x1); stv(b2 + j, x2); stv(b3 + j, x3);
    }
    for (; j < c1; j++) {
        double x0 = b0[j] * inv[0];
        double x1 = (b1[j] - a01 * x0) * inv[1];
        double x2 = (b2[j] - a02 * x0 - a12 * x1) * inv[2];
        double x3 = (b3[j] - a03 * x0 - a13 * x1 - a23 * x2) * inv[3];
        b0[j] = x0; b1[j] = x1; b2[j] = x2; b3[j] = x3;
    }
}

/* the same for R_d^-1 (backward substitution, rows from the bottom) */
static void block4_r(const double *R, int ld, int i0, const double *inv, double *B, long ldb, int c0, int c1)
{
    const double *r0 = R + (long)i0 * ld + i0, *r1 = r0 + ld, *r2 = r1 + ld;
    double a01 = r0[1], a02 = r0[2], a03 = r0[3], a12 = r1[2], a13 = r1[3], a23 = r2[3];
    double *b0 = B + (long)i0 * ldb, *b1 = b0 + ldb, *b2 = b1 + ldb, *b3 = b2 + ldb;
    int j = c0;
    for (; j + 4 <= c1; j += 4) {
        v4d x3 = ldv(b3 + j) * inv[3];
        v4d x2 = (ldv(b2 + j) - a23 * x3) * inv[2];
        v4d x1 = (ldv(b1 + j) - a12 * x2 - a13 * x3) * inv[1];
        v4d x0 = (ldv(b0 + j) - a01 * x1 - a02 * x2 - a03 * x3) * inv[0];
        stv(b0 + j, x0); stv(b1 + j, x1); stv(b2 + j, x2); stv(b3 + j, x3);
    }
    for (; j < c1; j++) {
        double x3 = b3[j] * inv[3];
        double x2 = (b2[j] - a23 * x3) * inv[2];
        double x1 = (b1[j] - a12 * x2 - a13 * x3) * inv[1];
        double x0 = (b0[j] - a01 * x1 - a02 * x2 - a03 * x3) * inv[0];
        b0[j] = x0; b1[j] = x1; b2[j] = x2; b3[j] = x3;
    }
}

static inline void diag4_inv(const double *R, int ld, int i0, double *inv)
{
    for (int k = 0; k < 4; k++) inv[k] = 1.0 / R[(long)(i0 + k) * ld + i0 + k];
}

/* A = R^T R in place (R upper), left-looking in blocks of 4 rows: the block's rows get the update
 * from all rows above at once (upd), then the block is factored. Returns 0 or the (1-based) row
 * where A is not positive definite. Only A's upper triangle is read; the strictly lower entries
 * of the 4 x 4 diagonal blocks are overwritten with scratch values. */
static int chol_u(int n, double *A, int ld)
{
    for (int i0 = 0; i0 < n; i0 += 4) {
        int nb = n - i0 < 4 ? n - i0 : 4;
        double *ri0 = A + (long)i0 * ld;
        if (i0) upd(nb, n - i0, 0, i0, 0, A + i0, 1, ld, A + i0, ld, ri0 + i0, ld, -1.0);
        /* the 4 x 4 diagonal block, then its rows right of it in one pass (block4_rt) */
        int ie = nb == 4 ? i0 + 4 : n;
        for (int i = i0; i < ie; i++) {
            double *ri = A + (long)i * ld;
            for (int p = i0; p < i; p++) {
                const double *rp = A + (long)p * ld;
                double f = rp[i];
                for (int j = i; j < (nb == 4 ? ie : n); j++) ri[j] -= f * rp[j];
            }
            double d = ri[i];
            if (!(d > 0.0)) return i + 1;
            d = sqrt(d);
            ri[i] = d;
            double inv = 1.0 / d;
            for (int j = i + 1; j < (nb == 4 ? ie : n); j++) ri[j] *= inv;
        }
        if (nb == 4 && ie < n) {
            double inv[4];
            diag4_inv(A, ld, i0, inv);
            block4_rt(A, ld, i0, inv, A, ld, ie, n);
        }
    }
    return 0;
}

/* B (n x c, ld ldb) <- R^-T B: blocks of 4 rows from the top, each updated from all rows above */
static void solve_rt(int n, const double *R, int ld, double *B, int ldb, int c)
{
    for (int i0 = 0; i0 < n; i0 += 4) {
        int nb = n - i0 < 4 ? n - i0 : 4;
        if (i0) upd(nb, c, 0, i0, 0, R + i0, 1, ld, B, ldb, B + (long)i0 * ldb, ldb, -1.0);
        if (nb == 4) {
            double inv[4];
            diag4_inv(R, ld, i0, inv);
            block4_rt(R, ld, i0, inv, B, ldb, 0, c);
            continue;
        }
        for (int i = i0; i < i0 + nb; i++) {
            double *bi = B + (long)i * ldb;
            for (int p = i0; p < i; p++) {
                const double *bp = B + (long)p * ldb;
                double f = R[(long)p * ld + i];
                for (int j = 0; j < c; j++) bi[j] -= f * bp[j];
            }
            double inv = 1.0 / R[(long)i * ld + i];
            for (int j = 0; j < c; j++) bi[j] *= inv;
        }
    }
}

/* B (n x c, ld ldb) <- R^-1 B: blocks of 4 rows from the bottom, each updated from all rows below */
static void solve_r(int n, const double *R, int ld, double *B, int ldb, int c)
{
    for (int i0 = (n - 1) & ~3; i0 >= 0; i0 -= 4) {
        int ie = n - i0 < 4 ? n : i0 + 4;
        if (ie < n) upd(ie - i0, c, ie, n, 0, R + (long)i0 * ld, ld, 1, B, ldb, B + (long)i0 * ldb, ldb, -1.0);
        if (ie - i0 == 4) {
            double inv[4];
            diag4_inv(R, ld, i0, inv);
            block4_r(R, ld, i0, inv, B, ldb, 0, c);
            continue;
        }
        for (int i = ie - 1; i >= i0; i--) {
            double *bi = B + (long)i * ldb;
            const double *ri = R + (long)i * ld;
            for (int p = i + 1; p < ie; p++) {
                const double *bp = B + (long)p * ldb;
                double f = ri[p];
                for (int j = 0; j < c; j++) bi[j] -= f * bp[j];
            }
            double inv = 1.0 / ri[i];
            for (int j = 0; j < c; j++) bi[j] *= inv;
        }
    }
}

/* b (n, stride 1) <- R^-T b, then R^-1 b if both */
static void trsv_rt(int n, const double *R, int ld, double *b)
{
    for (int k = 0; k < n; k++) {
        const double *rk = R + (long)k * ld;
        double v = b[k] / rk[k];
        b[k] = v;
        for (int i = k + 1; i < n; i++) b[i] -= rk[i] * v;
    }
}

static void trsv_r(int n, const double *R, int ld, double *b)
{
    for (int i = n - 1; i >= 0; i--) {
        const double *ri = R + (long)i * ld;
        double v = b[i];
        #pragma omp simd reduction(-:v)
        for (int k = i + 1; k < n; k++) v -= ri[k] * b[k];
        b[i] = v / ri[i];
    }
}

/* upper triangle of C (n x n) += scale W^T W, W (r x n) (see upd: UP_UPPER); set: C = scale W^T W */
static void syrk_tn(int r, int n, double scale, const double *W, int ldw, double *C, int ldc, int set)
{
    upd(n, n, 0, r, UP_UPPER | (set ? UP_SET : 0), W, 1, ldw, W, ldw, C, ldc, scale);
}

/* C (a x c) += scale A^T B, A (r x a), B (r x c); set: C = scale A^T B */
static void gemm_tn(int r, int a, int c, double scale, const double *A, int lda, const double *B, int ldb,
                    double *C, int ldc, int set)
{
    upd(a, c, 0, r, set ? UP_SET : 0, A, 1, lda, B, ldb, C, ldc, scale);
}

/* C (a x c) += scale A B, A (a x r), B (r x c); set: C = scale A B */
static void gemm_nn(int a, int r, int c, double scale, const double *A, int lda, const double *B, int ldb,
                    double *C, int ldc, int set)
{
    upd(a, c, 0, r, set ? UP_SET : 0, A, lda, 1, B, ldb, C, ldc, scale);
}

/* dst (cols x rows, ld ldd) = src^T (src rows x cols, ld lds), in 4 x 4 blocks of vectors */
typedef long v4l __attribute__((vector_size(32)));
static inline void transpose4(const double *a, long lds, double *d, long ldd)
{
    const v4l lo = {0, 4, 2, 6}, hi = {1, 5, 3, 7}, f = {0, 1, 4, 5}, g = {2, 3, 6, 7};
    v4d r0 = ldv(a), r1 = ldv(a + lds), r2 = ldv(a + 2 * lds), r3 = ldv(a + 3 * lds);
    v4d t0 = __builtin_shuffle(r0, r1, lo), t1 = __builtin_shuffle(r0, r1, hi);
    v4d t2 = __builtin_shuffle(r2, r3, lo), t3 = __builtin_shuffle(r2, r3, hi);
    stv(d, __builtin_shuffle(t0, t2, f));
    stv(d + ldd, __builtin_shuffle(t1, t3, f));
    stv(d + 2 * ldd, __builtin_shuffle(t0, t2, g));
    stv(d + 3 * ldd, __builtin_shuffle(t1, t3, g));
}

static void transpose(int rows, int cols, const double *src, long lds, double *dst, long ldd)
{
    int r4 = rows & ~3, c4 = cols & ~3;
    for (int i = 0; i < r4; i += 4)
        for (int j = 0; j < c4; j += 4) transpose4(src + (long)i * lds + j, lds, dst + (long)j * ldd + i, ldd);
    for (int i = 0; i < rows; i++)
        for (int j = (i < r4 ? c4 : 0); j < cols; j++) dst[(long)j * ldd + i] = src[(long)i * lds + j];
}

/* the strictly lower triangle of C (n x n) from its upper: 4 x 4 blocks transposed in registers,
 * the diagonal blocks and the edge entry by entry */
static void mirror_upper(int n, double *C, int ldc)
{
    int n4 = n & ~3;
    for (int i = 0; i < n4; i += 4)
        for (int j = i + 4; j < n4; j += 4) transpose4(C + (long)i * ldc + j, ldc, C + (long)j * ldc + i, ldc);
    for (int i = 0; i < n; i++) {
        double *ci = C + (long)i * ldc;
        for (int j = (i < n4 ? i & ~3 : 0); j < i; j++) ci[j] = C[(long)j * ldc + i];
    }
}

static void zero(double *A, int rows, int cols, int ld)
{
    for (int i = 0; i < rows; i++) memset(A + (long)i * ld, 0, sizeof(double) * cols);
}

/* out (n x n, ld ldo, full) = A^-1 = R^-1 R^-T from A = R^T R; Y: n * n work.
 * Y = R^-T (lower, zeros stored above) by blocks of 4 rows (its zeros skipped), then out = Y^T Y
 * (upper tiles, k from the tile's first row or column, mirrored). */
static void spd_inverse(int n, const double *R, int ld, double *out, int ldo, double *Y)
{
    for (int i0 = 0; i0 < n; i0 += 4) {
        int nb = n - i0 < 4 ? n - i0 : 4;
        /* rows i0.. from the rows above: only columns < i0 (Y[p][j] = 0 for j > p); set, not added */
        if (i0) upd(nb, i0, 0, i0, UP_KCOL | UP_SET, R + i0, 1, ld, Y, n, Y + (long)i0 * n, n, -1.0);
        int j0 = 0;                 /* columns < j0 done by block4_rt */
        if (nb == 4 && i0) {
            double inv[4];
            diag4_inv(R, ld, i0, inv);
            block4_rt(R, ld, i0, inv, Y, n, 0, i0);
            j0 = i0;
        }
        for (int i = i0; i < i0 + nb; i++) {
            double *yi = Y + (long)i * n;
            /* columns i0..: the unit row, zero up to 7 past the diagonal (the tiles read that far) */
            int je = i + 8 < n ? i + 8 : n;
            for (int j = i0; j < je; j++) yi[j] = 0.0;
            yi[i] = 1.0;
            for (int p = i0; p < i; p++) {
                const double *yp = Y + (long)p * n;
                double f = R[(long)p * ld + i];
                for (int j = j0; j <= p; j++) yi[j] -= f * yp[j];
            }
            double inv = 1.0 / R[(long)i * ld + i];
            for (int j = j0; j <= i; j++) yi[j] *= inv;
        }
    }
    upd(n, n, 0, n, UP_KCOL | UP_KROW | UP_UPPER | UP_SET, Y, 1, n, Y, n, out, ldo, 1.0);
    mirror_upper(n, out, ldo);
}

static int sparse_ready(sweep_t *s);

/* out (n x c, ld c) += A X for a sparse shared C (A = C[:n, m:m+n], listed by columns), X (n x c,
 * ld c): row i of the result gains A[i][j] times row j of X (vectorized row updates). */
static void add_sparse_A_rows(const sweep_t *s, const double *X, int c, double *out)
{
    int n = (int)s->n, m = (int)s->m, K = m + n + 1;
    const int *start = s->iw, *rows = s->iw + K + 1;
    for (int j = 0; j < n; j++) {
        const double *xj = X + (long)j * c;
        for (int k = start[m + j]; k < start[m + j + 1]; k++) {
            int i = rows[k];
            if (i >= n) continue;
            double v = s->C[(long)i * K + m + j];
            double *oi = out + (long)i * c;
            for (int l = 0; l < c; l++) oi[l] += v * xj[l];
        }
    }
}

/* S (n x n) = A X A^T + Q and u_out (n) = A u + a_e for a sparse shared C, X symmetric (n x n):
 * M = A X and S = A M^T (= A X A^T); M, Mt: n x n work. */
static void sandwich_sparse(const sweep_t *s, const double *X, const double *Q, double *S, double *M,
                            double *Mt, const double *u, const double *a_e, double *u_out)
{
    int n = (int)s->n;
    zero(M, n, n, n);
    add_sparse_A_rows(s, X, n, M);
    memcpy(u_out, a_e, sizeof(double) * n);
    add_sparse_A_rows(s, u, 1, u_out);
    transpose(n, n, M, n, Mt, n);
    memcpy(S, Q, sizeof(double) * n * n);
    add_sparse_A_rows(s, Mt, n, S);
}

/* forward message [S_t^-1 | S_t^-1 s_t] at t >= 1 (_Sweeps.forward). P = R^T R;
 * dense C: W = R^-T A^T, S = W^T W + Qbar, s_t = W^T R^-T p + a_eff;
 * sparse shared C: S = A P^-1 A^T + Qbar, s_t = A P^-1 p + a_eff (fewer flops: P^-1 by rows);
 * then S = V^T V, S^-1 = V^-1 V^-T. */
static int forward(sweep_t *s, work_t *w, long t)
{
    int n = (int)s->n, m = (int)s->m, N1 = n + 1, K = m + n + 1, info;
    long nn1 = (long)n * N1;
    const double *SA0 = s->SA + (t - 1) * nn1, *RA0 = s->RA + (t - 1) * nn1;
    const double *Ct = s->C + (t - 1) * s->C_s;
    const double *Qb = s->Qbar + (t - 1) * s->Qbar_s, *ae = s->a_eff + (t - 1) * n;
    double *Pa = w->Pa, *W = w->W, *S = w->S, *y = w->y, *tmp = w->tmp;
    /* the factor and the solves read [upper triangle | column n] of P only */
    for (int i = 0; i < n; i++) {
        long o = (long)i * N1;
        for (int j = i; j < N1; j++) Pa[o + j] = SA0[o + j] + RA0[o + j];
    }
    if ((info = chol_u(n, Pa, N1)) != 0) { s->err_info = info; return ERR_CHOL; }
    if (sparse_ready(s)) {
        double *X = w->Y1, *u = w->rhs;
        spd_inverse(n, Pa, N1, X, n, w->Y0);             /* P^-1 */
        for (int i = 0; i < n; i++) {
            const double *xi = X + (long)i * n;
            double v = 0.0;
            #pragma omp simd reduction(+:v)
            for (int j = 0; j < n; j++) v += xi[j] * Pa[(long)j * N1 + n];
            u[i] = v;
        }
        sandwich_sparse(s, X, Qb, S, W, w->Y0, u, ae, tmp);
    } else {
        for (int i = 0; i < n; i++)
            for (int j = 0; j < n; j++) W[(long)i * n + j] = Ct[(long)j * K + m + i];
        solve_rt(n, Pa, N1, W, n, n);
        for (int i = 0; i < n; i++) y[i] = Pa[(long)i * N1 + n];
        trsv_rt(n, Pa, N1, y);
        memcpy(S, Qb, sizeof(double) * n * n);
        syrk_tn(n, n, 1.0, W, n, S, n, 0);
        for (int j = 0; j < n; j++) tmp[j] = 0.0;
        for (int i = 0; i < n; i++) {
            double f = y[i];
            const double *wi = W + (long)i * n;
            for (int j = 0; j < n; j++) tmp[j] += f * wi[j];
        }
        for (int j = 0; j < n; j++) tmp[j] += ae[j];
    }
    if ((info = chol_u(n, S, n)) != 0) { s->err_info = info; return ERR_CHOL; }
    double *out = s->SA + t * nn1;
    spd_inverse(n, S, n, out, N1, w->Y0);
    for (int i = 0; i < n; i++) {
        const double *oi = out + (long)i * N1;
        double v = 0.0;
        #pragma omp simd reduction(+:v)
        for (int j = 0; j < n; j++) v += oi[j] * tmp[j];
        out[(long)i * N1 + n] = v;
    }
    return 0;
}

/* The truncated series of vstar with symmetric products (upper tiles only, mirrored): the block
 * sum_{k<=K} (-q)^k P'^(k+1) from S2 = P'^2: P' - q S2 + q^2 (P' - q S2) S2 (K = 3; K = 2: the last
 * product is P' S2), and the column sum_{k<=K} (-q)^k P'^k p' by matrix-vector products (P'
 * symmetric). The same terms as Horner's Y <- Pa - q P' Y, K times, in n^3 instead of K n^3. */
static int vstar_series(sweep_t *s, work_t *w, const double *Pa, double *Vs, int K)
{
    int n = (int)s->n, N1 = n + 1;
    double q = s->q, *S2 = w->Y0, *Y = w->Y1, *u = w->tmp, *u2 = w->rhs;
    syrk_tn(n, n, 1.0, Pa, N1, S2, n, 1);                   /* P'^T P' = P'^2 */
    mirror_upper(n, S2, n);
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) Vs[(long)i * N1 + j] = Pa[(long)i * N1 + j] - q * S2[(long)i * n + j];
    if (K >= 2) {
        const double *Yp = Pa;
        int ldy = N1;
        if (K >= 3) {
            for (int i = 0; i < n; i++) memcpy(Y + (long)i * n, Vs + (long)i * N1, sizeof(double) * n);
            Yp = Y;
            ldy = n;
        }
        /* (P' - q S2) and S2 commute: the product is symmetric */
        upd(n, n, 0, n, UP_UPPER, Yp, 1, ldy, S2, n, Vs, N1, q * q);
        mirror_upper(n, Vs, N1);
    }
    /* column: v = p' - q P' p' + q^2 P'^2 p' - q^3 P'^3 p' (K terms) */
    double c = 1.0;
    for (int i = 0; i < n; i++) { u[i] = Pa[(long)i * N1 + n]; Vs[(long)i * N1 + n] = u[i]; }
    for (int k = 1; k <= K; k++) {
        c *= -q;
        for (int i = 0; i < n; i++) {
            const double *pi = Pa + (long)i * N1;
            double v = 0.0;
            #pragma omp simd reduction(+:v)
            for (int j = 0; j < n; j++) v += pi[j] * u[j];
            u2[i] = v;
        }
        for (int i = 0; i < n; i++) { u[i] = u2[i]; Vs[(long)i * N1 + n] += c * u[i]; }
    }
    return 0;
}

/* [V* | V* m'] from Pa = [P' | p'] into Vs (_Sweeps._vstar) */
static int vstar(sweep_t *s, work_t *w, const double *Pa, double *Vs)
{
    int n = (int)s->n, N1 = n + 1, info;
    long nn1 = (long)n * N1;
    double q = s->q;
    v4d acc[4] = {{0}};                     /* 4 independent vector sums (the FMA latency) */
    long i = 0;
    for (; i + 16 <= nn1; i += 16)
        for (int k = 0; k < 4; k++) { v4d v = ldv(Pa + i + 4 * k); acc[k] += v * v; }
    v4d a4 = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    double ss = (a4[0] + a4[1]) + (a4[2] + a4[3]);
    for (; i < nn1; i++) ss += Pa[i] * Pa[i];
    double sc = q * sqrt(ss);
    if (sc <= 1e-4) {
        int K = sc <= 1e-8 ? 1 : (sc <= pow(10.0, -16.0 / 3.0) ? 2 : 3);
        return vstar_series(s, w, Pa, Vs, K);
    }
    /* (I + q P') V = [P' | p'] by Cholesky */
    double *E = w->E;
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) E[(long)i * n + j] = q * Pa[(long)i * N1 + j] + (i == j ? 1.0 : 0.0);
    if ((info = chol_u(n, E, n)) != 0) { s->err_info = info; return ERR_CHOL; }
    memcpy(Vs, Pa, sizeof(double) * nn1);
    solve_rt(n, E, n, Vs, N1, N1);
    solve_r(n, E, n, Vs, N1, N1);
    return 0;
}

/* A shared C (time-invariant model) is often sparse (pseudo-dynamics: A = [[I, dt I], [0, I]],
 * B = [[dt^2 I], [dt I]]): then the products with it skip its zeros (exact: a skipped term is
 * 0 * finite). The nonzeros are listed column by column: iw[0..K] column starts, then (row, value
 * index) pairs. Used when at most a quarter of C's entries are nonzero. */
static int sparse_ready(sweep_t *s)
{
    if (s->C_s != 0) return 0;
    if (s->sp_state) return s->sp_state == 1;
    int n = (int)s->n, m = (int)s->m, N1 = n + 1, K = m + n + 1, nnz = 0;
    int *start = s->iw, *rows = s->iw + K + 1;
    for (int j = 0; j < K; j++) {
        start[j] = nnz;
        for (int i = 0; i < N1; i++) if (s->C[(long)i * K + j] != 0.0) rows[nnz++] = i;
    }
    start[K] = nnz;
    s->sp_state = (4L * nnz <= (long)N1 * K) ? 1 : 2;
    return s->sp_state == 1;
}

/* G (n x K, row-major) = Vs (n x (n+1)) C, C sparse: column j of G is the sum over the nonzeros
 * C[k][j] of C[k][j] times column k of Vs, so G^T is built by row updates (vectorized) and
 * transposed back. VsT: n work (column n of Vs), GT: K x n work. */
static void mul_sparse_C(const sweep_t *s, const double *Vs, double *G, double *VsT, double *GT)
{
    int n = (int)s->n, N1 = n + 1, K = (int)(s->m + s->n + 1);
    const int *start = s->iw, *rows = s->iw + K + 1;
    /* column k < n of Vs is its row k (V* symmetric: mirrored by the series, to rounding by the
     * Cholesky route); column n (V* m') gathered once */
    double *vn = VsT;
    for (int i = 0; i < n; i++) vn[i] = Vs[(long)i * N1 + n];
    zero(GT, K, n, n);
    for (int j = 0; j < K; j++) {
        double *gj = GT + (long)j * n;
        for (int p = start[j]; p < start[j + 1]; p++) {
            int k = rows[p];
            double c = s->C[(long)k * K + j];
            const double *vk = k < n ? Vs + (long)k * N1 : vn;
            for (int i = 0; i < n; i++) gj[i] += c * vk[i];
        }
    }
    transpose(K, n, GT, n, G, K);
}

/* out (cols c0..c1 of C)^T Y: out ((c1-c0) x ny, ld ldo) = C[:n, c0:c1]^T Y (Y: n x ny, ld ldy) */
static void mul_sparse_CT(const sweep_t *s, int c0, int c1, const double *Y, int ldy, int ny, double *out, int ldo)
{
    int n = (int)s->n, K = (int)(s->m + s->n + 1);
    const int *start = s->iw, *rows = s->iw + K + 1;
    for (int j = c0; j < c1; j++) {
        double *oj = out + (long)(j - c0) * ldo;
        for (int c = 0; c < ny; c++) oj[c] = 0.0;
        for (int k = start[j]; k < start[j + 1]; k++) {
            int i = rows[k];
            if (i >= n) continue;
            double cv = s->C[(long)i * K + j];
            const double *yi = Y + (long)i * ldy;
            for (int c = 0; c < ny; c++) oj[c] += cv * yi[c];
        }
    }
}

/* backward message [V_t^-1 | V_t^-1 v_t] and controller Z[t] (_Sweeps.backward):
 * G = V* C, M = B^T V* B + H = R^T R, Kmat = R^-T [B^T V* A | B^T V*(m' - a) + h], Z = R^-1 Kmat,
 * V_t^-1 = sym(A^T V* A) - Kmat[:, :n]^T Kmat[:, :n], V_t^-1 v_t = A^T V*(m' - a) - Kmat[:, :n]^T Kmat[:, n] */
static int backward(sweep_t *s, work_t *w, long t, int reuse)
{
    int n = (int)s->n, m = (int)s->m, N1 = n + 1, K = m + n + 1, info;
    long nn1 = (long)n * N1;
    int rc;
    if (!reuse) {
        const double *V1 = s->VA + (t + 1) * nn1, *R1 = s->RA + (t + 1) * nn1;
        double *Pa = w->Pa;
        for (long i = 0; i < nn1; i++) Pa[i] = V1[i] + R1[i];
        if ((rc = vstar(s, w, w->Pa, w->Vs)) != 0) return rc;
    }
    const double *Ct = s->C + t * s->C_s;
    double *G = w->G, *FB = w->FB, *FA = w->FA, *KK = w->W, *kc = w->tmp;
    if (sparse_ready(s)) {
        mul_sparse_C(s, w->Vs, G, w->E, w->GT);
        mul_sparse_CT(s, 0, m, G, K, K, FB, K);
        mul_sparse_CT(s, m, m + n, G + m, K, N1, FA, N1);
    } else {
        gemm_nn(n, N1, K, 1.0, w->Vs, N1, Ct, K, G, K, 1);         /* G = V* C */
        gemm_tn(n, m, K, 1.0, Ct, K, G, K, FB, K, 1);               /* B^T G */
        gemm_tn(n, n, N1, 1.0, Ct + m, K, G + m, K, FA, N1, 1);     /* A^T G[:, m:] */
    }
    const double *Ht = s->H + t * s->H_s, *ht = s->h + t * m;
    for (int i = 0; i < m; i++) {
        for (int j = 0; j < m; j++) FB[(long)i * K + j] += Ht[i * m + j];
        FB[(long)i * K + m + n] += ht[i];
    }
    if ((info = chol_u(m, FB, K)) != 0) { s->err_info = info; return ERR_CHOL; }
    double *Kmat = FB + m;                                   /* m x (n+1), ld K */
    solve_rt(m, FB, K, Kmat, K, N1);
    double *Zt = s->Z + t * (long)m * N1;
    for (int i = 0; i < m; i++) memcpy(Zt + (long)i * N1, Kmat + (long)i * K, sizeof(double) * N1);
    solve_r(m, FB, K, Zt, N1, N1);
    /* KK (upper) = Kmat[:, :n]^T Kmat[:, :n] */
    syrk_tn(m, n, 1.0, Kmat, K, KK, n, 1);
    for (int i = 0; i < n; i++) kc[i] = 0.0;
    for (int k = 0; k < m; k++) {
        const double *kk = Kmat + (long)k * K;
        double f = kk[n];
        for (int i = 0; i < n; i++) kc[i] += f * kk[i];
    }
    /* row by row from FA^T and KK mirrored (contiguous, vectorized); (i, j) and (j, i) get the
     * same bits (the sum commutes) */
    double *out = s->VA + t * nn1, *FAT = w->Y0;
    transpose(n, n, FA, N1, FAT, n);
    mirror_upper(n, KK, n);
    for (int i = 0; i < n; i++) {
        double *oi = out + (long)i * N1;
        const double *fi = FA + (long)i * N1, *gi = FAT + (long)i * n, *ki = KK + (long)i * n;
        for (int j = 0; j < n; j++) oi[j] = 0.5 * (fi[j] + gi[j]) - ki[j];
        oi[n] = fi[n] - kc[i];
    }
    return 0;
}

/* belief mean b_t (_Sweeps.belief) */
static int belief(sweep_t *s, work_t *w, long t)
{
    int n = (int)s->n, N1 = n + 1, info;
    long nn1 = (long)n * N1;
    const double *a = s->SA + t * nn1, *v = s->VA + t * nn1, *r = s->RA + t * nn1;
    double *Ba = w->Ba, *b = s->b + t * n;
    /* the factorization reads the upper triangle only: [upper | column n] of S^-1 + V^-1 + R */
    for (int i = 0; i < n; i++) {
        long o = (long)i * N1;
        for (int j = i; j < N1; j++) Ba[o + j] = a[o + j] + v[o + j] + r[o + j];
        b[i] = Ba[o + n];
    }
    if ((info = chol_u(n, Ba, N1)) != 0) { s->err_info = info; return ERR_CHOL; }
    trsv_rt(n, Ba, N1, b);
    trsv_r(n, Ba, N1, b);
    return 0;
}

/* compiled relinearization of the dynamics at step t (_Sweeps.relinearize, dynamics part) */
static int relin_dyn(sweep_t *s, work_t *w, long t)
{
    int n = (int)s->n, m = (int)s->m, K = m + n + 1;
    double *A = w->Ad, *a = w->ad, *B = w->Bd, *BHi = w->BHi;
    ((lin_t)s->lin_fn)(s->lin_ctx, s->X + t * n, s->U + t * m, A, a, B);
    double *Ct = s->C + t * s->C_s, sum = 0.0;
    for (int i = 0; i < n; i++) {
        for (int j = 0; j < m; j++) Ct[(long)i * K + j] = B[i * m + j];
        for (int j = 0; j < n; j++) Ct[(long)i * K + m + j] = A[(long)i * n + j];
        Ct[(long)i * K + m + n] = -a[i];
    }
    #pragma omp simd reduction(+:sum)
    for (long i = 0; i < (long)(n + 1) * K; i++) sum += Ct[i];
    if (!isfinite(sum)) return ERR_LIN;
    const double *Hi = s->Hinv + t * s->Hinv_s, *ht = s->h + t * m;
    for (int i = 0; i < n; i++)
        for (int j = 0; j < m; j++) {
            double v = 0.0;
            for (int k = 0; k < m; k++) v += B[i * m + k] * Hi[k * m + j];
            BHi[i * m + j] = v;
        }
    double *Qb = s->Qbar + t * s->Qbar_s, *ae = s->a_eff + t * n;
    for (int i = 0; i < n; i++) {
        for (int j = 0; j < n; j++) {
            double v = 0.0;
            for (int k = 0; k < m; k++) v += BHi[i * m + k] * B[j * m + k];
            Qb[(long)i * n + j] = v + (i == j ? s->q : 0.0);
        }
        double v = 0.0;
        for (int k = 0; k < m; k++) v += BHi[i * m + k] * ht[k];
        ae[i] = a[i] + v;
    }
    return 0;
}

/* compiled task message RA[t] at X[t] (_Sweeps._relinearize_task) */
static int relin_task(sweep_t *s, work_t *w, long t)
{
    long n = s->n, N1 = n + 1;
    const double *x = s->X + t * n, *xp = s->Xprev + t * n;
    double *lx = w->lx, *lxx = w->lxx, *out = s->RA + t * n * N1, sum = 0.0, a2 = 2.0 * s->alpha;
    ((task_t)s->task_fn)(s->task_ctx, t, x, lx, lxx);
    for (long i = 0; i < n; i++) {
        const double *li = lxx + i * n;
        double *oi = out + i * N1, v = 0.0;
        #pragma omp simd reduction(+:v)
        for (long j = 0; j < n; j++) {
            oi[j] = li[j];
            v += li[j] * x[j];
        }
        oi[i] += a2;
        oi[n] = v - lx[i] + a2 * xp[i];
    }
    #pragma omp simd reduction(+:sum)
    for (long i = 0; i < n * N1; i++) sum += out[i];
    return isfinite(sum) ? 0 : ERR_LIN;
}

/* Run the sweeps from the state in s (sub = SUB_STEP, phase, t set by the caller at the start).
 * Returns 0 when done, > 0 a request to the caller (bit 1: dynamics of step s->t, bit 2: task
 * message of step s->t), < 0 an error (ERR_CHOL with s->err_info, ERR_LIN). */
int sweep_run(sweep_t *s)
{
    work_t w = layout(s);
    long n = s->n, T = s->T;
    int rc;
    for (;;) {
        if (s->sub == SUB_STEP) {
            long t = s->t;
            if (s->phase == PH_FWD) {
                if (t > T) { s->phase = PH_BWD; s->t = T - 1; continue; }
                if ((rc = forward(s, &w, t)) != 0) return rc;
            } else if (s->phase == PH_BWD) {
                if (t < 0) { s->phase = PH_DONE; return 0; }
                if ((rc = backward(s, &w, t, 0)) != 0) return rc;
            } else return 0;
            if (!s->relocate) { s->t += (s->phase == PH_FWD) ? 1 : -1; continue; }
            if ((rc = belief(s, &w, t)) != 0) return rc;
            s->r = 0;
            s->sub = SUB_CHECK;
        }
        if (s->sub == SUB_CHECK) {
            long t = s->t;
            double *x = s->X + t * n, *b = s->b + t * n, dd = 0.0;
            int next = s->r >= s->max_repeats;
            if (!next) {
                for (long i = 0; i < n; i++) { double d = b[i] - x[i]; dd += d * d; }
                next = !(sqrt(dd) > s->theta);
            }
            if (next) {
                s->t += (s->phase == PH_FWD) ? 1 : -1;
                s->sub = SUB_STEP;
                continue;
            }
            for (long i = 0; i < n; i++) x[i] += s->rate * (b[i] - x[i]);
            s->dyn_flag = t < T && s->dyn_mode != DYN_NONE;
            s->task_flag = s->active[t] != 0;
            long req = 0;
            if (s->dyn_flag && s->dyn_mode == DYN_C) {
                if ((rc = relin_dyn(s, &w, t)) != 0) return rc;
            }
            if (s->dyn_flag && s->dyn_mode == DYN_PY) req |= 1;
            if (s->task_flag) {
                if (s->task_fn) { if ((rc = relin_task(s, &w, t)) != 0) return rc; }
                else req |= 2;
            }
            s->sub = SUB_AFTER;
            if (req) return (int)req;
        }
        if (s->sub == SUB_AFTER) {
            long t = s->t;
            s->repeats++;
            int redo = s->phase == PH_BWD && s->dyn_flag;
            if (redo && (rc = backward(s, &w, t, 1)) != 0) return rc;
            if ((redo || s->task_flag) && (rc = belief(s, &w, t)) != 0) return rc;
            s->r++;
            s->sub = SUB_CHECK;
        }
    }
}

/* forward messages t = 1..T and every belief, no relinearization (_Sweeps.beliefs, theta = inf) */
int sweep_beliefs(sweep_t *s)
{
    work_t w = layout(s);
    int rc;
    for (long t = 1; t <= s->T; t++) if ((rc = forward(s, &w, t)) != 0) return rc;
    for (long t = 0; t <= s->T; t++) if ((rc = belief(s, &w, t)) != 0) return rc;
    return 0;
}

/* closed-loop rollout on a time-invariant affine model x' = A x + a + B u with u = o_t + O_t x
 * (planning.problem.controller_rollout on LinearDynamics): X (T+1, n), U (T, m) */
void lti_rollout(long T, long n, long m, const double *A, const double *a, const double *B,
                 const double *x0, const double *o, const double *O, double *X, double *U)
{
    memcpy(X, x0, sizeof(double) * n);
    for (long t = 0; t < T; t++) {
        const double *x = X + t * n;
        double *u = U + t * m, *xn = X + (t + 1) * n;
        for (long i = 0; i < m; i++) {
            const double *row = O + (t * m + i) * n;
            double v = 0.0;
            #pragma omp simd reduction(+:v)
            for (long j = 0; j < n; j++) v += row[j] * x[j];
            u[i] = o[t * m + i] + v;
        }
        for (long i = 0; i < n; i++) {
            double v = 0.0, w = 0.0;
            #pragma omp simd reduction(+:v)
            for (long j = 0; j < n; j++) v += A[i * n + j] * x[j];
            for (long j = 0; j < m; j++) w += B[i * m + j] * u[j];
            xn[i] = v + a[i] + w;
        }
    }
}

/* the dense kernels by themselves, for tests/test_kernels.py (row-major, numpy's layout) */
int k_chol_u(long n, double *A, long ld) { return chol_u((int)n, A, (int)ld); }
void k_solve_rt(long n, const double *R, long ld, double *B, long ldb, long c)
{ solve_rt((int)n, R, (int)ld, B, (int)ldb, (int)c); }
void k_solve_r(long n, const double *R, long ld, double *B, long ldb, long c)
{ solve_r((int)n, R, (int)ld, B, (int)ldb, (int)c); }
void k_spd_inverse(long n, const double *R, long ld, double *out, long ldo, double *Y)
{ spd_inverse((int)n, R, (int)ld, out, (int)ldo, Y); }
void k_gemm_nn(long a, long r, long c, double scale, const double *A, long lda, const double *B, long ldb,
               double *C, long ldc)
{ gemm_nn((int)a, (int)r, (int)c, scale, A, (int)lda, B, (int)ldb, C, (int)ldc, 0); }
void k_gemm_tn(long r, long a, long c, double scale, const double *A, long lda, const double *B, long ldb,
               double *C, long ldc)
{ gemm_tn((int)r, (int)a, (int)c, scale, A, (int)lda, B, (int)ldb, C, (int)ldc, 0); }
void k_syrk_tn(long r, long n, double scale, const double *W, long ldw, double *C, long ldc, long set)
{ syrk_tn((int)r, (int)n, scale, W, (int)ldw, C, (int)ldc, (int)set); }
void k_gemm_nn_set(long a, long r, long c, double scale, const double *A, long lda, const double *B, long ldb,
                   double *C, long ldc)
{ gemm_nn((int)a, (int)r, (int)c, scale, A, (int)lda, B, (int)ldb, C, (int)ldc, 1); }
void k_transpose(long rows, long cols, const double *src, long lds, double *dst, long ldd)
{ transpose((int)rows, (int)cols, src, lds, dst, ldd); }
