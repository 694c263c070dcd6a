/* AICO / R-AICO sweeps of raico/planning/aico/sweeps.py (Sweeps) in C: the same formulas, the same order of
 * steps, relinearizations and repeats (thesis Algorithm 1), without per-step Python overhead.
 *
 * Arrays are numpy's, row-major. The dense algebra (Cholesky factors, triangular solves, products)
 * is dense.c's register-tiled loops, no BLAS (raico/planning/kernels.py compiles dense.c, then this file,
 * as one translation unit). Where a step's C has the block form of a semi-implicit Euler step
 * (semi_implicit: A = J + e A_b, B = e B_b) the backward message and the dynamics relinearization
 * take their products from the velocity rows (the same matrices to rounding, fewer flops); every
 * other C takes the dense products. The message layout is Sweeps's:
 * SA[t], VA[t], RA[t] = [P | p] (n x (n+1)), C[t] = [[B, A, -a], [0, 0, 1]] ((n+1) x (m+n+1)),
 * Z[t] = [-O_t | o_t] (m x (n+1)).
 *
 * The kernel is resumable: where a relinearization needs Python (a task term costs the step, or
 * the dynamics have no compiled linearization) sweep_run returns a request (bit 1: dynamics,
 * bit 2: task message) with the step's point already moved; the caller fills C[t], Qbar[t],
 * a_eff[t] and/or RA[t] and calls sweep_run again, which continues where it stopped.
 * Build: gcc -O3 with fused multiply-adds where the CPU has them (kernels.FLAGS, Makefile target
 * `kernels`); the results equal the numpy code's to rounding (tests/planning/test_kernels.py), not bit for bit.
 */
#include <math.h>
#include <string.h>

typedef int (*lin_t)(const void *, const double *, const double *, double *, double *, double *);
typedef int (*task_t)(const void *, long, const double *, double *, double *);

enum { ERR_CHOL = -1, ERR_LIN = -2, ERR_H = -3 };
enum { PH_FWD = 0, PH_BWD = 1, PH_DONE = 2 };
enum { SUB_STEP = 0, SUB_CHECK = 1, SUB_AFTER = 2, SUB_LEAVE = 3 };
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
    /* the semi-implicit Euler step's time step (0: none; see semi_implicit) and the count of backward
     * messages and dynamics relinearizations that took its block form */
    double dt;
    long block_steps;
    unsigned char *blk;  /* (T): whether C[t] has the block form (block_form), 0 while not known */
} sweep_t;

/* Accepted shapes (raico/planning/aico/sweeps.py: Sweeps._check_kernel_shapes checks them before every call and
 * raises ValueError): T, n, m >= 1; SA, VA, RA (T+1, n, n+1); C (T, n+1, m+n+1) or one shared (stride
 * 0); Qbar (T, n, n) or shared; H, Hinv (T, m, m) or shared; h (T, m); a_eff (T, n); X, Xprev, b
 * (T+1, n); U (T, m); Z (T, m, n+1); active (T+1); blk (T), zeros at the start of a sweep; dt >= 0;
 * w and iw of the sizes below. */

/* work doubles needed for sizes n, m: exactly the sum of layout()'s blocks (no slack, so that the
 * sanitizer build sees any access past them) */
long sweep_iwork_size(long n, long m) { return 3 * (n + 1) * (m + n + 1) + 2 * (m + n + 2); }

long sweep_work_size(long n, long m)
{
    long N1 = n + 1, K = m + n + 1, h = n / 2;
    return 8 * n * N1 + 3 * n * n + 2 * n * K + m * K + 5 * n + n * m * 3
        + n * h + 2 * h * h + h * K + n + m * n + m * m;
}

/* work layout */
typedef struct { double *Pa, *Vs, *Ba, *Y0, *Y1, *FA, *W, *S, *G, *GT, *FB, *y, *tmp, *rhs, *Ad, *ad, *Bd, *BHi, *E, *lx, *lxx;
                 double *Ve, *E1, *D, *Yb, *gv, *Bt, *Hc; } work_t;

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
    long h = n / 2;         /* the block form's blocks (semi_implicit) */
    w.Ve = p; p += n * h;
    w.E1 = p; p += h * h;
    w.D = p; p += h * h;
    w.Yb = p; p += h * K;
    w.gv = p; p += n;
    w.Bt = p; p += m * n;
    w.Hc = p; p += m * m;   /* sweep_linearize: H_t's factor */
    w.Ad = w.E + n * N1;    /* n * (n+1) >= n * n */
    return w;
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

