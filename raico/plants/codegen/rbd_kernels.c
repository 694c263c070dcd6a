
/* ---- rigid-body kernels (raico/plants/codegen/rbd.py); every scalar is an array of 1 + nd doubles:
 * value, then nd partial derivatives (nd = 0: plain evaluation). A joint turns its body by q about
 * AXIS (revolute), or translates it by q along AXIS where PRISMATIC[b] ---- */
#define L_MAX (1 + 2 * MP)

typedef struct { int nd; } dctx;

static inline void d_set(int L, double *z, double v) { z[0] = v; for (int k = 1; k < L; k++) z[k] = 0.0; }
static inline void d_add(int L, double *z, const double *x, const double *y) { for (int k = 0; k < L; k++) z[k] = x[k] + y[k]; }
static inline void d_sub(int L, double *z, const double *x, const double *y) { for (int k = 0; k < L; k++) z[k] = x[k] - y[k]; }
static inline void d_addmul(int L, double *z, const double *x, const double *y)
{   /* z += x * y */
    double x0 = x[0], y0 = y[0];
    for (int k = 1; k < L; k++) z[k] += x[k] * y0 + x0 * y[k];
    z[0] += x0 * y0;
}
static inline void d_addcmul(int L, double *z, double c, const double *x) { for (int k = 0; k < L; k++) z[k] += c * x[k]; }

static inline void d_submul(int L, double *z, const double *x, const double *y)
{   /* z -= x * y */
    double x0 = x[0], y0 = y[0];
    for (int k = 1; k < L; k++) z[k] -= x[k] * y0 + x0 * y[k];
    z[0] -= x0 * y0;
}

/* 3-vectors and 3x3 matrices of duals: v[i * L + k], M[(3 r + c) * L + k] */
static void dv_cross(int L, double *z, const double *x, const double *y)
{   /* z = x x y (z distinct from x, y) */
    for (int k = 0; k < 3 * L; k++) z[k] = 0.0;
    d_addmul(L, z + 0 * L, x + 1 * L, y + 2 * L); d_submul(L, z + 0 * L, x + 2 * L, y + 1 * L);
    d_addmul(L, z + 1 * L, x + 2 * L, y + 0 * L); d_submul(L, z + 1 * L, x + 0 * L, y + 2 * L);
    d_addmul(L, z + 2 * L, x + 0 * L, y + 1 * L); d_submul(L, z + 2 * L, x + 1 * L, y + 0 * L);
}
/* z = A x, A dual 3x3, x dual 3 */
static void dm_vec(int L, double *z, const double *A, const double *x)
{
    for (int k = 0; k < 3 * L; k++) z[k] = 0.0;
    for (int r = 0; r < 3; r++) for (int c = 0; c < 3; c++) d_addmul(L, z + r * L, A + (3 * r + c) * L, x + c * L);
}
/* z = A c, A dual 3x3, c constant 3 */
static void dm_cvec(int L, double *z, const double *A, const double *c)
{
    for (int k = 0; k < 3 * L; k++) z[k] = 0.0;
    for (int r = 0; r < 3; r++) for (int j = 0; j < 3; j++) d_addcmul(L, z + r * L, c[j], A + (3 * r + j) * L);
}
/* Z = A B, A dual, B constant (row-major 3x3) */
static void dm_cmat(int L, double *Z, const double *A, const double *B)
{
    for (int k = 0; k < 9 * L; k++) Z[k] = 0.0;
    for (int r = 0; r < 3; r++) for (int c = 0; c < 3; c++) for (int j = 0; j < 3; j++)
        d_addcmul(L, Z + (3 * r + c) * L, B[3 * j + c], A + (3 * r + j) * L);
}
/* Z = A B, both dual */
static void dm_mat(int L, double *Z, const double *A, const double *B)
{
    for (int k = 0; k < 9 * L; k++) Z[k] = 0.0;
    for (int r = 0; r < 3; r++) for (int c = 0; c < 3; c++) for (int j = 0; j < 3; j++)
        d_addmul(L, Z + (3 * r + c) * L, A + (3 * r + j) * L, B + (3 * j + c) * L);
}

/* Derivative slots: a body's quantities depend only on the positions and velocities of the
 * joints between it and the world, so body b's duals carry NDB[b] partials (slots 1..NDB[b]):
 * its parent's, then d/dq_k and d/dv_k of its own joint k (if revolute). SLOT[b][s] is the global
 * index (q_k: k, v_k: MP + k) of slot s + 1. */
static int NDB[NB], SLOT[NB][2 * MP], maps_ready = 0;

static void init_maps(void)
{
    if (maps_ready) return;
    for (int b = 0; b < NB; b++) {
        int pa = PARENT[b], nd = 0;
        if (pa >= 0) { nd = NDB[pa]; memcpy(SLOT[b], SLOT[pa], sizeof(int) * nd); }
        if (QIDX[b] >= 0) { SLOT[b][nd] = QIDX[b]; SLOT[b][nd + 1] = MP + QIDX[b]; nd += 2; }
        NDB[b] = nd;
    }
    maps_ready = 1;
}

/* count duals from layout Lp (src) into layout L (dst): the extra partials are zero */
static void extend(int Lp, int L, const double *src, double *dst, int count)
{
    for (int c = 0; c < count; c++) {
        memcpy(dst + c * L, src + c * Lp, sizeof(double) * Lp);
        for (int k = Lp; k < L; k++) dst[c * L + k] = 0.0;
    }
}

/* body b's number of dual entries (value + partials) in mode nd (0: plain) */
static inline int LB(int nd, int b) { return nd ? 1 + NDB[b] : 1; }

/* Forward kinematics with duals: R[b] (9), p[b] (3): body poses in the world; ax[b], o[b]: the
 * joint axis and a point on it in the world (the joint frame's origin before a prismatic joint's
 * translation), each in body b's layout LB(nd, b). */
typedef struct { double R[9 * L_MAX], p[3 * L_MAX], ax[3 * L_MAX], o[3 * L_MAX]; } dpose;

