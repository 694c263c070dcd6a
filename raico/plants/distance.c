/* Distances between convex shapes by GJK (Gilbert, Johnson, Keerthi 1988), with witness points: the
 * separated pairs of raico.plants.scene.SignedDistances, batched. Loaded by raico/plants/scene.py.
 *
 * Shapes (index s, kinds[s]; params[4 s + k]):
 *   0 convex: the vertices V[vstart[s] .. vstart[s+1]) (rows of 3, the hull's vertices only) and their
 *     neighbours on the hull (adj[astart[v] .. astart[v+1]), global vertex indices): the support point
 *     is found by climbing the hull's edge graph (a linear function's local maximum on a convex
 *     polytope's vertices is its maximum);
 *   1 box: half extents params[0..2];
 *   2 sphere: a point, radius params[3];
 *   3 capsule: the segment z in [-params[2], params[2]], radius params[3];
 *   4 cylinder: radius params[0], z in [-params[2], params[2]].
 * Spheres and capsules enter GJK as their cores (a point, a segment); their radii are taken off after.
 * A sphere around each shape (centre spheres + 4 s in its frame, radius spheres[4 s + 3]) culls first: a
 * pair whose spheres are limit[q] apart is not measured (status 3, dist[q] the spheres' distance).
 *
 * Query q: shapes ga[q], gb[q] at world poses (R row-major 3x3, p) RA + 9 q, pA + 3 q (B alike), of the pair
 * key[q] (0 <= key < nkeys): hints + 2 key[q] is where each convex shape's support search starts (vertex
 * indices), in and out: the last support vertices, the start of the pair's next query (a nearby posture).
 * Out: dist[q] (m), the witness points in each shape's own frame wa + 3 q, wb + 3 q, the unit normal
 * from B to A in the world nrm + 3 q, status[q]: 0 done; 1 the cores overlap or come closer than
 * `tiny` (m) (penetration: the caller asks another method); 2 no convergence in `max_iter` iterations, or
 * a stop (rounding: no more progress) with the distance more than `gap` (m) above the lower bound of the
 * plane normal to the last v (the one the normal and the witness points come from);
 * 3 culled: a separating plane puts the shapes at least limit[q] apart, dist[q] that lower bound (the
 * witness points and the normal not written).
 * gjk_frames_batch: the same queries where the poses come from the bodies' frames (origins and axes' tips, the
 * compiled kinematics') and each geometry's pose in its body, and with the witness points in the world and the
 * distance's gradient row n . (J_A(p_A) - J_B(p_B)) from the frames' Jacobians: a batch's pair loop in one call.
 * Converged: ||v||^2 - v.w <= eps ||v||^2 (v the closest point of the simplex, w the new support point),
 * i.e. the distance is within a factor (1 - eps) of its lower bound v.w / ||v||.
 */
#include <math.h>
#include <string.h>

typedef struct {
    long kind;
    const double *V;      /* this shape's vertices (convex) */
    long nv;
    long v0;              /* global index of V[0] */
    const long *astart, *adj;
    const double *prm;
    const double *R, *p;  /* world pose */
    long hint;            /* last support vertex (convex) */
} shape_t;

static inline double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

/* support of the shape's core in the local direction d (3) -> s (3, local) */
static void support_local(shape_t *S, const double *d, double *s) {
    const double *P = S->prm;
    switch (S->kind) {
    case 0: {
        long best = S->hint, improved = 1;
        double bv = dot3(S->V + 3 * best, d);
        while (improved) {
            improved = 0;
            long g = best + S->v0;
            for (long k = S->astart[g]; k < S->astart[g + 1]; ++k) {
                long j = S->adj[k] - S->v0;
                double v = dot3(S->V + 3 * j, d);
                if (v > bv) { bv = v; best = j; improved = 1; }
            }
        }
        S->hint = best;
        memcpy(s, S->V + 3 * best, 3 * sizeof(double));
        return;
    }
    case 1:
        for (int i = 0; i < 3; ++i) s[i] = d[i] >= 0.0 ? P[i] : -P[i];
        return;
    case 2:
        s[0] = s[1] = s[2] = 0.0;
        return;
    case 3:
        s[0] = s[1] = 0.0;
        s[2] = d[2] >= 0.0 ? P[2] : -P[2];
        return;
    default: {   /* cylinder */
        double r = sqrt(d[0] * d[0] + d[1] * d[1]);
        if (r > 0.0) { s[0] = P[0] * d[0] / r; s[1] = P[0] * d[1] / r; }
        else { s[0] = s[1] = 0.0; }
        s[2] = d[2] >= 0.0 ? P[2] : -P[2];
        return;
    }
    }
}

