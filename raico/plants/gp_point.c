#include <math.h>
/* One query point of independent SE-ARD GPs sharing their training inputs (raico/plants/gp.py, scaled
 * units). Zs (D, N, d): training inputs divided by each output's length-scales; weights (D, N);
 * sf2 (D,); inv_ell (D, d); z (d,) scaled query.
 * Accepted shapes (raico/plants/gp.py routes every other model to its numpy code): N >= 1 training (or
 * inducing) points, 1 <= d <= 256 inputs (the stack buffers below), D >= 1 outputs, and for
 * gp_linearize also D <= 128 and d >= 2 D (x has 2 D entries, u the other d - 2 D); L (D, N, N);
 * work 2 N doubles; the rollout T >= 0: o (T, d - 2 D), O (T, d - 2 D, 2 D), X (T + 1, 2 D),
 * U (T, d - 2 D). */

/* Mean of output j at the query divided by its length-scales zs (d,); k (N,) receives the kernel
 * vector when not NULL; g (d,) accumulates sum_i w_i k_i (zs_i - zs) when not NULL. */
static double gp_mean_one(long N, long d, const double *Zj, const double *aj, double sf2j,
                          const double *zs, double *k, double *g)
{
    double m = 0.0;
    for (long i = 0; i < N; i++) {
        const double *zi = Zj + i * d;
        double s = 0.0;
        for (long c = 0; c < d; c++) { double e = zi[c] - zs[c]; s += e * e; }
        double e = exp(-0.5 * s);
        double w = aj[i] * sf2j * e;
        if (k) k[i] = sf2j * e;
        m += w;
        if (g) for (long c = 0; c < d; c++) g[c] += w * (zi[c] - zs[c]);
    }
    return m;
}

/* Scaled mean out_m (D,) and its gradient out_g (D, d). */
void gp_point(long N, long d, long D, const double *Zs, const double *weights, const double *sf2,
              const double *inv_ell, const double *z, double *out_m, double *out_g)
{
    double zs[256], g[256];
    for (long j = 0; j < D; j++) {
        const double *ie = inv_ell + j * d;
        for (long c = 0; c < d; c++) { zs[c] = z[c] * ie[c]; g[c] = 0.0; }
        out_m[j] = gp_mean_one(N, d, Zs + j * N * d, weights + j * N, sf2[j], zs, 0, g);
        for (long c = 0; c < d; c++) out_g[j * d + c] = g[c] * ie[c];
    }
}

/* gp_point's scaled mean out_m (D,) alone (the same numbers, no gradient). */
void gp_point_mean(long N, long d, long D, const double *Zs, const double *weights, const double *sf2,
                   const double *inv_ell, const double *z, double *out_m)
{
    double zs[256];
    for (long j = 0; j < D; j++) {
        const double *ie = inv_ell + j * d;
        for (long c = 0; c < d; c++) zs[c] = z[c] * ie[c];
        out_m[j] = gp_mean_one(N, d, Zs + j * N * d, weights + j * N, sf2[j], zs, 0, 0);
    }
}

/* gp_point plus the scaled latent variance out_v (D,) (not clipped) and its gradient out_gv (D, d):
 * with L (D, N, N) the lower Cholesky factors of K + sn2 I (row-major), v = L^-1 k,
 * var = sf2 - v.v, w = L^-T v = (K + sn2 I)^-1 k, dvar/dz = -2 sum_i w_i k_i (z_i - z) / ell^2
 * (thesis eq. 4.2). work: 2 N doubles. */
void gp_point_var(long N, long d, long D, const double *Zs, const double *weights, const double *sf2,
                  const double *inv_ell, const double *L, const double *z, double *out_m, double *out_g,
                  double *out_v, double *out_gv, double *work)
{
    double zs[256], g[256];
    double *k = work, *v = work + N;
    for (long j = 0; j < D; j++) {
        const double *ie = inv_ell + j * d, *Zj = Zs + j * N * d, *Lj = L + j * N * N;
        for (long c = 0; c < d; c++) { zs[c] = z[c] * ie[c]; g[c] = 0.0; }
        out_m[j] = gp_mean_one(N, d, Zj, weights + j * N, sf2[j], zs, k, g);
        for (long c = 0; c < d; c++) out_g[j * d + c] = g[c] * ie[c];
        double vv = 0.0;
        for (long i = 0; i < N; i++) {             /* forward substitution, row by row */
            const double *Li = Lj + i * N;
            double acc = k[i];
            for (long p = 0; p < i; p++) acc -= Li[p] * v[p];
            v[i] = acc / Li[i];
            vv += v[i] * v[i];
        }
        out_v[j] = sf2[j] - vv;
        for (long i = N - 1; i >= 0; i--) {        /* back substitution with L^T, by rows of L */
            const double *Li = Lj + i * N;
            double wi = v[i] / Li[i];
            v[i] = wi;
            for (long p = 0; p < i; p++) v[p] -= Li[p] * wi;
        }
        for (long c = 0; c < d; c++) g[c] = 0.0;
        for (long i = 0; i < N; i++) {
            const double *zi = Zj + i * d;
            double w = v[i] * k[i];
            for (long c = 0; c < d; c++) g[c] += w * (zi[c] - zs[c]);
        }
        for (long c = 0; c < d; c++) out_gv[j * d + c] = -2.0 * g[c] * ie[c];
    }
}