static void d_fk(int nd, const double *q, dpose *P)
{
    double RJ[9 * L_MAX], Rot[9 * L_MAX], RJ2[9 * L_MAX], t3[3 * L_MAX], tmp[9 * L_MAX];
    for (int b = 0; b < NB; b++) {
        int pa = PARENT[b], L = LB(nd, b);
        const double *RPJ = R_PJ + 9 * b, *pPJ = P_PJ + 3 * b, *RJB = R_JB + 9 * b, *pJB = P_JB + 3 * b;
        if (pa < 0) {
            for (int k = 0; k < 9 * L; k++) RJ[k] = 0.0;
            for (int r = 0; r < 9; r++) RJ[r * L] = RPJ[r];
            for (int k = 0; k < 3 * L; k++) P[b].o[k] = 0.0;
            for (int r = 0; r < 3; r++) P[b].o[r * L] = pPJ[r];
        } else {
            int Lp = LB(nd, pa);
            dm_cmat(Lp, tmp, P[pa].R, RPJ);
            extend(Lp, L, tmp, RJ, 9);
            dm_cvec(Lp, t3, P[pa].R, pPJ);
            for (int k = 0; k < 3 * Lp; k++) t3[k] += P[pa].p[k];
            extend(Lp, L, t3, P[b].o, 3);
        }
        const double *R_after = RJ;
        for (int k = 0; k < 3 * L; k++) t3[k] = 0.0;   /* the prismatic joint's translation */
        if (QIDX[b] >= 0 && PRISMATIC[b]) {
            const double *a = AXIS + 3 * b;
            double qd[L_MAX];
            for (int k = 0; k < L; k++) qd[k] = 0.0;
            qd[0] = q[QIDX[b]];
            if (nd) qd[L - 2] = 1.0;                         /* d/dq_k: the slot before d/dv_k */
            dm_cvec(L, P[b].ax, RJ, a);
            for (int r = 0; r < 3; r++) d_addmul(L, t3 + r * L, P[b].ax + r * L, qd);
        } else if (QIDX[b] >= 0) {
            const double *a = AXIS + 3 * b;
            double qv = q[QIDX[b]];
            double c[L_MAX], s[L_MAX], omc[L_MAX];
            for (int k = 0; k < L; k++) c[k] = s[k] = 0.0;
            c[0] = cos(qv); s[0] = sin(qv);
            if (nd) { c[L - 2] = -s[0]; s[L - 2] = c[0]; }   /* d/dq_k: the slot before d/dv_k */
            for (int k = 0; k < L; k++) omc[k] = -c[k];
            omc[0] += 1.0;
            /* Rot = c I + s [a]x + (1 - c) a a^T */
            double K[9] = {0.0, -a[2], a[1], a[2], 0.0, -a[0], -a[1], a[0], 0.0};
            for (int r = 0; r < 3; r++) for (int cc = 0; cc < 3; cc++) {
                double *z = Rot + (3 * r + cc) * L;
                for (int k = 0; k < L; k++) z[k] = (r == cc ? c[k] : 0.0) + K[3 * r + cc] * s[k] + a[r] * a[cc] * omc[k];
            }
            dm_cvec(L, P[b].ax, RJ, a);
            dm_mat(L, RJ2, RJ, Rot);
            R_after = RJ2;
        } else {
            for (int k = 0; k < 3 * L; k++) P[b].ax[k] = 0.0;
        }
        dm_cmat(L, P[b].R, R_after, RJB);
        dm_cvec(L, tmp, R_after, pJB);
        for (int k = 0; k < 3 * L; k++) P[b].p[k] = P[b].o[k] + t3[k] + tmp[k];
    }
}

/* a tree's bodies (the kinematics' tree: all bodies; the dynamics': the moving ones, welds merged) */
typedef struct {
    int nb;
    const int *parent, *qidx, *prismatic;
    const double *R_PJ, *P_PJ, *axis, *R_JB, *P_JB;
} tree_arrays;
static const tree_arrays KIN = {NB, PARENT, QIDX, PRISMATIC, R_PJ, P_PJ, AXIS, R_JB, P_JB};
static const tree_arrays DYN = {DNB, DPARENT, DQIDX, DPRISMATIC, DR_PJ, DP_PJ, DAXIS, DR_JB, DP_JB};

/* plain forward kinematics of the tree t: R (nb, 9), p (nb, 3), ax (nb, 3), o (nb, 3) */
static void fk_of(const tree_arrays *t, const double *q, double *R, double *p, double *ax, double *o)
{
    for (int b = 0; b < t->nb; b++) {
        int pa = t->parent[b];
        const double *RPJ = t->R_PJ + 9 * b, *pPJ = t->P_PJ + 3 * b, *RJB = t->R_JB + 9 * b, *pJB = t->P_JB + 3 * b;
        double RJ[9], Rot[9], RA[9];
        double *ob = o + 3 * b;
        if (pa < 0) {
            memcpy(RJ, RPJ, sizeof RJ);
            memcpy(ob, pPJ, 3 * sizeof(double));
        } else {
            const double *Rp = R + 9 * pa, *pp = p + 3 * pa;
            for (int r = 0; r < 3; r++) {
                for (int c = 0; c < 3; c++) RJ[3 * r + c] = Rp[3 * r] * RPJ[c] + Rp[3 * r + 1] * RPJ[3 + c] + Rp[3 * r + 2] * RPJ[6 + c];
                ob[r] = pp[r] + (Rp[3 * r] * pPJ[0] + Rp[3 * r + 1] * pPJ[1] + Rp[3 * r + 2] * pPJ[2]);
            }
        }
        const double *Ru = RJ;
        double tr[3] = {0.0, 0.0, 0.0};   /* the prismatic joint's translation */
        if (t->qidx[b] >= 0 && t->prismatic[b]) {
            const double *a = t->axis + 3 * b, qv = q[t->qidx[b]];
            for (int r = 0; r < 3; r++) {
                ax[3 * b + r] = RJ[3 * r] * a[0] + RJ[3 * r + 1] * a[1] + RJ[3 * r + 2] * a[2];
                tr[r] = qv * ax[3 * b + r];
            }
        } else if (t->qidx[b] >= 0) {
            const double *a = t->axis + 3 * b;
            double c = cos(q[t->qidx[b]]), s = sin(q[t->qidx[b]]), omc = 1.0 - c;
            double K[9] = {0.0, -a[2], a[1], a[2], 0.0, -a[0], -a[1], a[0], 0.0};
            for (int r = 0; r < 3; r++) for (int cc = 0; cc < 3; cc++)
                Rot[3 * r + cc] = (r == cc ? c : 0.0) + K[3 * r + cc] * s + a[r] * a[cc] * omc;
            for (int r = 0; r < 3; r++) {
                ax[3 * b + r] = RJ[3 * r] * a[0] + RJ[3 * r + 1] * a[1] + RJ[3 * r + 2] * a[2];
                for (int cc = 0; cc < 3; cc++) RA[3 * r + cc] = RJ[3 * r] * Rot[cc] + RJ[3 * r + 1] * Rot[3 + cc] + RJ[3 * r + 2] * Rot[6 + cc];
            }
            Ru = RA;
        } else {
            ax[3 * b] = ax[3 * b + 1] = ax[3 * b + 2] = 0.0;
        }
        for (int r = 0; r < 3; r++) {
            for (int c = 0; c < 3; c++) R[9 * b + 3 * r + c] = Ru[3 * r] * RJB[c] + Ru[3 * r + 1] * RJB[3 + c] + Ru[3 * r + 2] * RJB[6 + c];
            p[3 * b + r] = ob[r] + tr[r] + (Ru[3 * r] * pJB[0] + Ru[3 * r + 1] * pJB[1] + Ru[3 * r + 2] * pJB[2]);
        }
    }
}

