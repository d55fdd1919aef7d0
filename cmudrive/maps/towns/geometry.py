"""Small plane-geometry helpers for town layouts: curves, polylines, intersections (metres)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Points = NDArray[np.float64]  # (N, 2) polyline [m]


def bezier(p0: Points, p1: Points, p2: Points, p3: Points, step: float = 10.0) -> Points:
    """Cubic Bezier curve through control points, sampled about every ``step`` metres: (N, 2)."""
    ctrl = np.stack([p0, p1, p2, p3]).astype(float)
    chord = float(np.linalg.norm(np.diff(ctrl, axis=0), axis=1).sum())
    n = max(4, int(np.ceil(chord / step)) + 1)
    t = np.linspace(0.0, 1.0, n)[:, None]
    return (
        (1 - t) ** 3 * ctrl[0]
        + 3 * (1 - t) ** 2 * t * ctrl[1]
        + 3 * (1 - t) * t**2 * ctrl[2]
        + t**3 * ctrl[3]
    )


def arc_length(poly: Points) -> Points:
    """Cumulative length along a polyline, starting at 0: (N,)."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poly, axis=0), axis=1))])


def resample(poly: Points, step: float) -> Points:
    """Points about every ``step`` metres along ``poly`` (ends kept): (M, 2)."""
    s = arc_length(poly)
    n = max(2, int(np.ceil(s[-1] / step)) + 1)
    t = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(t, s, poly[:, 0]), np.interp(t, s, poly[:, 1])], axis=1)


def normals(poly: Points) -> Points:
    """Unit left normals of a polyline at its points (central differences): (N, 2)."""
    d = np.gradient(poly, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.stack([-d[:, 1], d[:, 0]], axis=1)


def offset(poly: Points, d: float) -> Points:
    """``poly`` moved ``d`` metres to its left (negative: right), point by point: (N, 2)."""
    return poly + d * normals(poly)


def segment_intersections(a: Points, b: Points) -> list[tuple[float, float, Points]]:
    """Crossings of polylines ``a`` and ``b`` as (arc position on a, arc position on b, point)."""
    p, r = a[:-1, None, :], np.diff(a, axis=0)[:, None, :]  # (Na-1, 1, 2)
    q, s = b[None, :-1, :], np.diff(b, axis=0)[None, :, :]  # (1, Nb-1, 2)
    den = r[..., 0] * s[..., 1] - r[..., 1] * s[..., 0]  # (Na-1, Nb-1)
    qp = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qp[..., 0] * s[..., 1] - qp[..., 1] * s[..., 0]) / den
        u = (qp[..., 0] * r[..., 1] - qp[..., 1] * r[..., 0]) / den
    hit = (np.abs(den) > 1e-12) & (t >= 0.0) & (t < 1.0) & (u >= 0.0) & (u < 1.0)
    sa, sb = arc_length(a), arc_length(b)
    out: list[tuple[float, float, Points]] = []
    for i, j in zip(*np.nonzero(hit), strict=True):
        ti, uj = float(t[i, j]), float(u[i, j])
        point = a[i] + ti * (a[i + 1] - a[i])
        out.append((sa[i] + ti * (sa[i + 1] - sa[i]), sb[j] + uj * (sb[j + 1] - sb[j]), point))
    return out


def cut(poly: Points, s0: float, s1: float) -> Points:
    """The part of ``poly`` between arc positions ``s0 < s1``, with interpolated ends: (M, 2)."""
    s = arc_length(poly)
    inner = poly[(s > s0 + 1e-6) & (s < s1 - 1e-6)]
    ends = [np.array([np.interp(v, s, poly[:, 0]), np.interp(v, s, poly[:, 1])]) for v in (s0, s1)]
    return np.vstack([ends[0], inner, ends[1]])