static double core_radius(const shape_t *S) { return (S->kind == 2 || S->kind == 3) ? S->prm[3] : 0.0; }

/* support in the world direction d: local point sl, world point sw */
static void support_world(shape_t *S, const double *d, double *sl, double *sw) {
    const double *R = S->R;
    double dl[3] = {R[0] * d[0] + R[3] * d[1] + R[6] * d[2], R[1] * d[0] + R[4] * d[1] + R[7] * d[2],
                    R[2] * d[0] + R[5] * d[1] + R[8] * d[2]};
    support_local(S, dl, sl);
    for (int i = 0; i < 3; ++i) sw[i] = R[3 * i] * sl[0] + R[3 * i + 1] * sl[1] + R[3 * i + 2] * sl[2] + S->p[i];
}

typedef struct { double w[3], a[3], b[3]; } vert_t;   /* w = a_world - b_world; a, b local */

/* closest point to the origin of the simplex (n = 1..4 vertices): barycentric lam (n), returns the number of
 * vertices kept (those with lam > 0, moved to the front), 0 where the origin is inside a tetrahedron */
static int closest_segment(vert_t *s, double *lam) {
    double ab[3], t, den;
    for (int i = 0; i < 3; ++i) ab[i] = s[1].w[i] - s[0].w[i];
    den = dot3(ab, ab);
    t = den > 0.0 ? -dot3(s[0].w, ab) / den : 0.0;
    if (t <= 0.0) { lam[0] = 1.0; return 1; }
    if (t >= 1.0) { s[0] = s[1]; lam[0] = 1.0; return 1; }
    lam[0] = 1.0 - t; lam[1] = t;
    return 2;
}

/* Ericson, Real-Time Collision Detection, 5.1.5, at the origin */
static int closest_triangle(vert_t *s, double *lam) {
    const double *a = s[0].w, *b = s[1].w, *c = s[2].w;
    double ab[3], ac[3], ma[3], mb[3], mc[3];
    for (int i = 0; i < 3; ++i) { ab[i] = b[i] - a[i]; ac[i] = c[i] - a[i]; ma[i] = -a[i]; mb[i] = -b[i]; mc[i] = -c[i]; }
    double d1 = dot3(ab, ma), d2 = dot3(ac, ma);
    if (d1 <= 0.0 && d2 <= 0.0) { lam[0] = 1.0; return 1; }
    double d3 = dot3(ab, mb), d4 = dot3(ac, mb);
    if (d3 >= 0.0 && d4 <= d3) { s[0] = s[1]; lam[0] = 1.0; return 1; }
    double vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
        double v = d1 / (d1 - d3);
        lam[0] = 1.0 - v; lam[1] = v; return 2;
    }
    double d5 = dot3(ab, mc), d6 = dot3(ac, mc);
    if (d6 >= 0.0 && d5 <= d6) { s[0] = s[2]; lam[0] = 1.0; return 1; }
    double vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
        double w = d2 / (d2 - d6);
        s[1] = s[2]; lam[0] = 1.0 - w; lam[1] = w; return 2;
    }
    double va = d3 * d6 - d5 * d4;
    if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
        double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        s[0] = s[1]; s[1] = s[2]; lam[0] = 1.0 - w; lam[1] = w; return 2;
    }
    double den = va + vb + vc;
    if (!(den > 0.0)) {   /* degenerate (collinear): the best of its edges */
        vert_t e[2] = {s[0], s[1]};
        double l[2];
        int n = closest_segment(e, l);
        memcpy(s, e, sizeof e);
        memcpy(lam, l, sizeof l);
        return n;
    }
    double v = vb / den, w = vc / den;
    lam[0] = 1.0 - v - w; lam[1] = v; lam[2] = w;
    return 3;
}

