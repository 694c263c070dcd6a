/* The augmented Lagrangian of box constraints (raico/planning/constraints.py: StateBox, ControlBox; the
 * shifted workspace's FiniteBoxAL, raico/planning/aico/shift.py) in one pass per box: its rows
 * g = [z[idx] - hi, lo - z[idx]], the multipliers' candidate lam = max(0, y + mu g) and the scaled violation,
 * and the Gauss-Newton model lam adds to the messages. The numpy code's operations in its order, without
 * contraction into fused multiply-adds (the library's flags): the same numbers bit for bit.
 *
 * Layout (row-major, numpy's): Z (rows, ldz) the states or the controls; idx (k) columns of Z, each in
 * [0, ldz); lo, hi (rows, k) with b_s = k, or one row (k) shared by every row with b_s = 0; y, lam (rows, 2k)
 * (upper rows first, then the lower ones, as the Python rows); tol (2k). Accepted: rows >= 0, k >= 0.
 */
#include <math.h>

/* lam = max(0, y + mu g) (y NULL: mu g); lam may be y (in place). Returns the number of lam > 0; *viol (if
 * not NULL) = the largest g / tol, at least 0. A side without bound (inf) gives g = -inf, lam = 0. */
long box_lams(long rows, long k, const long *idx, const double *Z, long ldz, const double *lo, const double *hi,
              long b_s, const double *y, double mu, double *lam, const double *tol, double *viol)
{
    long active = 0;
    double v = 0.0;
    for (long t = 0; t < rows; t++) {
        const double *z = Z + t * ldz, *l = lo + t * b_s, *h = hi + t * b_s;
        const double *yt = y ? y + t * 2 * k : 0;
        double *lt = lam + t * 2 * k;
        for (long j = 0; j < k; j++) {
            double x = z[idx[j]], g1 = x - h[j], g2 = l[j] - x;
            double m1 = mu * g1, m2 = mu * g2;
            double z1 = yt ? yt[j] + m1 : m1, z2 = yt ? yt[k + j] + m2 : m2;
            /* numpy's maximum(z, 0): z where z >= 0 (-0 kept) or NaN */
            double a1 = (z1 >= 0.0 || z1 != z1) ? z1 : 0.0, a2 = (z2 >= 0.0 || z2 != z2) ? z2 : 0.0;
            lt[j] = a1;
            lt[k + j] = a2;
            active += (a1 > 0.0) + (a2 > 0.0);
            if (viol) {
                double s1 = g1 / tol[j], s2 = g2 / tol[k + j];
                if (s1 > v) v = s1;
                if (s2 > v) v = s2;
            }
        }
    }
    if (viol) *viol = v;
    return active;
}

/* The model of lam (rows, 2k) added in place: column idx[j] of row t gains lam1 - lam2 in g (g_s doubles
 * between rows; NULL: none) and mu ((lam1 > 0) + (lam2 > 0)) on the diagonal d[t * d_s + idx[j] * d_i];
 * with u (u_s between rows): h[t * h_s + idx[j]] = (h + (mu act) u) - (lam1 - lam2) (a control message
 * h = H u - l_u; g NULL then). */
void box_model(long rows, long k, const long *idx, const double *lam, double mu, double *g, long g_s,
               double *d, long d_s, long d_i, const double *u, long u_s, double *h, long h_s)
{
    for (long t = 0; t < rows; t++) {
        const double *lt = lam + t * 2 * k;
        for (long j = 0; j < k; j++) {
            double a1 = lt[j], a2 = lt[k + j], diff = a1 - a2;
            double act = (double)(a1 > 0.0) + (double)(a2 > 0.0), c = mu * act;
            long i = idx[j];
            if (g) g[t * g_s + i] += diff;
            d[t * d_s + i * d_i] += c;
            if (u) {
                double p = c * u[t * u_s + i];
                double s = h[t * h_s + i] + p;
                h[t * h_s + i] = s - diff;
            }
        }
    }
}
