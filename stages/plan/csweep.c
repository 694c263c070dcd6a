/* AICO / R-AICO sweeps of stages/plan/aico.py (_Sweeps) in C: the same formulas, the same order of
 * steps, relinearizations and repeats (thesis Algorithm 1), without per-step Python overhead.
 *
 * Arrays are numpy's, row-major; BLAS/LAPACK (scipy's, passed in as addresses) see a row-major
 * (r x c) block as its column-major transpose (c x r). The message layout is _Sweeps's:
 * SA[t], VA[t], RA[t] = [P | p] (n x (n+1)), C[t] = [[B, A, -a], [0, 0, 1]] ((n+1) x (m+n+1)),
 * Z[t] = [-O_t | o_t] (m x (n+1)).
 *
 * The kernel is resumable: where a relinearization needs Python (a task term costs the step, or
 * the dynamics have no compiled linearization) sweep_run returns a request (bit 1: dynamics,
 * bit 2: task message) with the step's point already moved; the caller fills C[t], Qbar[t],
 * a_eff[t] and/or RA[t] and calls sweep_run again, which continues where it stopped.
 * Build: gcc -O2 -fPIC -shared -ffp-contract=off (see Makefile target `kernels`).
 */
#include <math.h>
#include <string.h>

typedef void (*dgemm_t)(const char *, const char *, const int *, const int *, const int *, const double *,
                        const double *, const int *, const double *, const int *, const double *, double *, const int *);
typedef void (*dsyrk_t)(const char *, const char *, const int *, const int *, const double *, const double *,
                        const int *, const double *, double *, const int *);
typedef void (*dtrsm_t)(const char *, const char *, const char *, const char *, const int *, const int *,
                        const double *, const double *, const int *, double *, const int *);
typedef void (*dtrsv_t)(const char *, const char *, const char *, const int *, const double *, const int *,
                        double *, const int *);
typedef void (*dgemv_t)(const char *, const int *, const int *, const double *, const double *, const int *,
                        const double *, const int *, const double *, double *, const int *);
typedef void (*dsymv_t)(const char *, const int *, const double *, const double *, const int *, const double *,
                        const int *, const double *, double *, const int *);
typedef void (*dpotrf_t)(const char *, const int *, double *, const int *, int *);
typedef void (*dpotri_t)(const char *, const int *, double *, const int *, int *);
typedef void (*dpotrs_t)(const char *, const int *, const int *, const double *, const int *, double *,
                         const int *, int *);
typedef void (*dposv_t)(const char *, const int *, const int *, double *, const int *, double *, const int *,
                        int *);
typedef int (*lin_t)(const void *, const double *, const double *, double *, double *, double *);
typedef int (*task_t)(const void *, long, const double *, double *, double *);

static dgemm_t dgemm_;
static dsyrk_t dsyrk_;
static dtrsm_t dtrsm_;
static dtrsv_t dtrsv_;
static dgemv_t dgemv_;
static dsymv_t dsymv_;
static dpotrf_t dpotrf_;
static dpotri_t dpotri_;
static dpotrs_t dpotrs_;
static dposv_t dposv_;

/* order of plants/codegen/c_backend.py: BLAS_NAMES + LAPACK_NAMES */
void sweep_set_blas(void **f)
{
    dgemm_ = (dgemm_t)f[0]; dsyrk_ = (dsyrk_t)f[1]; dtrsm_ = (dtrsm_t)f[2]; dtrsv_ = (dtrsv_t)f[3];
    dgemv_ = (dgemv_t)f[4]; dsymv_ = (dsymv_t)f[5];
    dpotrf_ = (dpotrf_t)f[6]; dpotri_ = (dpotri_t)f[7]; dpotrs_ = (dpotrs_t)f[8]; dposv_ = (dposv_t)f[9];
}

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
    return 8 * n * N1 + 3 * n * n + n * K + m * K + 5 * n + n * m * 3 + 64;
}

/* work layout */
typedef struct { double *Pa, *Vs, *Ba, *Y0, *Y1, *FA, *W, *S, *G, *FB, *y, *tmp, *rhs, *Ad, *ad, *Bd, *BHi, *E, *lx, *lxx; } work_t;

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
    w.E = p; p += 2 * n * N1;   /* (n x (n+1)) column-major rhs, and I + q P' */
    w.W = p; p += n * n;
    w.S = p; p += n * n;
    w.G = p; p += n * K;
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

static const double ONE = 1.0, ZERO = 0.0, MONE = -1.0;
static const int I1 = 1;