static void fk(const double *q, double *R, double *p, double *ax, double *o) { fk_of(&KIN, q, R, p, ax, o); }

/* the last configuration's kinematics, per thread: the task maps of one step evaluate several frames
 * at the same q (a placement: its rotation, then its position) */
typedef struct { int valid; double q[MP], R[9 * NB], p[3 * NB], ax[3 * NB], o[3 * NB]; } fk_memo;
static __thread fk_memo FK_MEMO;

static const fk_memo *fk_at(const double *q)
{
    fk_memo *m = &FK_MEMO;
    if (!m->valid || memcmp(m->q, q, sizeof(double) * MP) != 0) {
        fk(q, m->R, m->p, m->ax, m->o);
        memcpy(m->q, q, sizeof(double) * MP);
        m->valid = 1;
    }
    return m;
}

/* add to J (3 x MP, row-major, row stride ld) the translational Jacobian of world point r on body b */
static void point_jacobian(int b, const double *r, const double *ax, const double *o, double *J, int ld)
{
    for (int i = b; i >= 0; i = PARENT[i]) {
        int k = QIDX[i];
        if (k < 0) continue;
        const double *a = ax + 3 * i, *oi = o + 3 * i;
        if (PRISMATIC[i]) {   /* translation along the axis */
            J[k] += a[0]; J[ld + k] += a[1]; J[2 * ld + k] += a[2];
            continue;
        }
        double d0 = r[0] - oi[0], d1 = r[1] - oi[1], d2 = r[2] - oi[2];
        J[k] += a[1] * d2 - a[2] * d1;
        J[ld + k] += a[2] * d0 - a[0] * d2;
        J[2 * ld + k] += a[0] * d1 - a[1] * d0;
    }
}

static void angular_jacobian(int b, const double *ax, double *J, int ld)
{
    for (int i = b; i >= 0; i = PARENT[i]) {
        int k = QIDX[i];
        if (k < 0 || PRISMATIC[i]) continue;
        for (int r = 0; r < 3; r++) J[r * ld + k] += ax[3 * i + r];
    }
}

/* Accepted shapes of the exported kernels (raico/plants/codegen/rbd.py: TreeKernels checks them before
 * every call and raises ValueError; a body out of range also returns -1 here): q, v, a (MP); a body
 * 0 <= b < NB; R_BF (3 x 3), p_BF (3); npts >= 0 points pts (npts, 3); batches K >= 0 rows Q (K, MP). */

/* world positions pos (3 npts) of points pts (npts, 3) of frame F (X_BF: R_BF (9), p_BF (3)) on
 * body b, and their Jacobian J (3 npts x MP) */
int tree_frame_points(const double *q, int b, const double *RBF, const double *pBF, int npts,
                      const double *pts, double *pos, double *J)
{
    if (b < 0 || b >= NB || npts < 0) return -1;
    const fk_memo *K = fk_at(q);
    const double *R = K->R, *p = K->p, *ax = K->ax, *o = K->o;
    const double *Rb = R + 9 * b, *pb = p + 3 * b;
    memset(J, 0, sizeof(double) * 3 * npts * MP);
    for (int k = 0; k < npts; k++) {
        const double *x = pts + 3 * k;
        double f[3], w[3];
        for (int r = 0; r < 3; r++) f[r] = pBF[r] + (RBF[3 * r] * x[0] + RBF[3 * r + 1] * x[1] + RBF[3 * r + 2] * x[2]);
        for (int r = 0; r < 3; r++) w[r] = pb[r] + (Rb[3 * r] * f[0] + Rb[3 * r + 1] * f[1] + Rb[3 * r + 2] * f[2]);
        memcpy(pos + 3 * k, w, sizeof w);
        point_jacobian(b, w, ax, o, J + 3 * k * MP, MP);
    }
    return 0;
}

/* world rotation R_WF (9) of frame F (R_BF) on body b and the angular-velocity Jacobian Jw (3 x MP) */
int tree_frame_rotation(const double *q, int b, const double *RBF, double *RWF, double *Jw)
{
    if (b < 0 || b >= NB) return -1;
    const fk_memo *K = fk_at(q);
    const double *Rb = K->R + 9 * b, *ax = K->ax;
    for (int r = 0; r < 3; r++) for (int c = 0; c < 3; c++)
        RWF[3 * r + c] = Rb[3 * r] * RBF[c] + Rb[3 * r + 1] * RBF[3 + c] + Rb[3 * r + 2] * RBF[6 + c];
    memset(Jw, 0, sizeof(double) * 3 * MP);
    angular_jacobian(b, ax, Jw, MP);
    return 0;
}

