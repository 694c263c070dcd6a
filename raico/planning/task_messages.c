/* Compiled task messages (raico/planning/kernels.py: compile_task_set): the summed gradient l_x and
 * Gauss-Newton Hessian l_xx of via-point terms w (x* - phi(q))^T C (x* - phi(q)), one-sided bounds
 * w sum_i max(0, a_i . phi(q) - b_i)^2 and state targets w (x - x*)^T C (x - x*) at one state, as
 * ViaPoint / TaskInequality / StateTarget.add_point_derivatives. The maps: frame points, CoM, roll,
 * joints, and a frame's orientation / placement error log3(R*^T R) / log6(M*^-1 M) with their exact
 * Jacobians (Pinocchio's Jlog3 / Jlog6, as raico/plants/taskmaps.py). The task
 * maps' kinematics come from a robot's tree library (raico/plants/codegen/rbd_kernels.c) through the
 * function pointers of taskset_t; the AICO sweep kernel (csweep.c) calls taskset_eval. */
#include <math.h>
#include <string.h>

/* what a term evaluates (raico/planning/kernels.py: MessageKind, the same values) */
enum message_kind { MK_FRAME_POINTS = 0, MK_CENTER_OF_MASS = 1, MK_ROLL = 2, MK_JOINTS = 3, MK_STATE_TARGET = 4,
                    MK_FRAME_ROTATION = 5, MK_FRAME_PLACEMENT = 6, MK_GRAVITY = 7 };
/* what a term costs of its map's value (raico/planning/kernels.py: CostKind) */
enum cost_kind { CK_VIA = 0, CK_BOUNDS = 1 };

#define TMAX 64      /* rows of one task map's output */
#define MPMAX 64     /* plant positions */
#define BMAX 128     /* bounds of one term */
/* Accepted shapes (raico/planning/kernels.py: compile_task_set checks them and leaves any other problem to
 * the Python task messages): plant positions 1 <= m <= MPMAX, planning positions 1 <= nq <= MPMAX with
 * nx = 2 nq, P (m, nq); per term dim <= TMAX rows, a frame's 3 npts <= TMAX, rows[r] < the map's full
 * output (3 npts, 3, 1, 3 or 6), S (dim, nq), target (dim or nx), C (dim x dim or nx x nx), active (T + 1);
 * bounds: nb <= BMAX, A (nb, dim), b (nb); R_target (3 x 3), p_target (3); t in 0..T. */

typedef int (*frame_points_fn)(const double *q, int b, const double *RBF, const double *pBF, int npts,
                               const double *pts, double *pos, double *J);
typedef int (*com_fn)(const double *q, double *c, double *J);
typedef int (*frame_rotation_fn)(const double *q, int b, const double *RBF, double *RWF, double *Jw);
typedef int (*gravity_fn)(const double *q, double *g, double *G);

typedef struct {
    long kind;               /* enum message_kind */
    long body, npts, dim;
    const double *R_BF, *p_BF, *pts;
    const long *rows;        /* rows of the map's full output kept (dim) */
    const double *S;         /* joints: (dim, nq) */
    const double *target, *C;
    double weight;
    const unsigned char *active;   /* (T + 1) */
    long cost, nb;           /* enum cost_kind; bounds: their number */
    const double *A, *b;     /* bounds: A (nb, dim), b (nb) */
    const double *R_target, *p_target;   /* rotation / placement: the target pose (world) */
    long target_stride;      /* > 0: the target of step t is target + t * target_stride (gravity: u_t; a
                              * state target per step) */
    long last_step;          /* > 0: the term costs steps t < last_step only (a joint term: 0..T-1) */
} vterm_t;

typedef struct {
    long nq, nx, identity, nterms, m;   /* m: the plant's positions (the tree's MP) */
    const double *P;         /* (m, nq) */
    const vterm_t *terms;
    frame_points_fn frame_points;       /* the robot's tree library */
    com_fn com;
    frame_rotation_fn frame_rotation;
    gravity_fn gravity;      /* g = tau(q, 0, 0) (m) and, unless NULL, dg/dq (m x m) */
} taskset_t;

