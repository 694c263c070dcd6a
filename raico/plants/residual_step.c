#include <math.h>
#include <string.h>
/* The model file plus a residual GP (raico/plants/learned.py: ResidualDynamics, stepped k times per control step as
 * raico/plants/dynamics.py's SubstepDynamics), compiled from the two compiled parts: the model file's dyn_qddot and
 * dyn_linearize (raico/plants/fast_analytic_driver.c, through their addresses) and gp_point.c's gp_point (the GP
 * mean and its input gradient, scaled units). One inner step of dt: qdd = f_model(q, v, u) + mean(q, v, u),
 * v' = v + dt qdd, q' = q + dt v'; its linearization is the model file's plus the GP mean's (dv'/d(x, u) += dt F,
 * dq'/d(x, u) += dt^2 F, F = d mean / d(x, u)), aff = f(x, u) - A x - B u, as ResidualDynamics.linearize. k steps
 * per control step (the control held): A = A_k ... A_1, B = sum_i A_k ... A_{i+1} B_i, aff = f^k(x, u) - A x - B u,
 * as SubstepDynamics.linearize. Shapes: nq >= 1 joints, nx = 2 nq, nu = d - nx >= 1 controls, 1 <= d <= 256,
 * N >= 1 GP points, k >= 1; work res_work_size(nq, d) doubles; A (nx, nx), aff (nx,), B (nx, nu) row-major;
 * the rollout: o (T, nu), O (T, nu, nx), X (T + 1, nx) (X[0] set by the caller), U (T, nu). A non-finite input
 * gives NaN (and -1 from res_linearize), never a read past an array. */

typedef int (*qdd_fn)(const void *, const double *, const double *, double *);
typedef int (*lin_fn)(const void *, const double *, const double *, double *, double *, double *);
typedef void (*gp_fn)(long, long, long, const double *, const double *, const double *, const double *,
                      const double *, double *, double *);
typedef void (*gp_mean_fn)(long, long, long, const double *, const double *, const double *, const double *,
                           const double *, double *);

typedef struct {
    void *base_qdd, *base_lin, *base_ctx;   /* the model file's dyn_qddot, dyn_linearize and their context */
    void *gp_point, *gp_mean;               /* gp_point.c's gp_point and gp_point_mean */
    long N, d, nq, k;                       /* GP points, GP inputs, joints, inner steps per control step */
    const double *Zs, *weights, *sf2, *inv_ell, *x_mean, *x_std, *y_mean, *y_std;
    double dt;                              /* the inner step (s) */
    double *work;                           /* res_work_size(nq, d) doubles */
} res_t;

long res_work_size(long nq, long d)
{
    long nx = 2 * nq, nu = d - nx;
    return 5 * nx * nx + 4 * nx * nu + 6 * nx + 3 * nq + 2 * nq * d + 2 * d;
}

/* The GP's mean accelerations m (nq,) and, with F not NULL, their gradient F (nq, d) in physical units at
 * (x, u); -1 (nothing written) where the input is not finite. g: nq * d doubles of scratch, z: 2 d. */
static int gp_eval(const res_t *c, const double *x, const double *u, double *m, double *F, double *g, double *z)
{
    long d = c->d, nx = 2 * c->nq;
    for (long i = 0; i < d; i++) {
        double xi = i < nx ? x[i] : u[i - nx];
        z[i] = (xi - c->x_mean[i]) / c->x_std[i];
        if (!isfinite(z[i])) return -1;
    }
    if (F) ((gp_fn)c->gp_point)(c->N, d, c->nq, c->Zs, c->weights, c->sf2, c->inv_ell, z, m, g);
    else ((gp_mean_fn)c->gp_mean)(c->N, d, c->nq, c->Zs, c->weights, c->sf2, c->inv_ell, z, m);
    for (long j = 0; j < c->nq; j++) {
        m[j] = m[j] * c->y_std[j] + c->y_mean[j];
        if (F)
            for (long i = 0; i < d; i++) F[j * d + i] = g[j * d + i] * (c->y_std[j] / c->x_std[i]);
    }
    return 0;
}

/* One inner step x -> xn (nx,) (xn may not alias x); -1 and NaN where not finite. s: scratch of
 * 2 nq + nq d + 2 d doubles. */
static int inner_step(const res_t *c, const double *x, const double *u, double *xn, double *s)
{
    long nq = c->nq;
    double *qb = s, *m = s + nq, *g = s + 2 * nq, *z = g + nq * c->d;
    if (gp_eval(c, x, u, m, 0, g, z) != 0) {
        for (long i = 0; i < 2 * nq; i++) xn[i] = NAN;
        return -1;
    }
    ((qdd_fn)c->base_qdd)(c->base_ctx, x, u, qb);
    for (long i = 0; i < nq; i++) {
        double v1 = x[nq + i] + c->dt * (qb[i] + m[i]);
        xn[nq + i] = v1;
        xn[i] = x[i] + c->dt * v1;
    }
    return 0;
}