/* centre of mass c (3) in the world and its Jacobian J (3 x MP) */
int tree_com(const double *q, double *c, double *J)
{
    const fk_memo *K = fk_at(q);
    const double *R = K->R, *p = K->p, *ax = K->ax, *o = K->o;
    double total = 0.0;
    double Jb[3 * MP];
    c[0] = c[1] = c[2] = 0.0;
    memset(J, 0, sizeof(double) * 3 * MP);
    for (int b = 0; b < NB; b++) {
        double mb = MASS[b];
        if (mb == 0.0) continue;
        const double *Rb = R + 9 * b, *pb = p + 3 * b, *cb = COM + 3 * b;
        double w[3];
        for (int r = 0; r < 3; r++) w[r] = pb[r] + (Rb[3 * r] * cb[0] + Rb[3 * r + 1] * cb[1] + Rb[3 * r + 2] * cb[2]);
        memset(Jb, 0, sizeof Jb);
        point_jacobian(b, w, ax, o, Jb, MP);
        for (int r = 0; r < 3; r++) c[r] += mb * w[r];
        for (int k = 0; k < 3 * MP; k++) J[k] += mb * Jb[k];
        total += mb;
    }
    for (int r = 0; r < 3; r++) c[r] /= total;
    for (int k = 0; k < 3 * MP; k++) J[k] /= total;
    return 0;
}

/* inverse dynamics tau (MP) at (q, v, a) by Newton-Euler in world coordinates; nd = 0: plain,
 * nd = 2 MP: tau_d (MP x (1 + 2 MP)) holds the value and d/d(q, v) of each torque (global layout:
 * slot 1 + k is d/dq_k, slot 1 + MP + k is d/dv_k) */
static void rnea(int nd, const double *q, const double *v, const double *a, double *tau_d)
{
    int LF = 1 + nd;   /* the global layout */
    static __thread dpose P[NB];
    static __thread double W[NB][6 * 3 * L_MAX];   /* omega, vO, alpha, aO, n, f per body (its layout) */
    static __thread double F[NB][6 * L_MAX];       /* n, f summed over the subtree (global layout) */
    init_maps();
    d_fk(nd, q, P);
    double t1[3 * L_MAX], t2[3 * L_MAX], t3[3 * L_MAX], S2[3 * L_MAX], cW[3 * L_MAX], vc[3 * L_MAX];
    double RI[9 * L_MAX], IW[9 * L_MAX], RT[9 * L_MAX], qdk[L_MAX];
    for (int b = 0; b < NB; b++) {
        int L = LB(nd, b);
        double *om = W[b], *vO = om + 3 * L, *al = vO + 3 * L, *aO = al + 3 * L, *n = aO + 3 * L, *f = n + 3 * L;
        int pa = PARENT[b];
        if (pa < 0) {
            for (int k = 0; k < 12 * L; k++) om[k] = 0.0;
            for (int r = 0; r < 3; r++) aO[r * L] = -GRAVITY[r];
        } else {
            extend(LB(nd, pa), L, W[pa], om, 12);
        }
        int k = QIDX[b];
        if (k >= 0 && PRISMATIC[b]) {
            /* motion axis (0, a): vO += a qd; aO += a qdd + (omega x a) qd (alpha, omega unchanged) */
            const double *ax = P[b].ax;
            double qdd = a[k];
            for (int i = 0; i < L; i++) qdk[i] = 0.0;
            qdk[0] = v[k];
            if (nd) qdk[L - 1] = 1.0;               /* d/dv_k: the body's last slot */
            dv_cross(L, t1, om, ax);                /* omega x a */
            for (int r = 0; r < 3; r++) {
                d_addmul(L, vO + r * L, ax + r * L, qdk);
                d_addcmul(L, aO + r * L, qdd, ax + r * L);
                d_addmul(L, aO + r * L, t1 + r * L, qdk);
            }
        } else if (k >= 0) {
            const double *ax = P[b].ax, *o = P[b].o;
            double qdd = a[k];
            for (int i = 0; i < L; i++) qdk[i] = 0.0;
            qdk[0] = v[k];
            if (nd) qdk[L - 1] = 1.0;               /* d/dv_k: the body's last slot */
            dv_cross(L, S2, o, ax);                 /* linear part of the motion axis: o x a */
            for (int r = 0; r < 3; r++) {
                d_addmul(L, om + r * L, ax + r * L, qdk);
                d_addmul(L, vO + r * L, S2 + r * L, qdk);
            }
            /* accelerations: + S qdd + (V x S) qd */
            dv_cross(L, t1, om, ax);                 /* omega x a */
            dv_cross(L, t2, om, S2);                 /* omega x (o x a) */
            dv_cross(L, t3, vO, ax);                 /* vO x a */
            for (int r = 0; r < 3; r++) {
                d_addcmul(L, al + r * L, qdd, ax + r * L);
                d_addmul(L, al + r * L, t1 + r * L, qdk);
                d_addcmul(L, aO + r * L, qdd, S2 + r * L);
                d_add(L, t2 + r * L, t2 + r * L, t3 + r * L);
                d_addmul(L, aO + r * L, t2 + r * L, qdk);
            }
        }
        /* body: com cW, velocity vc = vO + omega x cW, acceleration ac = aO + alpha x cW + omega x vc */
        double mb = MASS[b];
        dm_cvec(L, t1, P[b].R, COM + 3 * b);
        for (int i = 0; i < 3 * L; i++) cW[i] = P[b].p[i] + t1[i];
        dv_cross(L, t1, om, cW);
        for (int i = 0; i < 3 * L; i++) vc[i] = vO[i] + t1[i];
        dv_cross(L, t1, al, cW);
        dv_cross(L, t2, om, vc);
        for (int i = 0; i < 3 * L; i++) f[i] = mb * (aO[i] + t1[i] + t2[i]);
        /* n_c = I_W alpha + omega x I_W omega, I_W = R I R^T; n_O = n_c + cW x f */
        dm_cmat(L, RI, P[b].R, I_COM + 9 * b);
        for (int r = 0; r < 3; r++) for (int c = 0; c < 3; c++) memcpy(RT + (3 * r + c) * L, P[b].R + (3 * c + r) * L, sizeof(double) * L);
        dm_mat(L, IW, RI, RT);
        dm_vec(L, t1, IW, al);
        dm_vec(L, t2, IW, om);
        dv_cross(L, t3, om, t2);
        dv_cross(L, t2, cW, f);
        for (int i = 0; i < 3 * L; i++) n[i] = t1[i] + t3[i] + t2[i];
        /* its force in the global layout */
        double *Fb = F[b];
        for (int i = 0; i < 6 * LF; i++) Fb[i] = 0.0;
        for (int c = 0; c < 6; c++) {
            const double *src = n + c * L;   /* n then f: contiguous 6 duals */
            double *dst = Fb + c * LF;
            dst[0] = src[0];
            if (nd) for (int s = 1; s < L; s++) dst[1 + SLOT[b][s - 1]] = src[s];
        }
    }
    /* backward: forces to the root; tau_k = a . n_O + (o x a) . f (global layout); prismatic: a . f */
    for (int i = 0; i < MP * LF; i++) tau_d[i] = 0.0;
    double axF[3 * L_MAX], S2F[3 * L_MAX];
    for (int b = NB - 1; b >= 0; b--) {
        double *n = F[b], *f = n + 3 * LF;
        int k = QIDX[b], L = LB(nd, b);
        if (k >= 0) {
            double *tk = tau_d + k * LF;
            if (PRISMATIC[b]) for (int i = 0; i < 3 * L; i++) S2[i] = 0.0;
            else dv_cross(L, S2, P[b].o, P[b].ax);
            for (int c = 0; c < 3; c++) {
                const double *sa = P[b].ax + c * L, *ss = S2 + c * L;
                double *da = axF + c * LF, *ds = S2F + c * LF;
                for (int i = 0; i < LF; i++) da[i] = ds[i] = 0.0;
                da[0] = sa[0]; ds[0] = ss[0];
                if (nd) for (int s = 1; s < L; s++) { da[1 + SLOT[b][s - 1]] = sa[s]; ds[1 + SLOT[b][s - 1]] = ss[s]; }
            }
            /* (angular, linear) parts of the motion axis: (a, o x a), prismatic (0, a) */
            const double *Sw = PRISMATIC[b] ? S2F : axF, *Sv = PRISMATIC[b] ? axF : S2F;
            for (int r = 0; r < 3; r++) {
                d_addmul(LF, tk, Sw + r * LF, n + r * LF);
                d_addmul(LF, tk, Sv + r * LF, f + r * LF);
            }
            tk[0] += DAMPING[k] * v[k] + REFLECTED[k] * a[k];
            if (nd) tk[1 + MP + k] += DAMPING[k];
        }
        int pa = PARENT[b];
        if (pa >= 0) {
            double *np = F[pa];
            for (int i = 0; i < 6 * LF; i++) np[i] += n[i];
        }
    }
}


