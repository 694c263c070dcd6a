/* Compiled task messages (planning/kernels.py: compile_task_set): the summed gradient l_x and
 * Gauss-Newton Hessian l_xx of via-point terms w (x* - phi(q))^T C (x* - phi(q)) and state targets
 * w (x - x*)^T C (x - x*) at one state, as ViaPoint / StateTarget.add_point_derivatives. The task
 * maps' kinematics come from a robot's tree library (plants/codegen/rbd_kernels.c) through the
 * function pointers of taskset_t; the AICO sweep kernel (csweep.c) calls taskset_eval. */
#include <math.h>
#include <string.h>

/* what a term evaluates (planning/kernels.py: MessageKind, the same values) */
enum message_kind { MK_FRAME_POINTS = 0, MK_CENTER_OF_MASS = 1, MK_ROLL = 2, MK_JOINTS = 3, MK_STATE_TARGET = 4 };

#define TMAX 64      /* rows of one task map's output */
#define MPMAX 64     /* plant positions */
/* Accepted shapes (planning/kernels.py: compile_task_set checks them and leaves any other problem to
 * the Python task messages): plant positions 1 <= m <= MPMAX, planning positions 1 <= nq <= MPMAX with
 * nx = 2 nq, P (m, nq); per term dim <= TMAX rows, a frame's 3 npts <= TMAX, rows[r] < the map's full
 * output (3 npts, 3 or 1), S (dim, nq), target (dim or nx), C (dim x dim or nx x nx), active (T + 1);
 * t in 0..T. */

typedef int (*frame_points_fn)(const double *q, int b, const double *RBF, const double *pBF, int npts,
                               const double *pts, double *pos, double *J);
typedef int (*com_fn)(const double *q, double *c, double *J);
typedef int (*frame_rotation_fn)(const double *q, int b, const double *RBF, double *RWF, double *Jw);

typedef struct {
    long kind;               /* enum message_kind */
    long body, npts, dim;
    const double *R_BF, *p_BF, *pts;
    const long *rows;        /* rows of the map's full output kept (dim) */
    const double *S;         /* joints: (dim, nq) */
    const double *target, *C;
    double weight;
    const unsigned char *active;   /* (T + 1) */
} vterm_t;

typedef struct {
    long nq, nx, identity, nterms, m;   /* m: the plant's positions (the tree's MP) */
    const double *P;         /* (m, nq) */
    const vterm_t *terms;
    frame_points_fn frame_points;       /* the robot's tree library */
    com_fn com;
    frame_rotation_fn frame_rotation;
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

int taskset_eval(const void *cv, long t, const double *x, double *lx, double *lxx)
{
    const taskset_t *ts = (const taskset_t *)cv;
    int nq = (int)ts->nq, nx = (int)ts->nx, MP = (int)ts->m;
    double qp[MPMAX], full[TMAX], Jf[TMAX * MPMAX], phi[TMAX], J[TMAX * MPMAX], CJ[TMAX * MPMAX], e[2 * MPMAX];
    memset(lx, 0, sizeof(double) * nx);
    memset(lxx, 0, sizeof(double) * nx * nx);
    if (ts->identity) memcpy(qp, x, sizeof(double) * MP);
    else for (int i = 0; i < MP; i++) { double v = 0.0; for (int j = 0; j < nq; j++) v += ts->P[i * nq + j] * x[j]; qp[i] = v; }
    for (long k = 0; k < ts->nterms; k++) {
        const vterm_t *tm = ts->terms + k;
        if (tm->weight == 0.0 || !tm->active[t]) continue;
        int dim = (int)tm->dim;
        double w2 = 2.0 * tm->weight;
        if (tm->kind == MK_STATE_TARGET) {   /* state target: lx = 2w C (x - x*), lxx = 2w C */
            for (int i = 0; i < nx; i++) e[i] = x[i] - tm->target[i];
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
        if (tm->kind == MK_JOINTS) {   /* phi = S q, J = S (planning coordinates) */
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
        /* CJ = C J; lx[:nq] -= 2w (x* - phi)^T CJ; lxx[:nq, :nq] += 2w J^T CJ (sums in a
         * different order than the numpy terms', equal to rounding) */
        for (int r = 0; r < dim; r++) {
            e[r] = tm->target[r] - phi[r];
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
    return 0;
}

void *taskset_eval_address(void) { return (void *)&taskset_eval; }