/* forward message [S_t^-1 | S_t^-1 s_t] at t >= 1 (Sweeps.forward). P = R^T R;
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
        transpose(n, n, Ct + m, K, W, n);                 /* W = A^T (4 x 4 blocks: C[t] row by row) */
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

/* [V* | V* m'] from Pa = [P' | p'] into Vs (Sweeps._vstar) */
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

/* Whether C[t] = [[B, A, -a], [0, 0, 1]] has the block form of a semi-implicit Euler step with time step
 * dt (s->dt > 0, n even, h = n/2 positions and h velocities; a = qdd(q, v, u) the acceleration):
 *     A = [[I + dt^2 a_q, dt I + dt^2 a_v], [dt a_q, I + dt a_v]],  B = [[dt^2 a_u], [dt a_u]],
 * i.e. A = J + e A_b and B = e B_b with the velocity rows A_b = A[h:], B_b = B[h:], e = [dt I; I] (n x h)
 * and J = [[I, 0], [0, 0]]: the position rows are dt times the velocity rows plus J. Checked entry by
 * entry to a few units in the last place (a model computing them so rounds them alike; a fused
 * multiply-add may differ in the last bit), so the block form is used only where it is the same matrix
 * to rounding; every other model takes the dense products. O(n (n + m)) compares per call. */
static int semi_implicit(const sweep_t *s, const double *Ct)
{
    long n = s->n, m = s->m, K = m + n + 1, h = n / 2;
    double dt = s->dt, tol = 8.0 * 2.220446049250313e-16;
    if (!(dt > 0.0) || n != 2 * h) return 0;
    for (long i = 0; i < h; i++) {
        const double *top = Ct + i * K, *bot = Ct + (h + i) * K;
        double v = dt * bot[m + i] + 1.0;
        int bad = !(fabs(top[m + i] - v) <= tol * fabs(v));     /* the diagonal, then the rest by row */
        for (long j = 0; j < m + n; j++) {
            double u = dt * bot[j];
            bad |= (j != m + i) & !(fabs(top[j] - u) <= tol * fabs(u));
        }
        if (bad) return 0;
    }
    return 1;
}

/* semi_implicit of C[t], remembered per step in s->blk (0: not known, 1: block form, 2: not); a
 * relinearization of step t's dynamics forgets it */
static int block_form(const sweep_t *s, long t)
{
    if (!s->blk[t]) s->blk[t] = semi_implicit(s, s->C + t * s->C_s) ? 1 : 2;
    return s->blk[t] == 1;
}

/* The products of the backward message in the block form (semi_implicit): with Vs = [V* | V* m'],
 * g = V* (m' - a), Ve = V* e (n x h), E1 = e^T V* e (h x h), Z1 = E1 A_b (h x n) and
 * Y = e^T [V* B | V* A | g] = [E1 B_b | Ve^T J + Z1 | e^T g] (h x K):
 *     FB = B^T [V* B | V* A | g] = B_b^T Y                                   (m x K)
 *     FA = [A^T V* A | A^T g],  A^T V* A = J V* J + (T2 + T2^T) + A_b^T Z1 with T2 = J Ve A_b,
 *          A^T g = A_b^T e^T g + J g                                        (n x (n+1))
 * A^T V* A symmetric by construction (its upper triangle computed, mirrored). The same FB and FA as
 * the dense G = V* C, B^T G, A^T G (to rounding) in 2.5 n^3 flops for m = h instead of 6.5 n^3.
 * T2 goes to the n x K block G (unused on this route). */