/* y (n) += a x (n), 4 at a time with vector extensions (per element the same multiply and add as
 * the scalar loop: gcc -O2 does not vectorize loops of unknown length) */
typedef double v4d_ __attribute__((vector_size(32)));
static inline void v_axpy(int n, double a, const double *x, double *y)
{
    int j = 0;
    for (; j + 4 <= n; j += 4) {
        v4d_ xv, yv;
        memcpy(&xv, x + j, sizeof xv);
        memcpy(&yv, y + j, sizeof yv);
        yv += a * xv;
        memcpy(y + j, &yv, sizeof yv);
    }
    for (; j < n; j++) y[j] += a * x[j];
}

/* -- SO(3) / SE(3) logarithms and their Jacobians: raico/plants/taskmaps.py's formulas (Pinocchio's), 3 x 3
 * matrices row-major ------------------------------------------------------------------------------ */
static double prec2(void) { return pow(2.220446049250313e-16, 1.0 / 3.0); }   /* eps^(1/3) */
static double prec3(void) { return pow(2.220446049250313e-16, 1.0 / 4.0); }   /* eps^(1/4) */
#define EPS_ 2.220446049250313e-16

static void cross3(const double *a, const double *b, double *c)
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

/* the rotation vector r (3) of R (3 x 3) and its angle theta (log3_angle of raico/plants/taskmaps.py) */
static double log3_angle(const double *R, double *r)
{
    double c0[3], c1[3], c2[3], c0n[3], Rn[9];
    double n0 = sqrt(R[0] * R[0] + R[3] * R[3] + R[6] * R[6]), n1 = sqrt(R[1] * R[1] + R[4] * R[4] + R[7] * R[7]);
    for (int i = 0; i < 3; i++) { c0[i] = R[3 * i] / n0; c1[i] = R[3 * i + 1] / n1; }
    cross3(c0, c1, c2);
    cross3(c1, c2, c0n);
    for (int i = 0; i < 3; i++) { Rn[3 * i] = c0n[i]; Rn[3 * i + 1] = c1[i]; Rn[3 * i + 2] = c2[i]; }
    double P2 = prec2(), tr = Rn[0] + Rn[4] + Rn[8], cv = (tr - 1.0) / 2.0;
    if (cv >= -1.0 + P2) {
        double theta = tr <= 3.0 - P2 ? acos(cv) : sqrt(2.0 * (1.0 - cv) + EPS_ * EPS_);
        double a[3] = {0.5 * (Rn[7] - Rn[5]), 0.5 * (Rn[2] - Rn[6]), 0.5 * (Rn[3] - Rn[1])};
        double t;
        if (theta >= P2) t = theta / sin(theta);
        else { double n2 = a[0] * a[0] + a[1] * a[1] + a[2] * a[2]; t = 1.0 + n2 / 6.0 + n2 * n2 * 3.0 / 40.0; }
        for (int i = 0; i < 3; i++) r[i] = t * a[i];
        return theta;
    }
    /* near pi: the axis from the quaternion of the largest diagonal entry */
    double val[3];
    for (int i = 0; i < 3; i++) val[i] = 2.0 * Rn[4 * i] - tr + 1.0;
    int i0 = val[0] >= val[1] ? (val[0] >= val[2] ? 0 : 2) : (val[1] >= val[2] ? 1 : 2);
    int i1 = (i0 + 1) % 3, i2 = (i0 + 2) % 3;
    double s = sqrt(val[i0] + EPS_ + EPS_ * EPS_) * (Rn[3 * i2 + i1] >= Rn[3 * i1 + i2] ? 1.0 : -1.0);
    double axis[3];
    axis[i0] = s / 2.0;
    axis[i1] = (Rn[3 * i1 + i0] + Rn[3 * i0 + i1]) / (2.0 * s);
    axis[i2] = (Rn[3 * i2 + i0] + Rn[3 * i0 + i2]) / (2.0 * s);
    double w = (Rn[3 * i2 + i1] - Rn[3 * i1 + i2]) / (2.0 * s);
    double norm = sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
    double theta = 2.0 * atan2(norm, w);
    for (int i = 0; i < 3; i++) r[i] = theta * axis[i] / norm;
    return theta;
}

