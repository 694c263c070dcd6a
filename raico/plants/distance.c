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

/* every query; returns the number with status 1 or 2 */
long gjk_batch(long nq, const long *ga, const long *gb, const double *RA, const double *pA, const double *RB,
               const double *pB, const double *limit, const long *key, long nkeys, long *hints, const long *kinds, const double *params, const long *vstart, const double *V,
               const long *astart, const long *adj, const double *spheres, double eps, double tiny, double gap,
               long max_iter,
               double *dist, double *wa, double *wb, double *nrm, long *status) {
    long bad = 0;
    for (long q = 0; q < nq; ++q) {
        shape_t A, B;
        make_shape(&A, ga[q], kinds, params, vstart, V, astart, adj, RA + 9 * q, pA + 3 * q);
        make_shape(&B, gb[q], kinds, params, vstart, V, astart, adj, RB + 9 * q, pB + 3 * q);
        if ((A.kind == 0 && A.nv < 1) || (B.kind == 0 && B.nv < 1)) { status[q] = 2; ++bad; continue; }
        if (key[q] < 0 || key[q] >= nkeys) { status[q] = 2; ++bad; continue; }
        {   /* the bounding spheres first */
            const double *ca = spheres + 4 * ga[q], *cb = spheres + 4 * gb[q];
            double wa_[3], wb_[3], e[3];
            for (int i = 0; i < 3; ++i) {
                wa_[i] = A.R[3 * i] * ca[0] + A.R[3 * i + 1] * ca[1] + A.R[3 * i + 2] * ca[2] + A.p[i];
                wb_[i] = B.R[3 * i] * cb[0] + B.R[3 * i + 1] * cb[1] + B.R[3 * i + 2] * cb[2] + B.p[i];
                e[i] = wa_[i] - wb_[i];
            }
            double lb = sqrt(dot3(e, e)) - ca[3] - cb[3];
            if (lb >= limit[q]) { dist[q] = lb; status[q] = 3; continue; }
        }
        long *h = hints + 2 * key[q];
        if (A.kind == 0 && h[0] >= 0 && h[0] < A.nv) A.hint = h[0];
        if (B.kind == 0 && h[1] >= 0 && h[1] < B.nv) B.hint = h[1];
        dist[q] = NAN;
        status[q] = gjk_pair(&A, &B, limit[q], eps, tiny, gap, max_iter, dist + q, wa + 3 * q, wb + 3 * q, nrm + 3 * q);
        h[0] = A.hint;
        h[1] = B.hint;
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