static void cross3(const double *a, const double *b, double *c) {
    c[0] = a[1] * b[2] - a[2] * b[1]; c[1] = a[2] * b[0] - a[0] * b[2]; c[2] = a[0] * b[1] - a[1] * b[0];
}

static void combine(const vert_t *s, const double *lam, int n, double *v) {
    v[0] = v[1] = v[2] = 0.0;
    for (int k = 0; k < n; ++k)
        for (int i = 0; i < 3; ++i) v[i] += lam[k] * s[k].w[i];
}

static int closest_tetrahedron(vert_t *s, double *lam) {
    static const int F[4][4] = {{0, 1, 2, 3}, {0, 2, 3, 1}, {0, 3, 1, 2}, {1, 3, 2, 0}};   /* face, opposite */
    double best = INFINITY;
    vert_t bs[3];
    double bl[3];
    int bn = -1;
    for (int f = 0; f < 4; ++f) {
        const double *a = s[F[f][0]].w, *b = s[F[f][1]].w, *c = s[F[f][2]].w, *d = s[F[f][3]].w;
        double ab[3], ac[3], nn[3], ad[3];
        for (int i = 0; i < 3; ++i) { ab[i] = b[i] - a[i]; ac[i] = c[i] - a[i]; ad[i] = d[i] - a[i]; }
        cross3(ab, ac, nn);
        double sp = -dot3(a, nn), sd = dot3(ad, nn);
        if (!(sp * sd < 0.0) && sd != 0.0) continue;   /* the origin on the opposite vertex's side */
        vert_t t[3] = {s[F[f][0]], s[F[f][1]], s[F[f][2]]};
        double l[3], v[3];
        int n = closest_triangle(t, l);
        combine(t, l, n, v);
        double q = dot3(v, v);
        if (q < best) { best = q; bn = n; memcpy(bs, t, sizeof(vert_t) * (size_t)n); memcpy(bl, l, sizeof(double) * (size_t)n); }
    }
    if (bn < 0) return 0;
    memcpy(s, bs, sizeof(vert_t) * (size_t)bn);
    memcpy(lam, bl, sizeof(double) * (size_t)bn);
    return bn;
}

static int closest(vert_t *s, int n, double *lam) {
    if (n == 1) { lam[0] = 1.0; return 1; }
    if (n == 2) return closest_segment(s, lam);
    if (n == 3) return closest_triangle(s, lam);
    return closest_tetrahedron(s, lam);
}