/* Jlog3 (3 x 3) from theta and r = log3(R) */
static void jlog3(double theta, const double *r, double *J)
{
    double alpha, diag;
    if (theta < prec3()) {
        alpha = 1.0 / 12.0 + theta * theta / 720.0;
        diag = 0.5 * (2.0 - theta * theta / 6.0);
    } else {
        double st_1mct = sin(theta) / (1.0 - cos(theta));
        alpha = 1.0 / (theta * theta) - st_1mct / (2.0 * theta);
        diag = 0.5 * theta * st_1mct;
    }
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) J[3 * i + j] = alpha * r[i] * r[j] + (i == j ? diag : 0.0);
    J[1] -= 0.5 * r[2]; J[2] += 0.5 * r[1];
    J[3] += 0.5 * r[2]; J[5] -= 0.5 * r[0];
    J[6] -= 0.5 * r[1]; J[7] += 0.5 * r[0];
}

/* log6 (6, linear part first) of the pose (R, p) and Jlog6 (6 x 6) */
static void log6_jlog6(const double *R, const double *p, double *out, double *J6)
{
    double a[3] = {0.5 * (R[7] - R[5]), 0.5 * (R[2] - R[6]), 0.5 * (R[3] - R[1])};
    double t2 = a[0] * a[0] + a[1] * a[1] + a[2] * a[2], w[3], alpha, beta, wxp[3];
    double theta = log3_angle(R, w);
    if (R[0] + R[4] + R[8] >= 3.0 - prec2()) {
        alpha = 1.0 - t2 / 12.0 - t2 * t2 / 720.0;
        beta = 1.0 / 12.0 + t2 / 720.0;
    } else {
        double st = sin(theta), ct = cos(theta);
        alpha = theta * st / (2.0 * (1.0 - ct));
        beta = 1.0 / (theta * theta) - st / (2.0 * theta * (1.0 - ct));
    }
    cross3(w, p, wxp);
    double wp = w[0] * p[0] + w[1] * p[1] + w[2] * p[2];
    for (int i = 0; i < 3; i++) { out[i] = alpha * p[i] - 0.5 * wxp[i] + beta * wp * w[i]; out[3 + i] = w[i]; }
    /* Jlog6 = [[A, C A], [0, A]] */
    double A[9], C[9], v[3], bd, th2 = theta * theta;
    jlog3(theta, w, A);
    if (theta < prec3()) { beta = 1.0 / 12.0 + th2 / 720.0; bd = 1.0 / 360.0; }
    else {
        double tinv = 1.0 / theta, t2inv = tinv * tinv, st = sin(theta), ct = cos(theta);
        double inv_2_2ct = 1.0 / (2.0 * (1.0 - ct));
        beta = t2inv - st * tinv * inv_2_2ct;
        bd = -2.0 * t2inv * t2inv + (1.0 + st * tinv) * t2inv * inv_2_2ct;
    }
    for (int i = 0; i < 3; i++) v[i] = bd * wp * w[i] - (th2 * bd + 2.0 * beta) * p[i];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) C[3 * i + j] = v[i] * w[j] + beta * w[i] * p[j] + (i == j ? wp * beta : 0.0);
    C[1] -= 0.5 * p[2]; C[2] += 0.5 * p[1];
    C[3] += 0.5 * p[2]; C[5] -= 0.5 * p[0];
    C[6] -= 0.5 * p[1]; C[7] += 0.5 * p[0];
    memset(J6, 0, sizeof(double) * 36);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double ca = 0.0;
            for (int k = 0; k < 3; k++) ca += C[3 * i + k] * A[3 * k + j];
            J6[6 * i + j] = A[3 * i + j];
            J6[6 * (3 + i) + 3 + j] = A[3 * i + j];
            J6[6 * i + 3 + j] = ca;
        }
}