/* ---- the analytical derivatives of the inverse dynamics (Carpentier & Mansard 2018), in world
 * coordinates: spatial motion vectors (omega, v_O) and forces (n_O, f) at the world origin, each a
 * double[6] (angular part first). A joint's motion axis S (revolute (a, o x a), prismatic (0, a))
 * depends on the positions of the joints above it only, d S_i/dq_j = S_j x S_i for j above i.
 * Per body k: velocity V_k, acceleration A_k (gravity as the base's acceleration), inertia I_k
 * (mass m, first moment h = m c, rotational inertia J about the origin), its rate
 * dI_k/dt = V_k x* I_k - I_k V_k x (an inertia of mass 0: first moment hd, rotational Jd), momentum
 * I_k V_k, force f_k = I_k A_k + V_k x* I_k V_k; over the subtree of body i: Ic_i, Bc_i (the summed
 * rates), H_i (momenta), F_i (forces), tau_i = S_i . F_i. With, for a joint j below body l = parent(j),
 * u_j = S_j x V_l and alpha_j = S_j x A_l - u_j x V_l, and for every joint i, w_i = Ic_i S_i,
 * y_i = Bc_i S_i, z_i = S_i x* H_i, for j at or above i:
 *   M_ij = w_i . S_j,
 *   dtau_i/dq_j = -w_i . alpha_j + (z_i - y_i) . u_j,   dtau_i/dv_j = (y_i - z_i) . S_j - 2 w_i . u_j,
 *   dtau_j/dq_i = S_j . (S_i x* F_i - Ic_i alpha_i - Bc_i u_i - u_i x* H_i),
 *   dtau_j/dv_i = S_j . (y_i + S_i x* H_i - 2 Ic_i u_i),
 * every other entry zero; plus the joints' damping d v and reflected inertia r a. Cost: O(1) per body
 * and about 40 flops per pair of joints on a path to the root (forward mode: O(depth) per body). ---- */

/* c = a x b (3-vectors) */
static inline void x3(double *c, const double *a, const double *b)
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}
static inline double dot6(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4] + a[5] * b[5];
}
/* z = a x b (motion on motion) */
static void mcross(double *z, const double *a, const double *b)
{
    double t[3];
    x3(z, a, b);
    x3(z + 3, a, b + 3);
    x3(t, a + 3, b);
    z[3] += t[0]; z[4] += t[1]; z[5] += t[2];
}
/* z = a x* f (motion on force) */
static void fcross(double *z, const double *a, const double *f)
{
    double t[3];
    x3(z, a, f);
    x3(t, a + 3, f + 3);
    z[0] += t[0]; z[1] += t[1]; z[2] += t[2];
    x3(z + 3, a, f + 3);
}
/* symmetric 3x3 J (xx, yy, zz, xy, xz, yz) times w */
static inline void sym3(double *z, const double *J, const double *w)
{
    z[0] = J[0] * w[0] + J[3] * w[1] + J[4] * w[2];
    z[1] = J[3] * w[0] + J[1] * w[1] + J[5] * w[2];
    z[2] = J[4] * w[0] + J[5] * w[1] + J[2] * w[2];
}
/* z = I x for the inertia (m, h, J): (J w + h x v, m v - h x w) */
static void inertia_apply(double *z, double m, const double *h, const double *J, const double *x)
{
    double t[3];
    sym3(z, J, x);
    x3(t, h, x + 3);
    z[0] += t[0]; z[1] += t[1]; z[2] += t[2];
    x3(t, h, x);
    z[3] = m * x[3] - t[0]; z[4] = m * x[4] - t[1]; z[5] = m * x[5] - t[2];
}

/* the state of one evaluation on the dynamics' tree (the moving bodies, welds merged: DNB bodies,
 * rbd.py's dynamics_tree): pass 1 at (q, v), pass 2 at a */