/* forward message [S_t^-1 | S_t^-1 s_t] at t >= 1 (_Sweeps.forward) */
static int forward(sweep_t *s, work_t *w, long t)
{
    int n = (int)s->n, m = (int)s->m, N1 = n + 1, K = m + n + 1, info = 0;
    long nn1 = (long)n * N1;
    const double *SA0 = s->SA + (t - 1) * nn1, *RA0 = s->RA + (t - 1) * nn1;
    const double *Ct = s->C + (t - 1) * s->C_s;
    double *Pa = w->Pa, *W = w->W, *S = w->S, *y = w->y, *tmp = w->tmp;
    for (long i = 0; i < nn1; i++) Pa[i] = SA0[i] + RA0[i];
    /* P = L L^T: column-major view of Pa's leading block (ld n+1), upper = U = L^T */
    dpotrf_("U", &n, Pa, &N1, &info);
    if (info != 0) { s->err_info = info; return ERR_CHOL; }
    /* W (column-major, n x n) = A^T, then L^-1 A^T: the row-major buffer then holds W^T = A L^-T */
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) W[i + j * n] = Ct[(long)j * K + m + i];
    dtrsm_("L", "U", "T", "N", &n, &n, &ONE, Pa, &N1, W, &n);
    /* y = L^-1 p */
    for (int i = 0; i < n; i++) y[i] = Pa[(long)i * N1 + n];
    dtrsv_("U", "T", "N", &n, Pa, &N1, y, &I1);
    /* S = W^T W + Qbar (upper), S^-1 from its Cholesky factor */
    const double *Qb = s->Qbar + (t - 1) * s->Qbar_s;
    memcpy(S, Qb, sizeof(double) * n * n);
    dsyrk_("U", "T", &n, &n, &ONE, W, &n, &ONE, S, &n);
    dpotrf_("U", &n, S, &n, &info);
    if (info != 0) { s->err_info = info; return ERR_CHOL; }
    dpotri_("U", &n, S, &n, &info);
    if (info != 0) { s->err_info = info; return ERR_CHOL; }
    double *out = s->SA + t * nn1;
    for (int j = 0; j < n; j++)
        for (int i = 0; i <= j; i++) {
            double v = S[i + (long)j * n];
            out[(long)i * N1 + j] = v;
            out[(long)j * N1 + i] = v;
        }
    /* s_t = A P^-1 p + a_eff = W^T y + a_eff; S^-1 s_t into the last column */
    dgemv_("T", &n, &n, &ONE, W, &n, y, &I1, &ZERO, tmp, &I1);
    const double *ae = s->a_eff + (t - 1) * n;
    for (int i = 0; i < n; i++) tmp[i] += ae[i];
    dsymv_("U", &n, &ONE, S, &n, tmp, &I1, &ZERO, out + n, &N1);
    return 0;
}

/* [V* | V* m'] from Pa = [P' | p'] into Vs (_Sweeps._vstar) */
static int vstar(sweep_t *s, work_t *w, const double *Pa, double *Vs)
{
    int n = (int)s->n, N1 = n + 1, info = 0;
    long nn1 = (long)n * N1;
    double q = s->q, ss = 0.0;
    for (long i = 0; i < nn1; i++) ss += Pa[i] * Pa[i];
    double sc = q * sqrt(ss);
    if (sc <= 1e-4) {
        int K = sc <= 1e-8 ? 1 : (sc <= pow(10.0, -16.0 / 3.0) ? 2 : 3);
        /* column-major Y^T ((n+1) x n, ld n+1) <- Pa^T - q Y^T P'  (P' symmetric) */
        const double *Y = Pa;
        double mq = -q;
        for (int k = 0; k < K; k++) {
            double *Yn = (k == K - 1) ? Vs : ((k % 2 == 0) ? w->Y0 : w->Y1);
            memcpy(Yn, Pa, sizeof(double) * nn1);
            dgemm_("N", "N", &N1, &n, &n, &mq, Y, &N1, Pa, &N1, &ONE, Yn, &N1);
            Y = Yn;
        }
        return 0;
    }
    /* (I + q P') X = [P' | p'] by Cholesky */
    double *E = w->E + 0, *R = w->Y0;   /* E: n x n column-major, R: n x (n+1) column-major */
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) E[i + (long)j * n] = q * Pa[(long)j * N1 + i] + (i == j ? 1.0 : 0.0);
    for (int j = 0; j < N1; j++)
        for (int i = 0; i < n; i++) R[i + (long)j * n] = Pa[(long)i * N1 + j];
    dpotrf_("U", &n, E, &n, &info);
    if (info != 0) { s->err_info = info; return ERR_CHOL; }
    dpotrs_("U", &n, &N1, E, &n, R, &n, &info);
    for (int j = 0; j < N1; j++)
        for (int i = 0; i < n; i++) Vs[(long)i * N1 + j] = R[i + (long)j * n];
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