/* One inner step's A (nx, nx), aff (nx,), B (nx, nu); s: scratch of nq + 2 nq d + d doubles. */
static int inner_lin(const res_t *c, const double *x, const double *u, double *A, double *aff, double *B, double *s)
{
    long nq = c->nq, nx = 2 * nq, d = c->d, nu = d - nx;
    double *m = s, *F = m + nq, *st = F + nq * d;
    if (gp_eval(c, x, u, m, F, st, st + nq * d) != 0) {
        for (long i = 0; i < nx * nx; i++) A[i] = NAN;
        for (long i = 0; i < nx * nu; i++) B[i] = NAN;
        for (long i = 0; i < nx; i++) aff[i] = NAN;
        return -1;
    }
    ((lin_fn)c->base_lin)(c->base_ctx, x, u, A, aff, B);
    /* the step is the base's plus (dt^2 m, dt m); the GP's part of A, B is G = (dt^2 F; dt F), so
     * aff = aff_base + (dt^2 m, dt m) - G (x, u) */
    double dt = c->dt, dt2 = dt * dt;
    for (long j = 0; j < nq; j++) {
        const double *Fj = F + j * d;
        double *Av = A + (nq + j) * nx, *Aq = A + j * nx, *Bv = B + (nq + j) * nu, *Bq = B + j * nu;
        double gx = 0.0;
        for (long i = 0; i < nx; i++) { Av[i] += dt * Fj[i]; Aq[i] += dt2 * Fj[i]; gx += Fj[i] * x[i]; }
        for (long i = 0; i < nu; i++) { Bv[i] += dt * Fj[nx + i]; Bq[i] += dt2 * Fj[nx + i]; gx += Fj[nx + i] * u[i]; }
        aff[nq + j] += dt * (m[j] - gx);
        aff[j] += dt2 * (m[j] - gx);
    }
    return 0;
}

/* The control step's linearization (the csweep.c lin_t contract): k inner steps chained. */
int res_linearize(const void *cv, const double *x, const double *u, double *A, double *aff, double *B)
{
    const res_t *c = (const res_t *)cv;
    long nq = c->nq, nx = 2 * nq, nu = c->d - nx;
    double *w = c->work;
    double *Ai = w, *Bi = Ai + nx * nx, *ai = Bi + nx * nu, *An = ai + nx, *Bn = An + nx * nx;
    double *xi = Bn + nx * nu, *xt = xi + nx, *s = xt + nx;
    if (c->k == 1) return inner_lin(c, x, u, A, aff, B, s);
    int rc = 0;
    for (long i = 0; i < nx * nx; i++) A[i] = 0.0;
    for (long i = 0; i < nx; i++) A[i * nx + i] = 1.0;
    for (long i = 0; i < nx * nu; i++) B[i] = 0.0;
    memcpy(xi, x, nx * sizeof(double));
    for (long step = 0; step < c->k; step++) {
        if (inner_lin(c, xi, u, Ai, ai, Bi, s) != 0) rc = -1;
        for (long r = 0; r < nx; r++) {          /* A <- Ai A, B <- Ai B + Bi, xi <- Ai xi + ai + Bi u */
            const double *Ar = Ai + r * nx;
            for (long col = 0; col < nx; col++) {
                double acc = 0.0;
                for (long p = 0; p < nx; p++) acc += Ar[p] * A[p * nx + col];
                An[r * nx + col] = acc;
            }
            for (long col = 0; col < nu; col++) {
                double acc = 0.0;
                for (long p = 0; p < nx; p++) acc += Ar[p] * B[p * nu + col];
                Bn[r * nu + col] = acc + Bi[r * nu + col];
            }
            double acc = 0.0, bu = 0.0;
            for (long p = 0; p < nx; p++) acc += Ar[p] * xi[p];
            for (long p = 0; p < nu; p++) bu += Bi[r * nu + p] * u[p];
            xt[r] = acc + ai[r] + bu;
        }
        memcpy(A, An, nx * nx * sizeof(double));
        memcpy(B, Bn, nx * nu * sizeof(double));
        memcpy(xi, xt, nx * sizeof(double));
    }
    for (long r = 0; r < nx; r++) {
        double sa = 0.0, sb = 0.0;
        for (long i = 0; i < nx; i++) sa += A[r * nx + i] * x[i];
        for (long i = 0; i < nu; i++) sb += B[r * nu + i] * u[i];
        aff[r] = xi[r] - sa - sb;
    }
    return rc;
}

void *res_linearize_address(void) { return (void *)&res_linearize; }

/* One control step: k inner steps from x (nx,) with u held, into xn (nx,). */
int res_step(const res_t *c, const double *x, const double *u, double *xn)
{
    long nx = 2 * c->nq;
    double *xi = c->work, *xt = xi + nx, *s = xt + nx;
    int rc = 0;
    memcpy(xi, x, nx * sizeof(double));
    for (long step = 0; step < c->k; step++) {
        if (inner_step(c, xi, u, xt, s) != 0) rc = -1;
        memcpy(xi, xt, nx * sizeof(double));
    }
    memcpy(xn, xi, nx * sizeof(double));
    return rc;
}

/* The rollout of u_t = o_t + O_t x_t from X[0]: X (T + 1, nx), U (T, nu); NaN propagates. */
int res_rollout(const res_t *c, long T, const double *o, const double *O, double *X, double *U)
{
    long nx = 2 * c->nq, nu = c->d - nx;
    for (long t = 0; t < T; t++) {
        const double *x = X + t * nx, *Ot = O + t * nu * nx;
        double *u = U + t * nu;
        for (long r = 0; r < nu; r++) {
            double acc = 0.0;
            for (long i = 0; i < nx; i++) acc += Ot[r * nx + i] * x[i];
            u[r] = o[t * nu + r] + acc;
        }
        res_step(c, x, u, X + (t + 1) * nx);
    }
    return 0;
}