static long gjk_pair(shape_t *A, shape_t *B, double limit, double eps, double tiny, double gap, long max_iter,
                     double *dist, double *wa, double *wb, double *nrm) {
    double ra = core_radius(A), rb = core_radius(B), reach = limit + ra + rb;
    vert_t s[4];
    double lam[4] = {1.0, 0.0, 0.0, 0.0}, v[3], d[3];
    int n = 1;
    for (int i = 0; i < 3; ++i) d[i] = B->p[i] - A->p[i];
    if (dot3(d, d) == 0.0) d[0] = 1.0;
    {   /* the first vertex: A's support toward B, B's away from A */
        double md[3] = {-d[0], -d[1], -d[2]}, aw[3], bw[3];
        support_world(A, d, s[0].a, aw);
        support_world(B, md, s[0].b, bw);
        for (int i = 0; i < 3; ++i) s[0].w[i] = aw[i] - bw[i];
    }
    memcpy(v, s[0].w, sizeof v);
    long status = 2;
    double vv = dot3(v, v), bound = -INFINITY;   /* v.w / |v|: the lower bound of the plane normal to v */
    for (long it = 0; it < max_iter; ++it) {
        if (vv <= tiny * tiny) { status = 1; break; }
        double md[3] = {-v[0], -v[1], -v[2]}, aw[3], bw[3];
        vert_t w;
        support_world(A, md, w.a, aw);
        support_world(B, v, w.b, bw);
        for (int i = 0; i < 3; ++i) w.w[i] = aw[i] - bw[i];
        double vw = dot3(v, w.w);
        bound = vw / sqrt(vv);
        if (vw > 0.0 && vw * vw >= reach * reach * vv) {   /* the plane normal to v separates them by >= limit */
            *dist = vw / sqrt(vv) - ra - rb;
            return 3;
        }
        if (vv - vw <= eps * vv) { status = 0; break; }
        int dup = 0;
        for (int k = 0; k < n; ++k) dup |= (w.w[0] == s[k].w[0] && w.w[1] == s[k].w[1] && w.w[2] == s[k].w[2]);
        if (dup) { status = 0; break; }
        s[n++] = w;
        double lnew[4];
        vert_t keep[4];
        memcpy(keep, s, sizeof s);
        int m = closest(s, n, lnew);
        if (m == 0) { status = 1; break; }   /* the origin inside: overlap */
        double vn[3];
        combine(s, lnew, m, vn);
        double vvn = dot3(vn, vn);
        if (vvn >= vv) {   /* no progress (rounding): the last simplex stands */
            memcpy(s, keep, sizeof s);
            n -= 1;
            status = 0;
            break;
        }
        n = m;
        memcpy(lam, lnew, sizeof lnew);
        memcpy(v, vn, sizeof v);
        vv = vvn;
    }
    double nv = sqrt(vv);
    if (status == 0 && nv - bound > gap) status = 2;
    if (status == 0 && nv - ra - rb <= tiny) status = 1;
    if (status != 0) return status;
    double pa[3] = {0, 0, 0}, pb[3] = {0, 0, 0};
    for (int k = 0; k < n; ++k)
        for (int i = 0; i < 3; ++i) { pa[i] += lam[k] * s[k].a[i]; pb[i] += lam[k] * s[k].b[i]; }
    for (int i = 0; i < 3; ++i) nrm[i] = v[i] / nv;   /* v = a - b: from B to A */
    const double *RA = A->R, *RB = B->R;
    for (int i = 0; i < 3; ++i) {   /* radii: the surface points along the normal, in the local frames */
        wa[i] = pa[i] - ra * (RA[i] * nrm[0] + RA[3 + i] * nrm[1] + RA[6 + i] * nrm[2]);
        wb[i] = pb[i] + rb * (RB[i] * nrm[0] + RB[3 + i] * nrm[1] + RB[6 + i] * nrm[2]);
    }
    *dist = nv - ra - rb;
    return 0;
}

static void make_shape(shape_t *S, long g, const long *kinds, const double *params, const long *vstart,
                       const double *V, const long *astart, const long *adj, const double *R, const double *p) {
    S->kind = kinds[g];
    S->v0 = vstart[g];
    S->nv = vstart[g + 1] - vstart[g];
    S->V = V + 3 * vstart[g];
    S->astart = astart;
    S->adj = adj;
    S->prm = params + 4 * g;
    S->R = R;
    S->p = p;
    S->hint = 0;
}

/* one query of shapes ga, gb (their poses in A, B) of hint pair h: the bounding spheres, then GJK */
static long one_query(shape_t *A, shape_t *B, long ga, long gb, double limit, long *h, const double *spheres,
                      double eps, double tiny, double gap, long max_iter, double *dist, double *wa, double *wb,
                      double *nrm) {
    if ((A->kind == 0 && A->nv < 1) || (B->kind == 0 && B->nv < 1)) return 2;
    {   /* the bounding spheres first */
        const double *ca = spheres + 4 * ga, *cb = spheres + 4 * gb;
        double e[3];
        for (int i = 0; i < 3; ++i)
            e[i] = A->R[3 * i] * ca[0] + A->R[3 * i + 1] * ca[1] + A->R[3 * i + 2] * ca[2] + A->p[i]
                   - (B->R[3 * i] * cb[0] + B->R[3 * i + 1] * cb[1] + B->R[3 * i + 2] * cb[2] + B->p[i]);
        double lb = sqrt(dot3(e, e)) - ca[3] - cb[3];
        if (lb >= limit) { *dist = lb; return 3; }
    }
    if (A->kind == 0 && h[0] >= 0 && h[0] < A->nv) A->hint = h[0];
    if (B->kind == 0 && h[1] >= 0 && h[1] < B->nv) B->hint = h[1];
    *dist = NAN;
    long st = gjk_pair(A, B, limit, eps, tiny, gap, max_iter, dist, wa, wb, nrm);
    h[0] = A->hint;
    h[1] = B->hint;
    return st;
}