/* out (r x K, ld ldo, row-major) = X (r x (n+1), ld ldx, row-major) C, C sparse */
static void mul_sparse_C(const sweep_t *s, int r, const double *X, int ldx, int col0, int col1, double *out, int ldo)
{
    int K = (int)(s->m + s->n + 1);
    const int *start = s->iw, *rows = s->iw + K + 1;
    for (int i = 0; i < r; i++) {
        const double *xi = X + (long)i * ldx;
        double *oi = out + (long)i * ldo;
        for (int j = col0; j < col1; j++) {
            double v = 0.0;
            for (int k = start[j]; k < start[j + 1]; k++) v += xi[rows[k]] * s->C[(long)rows[k] * K + j];
            oi[j - col0] = v;
        }
    }
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

/* backward message [V_t^-1 | V_t^-1 v_t] and controller Z[t] (_Sweeps.backward) */
static int backward(sweep_t *s, work_t *w, long t, int reuse)
{
    int n = (int)s->n, m = (int)s->m, N1 = n + 1, K = m + n + 1, info = 0;
    long nn1 = (long)n * N1;
    int rc;
    if (!reuse) {
        const double *V1 = s->VA + (t + 1) * nn1, *R1 = s->RA + (t + 1) * nn1;
        for (long i = 0; i < nn1; i++) w->Pa[i] = V1[i] + R1[i];
        if ((rc = vstar(s, w, w->Pa, w->Vs)) != 0) return rc;
    }
    const double *Ct = s->C + t * s->C_s;
    double *G = w->G, *FB = w->FB, *FA = w->FA;
    if (sparse_ready(s)) {
        mul_sparse_C(s, n, w->Vs, N1, 0, K, G, K);
        mul_sparse_CT(s, 0, m, G, K, K, FB, K);
        mul_sparse_CT(s, m, m + n, G + m, K, N1, FA, N1);
    } else {
        /* G = Vs Ct (n x K): column-major G^T = Ct^T Vs^T */
        dgemm_("N", "N", &K, &n, &N1, &ONE, Ct, &K, w->Vs, &N1, &ZERO, G, &K);
        /* FB = B^T G (m x K): FB^T = G^T B */
        dgemm_("N", "T", &K, &m, &n, &ONE, G, &K, Ct, &K, &ZERO, FB, &K);
        /* FA = A^T G[:, m:] (n x (n+1)): FA^T = G[:, m:]^T A */
        dgemm_("N", "T", &N1, &n, &n, &ONE, G + m, &K, Ct + m, &K, &ZERO, FA, &N1);
    }
    const double *Ht = s->H + t * s->H_s, *ht = s->h + t * m;
    for (int i = 0; i < m; i++) {
        for (int j = 0; j < m; j++) FB[(long)i * K + j] += Ht[i * m + j];
        FB[(long)i * K + m + n] += ht[i];
    }
    /* M = FB[:, :m] = L L^T; K^T = rhs^T L^-T in place (rows m.. of the column-major FB) */
    dpotrf_("U", &m, FB, &K, &info);
    if (info != 0) { s->err_info = info; return ERR_CHOL; }
    dtrsm_("R", "U", "N", "N", &N1, &m, &ONE, FB, &K, FB + m, &K);
    /* Z = L^-T K: Z^T = K^T L^-1 */
    double *Zt = s->Z + t * (long)m * N1;
    for (int j = 0; j < m; j++)
        for (int i = 0; i < N1; i++) Zt[i + (long)j * N1] = FB[m + i + (long)j * K];
    dtrsm_("R", "U", "T", "N", &N1, &m, &ONE, FB, &K, Zt, &N1);
    /* FA -= K[:, :n]^T K: FA^T -= K^T K[:, :n] */
    dgemm_("N", "T", &N1, &n, &m, &MONE, FB + m, &K, FB + m, &K, &ONE, FA, &N1);
    double *out = s->VA + t * nn1;
    for (int i = 0; i < n; i++) {
        for (int j = 0; j < n; j++) out[(long)i * N1 + j] = 0.5 * (FA[(long)i * N1 + j] + FA[(long)j * N1 + i]);
        out[(long)i * N1 + n] = FA[(long)i * N1 + n];
    }
    return 0;
}

/* belief mean b_t (_Sweeps.belief) */
static int belief(sweep_t *s, work_t *w, long t)
{
    int n = (int)s->n, N1 = n + 1, info = 0;
    long nn1 = (long)n * N1;
    const double *a = s->SA + t * nn1, *v = s->VA + t * nn1, *r = s->RA + t * nn1;
    double *Ba = w->Ba, *b = s->b + t * n;
    for (long i = 0; i < nn1; i++) Ba[i] = a[i] + v[i] + r[i];
    for (int i = 0; i < n; i++) b[i] = Ba[(long)i * N1 + n];
    dposv_("U", &n, &I1, Ba, &N1, b, &n, &info);
    if (info != 0) { s->err_info = info; return ERR_CHOL; }
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
        double v = 0.0;
        for (long j = 0; j < n; j++) {
            out[i * N1 + j] = lxx[i * n + j] + (i == j ? a2 : 0.0);
            v += lxx[i * n + j] * x[j];
        }
        out[i * N1 + n] = v - lx[i] + a2 * xp[i];
    }
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
 * (stages.plan.problem.controller_rollout on LinearDynamics): X (T+1, n), U (T, m) */
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
            for (long j = 0; j < n; j++) v += row[j] * x[j];
            u[i] = o[t * m + i] + v;
        }
        for (long i = 0; i < n; i++) {
            double v = 0.0, w = 0.0;
            for (long j = 0; j < n; j++) v += A[i * n + j] * x[j];
            for (long j = 0; j < m; j++) w += B[i * m + j] * u[j];
            xn[i] = v + a[i] + w;
        }
    }
}