static void backward_block(const sweep_t *s, work_t *w, const double *Ct)
{
    int n = (int)s->n, m = (int)s->m, N1 = n + 1, K = m + n + 1, h = n / 2;
    double dt = s->dt;
    const double *Vs = w->Vs, *Bb = Ct + (long)h * K, *Ab = Bb + m;
    double *Ve = w->Ve, *E1 = w->E1, *Y = w->Yb, *g = w->gv, *FB = w->FB, *FA = w->FA, *T2 = w->G;
    for (int i = 0; i < n; i++) {
        const double *vi = Vs + (long)i * N1;
        double *ei = Ve + (long)i * h, v = vi[n];
        for (int j = 0; j < h; j++) ei[j] = dt * vi[j] + vi[h + j];
        #pragma omp simd reduction(+:v)
        for (int j = 0; j < n; j++) v += vi[j] * Ct[(long)j * K + m + n];   /* C[:n, K-1] = -a */
        g[i] = v;
    }
    for (int i = 0; i < h; i++)
        for (int j = 0; j < h; j++) E1[(long)i * h + j] = dt * Ve[(long)i * h + j] + Ve[(long)(h + i) * h + j];
    gemm_nn(h, h, m, 1.0, E1, h, Bb, K, Y, K, 1);                             /* E1 B_b */
    gemm_nn(h, h, n, 1.0, E1, h, Ab, K, Y + m, K, 1);                         /* Z1 = E1 A_b */
    upd(n, n, 0, h, UP_UPPER | UP_SET, Ab, 1, K, Y + m, K, FA, N1, 1.0);     /* upper of A_b^T Z1 */
    gemm_nn(h, h, n, 1.0, Ve, h, Ab, K, T2, n, 1);                            /* T2 rows: Ve[:h] A_b */
    for (int i = 0; i < h; i++) {
        double *yi = Y + (long)i * K;
        for (int j = 0; j < h; j++) yi[m + j] += Ve[(long)j * h + i];         /* Y: + Ve^T J */
        yi[m + n] = dt * g[i] + g[h + i];                                     /* e^T g */
    }
    gemm_tn(h, m, K, 1.0, Bb, K, Y, K, FB, K, 1);                             /* B_b^T Y */
    for (int i = 0; i < n; i++) {
        double *fi = FA + (long)i * N1;
        const double *ti = T2 + (long)i * n;
        if (i < h) {                                                          /* J V* J + T2 (rows < h) */
            const double *vi = Vs + (long)i * N1;
            for (int j = i; j < h; j++) fi[j] += vi[j] + ti[j] + T2[(long)j * n + i];
            for (int j = (i > h ? i : h); j < n; j++) fi[j] += ti[j];
        }
        double v = i < h ? g[i] : 0.0;                                        /* A^T g */
        for (int k = 0; k < h; k++) v += Ab[(long)k * K + i] * Y[(long)k * K + m + n];
        fi[n] = v;
    }
    mirror_upper(n, FA, N1);
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

/* backward message [V_t^-1 | V_t^-1 v_t] and controller Z[t] (Sweeps.backward):
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
    } else if (block_form(s, t)) {
        backward_block(s, w, Ct);
        s->block_steps++;
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

/* belief mean b_t (Sweeps.belief) */
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

/* compiled relinearization of the dynamics at step t (Sweeps.relinearize, dynamics part) */
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
    double *Qb = s->Qbar + t * s->Qbar_s, *ae = s->a_eff + t * n, *Bt = w->Bt, *bh = w->tmp;
    s->blk[t] = 0;
    if (block_form(s, t)) {
        /* B = e B_b: B H^-1 B^T = e D e^T with D = B_b H^-1 B_b^T (h x h), B H^-1 h = e (B_b H^-1 h) */
        int h = n / 2;
        double dt = s->dt, *D = w->D;
        const double *Bb = Ct + (long)h * K;
        gemm_nn(h, m, m, 1.0, Bb, K, Hi, m, BHi, m, 1);                  /* B_b H^-1 */
        transpose(h, m, Bb, K, Bt, h);
        upd(h, h, 0, m, UP_UPPER | UP_SET, BHi, m, 1, Bt, h, D, h, 1.0);   /* upper of D */
        mirror_upper(h, D, h);
        for (int i = 0; i < h; i++) {
            const double *di = D + (long)i * h;
            double *q0 = Qb + (long)i * n, *q1 = Qb + (long)(h + i) * n;
            for (int j = 0; j < h; j++) {
                double d = di[j], dd = dt * d;
                q0[j] = dt * dd; q0[h + j] = dd;
                q1[j] = dd; q1[h + j] = d;
            }
            double u = 0.0;
            for (int k = 0; k < m; k++) u += BHi[(long)i * m + k] * ht[k];
            bh[i] = u;
        }
        for (int i = 0; i < h; i++) { ae[i] = a[i] + dt * bh[i]; ae[h + i] = a[h + i] + bh[i]; }
        s->block_steps++;
        for (int i = 0; i < n; i++) Qb[(long)i * n + i] += s->q;
        return 0;
    }
    /* other models: the loops (and the rounding) of the sweeps before the block form */
    for (int i = 0; i < n; i++)
        for (int j = 0; j < m; j++) {
            double v = 0.0;
            for (int k = 0; k < m; k++) v += B[i * m + k] * Hi[k * m + j];
            BHi[i * m + j] = v;
        }
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

/* compiled task message RA[t] at X[t] (Sweeps._relinearize_task) */
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
        if (s->sub == SUB_LEAVE) {   /* the caller relinearized the dynamics of the step left */
            s->blk[s->t] = 0;
            s->t += 1;
            s->sub = SUB_STEP;
        }
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
            /* In the forward sweep nothing reads the dynamics of step t before the step is left (the
             * belief of t does not depend on them): they are relinearized once, at the final point,
             * the numbers of a relinearization at every move (the last one wins) */
            if (next && s->phase == PH_FWD && s->r > 0 && t < T && s->dyn_mode != DYN_NONE) {
                if (s->dyn_mode == DYN_PY) { s->sub = SUB_LEAVE; return 1; }
                if ((rc = relin_dyn(s, &w, t)) != 0) return rc;
            }
            if (next) {
                s->t += (s->phase == PH_FWD) ? 1 : -1;
                s->sub = SUB_STEP;
                continue;
            }
            for (long i = 0; i < n; i++) x[i] += s->rate * (b[i] - x[i]);
            s->dyn_flag = t < T && s->dyn_mode != DYN_NONE && s->phase == PH_BWD;   /* forward: on leaving */
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
            if (s->dyn_flag && s->dyn_mode == DYN_PY) s->blk[t] = 0;   /* the caller relinearized them */
            s->repeats++;
            int redo = s->dyn_flag;
            if (redo && (rc = backward(s, &w, t, 1)) != 0) return rc;
            if ((redo || s->task_flag) && (rc = belief(s, &w, t)) != 0) return rc;
            s->r++;
            s->sub = SUB_CHECK;
        }
    }
}