/* every query; returns the number with status 1 or 2 */
long gjk_batch(long nq, const long *ga, const long *gb, const double *RA, const double *pA, const double *RB,
               const double *pB, const double *limit, const long *key, long nkeys, long *hints, const long *kinds, const double *params, const long *vstart, const double *V,
               const long *astart, const long *adj, const double *spheres, double eps, double tiny, double gap,
               long max_iter,
               double *dist, double *wa, double *wb, double *nrm, long *status) {
    long bad = 0;
    for (long q = 0; q < nq; ++q) {
        shape_t A, B;
        if (key[q] < 0 || key[q] >= nkeys) { status[q] = 2; ++bad; continue; }
        make_shape(&A, ga[q], kinds, params, vstart, V, astart, adj, RA + 9 * q, pA + 3 * q);
        make_shape(&B, gb[q], kinds, params, vstart, V, astart, adj, RB + 9 * q, pB + 3 * q);
        status[q] = one_query(&A, &B, ga[q], gb[q], limit[q], hints + 2 * key[q], spheres, eps, tiny, gap, max_iter,
                              dist + q, wa + 3 * q, wb + 3 * q, nrm + 3 * q);
        bad += status[q] == 1 || status[q] == 2;
    }
    return bad;
}

/* a geometry's world pose from its body's frame: the body's origin and axes' tips fr (4 x 3, world; NULL: the
 * world itself), the geometry's pose in the body R_BG (3x3), p_BG -> R (3x3), p (3) */
static void geometry_pose(const double *fr, const double *R_BG, const double *p_BG, double *R, double *p) {
    if (!fr) { memcpy(R, R_BG, 9 * sizeof(double)); memcpy(p, p_BG, 3 * sizeof(double)); return; }
    double RB[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) RB[3 * i + j] = fr[3 * (1 + j) + i] - fr[i];   /* column j: axis j */
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j)
            R[3 * i + j] = RB[3 * i] * R_BG[j] + RB[3 * i + 1] * R_BG[3 + j] + RB[3 * i + 2] * R_BG[6 + j];
        p[i] = fr[i] + RB[3 * i] * p_BG[0] + RB[3 * i + 1] * p_BG[1] + RB[3 * i + 2] * p_BG[2];
    }
}

/* a geometry's point w (its frame) in its body's frame p_B, in the world W, and (Jf not NULL: the frame's
 * Jacobians, rows 0-2 the origin's, 3 + 3 i.. axis tip i's, 12 x m) jrow += sign n . J(p_B), where
 * J(p_B) = J_o + sum_i p_B[i] (J_e[i] - J_o) */
static void witness(const double *fr, const double *Jf, long m, const double *R_BG, const double *p_BG,
                    const double *w, const double *n, double sign, double *W, double *jrow) {
    double pB[3];
    for (int i = 0; i < 3; ++i) pB[i] = R_BG[3 * i] * w[0] + R_BG[3 * i + 1] * w[1] + R_BG[3 * i + 2] * w[2] + p_BG[i];
    if (!fr) { memcpy(W, pB, sizeof pB); return; }
    for (int i = 0; i < 3; ++i)
        W[i] = fr[i] + (fr[3 + i] - fr[i]) * pB[0] + (fr[6 + i] - fr[i]) * pB[1] + (fr[9 + i] - fr[i]) * pB[2];
    if (!Jf || !jrow) return;
    double c0 = 1.0 - pB[0] - pB[1] - pB[2];   /* J(p_B) = c0 J_o + sum_i p_B[i] J_tip[i] */
    for (int c = 0; c < 3; ++c) {
        double a0 = sign * n[c] * c0, a[3] = {sign * n[c] * pB[0], sign * n[c] * pB[1], sign * n[c] * pB[2]};
        const double *J0 = Jf + c * m, *J1 = Jf + (3 + c) * m, *J2 = Jf + (6 + c) * m, *J3 = Jf + (9 + c) * m;
        for (long k = 0; k < m; ++k) jrow[k] += a0 * J0[k] + a[0] * J1[k] + a[1] * J2[k] + a[2] * J3[k];
    }
}

