
/* ---- rigid-body kernels (plants/codegen/rbd.py); every scalar is an array of 1 + nd doubles:
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

/* plain forward kinematics: R (NB, 9), p (NB, 3), ax (NB, 3), o (NB, 3) */
static void fk(const double *q, double *R, double *p, double *ax, double *o)
{
    for (int b = 0; b < NB; b++) {
        int pa = PARENT[b];
        const double *RPJ = R_PJ + 9 * b, *pPJ = P_PJ + 3 * b, *RJB = R_JB + 9 * b, *pJB = P_JB + 3 * b;
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
        if (QIDX[b] >= 0 && PRISMATIC[b]) {
            const double *a = AXIS + 3 * b, qv = q[QIDX[b]];
            for (int r = 0; r < 3; r++) {
                ax[3 * b + r] = RJ[3 * r] * a[0] + RJ[3 * r + 1] * a[1] + RJ[3 * r + 2] * a[2];
                tr[r] = qv * ax[3 * b + r];
            }
        } else if (QIDX[b] >= 0) {
            const double *a = AXIS + 3 * b;
            double c = cos(q[QIDX[b]]), s = sin(q[QIDX[b]]), omc = 1.0 - c;
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

/* Accepted shapes of the exported kernels (plants/codegen/rbd.py: TreeKernels checks them before
 * every call and raises ValueError; a body out of range also returns -1 here): q, v, a (MP); a body
 * 0 <= b < NB; R_BF (3 x 3), p_BF (3); npts >= 0 points pts (npts, 3); batches K >= 0 rows Q (K, MP). */

/* world positions pos (3 npts) of points pts (npts, 3) of frame F (X_BF: R_BF (9), p_BF (3)) on
 * body b, and their Jacobian J (3 npts x MP) */
int tree_frame_points(const double *q, int b, const double *RBF, const double *pBF, int npts,
                      const double *pts, double *pos, double *J)
{
    if (b < 0 || b >= NB || npts < 0) return -1;
    double R[9 * NB], p[3 * NB], ax[3 * NB], o[3 * NB];
    fk(q, R, p, ax, o);
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
    double R[9 * NB], p[3 * NB], ax[3 * NB], o[3 * NB];
    fk(q, R, p, ax, o);
    const double *Rb = R + 9 * b;
    for (int r = 0; r < 3; r++) for (int c = 0; c < 3; c++)
        RWF[3 * r + c] = Rb[3 * r] * RBF[c] + Rb[3 * r + 1] * RBF[3 + c] + Rb[3 * r + 2] * RBF[6 + c];
    memset(Jw, 0, sizeof(double) * 3 * MP);
    angular_jacobian(b, ax, Jw, MP);
    return 0;
}

/* centre of mass c (3) in the world and its Jacobian J (3 x MP) */
int tree_com(const double *q, double *c, double *J)
{
    double R[9 * NB], p[3 * NB], ax[3 * NB], o[3 * NB], total = 0.0;
    fk(q, R, p, ax, o);
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

/* mass matrix (MP x MP) */
static void mass_matrix(const double *q, double *M)
{
    double R[9 * NB], p[3 * NB], ax[3 * NB], o[3 * NB];
    double Jv[3 * MP], Jw[3 * MP], IJ[3 * MP];
    fk(q, R, p, ax, o);
    memset(M, 0, sizeof(double) * MP * MP);
    for (int b = 0; b < NB; b++) {
        double mb = MASS[b];
        const double *Rb = R + 9 * b, *pb = p + 3 * b, *cb = COM + 3 * b, *Ib = I_COM + 9 * b;
        double w[3], RI[9], IW[9];
        for (int r = 0; r < 3; r++) w[r] = pb[r] + (Rb[3 * r] * cb[0] + Rb[3 * r + 1] * cb[1] + Rb[3 * r + 2] * cb[2]);
        memset(Jv, 0, sizeof Jv);
        memset(Jw, 0, sizeof Jw);
        point_jacobian(b, w, ax, o, Jv, MP);
        angular_jacobian(b, ax, Jw, MP);
        /* I_W = R I R^T */
        for (int r = 0; r < 3; r++) for (int c = 0; c < 3; c++)
            RI[3 * r + c] = Rb[3 * r] * Ib[c] + Rb[3 * r + 1] * Ib[3 + c] + Rb[3 * r + 2] * Ib[6 + c];
        for (int r = 0; r < 3; r++) for (int c = 0; c < 3; c++)
            IW[3 * r + c] = RI[3 * r] * Rb[3 * c] + RI[3 * r + 1] * Rb[3 * c + 1] + RI[3 * r + 2] * Rb[3 * c + 2];
        for (int r = 0; r < 3; r++) for (int k = 0; k < MP; k++)
            IJ[r * MP + k] = IW[3 * r] * Jw[k] + IW[3 * r + 1] * Jw[MP + k] + IW[3 * r + 2] * Jw[2 * MP + k];
        for (int i = 0; i < MP; i++) for (int j = 0; j < MP; j++) {
            double s = 0.0;
            for (int r = 0; r < 3; r++) s += mb * Jv[r * MP + i] * Jv[r * MP + j] + Jw[r * MP + i] * IJ[r * MP + j];
            M[i * MP + j] += s;
        }
    }
    for (int i = 0; i < MP; i++) M[i * MP + i] += REFLECTED[i];
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

/* the CompiledDynamics interface of plants/codegen/derive.py (see plants/fast_analytic.py):
 * gen_mh: xs = (q, v) -> out = (M, h); gen_first: also carry = (q, v); gen_second: ys = (a, q, v)
 * -> dID/d(q, v) (MP x 2 MP) */
static void gen_mh(const double *xs, double *out)
{
    double zero[MP];
    memset(zero, 0, sizeof zero);
    mass_matrix(xs, out);
    rnea(0, xs, xs + MP, zero, out + MP * MP);
}
static void gen_first(const double *xs, double *out, double *carry)
{
    gen_mh(xs, out);
    memcpy(carry, xs, sizeof(double) * 2 * MP);
}
static void gen_second(const double *ys, double *out)
{
    static __thread double td[MP * L_MAX];
    int L = 1 + 2 * MP;
    rnea(2 * MP, ys + MP, ys + 2 * MP, ys, td);
    for (int i = 0; i < MP; i++) for (int k = 0; k < 2 * MP; k++) out[i * 2 * MP + k] = td[i * L + 1 + k];
}

/* exported for the checks and the task maps */
int tree_mass_matrix(const double *q, double *M) { mass_matrix(q, M); return 0; }
int tree_inverse_dynamics(const double *q, const double *v, const double *a, double *tau) { rnea(0, q, v, a, tau); return 0; }
int tree_id_derivatives(const double *q, const double *v, const double *a, double *D)
{
    double ys[3 * MP];
    memcpy(ys, a, sizeof(double) * MP); memcpy(ys + MP, q, sizeof(double) * MP); memcpy(ys + 2 * MP, v, sizeof(double) * MP);
    gen_second(ys, D);
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