typedef struct {
    double S[DNB][6], V[DNB][6], A0[DNB][6];    /* motion axis, velocity, acceleration at a = 0 */
    double m[DNB], h[DNB][3], J[DNB][6];        /* the body's inertia, then the subtree's (Ic) */
    double hd[DNB][3], Jd[DNB][6];              /* Bc: the subtree's inertia rate */
    double H[DNB][6], F0[DNB][6];               /* the subtree's momentum and force at a = 0 */
    double Ib[DNB][10];                         /* the body's own inertia (m, h, J), for pass 2 */
    double u[DNB][6], w[DNB][6], zy[DNB][6];    /* u_j, w_i, z_i - y_i */
    double y[DNB][6];                           /* y_i */
    double dA[DNB][6], F[DNB][6], alpha[DNB][6];  /* pass 2 */
} tree_work;

static __thread tree_work TREE_W;   /* one evaluation's state per thread */

/* pass 1 at (q, v): M (MP x MP, with the reflected inertia) and the bias torques h (MP) = ID(q, v, 0);
 * full = 0: these only (not what pass 2 needs) */
static void tree_pass1(const double *q, const double *v, int full, tree_work *W, double *M, double *hb)
{
    double R[9 * DNB], p[3 * DNB], axw[3 * DNB], o[3 * DNB];
    fk_of(&DYN, q, R, p, axw, o);
    for (int b = 0; b < DNB; b++) {
        int pa = DPARENT[b], k = DQIDX[b];
        double *S = W->S[b], *V = W->V[b], *A0 = W->A0[b], *u = W->u[b];
        const double *ax = axw + 3 * b;
        for (int i = 0; i < 6; i++) S[i] = u[i] = 0.0;
        if (k >= 0 && DPRISMATIC[b]) { S[3] = ax[0]; S[4] = ax[1]; S[5] = ax[2]; }
        else if (k >= 0) { S[0] = ax[0]; S[1] = ax[1]; S[2] = ax[2]; x3(S + 3, o + 3 * b, ax); }
        if (pa < 0) {
            for (int i = 0; i < 6; i++) V[i] = A0[i] = 0.0;
            for (int i = 0; i < 3; i++) A0[3 + i] = -GRAVITY[i];
        } else {
            memcpy(V, W->V[pa], sizeof(double) * 6);
            memcpy(A0, W->A0[pa], sizeof(double) * 6);
            if (k >= 0) mcross(u, S, W->V[pa]);
        }
        if (k >= 0) {   /* V += S v_k; A0 += (V x S) v_k = -u v_k */
            double vk = v[k];
            for (int i = 0; i < 6; i++) { V[i] += S[i] * vk; A0[i] -= u[i] * vk; }
        }
        /* the body's inertia about the origin: h = m c, J = R I_c R^T + m (|c|^2 1 - c c^T) */
        double mb = DMASS[b], c[3], RI[9], Jf[9];
        const double *Rb = R + 9 * b, *Ic = DI_COM + 9 * b, *cb = DCOM + 3 * b;
        for (int r = 0; r < 3; r++) c[r] = p[3 * b + r] + (Rb[3 * r] * cb[0] + Rb[3 * r + 1] * cb[1] + Rb[3 * r + 2] * cb[2]);
        for (int r = 0; r < 3; r++) for (int cc = 0; cc < 3; cc++)
            RI[3 * r + cc] = Rb[3 * r] * Ic[cc] + Rb[3 * r + 1] * Ic[3 + cc] + Rb[3 * r + 2] * Ic[6 + cc];
        for (int r = 0; r < 3; r++) for (int cc = 0; cc < 3; cc++)
            Jf[3 * r + cc] = RI[3 * r] * Rb[3 * cc] + RI[3 * r + 1] * Rb[3 * cc + 1] + RI[3 * r + 2] * Rb[3 * cc + 2];
        double c2 = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
        double *h = W->h[b], *J = W->J[b];
        for (int r = 0; r < 3; r++) h[r] = mb * c[r];
        J[0] = Jf[0] + mb * (c2 - c[0] * c[0]);
        J[1] = Jf[4] + mb * (c2 - c[1] * c[1]);
        J[2] = Jf[8] + mb * (c2 - c[2] * c[2]);
        J[3] = 0.5 * (Jf[1] + Jf[3]) - mb * c[0] * c[1];
        J[4] = 0.5 * (Jf[2] + Jf[6]) - mb * c[0] * c[2];
        J[5] = 0.5 * (Jf[5] + Jf[7]) - mb * c[1] * c[2];
        W->m[b] = mb;
        double *Ib = W->Ib[b];
        Ib[0] = mb; memcpy(Ib + 1, h, sizeof(double) * 3); memcpy(Ib + 4, J, sizeof(double) * 6);
        /* momentum, force at a = 0, and the inertia's rate: hd = w x h + m v,
         * Jd = X + X^T - (h v^T + v h^T) + 2 (v . h) 1 with X = [w]x J */
        double *Hb = W->H[b], *F0 = W->F0[b], t[6];
        inertia_apply(Hb, mb, h, J, V);
        inertia_apply(F0, mb, h, J, A0);
        fcross(t, V, Hb);
        for (int i = 0; i < 6; i++) F0[i] += t[i];
        if (!full) continue;
        const double *om = V, *vo = V + 3;
        double *hd = W->hd[b], *Jd = W->Jd[b], X[9], Jc[9] = {J[0], J[3], J[4], J[3], J[1], J[5], J[4], J[5], J[2]};
        x3(hd, om, h);
        for (int r = 0; r < 3; r++) hd[r] += mb * vo[r];
        for (int cc = 0; cc < 3; cc++) {
            double col[3] = {Jc[cc], Jc[3 + cc], Jc[6 + cc]}, z[3];
            x3(z, om, col);
            X[cc] = z[0]; X[3 + cc] = z[1]; X[6 + cc] = z[2];
        }
        double vh2 = 2.0 * (vo[0] * h[0] + vo[1] * h[1] + vo[2] * h[2]);
        Jd[0] = 2.0 * X[0] - 2.0 * h[0] * vo[0] + vh2;
        Jd[1] = 2.0 * X[4] - 2.0 * h[1] * vo[1] + vh2;
        Jd[2] = 2.0 * X[8] - 2.0 * h[2] * vo[2] + vh2;
        Jd[3] = X[1] + X[3] - (h[0] * vo[1] + vo[0] * h[1]);
        Jd[4] = X[2] + X[6] - (h[0] * vo[2] + vo[0] * h[2]);
        Jd[5] = X[5] + X[7] - (h[1] * vo[2] + vo[1] * h[2]);
    }
    /* subtree sums towards the root (children come after their parents) */
    for (int b = DNB - 1; b >= 0; b--) {
        int pa = DPARENT[b];
        if (pa < 0) continue;
        W->m[pa] += W->m[b];
        for (int i = 0; i < 3; i++) W->h[pa][i] += W->h[b][i];
        for (int i = 0; i < 6; i++) { W->J[pa][i] += W->J[b][i]; W->F0[pa][i] += W->F0[b][i]; }
        if (!full) continue;
        for (int i = 0; i < 3; i++) W->hd[pa][i] += W->hd[b][i];
        for (int i = 0; i < 6; i++) { W->Jd[pa][i] += W->Jd[b][i]; W->H[pa][i] += W->H[b][i]; }
    }
    if (M) memset(M, 0, sizeof(double) * MP * MP);   /* M NULL: w and h only (the gravity's pass) */
    for (int i = 0; i < DNB; i++) {
        int ki = DQIDX[i];
        if (ki < 0) continue;
        const double *S = W->S[i];
        double *w = W->w[i], *y = W->y[i], *zy = W->zy[i], z[6], t[3];
        inertia_apply(w, W->m[i], W->h[i], W->J[i], S);
        if (full) {
            sym3(y, W->Jd[i], S);   /* y = Bc S: (Jd s_w + hd x s_v, -hd x s_w) */
            x3(t, W->hd[i], S + 3);
            y[0] += t[0]; y[1] += t[1]; y[2] += t[2];
            x3(t, W->hd[i], S);
            y[3] = -t[0]; y[4] = -t[1]; y[5] = -t[2];
            fcross(z, S, W->H[i]);
            for (int r = 0; r < 6; r++) zy[r] = z[r] - y[r];
        }
        hb[ki] = dot6(S, W->F0[i]) + DAMPING[ki] * v[ki];
        if (!M) continue;
        for (int j = i; j >= 0; j = DPARENT[j]) {
            int kj = DQIDX[j];
            if (kj < 0) continue;
            double mij = dot6(w, W->S[j]);
            M[ki * MP + kj] = mij;
            M[kj * MP + ki] = mij;
        }
        M[ki * MP + ki] += REFLECTED[ki];
    }
}

