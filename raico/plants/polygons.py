"""Convex support polygons in the ground plane (m): hulls, edges as half-planes, the signed distance
of a point to the boundary (a static margin), shrinking by a margin and the nearest point that keeps
it. One module for the plan's balance term (``raico.stages.plan.balance``), the standing start's projection
(``raico.plants.floating``) and the execution metrics (``raico.stages.evaluate.metrics``)."""

from __future__ import annotations

import numpy as np


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Vertices ``(k, 2)`` of the convex hull of ``points (n, 2)``, counter-clockwise."""
    from scipy.spatial import ConvexHull

    pts = np.asarray(points, float).reshape(-1, 2)
    return pts[ConvexHull(pts).vertices]  # 2-d hulls: counter-clockwise


def halfplanes(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edges of a convex counter-clockwise polygon ``(k, 2)`` as ``A p <= b``: unit outward normals
    ``A (k, 2)`` and offsets ``b (k,)`` (m), so ``b - A p`` are the distances to the edges' lines."""
    P = np.asarray(poly, float)
    E = np.roll(P, -1, axis=0) - P
    N = np.c_[E[:, 1], -E[:, 0]]
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    return N, np.einsum("ki,ki->k", N, P)


def signed_margin(poly: np.ndarray, p: np.ndarray) -> float:
    """Distance (m) of ``p (2,)`` to the boundary of convex ``poly (k, 2)``: > 0 inside, < 0 outside.
    A segment or a point has no inside: minus the distance to it. No polygon: NaN."""
    poly = np.asarray(poly, float).reshape(-1, 2)
    if len(poly) == 0:
        return float("nan")
    if len(poly) < 3:
        a, b = poly[0], poly[-1]
        ab = b - a
        t = 0.0 if not ab.any() else float(np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0))
        return -float(np.linalg.norm(p - (a + t * ab)))
    from scipy.spatial import ConvexHull

    hull = ConvexHull(poly)
    d = hull.equations[:, :2] @ p + hull.equations[:, 2]  # outward normals: d <= 0 inside
    if d.max() <= 0:
        return float(-d.max())
    # outside: the distance to the nearest edge
    V = poly[hull.vertices]
    dist = [-signed_margin(np.array([V[i], V[(i + 1) % len(V)]]), p) for i in range(len(V))]
    return -float(min(dist))


def nearest_on_segment(a: np.ndarray, c: np.ndarray, p: np.ndarray) -> np.ndarray:
    ac = c - a
    t = float(np.clip((p - a) @ ac / (ac @ ac), 0.0, 1.0)) if ac.any() else 0.0
    return a + t * ac


def shrink(poly: np.ndarray, margin: float) -> np.ndarray:
    """The polygon ``(k', 2)`` of the points at least ``margin`` (m) inside every edge of convex
    ``poly`` (edges too short for the margin vanish); ``ValueError`` if nothing is left."""
    from scipy.spatial import HalfspaceIntersection

    A, b = halfplanes(poly)
    centre = np.asarray(poly, float).mean(0)
    if (b - A @ centre).min() <= margin:
        raise ValueError(f"the support polygon has no point {margin} m inside every edge")
    hs = HalfspaceIntersection(np.c_[A, -(b - margin)], centre)
    return convex_hull(hs.intersections)


def nearest_feasible(poly: np.ndarray, margin: float, p: np.ndarray) -> np.ndarray:
    """The point ``(2,)`` nearest to ``p`` at least ``margin`` (m) inside ``poly`` (``p`` if it is)."""
    inner = shrink(poly, margin)
    if signed_margin(inner, p) >= 0:
        return np.array(p, float)
    cands = [nearest_on_segment(a, c, p) for a, c in zip(inner, np.roll(inner, -1, axis=0))]
    return min(cands, key=lambda z: float(np.linalg.norm(p - z)))
