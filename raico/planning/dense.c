/* Dense linear algebra of the AICO sweep kernel (raico/planning/csweep.c), in its own file:
 * register-tiled products, Cholesky factors, triangular solves and the SPD inverse, row-major,
 * no BLAS. raico/planning/kernels.py compiles this file and csweep.c as one translation unit (this file
 * first; the functions stay static, so the compiler inlines them as before); the k_* entry points
 * at the end exist for tests/planning/test_kernels.py, which checks each against numpy.
 */
#include <math.h>
#include <string.h>

/* -- small dense kernels (row-major) ----------------------------------------------------------
 * Every product, factorization and solve below is built on one register-tiled update (upd): a
 * 4 x 8 block of the result kept in eight 4-wide vector accumulators over the whole inner
 * dimension (4 x 16 in eight 8-wide ones where the CPU has AVX-512: see mk16), with 4 x 8, 4 x 4 and
 * 4 x (1..3) edge tiles. For the sweeps' sizes (n <= ~100: everything
 * in L1/L2) this beats OpenBLAS, whose calls cost 0.3-0.5 us each and whose small-size LAPACK
 * runs at level-2 speed. Measured at n = 50, cycles per call, hot cache, best of 2000, this box:
 * Cholesky 12.8k -> 8.6k (the previous rank-4 loops), SPD inverse 29k -> 16.7k, V* series
 * (OpenBLAS syrk + gemm) 53.6k -> 36.0k, syrk 50 x 25 (OpenBLAS) 10.3k -> 5.3k; in the sweeps,
 * where each step's messages come from memory, the gain is smaller: the Nao balancing run (25
 * iterations) took 0.76-0.81x the previous kernel's time, interleaved A/B. The vectors are GCC vector extensions:
 * with -mavx2 -mfma one ymm register each, without them the compiler splits them.
 * Measured after the 16-column tile (this box, AVX-512): a 64 x 64 x 64 product 12.1 -> 7.9 us, the
 * backward sweep of a 32-joint chain (n = 64, m = 32, T = 100) 4.7 -> 3.4 ms.
 * A Cholesky factor R is upper, row-major, A = R^T R; only A's upper triangle is read. */
typedef double v4d __attribute__((vector_size(32)));
static inline v4d ldv(const double *p) { v4d v; memcpy(&v, p, sizeof v); return v; }
static inline void stv(double *p, v4d v) { memcpy(p, &v, sizeof v); }

/* tile of nr (<= 4) rows x 2H columns in H-wide vectors V (load LD, store ST):
 * c[r][j] += scale sum_{k=kb}^{ke-1} X(r, k) y[k][j], X(r, k) = x[r xr + k xk]. Every entry of C gets its
 * own accumulator, k ascending, one multiply-add per k, then the scaled add: the 8- and 16-column tiles
 * give the same numbers bit for bit. */
#define TILE_KERNEL(NAME, V, H, LD, ST)                                                                      \
static inline __attribute__((always_inline)) void NAME(int nr, int kb, int ke, const double *x, long xr,   \
                                                       long xk, const double *y, long ldy, double *c,     \
                                                       long ldc, double scale, int set)                   \
{                                                                                                          \
    V a0 = {0}, a1 = {0}, b0 = {0}, b1 = {0}, c0 = {0}, c1 = {0}, d0 = {0}, d1 = {0};                      \
    for (int k = kb; k < ke; k++) {                                                                        \
        const double *yk = y + (long)k * ldy, *xk_ = x + (long)k * xk;                                     \
        V y0 = LD(yk), y1 = LD(yk + H);                                                                    \
        double f = xk_[0];                                                                                 \
        a0 += f * y0; a1 += f * y1;                                                                        \
        if (nr > 1) { f = xk_[xr]; b0 += f * y0; b1 += f * y1; }                                           \
        if (nr > 2) { f = xk_[2 * xr]; c0 += f * y0; c1 += f * y1; }                                       \
        if (nr > 3) { f = xk_[3 * xr]; d0 += f * y0; d1 += f * y1; }                                       \
    }                                                                                                      \
    if (set) {                                                                                             \
        ST(c, scale * a0); ST(c + H, scale * a1);                                                          \
        if (nr > 1) { c += ldc; ST(c, scale * b0); ST(c + H, scale * b1); }                                \
        if (nr > 2) { c += ldc; ST(c, scale * c0); ST(c + H, scale * c1); }                                \
        if (nr > 3) { c += ldc; ST(c, scale * d0); ST(c + H, scale * d1); }                                \
        return;                                                                                            \
    }                                                                                                      \
    ST(c, LD(c) + scale * a0); ST(c + H, LD(c + H) + scale * a1);                                          \
    if (nr > 1) { c += ldc; ST(c, LD(c) + scale * b0); ST(c + H, LD(c + H) + scale * b1); }                \
    if (nr > 2) { c += ldc; ST(c, LD(c) + scale * c0); ST(c + H, LD(c + H) + scale * c1); }                \
    if (nr > 3) { c += ldc; ST(c, LD(c) + scale * d0); ST(c + H, LD(c + H) + scale * d1); }                \
}

TILE_KERNEL(mk8, v4d, 4, ldv, stv)

#if defined(__AVX512F__)
/* AVX-512 (raico/planning/kernels.py adds -mavx512f where the CPU has it): mk8's tile twice as wide, nr (<= 4)
 * rows x 16 columns in 8-wide vectors, in half the instructions. */
typedef double v8d __attribute__((vector_size(64)));
static inline v8d ldw(const double *p) { v8d v; memcpy(&v, p, sizeof v); return v; }
static inline void stw(double *p, v8d v) { memcpy(p, &v, sizeof v); }
#define TILE_W 16
TILE_KERNEL(mk16, v8d, 8, ldw, stw)
#else
#define TILE_W 8
#endif

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
            int w = Cn - j0 >= TILE_W ? TILE_W : (Cn - j0 >= 8 ? 8 : (Cn - j0 >= 4 ? 4 : Cn - j0));
            const double *y = Y + j0;
            double *cc = c + j0;
            if (k0 >= ke && !set) { j0 += w; continue; }
            if (k0 > ke) k0 = ke;
#if defined(__AVX512F__)
            if (w == 16) {
                switch (nr) {
                case 4: mk16(4, k0, ke, x, xr, xk, y, ldy, cc, ldc, scale, set); break;
                case 3: mk16(3, k0, ke, x, xr, xk, y, ldy, cc, ldc, scale, set); break;
                case 2: mk16(2, k0, ke, x, xr, xk, y, ldy, cc, ldc, scale, set); break;
                default: mk16(1, k0, ke, x, xr, xk, y, ldy, cc, ldc, scale, set);
                }
            } else
#endif
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
            /* columns i0..: the unit row, zero up to TILE_W - 1 past the diagonal (the tiles read that far) */
            int je = i + TILE_W < n ? i + TILE_W : n;
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

/* the dense kernels by themselves, for the tests (row-major, numpy's layout). Accepted: every size
 * >= 1, every leading dimension >= its matrix's row length (the tests pad each operand and check that
 * nothing outside its block changes); Y of k_spd_inverse holds n x n doubles. */
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