/* pass 2 at the accelerations a (MP) after tree_pass1 at (q, v): tau (MP) = ID(q, v, a) (may be
 * NULL) and D = dID/d(q, v) (MP x 2 MP) */
static void tree_pass2(tree_work *W, const double *v, const double *a, double *tau, double *D)
{
    for (int b = 0; b < DNB; b++) {
        int pa = DPARENT[b], k = DQIDX[b];
        double *dA = W->dA[b], *F = W->F[b];
        if (pa < 0) for (int i = 0; i < 6; i++) dA[i] = 0.0;
        else memcpy(dA, W->dA[pa], sizeof(double) * 6);
        if (k >= 0) {
            double ak = a[k];
            for (int i = 0; i < 6; i++) dA[i] += W->S[b][i] * ak;
            /* alpha_j = S_j x A_l - u_j x V_l, l = parent (the world: A = (0, -g), V = 0) */
            double Al[6], t[6];
            if (pa < 0) {
                for (int i = 0; i < 3; i++) { Al[i] = 0.0; Al[3 + i] = -GRAVITY[i]; }
                mcross(W->alpha[b], W->S[b], Al);
            } else {
                for (int i = 0; i < 6; i++) Al[i] = W->A0[pa][i] + W->dA[pa][i];
                mcross(W->alpha[b], W->S[b], Al);
                mcross(t, W->u[b], W->V[pa]);
                for (int i = 0; i < 6; i++) W->alpha[b][i] -= t[i];
            }
        }
        const double *Ib = W->Ib[b];
        inertia_apply(F, Ib[0], Ib + 1, Ib + 4, dA);
    }
    for (int b = DNB - 1; b >= 0; b--) {   /* F: the subtree's sum of I_k dA_k, then + F0 */
        int pa = DPARENT[b];
        if (pa >= 0) for (int i = 0; i < 6; i++) W->F[pa][i] += W->F[b][i];
    }
    for (int b = 0; b < DNB; b++) for (int i = 0; i < 6; i++) W->F[b][i] += W->F0[b][i];
    memset(D, 0, sizeof(double) * 2 * MP * MP);
    for (int i = 0; i < DNB; i++) {
        int ki = DQIDX[i];
        if (ki < 0) continue;
        const double *S = W->S[i], *u = W->u[i], *w = W->w[i], *zy = W->zy[i], *al = W->alpha[i];
        double Phi[6], Psi[6], t[6], t2[6];
        /* Phi = S x* F - Ic alpha - Bc u - u x* H; Psi = y + S x* H - 2 Ic u */
        fcross(Phi, S, W->F[i]);
        inertia_apply(t, W->m[i], W->h[i], W->J[i], al);
        for (int r = 0; r < 6; r++) Phi[r] -= t[r];
        sym3(t, W->Jd[i], u);
        x3(t2, W->hd[i], u + 3);
        for (int r = 0; r < 3; r++) Phi[r] -= t[r] + t2[r];
        x3(t2, W->hd[i], u);
        for (int r = 0; r < 3; r++) Phi[3 + r] += t2[r];
        fcross(t, u, W->H[i]);
        for (int r = 0; r < 6; r++) Phi[r] -= t[r];
        fcross(Psi, S, W->H[i]);
        inertia_apply(t, W->m[i], W->h[i], W->J[i], u);
        for (int r = 0; r < 6; r++) Psi[r] += W->y[i][r] - 2.0 * t[r];
        if (tau) tau[ki] = dot6(S, W->F[i]) + DAMPING[ki] * v[ki] + REFLECTED[ki] * a[ki];
        double *Dq = D + (long)ki * 2 * MP, *Dv = Dq + MP;
        for (int j = i; j >= 0; j = DPARENT[j]) {
            int kj = DQIDX[j];
            if (kj < 0) continue;
            const double *Sj = W->S[j], *uj = W->u[j];
            Dq[kj] = dot6(zy, uj) - dot6(w, W->alpha[j]);
            Dv[kj] = -dot6(zy, Sj) - 2.0 * dot6(w, uj);
            if (j != i) {
                D[(long)kj * 2 * MP + ki] = dot6(Sj, Phi);
                D[(long)kj * 2 * MP + MP + ki] = dot6(Sj, Psi);
            }
        }
        Dv[ki] += DAMPING[ki];
    }
}