/* rows (nr x MP) = M (nr x nc) X (nc x MP) */
static void small_mm(int nr, int nc, int MP, const double *M, const double *X, double *out)
{
    for (int i = 0; i < nr; i++) {
        double *o = out + i * MP;
        for (int j = 0; j < MP; j++) o[j] = 0.0;
        for (int k = 0; k < nc; k++) { double m = M[i * nc + k]; for (int j = 0; j < MP; j++) o[j] += m * X[k * MP + j]; }
    }
}

/* the orientation error r = log3(Rt^T R) (3) and J = Jlog3 R^T Jw (3 x MP) */
static void rotation_error(const double *Rt, const double *R, const double *Jw, int MP, double *r, double *J)
{
    double Rrel[9], Jl[9], M[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) Rrel[3 * i + j] = Rt[i] * R[j] + Rt[3 + i] * R[3 + j] + Rt[6 + i] * R[6 + j];
    double theta = log3_angle(Rrel, r);
    jlog3(theta, r, Jl);
    for (int i = 0; i < 3; i++)      /* M = Jlog3 R^T */
        for (int j = 0; j < 3; j++) M[3 * i + j] = Jl[3 * i] * R[3 * j] + Jl[3 * i + 1] * R[3 * j + 1] + Jl[3 * i + 2] * R[3 * j + 2];
    small_mm(3, 3, MP, M, Jw, J);
}

/* the placement error log6(Mt^-1 M) (6) and J = Jlog6 [R^T Jv; R^T Jw] (6 x MP) */
static void placement_error(const double *Rt, const double *pt, const double *R, const double *p,
                            const double *Jv, const double *Jw, int MP, double *r, double *J)
{
    double Rrel[9], prel[3], J6[36], RT[9], JL[6 * MPMAX];
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++) { Rrel[3 * i + j] = Rt[i] * R[j] + Rt[3 + i] * R[3 + j] + Rt[6 + i] * R[6 + j]; RT[3 * i + j] = R[3 * j + i]; }
        prel[i] = Rt[i] * (p[0] - pt[0]) + Rt[3 + i] * (p[1] - pt[1]) + Rt[6 + i] * (p[2] - pt[2]);
    }
    log6_jlog6(Rrel, prel, r, J6);
    small_mm(3, 3, MP, RT, Jv, JL);
    small_mm(3, 3, MP, RT, Jw, JL + 3 * MP);
    small_mm(6, 6, MP, J6, JL, J);
}

/* the terms at one state x (nx) of step t: lx (nx), lxx (nx x nx) set to their summed gradient and
 * Gauss-Newton Hessian unless NULL; *cost (unless NULL) gains their summed value */