/* Controller rollout on the learned dynamics (raico/plants/learned.py): u_t = o_t + O_t x_t, the GP mean
 * accelerations qdd = m y_std + y_mean at z = ((x, u) - x_mean) / x_std (NaN if z is not finite),
 * semi-implicit Euler v' = v + dt qdd, q' = q + dt v'. D = n_q outputs, n_x = 2 D, n_u = d - n_x;
 * o (T, n_u), O (T, n_u, n_x), X (T + 1, n_x) with X[0] = x0 set by the caller, U (T, n_u). */
void gp_rollout(long T, long N, long d, long D, const double *Zs, const double *weights,
                const double *sf2, const double *inv_ell, const double *x_mean, const double *x_std,
                const double *y_mean, const double *y_std, double dt, const double *o, const double *O,
                double *X, double *U)
{
    long nx = 2 * D, nu = d - nx;
    double z[256], zs[256];
    for (long t = 0; t < T; t++) {
        const double *x = X + t * nx, *ot = o + t * nu, *Ot = O + t * nu * nx;
        double *u = U + t * nu, *x1 = X + (t + 1) * nx;
        for (long r = 0; r < nu; r++) {
            double acc = 0.0;
            for (long c = 0; c < nx; c++) acc += Ot[r * nx + c] * x[c];
            u[r] = ot[r] + acc;
        }
        int finite = 1;
        for (long c = 0; c < d; c++) {
            double xc = c < nx ? x[c] : u[c - nx];
            z[c] = (xc - x_mean[c]) / x_std[c];
            if (!isfinite(z[c])) finite = 0;
        }
        for (long j = 0; j < D; j++) {
            double qdd = NAN;
            if (finite) {
                const double *ie = inv_ell + j * d;
                for (long c = 0; c < d; c++) zs[c] = z[c] * ie[c];
                qdd = gp_mean_one(N, d, Zs + j * N * d, weights + j * N, sf2[j], zs, 0, 0) * y_std[j] + y_mean[j];
            }
            double v1 = x[D + j] + dt * qdd;
            x1[D + j] = v1;
            x1[j] = x[j] + dt * v1;
        }
    }
}

/* The learned dynamics' linearization at one state (raico/plants/learned.py: LearnedDynamics.linearize, the
 * AICO sweep kernel's compiled relinearization, raico/planning/csweep.c lin_t): x (2 D,), u (d - 2 D,) ->
 * A (2 D, 2 D), aff (2 D,), B (2 D, d - 2 D), row-major, with F = d qdd / d(x, u) from the GP mean:
 * dv'/dx = [0, I] + dt F_x, dq'/dx = [I, 0] + dt dv'/dx, dv'/du = dt F_u, dq'/du = dt dv'/du,
 * aff = f(x, u) - A x - B u. NaN everywhere (and -1) where the input is not finite. */
typedef struct {
    long N, d, D;
    const double *Zs, *weights, *sf2, *inv_ell, *x_mean, *x_std, *y_mean, *y_std;
    double dt;
} gp_dyn_t;

int gp_linearize(const void *cv, const double *x, const double *u, double *A, double *aff, double *B)
{
    const gp_dyn_t *c = (const gp_dyn_t *)cv;
    long d = c->d, D = c->D, nx = 2 * D, nu = d - nx;
    double z[256], m[128], g[128 * 256];
    int finite = 1;
    for (long k = 0; k < d; k++) {
        double xk = k < nx ? x[k] : u[k - nx];
        z[k] = (xk - c->x_mean[k]) / c->x_std[k];
        if (!isfinite(z[k])) finite = 0;
    }
    if (!finite) {
        for (long i = 0; i < nx * nx; i++) A[i] = NAN;
        for (long i = 0; i < nx * nu; i++) B[i] = NAN;
        for (long i = 0; i < nx; i++) aff[i] = NAN;
        return -1;
    }
    gp_point(c->N, d, D, c->Zs, c->weights, c->sf2, c->inv_ell, z, m, g);
    double dt = c->dt;
    for (long i = 0; i < D; i++) {
        double *Av = A + (D + i) * nx, *Aq = A + i * nx, *Bv = B + (D + i) * nu, *Bq = B + i * nu;
        for (long k = 0; k < d; k++) {
            double F = g[i * d + k] * (c->y_std[i] / c->x_std[k]);
            if (k < nx) Av[k] = F * dt; else Bv[k - nx] = F * dt;
        }
        Av[D + i] += 1.0;
        for (long k = 0; k < nx; k++) Aq[k] = Av[k] * dt;
        Aq[i] += 1.0;
        for (long k = 0; k < nu; k++) Bq[k] = Bv[k] * dt;
        double mean = m[i] * c->y_std[i] + c->y_mean[i];
        double v1 = x[D + i] + dt * mean;
        aff[D + i] = v1;
        aff[i] = x[i] + dt * v1;
    }
    for (long r = 0; r < nx; r++) {
        double s = 0.0;
        for (long k = 0; k < nx; k++) s += A[r * nx + k] * x[k];
        aff[r] -= s;
        s = 0.0;
        for (long k = 0; k < nu; k++) s += B[r * nu + k] * u[k];
        aff[r] -= s;
    }
    return 0;
}

void *gp_linearize_address(void) { return (void *)&gp_linearize; }