/* the gravity torques' Jacobian G = dID(q, 0, 0)/dq (MP x MP) after tree_pass1 at (q, 0) with M NULL:
 * tree_pass2's derivatives at v = 0, a = 0, where every velocity term vanishes (V = u = H = Bc = 0),
 * A_l = (0, -g) for every body and F_i = F0_i = Ic_i (0, -g): alpha_j = S_j x (0, -g) and, for j at
 * or above i, G_ij = -w_i . alpha_j, G_ji = S_j . (S_i x* F_i - Ic_i alpha_i) (j != i). */
static void tree_gravity_pass(tree_work *W, double *G)
{
    double Al[6] = {0.0, 0.0, 0.0, -GRAVITY[0], -GRAVITY[1], -GRAVITY[2]};
    for (int b = 0; b < DNB; b++) if (DQIDX[b] >= 0) mcross(W->alpha[b], W->S[b], Al);
    memset(G, 0, sizeof(double) * MP * MP);
    for (int i = 0; i < DNB; i++) {
        int ki = DQIDX[i];
        if (ki < 0) continue;
        const double *w = W->w[i];
        double Phi[6], t[6];
        fcross(Phi, W->S[i], W->F0[i]);
        inertia_apply(t, W->m[i], W->h[i], W->J[i], W->alpha[i]);
        for (int r = 0; r < 6; r++) Phi[r] -= t[r];
        for (int j = i; j >= 0; j = DPARENT[j]) {
            int kj = DQIDX[j];
            if (kj < 0) continue;
            G[(long)ki * MP + kj] = -dot6(w, W->alpha[j]);
            if (j != i) G[(long)kj * MP + ki] = dot6(W->S[j], Phi);
        }
    }
}

/* the tree's part of the dynamics driver (raico/plants/fast_analytic_driver.c, TREE_DYN): gen_mh: xs = (q, v)
 * -> out = (M, h); tree_pass1 / tree_pass2 for the derivatives */
static void gen_mh(const double *xs, double *out)
{
    tree_pass1(xs, xs + MP, 0, &TREE_W, out, out + MP * MP);
}

/* exported for the checks and the task maps (the task maps' inverse dynamics: Newton-Euler above;
 * its forward-mode derivatives for the checks) */
int tree_mass_matrix(const double *q, double *M)
{
    double v[MP], hb[MP];
    memset(v, 0, sizeof v);
    tree_pass1(q, v, 0, &TREE_W, M, hb);
    return 0;
}
int tree_inverse_dynamics(const double *q, const double *v, const double *a, double *tau) { rnea(0, q, v, a, tau); return 0; }
int tree_id_derivatives(const double *q, const double *v, const double *a, double *D)
{
    static __thread double td[MP * L_MAX];
    int L = 1 + 2 * MP;
    rnea(2 * MP, q, v, a, td);
    for (int i = 0; i < MP; i++) for (int k = 0; k < 2 * MP; k++) D[i * 2 * MP + k] = td[i * L + 1 + k];
    return 0;
}
/* the analytical route: tau = ID(q, v, a) (MP), M (MP x MP), D = dID/d(q, v) (MP x 2 MP) */
int tree_id_analytic(const double *q, const double *v, const double *a, double *tau, double *M, double *D)
{
    double hb[MP];
    tree_pass1(q, v, 1, &TREE_W, M, hb);
    tree_pass2(&TREE_W, v, a, tau, D);
    return 0;
}
/* the gravity torques g (MP) = ID(q, 0, 0) and, unless G is NULL, their Jacobian G = dg/dq (MP x MP)
 * analytically (tree_inverse_dynamics and the columns dq of tree_id_derivatives at v = a = 0, to
 * rounding) */
int tree_gravity(const double *q, double *g, double *G)
{
    double v[MP];
    memset(v, 0, sizeof v);
    tree_pass1(q, v, 0, &TREE_W, NULL, g);
    if (G) tree_gravity_pass(&TREE_W, G);
    return 0;
}
/* batches: K configurations qp (K, MP) */
int tree_frame_points_batch(int K, const double *Q, int b, const double *RBF, const double *pBF, int npts,
                            const double *pts, double *pos, double *J)
{
    if (b < 0 || b >= NB || npts < 0) return -1;
    for (int k = 0; k < K; k++)
        tree_frame_points(Q + (long)k * MP, b, RBF, pBF, npts, pts, pos + (long)k * 3 * npts, J + (long)k * 3 * npts * MP);
    return 0;
}
int tree_com_batch(int K, const double *Q, double *c, double *J)
{
    for (int k = 0; k < K; k++) tree_com(Q + (long)k * MP, c + 3L * k, J + 3L * k * MP);
    return 0;
}
int tree_frame_rotation_batch(int K, const double *Q, int b, const double *RBF, double *R, double *Jw)
{
    if (b < 0 || b >= NB) return -1;
    for (int k = 0; k < K; k++) tree_frame_rotation(Q + (long)k * MP, b, RBF, R + 9L * k, Jw + 3L * k * MP);
    return 0;
}
/* the frames of nb bodies at each row of Q (K, MP), the kinematics once per row: each body's origin and the
 * tips of its axes (4 points: 0, e_x, e_y, e_z in its frame) in the world, pos (K, nb, 4, 3), and their
 * Jacobians J (K, nb, 12, MP) */
int tree_body_frames_batch(int K, const double *Q, int nb, const int *bodies, double *pos, double *J)
{
    static const double I3[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1}, Z3[3] = {0, 0, 0};
    static const double P4[12] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1};
    if (K < 0 || nb < 0) return -1;
    for (int j = 0; j < nb; j++)
        if (bodies[j] < 0 || bodies[j] >= NB) return -1;
    for (int k = 0; k < K; k++)
        for (int j = 0; j < nb; j++) {
            long at = (long)k * nb + j;
            tree_frame_points(Q + (long)k * MP, bodies[j], I3, Z3, 4, P4, pos + 12 * at, J + 12 * at * MP);
        }
    return 0;
}