static void eval_terms(const taskset_t *ts, long t, const double *x, double *lx, double *lxx, double *cost)
{
    int nq = (int)ts->nq, nx = (int)ts->nx, MP = (int)ts->m;
    double qp[MPMAX], full[TMAX], Jf[TMAX * MPMAX], phi[TMAX], J[TMAX * MPMAX], CJ[TMAX * MPMAX], e[2 * MPMAX];
    if (lx) {
        memset(lx, 0, sizeof(double) * nx);
        memset(lxx, 0, sizeof(double) * nx * nx);
    }
    if (ts->identity) memcpy(qp, x, sizeof(double) * MP);
    else for (int i = 0; i < MP; i++) { double v = 0.0; for (int j = 0; j < nq; j++) v += ts->P[i * nq + j] * x[j]; qp[i] = v; }
    for (long k = 0; k < ts->nterms; k++) {
        const vterm_t *tm = ts->terms + k;
        if (tm->weight == 0.0 || !tm->active[t] || (tm->last_step > 0 && t >= tm->last_step)) continue;
        int dim = (int)tm->dim;
        const double *target = tm->target + (tm->target_stride > 0 ? t * tm->target_stride : 0);
        double w2 = 2.0 * tm->weight;
        if (tm->kind == MK_STATE_TARGET) {   /* state target: lx = 2w C (x - x*), lxx = 2w C */
            for (int i = 0; i < nx; i++) e[i] = x[i] - target[i];
            if (cost) {
                double c = 0.0;
                for (int i = 0; i < nx; i++) { double v = 0.0; for (int j = 0; j < nx; j++) v += tm->C[i * nx + j] * e[j]; c += e[i] * v; }
                *cost += tm->weight * c;
            }
            if (!lx) continue;
            for (int j = 0; j < nx; j++) {
                double v = 0.0;
                for (int i = 0; i < nx; i++) v += e[i] * tm->C[i * nx + j];
                lx[j] += w2 * v;
            }
            for (int i = 0; i < nx * nx; i++) lxx[i] += w2 * tm->C[i];
            continue;
        }
        if (tm->kind == MK_FRAME_POINTS) {
            ts->frame_points(qp, (int)tm->body, tm->R_BF, tm->p_BF, (int)tm->npts, tm->pts, full, Jf);
        } else if (tm->kind == MK_CENTER_OF_MASS) {
            ts->com(qp, full, Jf);
        } else if (tm->kind == MK_FRAME_ROTATION || tm->kind == MK_FRAME_PLACEMENT) {
            double R[9], Jw[3 * MPMAX];
            ts->frame_rotation(qp, (int)tm->body, tm->R_BF, R, Jw);
            if (tm->kind == MK_FRAME_ROTATION) rotation_error(tm->R_target, R, Jw, MP, full, Jf);
            else {
                double p[3], Jv[3 * MPMAX], origin[3] = {0.0, 0.0, 0.0};
                ts->frame_points(qp, (int)tm->body, tm->R_BF, tm->p_BF, 1, origin, p, Jv);
                placement_error(tm->R_target, tm->p_target, R, p, Jv, Jw, MP, full, Jf);
            }
        } else if (tm->kind == MK_ROLL) {   /* roll = atan2(R[2,1], R[2,2]) of the frame's rotation */
            double R[9], Jw[3 * MPMAX];
            ts->frame_rotation(qp, (int)tm->body, tm->R_BF, R, Jw);
            double y0 = R[1], y1 = R[4], a = R[7], z0 = R[2], z1 = R[5], b = R[8], den = a * a + b * b;
            full[0] = atan2(a, b);
            for (int j = 0; j < MP; j++) {
                double da = y1 * Jw[j] - y0 * Jw[MP + j], db = z1 * Jw[j] - z0 * Jw[MP + j];
                Jf[j] = (b * da - a * db) / den;
            }
        }
        if (tm->kind == MK_GRAVITY) {   /* phi = g(q) = P^T tau(P q, 0, 0), J = P^T dtau/dq P */
            /* the derivatives (Jf: MP x MP) only where a gradient is asked (a cost alone needs g) */
            ts->gravity(qp, full, lx ? Jf : NULL);
            for (int r = 0; r < dim; r++) {
                double *Jo = J + r * nq, v = 0.0;
                if (ts->identity) { phi[r] = full[r]; if (lx) memcpy(Jo, Jf + r * MP, sizeof(double) * nq); continue; }
                if (lx) for (int j = 0; j < nq; j++) Jo[j] = 0.0;
                for (int i = 0; i < MP; i++) {
                    double pir = ts->P[i * nq + r];
                    if (pir == 0.0) continue;
                    v += pir * full[i];
                    if (lx) for (int k = 0; k < MP; k++) v_axpy(nq, pir * Jf[i * MP + k], ts->P + k * nq, Jo);
                }
                phi[r] = v;
            }
        } else if (tm->kind == MK_JOINTS) {   /* phi = S q, J = S (planning coordinates) */
            for (int r = 0; r < dim; r++) {
                double v = 0.0;
                for (int j = 0; j < nq; j++) v += tm->S[r * nq + j] * x[j];
                phi[r] = v;
                memcpy(J + r * nq, tm->S + r * nq, sizeof(double) * nq);
            }
        } else {
            for (int r = 0; r < dim; r++) {
                int src = (int)tm->rows[r];
                phi[r] = full[src];
                const double *Jr = Jf + src * MP;
                double *Jo = J + r * nq;
                if (ts->identity) memcpy(Jo, Jr, sizeof(double) * nq);
                else {   /* J = Jf P by rows of P */
                    for (int j = 0; j < nq; j++) Jo[j] = 0.0;
                    for (int i = 0; i < MP; i++) v_axpy(nq, Jr[i], ts->P + i * nq, Jo);
                }
            }
        }
        if (tm->cost == CK_BOUNDS) {   /* h = max(0, A phi - b): lx += 2w (A J)^T h, lxx += 2w (A_h J)^T (A_h J) */
            for (int i = 0; i < tm->nb; i++) {
                const double *Ai = tm->A + i * dim;
                double v = 0.0;
                for (int r = 0; r < dim; r++) v += Ai[r] * phi[r];
                double h = v - tm->b[i];
                if (!(h > 0.0)) continue;
                if (cost) *cost += tm->weight * h * h;
                if (!lx) continue;
                for (int j = 0; j < nq; j++) e[j] = 0.0;    /* e = a_i J (nq) */
                for (int r = 0; r < dim; r++) v_axpy(nq, Ai[r], J + r * nq, e);
                v_axpy(nq, w2 * h, e, lx);
                for (int a = 0; a < nq; a++) v_axpy(nq, w2 * e[a], e, lxx + a * nx);
            }
            continue;
        }
        /* CJ = C J; lx[:nq] -= 2w (x* - phi)^T CJ; lxx[:nq, :nq] += 2w J^T CJ (sums in a
         * different order than the numpy terms', equal to rounding) */
        for (int r = 0; r < dim; r++) e[r] = target[r] - phi[r];
        if (cost) {
            double c = 0.0;
            for (int r = 0; r < dim; r++) { double v = 0.0; for (int i = 0; i < dim; i++) v += tm->C[r * dim + i] * e[i]; c += e[r] * v; }
            *cost += tm->weight * c;
        }
        if (!lx) continue;
        for (int r = 0; r < dim; r++) {
            double *CJr = CJ + r * nq;
            for (int j = 0; j < nq; j++) CJr[j] = 0.0;
            for (int i = 0; i < dim; i++) v_axpy(nq, tm->C[r * dim + i], J + i * nq, CJr);
        }
        for (int r = 0; r < dim; r++) v_axpy(nq, -w2 * e[r], CJ + r * nq, lx);
        for (int r = 0; r < dim; r++) {
            const double *Jr = J + r * nq, *CJr = CJ + r * nq;
            for (int i = 0; i < nq; i++) v_axpy(nq, w2 * Jr[i], CJr, lxx + i * nx);
        }
    }
}

int taskset_eval(const void *cv, long t, const double *x, double *lx, double *lxx)
{
    eval_terms((const taskset_t *)cv, t, x, lx, lxx, NULL);
    return 0;
}

/* K states X (K, nx) of steps steps[k] (each in 0..T): LX (K, nx), LXX (K, nx, nx) as taskset_eval
 * row by row unless LX is NULL; costs (K) set to each row's summed value unless NULL */
int taskset_rows(const void *cv, long K, const long *steps, const double *X, double *LX, double *LXX, double *costs)
{
    const taskset_t *ts = (const taskset_t *)cv;
    long nx = ts->nx;
    for (long k = 0; k < K; k++) {
        double *c = costs ? costs + k : NULL;
        if (c) *c = 0.0;
        eval_terms(ts, steps[k], X + k * nx, LX ? LX + k * nx : NULL, LX ? LXX + k * nx * nx : NULL, c);
    }
    return 0;
}

void *taskset_eval_address(void) { return (void *)&taskset_eval; }