/* queries q of the rows tq[q] of a batch and the pairs pq[q] (the geometries ia[pq], ib[pq], each the
 * GJK shape of its index; geometry g on body column gbody[g] of the frames, -1: the world; at R_BG + 9 g,
 * p_BG + 3 g in it), the frames computed at the rows' rowmap[t] (-1: none: status 2):
 * fr (rows, nbf, 4, 3) origins and axes' tips, Jf (rows, nbf, 12, m) their Jacobians (NULL: no jrow).
 * hints + 2 pq[q] as gjk_batch's key. Out as gjk_batch, and where done (status 0) the witness points in the
 * world W + 6 q (A's, B's) and jrow + m q = n . (J_A(p_A) - J_B(p_B)) (m); returns the number with status 1, 2 */
long gjk_frames_batch(long nq, const long *tq, const long *pq, long npairs, const long *ia, const long *ib,
                      long ngeo, const long *gbody, const double *R_BG, const double *p_BG, long nrows,
                      const long *rowmap, long nbf, const double *fr, const double *Jf, long m,
                      const double *limit, long *hints, const long *kinds, const double *params, const long *vstart,
                      const double *V, const long *astart, const long *adj, const double *spheres, double eps,
                      double tiny, double gap, long max_iter,
                      double *dist, double *W, double *nrm, double *jrow, long *status) {
    long bad = 0;
    for (long q = 0; q < nq; ++q) {
        long p = pq[q], t = tq[q];
        status[q] = 2;
        dist[q] = NAN;
        if (p < 0 || p >= npairs || t < 0 || t >= nrows) { ++bad; continue; }
        long ga = ia[p], gb = ib[p], r = rowmap[t];
        if (ga < 0 || ga >= ngeo || gb < 0 || gb >= ngeo || gbody[ga] >= nbf || gbody[gb] >= nbf
            || ((gbody[ga] >= 0 || gbody[gb] >= 0) && r < 0)) { ++bad; continue; }
        const double *fa = gbody[ga] >= 0 ? fr + 12 * (r * nbf + gbody[ga]) : NULL;
        const double *fb = gbody[gb] >= 0 ? fr + 12 * (r * nbf + gbody[gb]) : NULL;
        double RA[9], pA[3], RB[9], pB[3], wa[3], wb[3];
        geometry_pose(fa, R_BG + 9 * ga, p_BG + 3 * ga, RA, pA);
        geometry_pose(fb, R_BG + 9 * gb, p_BG + 3 * gb, RB, pB);
        shape_t A, B;
        make_shape(&A, ga, kinds, params, vstart, V, astart, adj, RA, pA);
        make_shape(&B, gb, kinds, params, vstart, V, astart, adj, RB, pB);
        status[q] = one_query(&A, &B, ga, gb, limit[q], hints + 2 * p, spheres, eps, tiny, gap, max_iter,
                              dist + q, wa, wb, nrm + 3 * q);
        if (status[q] == 0) {
            double *jq = Jf ? jrow + m * q : NULL;
            if (jq) memset(jq, 0, (size_t)m * sizeof(double));
            witness(fa, fa && Jf ? Jf + 12 * m * (r * nbf + gbody[ga]) : NULL, m, R_BG + 9 * ga, p_BG + 3 * ga, wa,
                    nrm + 3 * q, 1.0, W + 6 * q, jq);
            witness(fb, fb && Jf ? Jf + 12 * m * (r * nbf + gbody[gb]) : NULL, m, R_BG + 9 * gb, p_BG + 3 * gb, wb,
                    nrm + 3 * q, -1.0, W + 6 * q + 3, jq);
        }
        bad += status[q] == 1 || status[q] == 2;
    }
    return bad;
}

/* the support point (local) of shape g in the local direction d: for the tests (hill climbing against
 * the largest product over every vertex) */
void gjk_support(long g, const double *d, const long *kinds, const double *params, const long *vstart,
                 const double *V, const long *astart, const long *adj, long hint, double *s) {
    static const double I[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1}, Z[3] = {0, 0, 0};
    shape_t S;
    make_shape(&S, g, kinds, params, vstart, V, astart, adj, I, Z);
    S.hint = S.kind == 0 && hint >= 0 && hint < S.nv ? hint : 0;
    support_local(&S, d, s);
}
