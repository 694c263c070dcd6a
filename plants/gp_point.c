
#include <math.h>
/* Zs (D, N, d): training inputs divided by each output's length-scales; weights (D, N); sf2 (D,);
 * inv_ell (D, d); z (d,) scaled query. out_m (D,), out_g (D, d): scaled mean and gradient. */
void gp_point(long N, long d, long D, const double *Zs, const double *weights, const double *sf2,
              const double *inv_ell, const double *z, double *out_m, double *out_g)
{
    double zs[256], g[256];
    for (long j = 0; j < D; j++) {
        const double *Zj = Zs + j * N * d, *aj = weights + j * N, *ie = inv_ell + j * d;
        for (long k = 0; k < d; k++) { zs[k] = z[k] * ie[k]; g[k] = 0.0; }
        double m = 0.0;
        for (long i = 0; i < N; i++) {
            const double *zi = Zj + i * d;
            double s = 0.0;
            for (long k = 0; k < d; k++) { double e = zi[k] - zs[k]; s += e * e; }
            double w = aj[i] * sf2[j] * exp(-0.5 * s);
            m += w;
            for (long k = 0; k < d; k++) g[k] += w * (zi[k] - zs[k]);
        }
        out_m[j] = m;
        for (long k = 0; k < d; k++) out_g[j * d + k] = g[k] * ie[k];
    }
}