/* The dynamics' part of one iteration's linearization along X, U in one call (the shifted workspace's,
 * raico/planning/aico/shift.py; Sweeps.linearize_all's): flags & LIN_DYN (dyn_mode DYN_C, a C per step): the
 * dynamics at every step t < T (lin_fn at X[t], U[t] into C[t], as relin_dyn: the numbers of the model's batch
 * linearization, bit for bit); then H[t] (H_s = 0: one shared) checked positive definite and H, h finite (the
 * checks of Sweeps._control_marginals and _check_finite; nothing else is written). blk zeroed (C[t]'s block form
 * not known). Shapes: sweep_run's. Returns 0, ERR_LIN (a non-finite C[t], H[t] or h[t]) or ERR_H (H[t] not
 * positive definite; err_info = t). */
enum { LIN_DYN = 1 };

int sweep_linearize(sweep_t *s, long flags)
{
    work_t w = layout(s);
    long T = s->T, n = s->n, m = s->m, N1 = n + 1, K = m + n + 1;
    memset(s->blk, 0, (size_t)T);
    if ((flags & LIN_DYN) && s->dyn_mode == DYN_C && s->C_s) {
        for (long t = 0; t < T; t++) {
            ((lin_t)s->lin_fn)(s->lin_ctx, s->X + t * n, s->U + t * m, w.Ad, w.ad, w.Bd);
            double *Ct = s->C + t * s->C_s, sum = 0.0;
            for (long i = 0; i < n; i++) {
                for (long j = 0; j < m; j++) Ct[i * K + j] = w.Bd[i * m + j];
                for (long j = 0; j < n; j++) Ct[i * K + m + j] = w.Ad[i * n + j];
                Ct[i * K + m + n] = -w.ad[i];
            }
            #pragma omp simd reduction(+:sum)
            for (long i = 0; i < N1 * K; i++) sum += Ct[i];
            if (!isfinite(sum)) return ERR_LIN;
        }
    }
    for (long t = 0; t < T; t++) {
        const double *Ht = s->H + t * s->H_s, *ht = s->h + t * m;
        double sum = 0.0;
        for (long i = 0; i < m; i++) sum += ht[i];
        if (t == 0 || s->H_s) {
            for (long i = 0; i < m * m; i++) { w.Hc[i] = Ht[i]; sum += Ht[i]; }
            if (!isfinite(sum)) return ERR_LIN;
            if (chol_u((int)m, w.Hc, (int)m) != 0) { s->err_info = t; return ERR_H; }
        } else if (!isfinite(sum)) return ERR_LIN;
    }
    return 0;
}

/* whether all of a (k doubles) is finite */
int all_finite(const double *a, long k)
{
    int ok = 1;
    for (long i = 0; i < k; i++) ok &= isfinite(a[i]) != 0;
    return ok;
}

/* forward messages t = 1..T and every belief, no relinearization (Sweeps.beliefs, theta = inf) */
int sweep_beliefs(sweep_t *s)
{
    work_t w = layout(s);
    int rc;
    for (long t = 1; t <= s->T; t++) if ((rc = forward(s, &w, t)) != 0) return rc;
    for (long t = 0; t <= s->T; t++) if ((rc = belief(s, &w, t)) != 0) return rc;
    return 0;
}

/* closed-loop rollout on a time-invariant affine model x' = A x + a + B u with u = o_t + O_t x
 * (raico.planning.problem.controller_rollout on LinearDynamics): X (T+1, n), U (T, m) */
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
