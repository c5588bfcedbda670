"""Distance from points on a surface patch to the patch's boundary, along the surface.

A trained 3DGS keeps silhouettes and creases sharp by densifying there: Gaussians near
an edge are small. The 3DGS variant (:mod:`.gaussians3d`) limits a surface Gaussian's
in-plane extent by this distance. Per primitive (local coordinates, see
:mod:`.surfaces`):

* rectangle — ``min(a − |x|, b − |y|)``; annulus — ``min(r_out − ρ, ρ − r_in)``;
* cylinder patch — ``min(z − z0, z1 − z)`` and, for an open arc, ``r`` × the angle to the
  nearer arc end; a leaf — the axial distance to its outline ``½ (z1 − z0) sin(π s)``
  and the arc distance to its tips;
* sphere patch — ``r`` × the polar angle to a cut (none for a full sphere);
* torus — ``R`` × the major angle to an arc end (none for a full torus).

Closed directions (a full cylinder's seam) have no edge (``inf``).
"""

from __future__ import annotations

import math

import numpy as np

from .surfaces import Cylinder, Disc, Rect, Sphere, Surface, Torus

__all__ = ["edge_distance"]

TWO_PI = 2.0 * math.pi


def _arc_pos(angle: np.ndarray, a0: float) -> np.ndarray:
    return np.mod(angle - a0, TWO_PI)


def edge_distance(s: Surface, points: np.ndarray) -> np.ndarray:
    """``[N]`` distance along the patch from world ``points`` (on it) to its boundary."""
    q = s.frame.to_local(points)
    inf = np.full(len(q), np.inf)
    if isinstance(s, Rect):
        return np.minimum(s.a - np.abs(q[:, 0]), s.b - np.abs(q[:, 1]))
    if isinstance(s, Disc):
        rho = np.hypot(q[:, 0], q[:, 1])
        d = s.r_out - rho
        return np.minimum(d, rho - s.r_in) if s.r_in > 0 else d
    if isinstance(s, Cylinder):
        th = _arc_pos(np.arctan2(q[:, 1], q[:, 0]), s.th0)
        span = s.th1 - s.th0
        if s.leaf:
            u = np.clip(th / span, 0.0, 1.0)
            half = 0.5 * (s.z1 - s.z0) * np.sin(math.pi * u)
            zc = 0.5 * (s.z0 + s.z1)
            d = half - np.abs(q[:, 2] - zc)
        else:
            d = np.minimum(q[:, 2] - s.z0, s.z1 - q[:, 2])
        if not s.full:
            d = np.minimum(d, s.r * np.minimum(th, span - th))
        return d
    if isinstance(s, Sphere):
        r3 = np.linalg.norm(q, axis=1)
        pol = np.arccos(np.clip(q[:, 2] / np.maximum(r3, 1e-300), -1.0, 1.0))
        d = inf
        if s.pol0 > 0.0:
            d = np.minimum(d, s.r * (pol - s.pol0))
        if s.pol1 < math.pi:
            d = np.minimum(d, s.r * (s.pol1 - pol))
        return d
    if isinstance(s, Torus):
        if s.full:
            return inf
        psi = _arc_pos(np.arctan2(q[:, 1], q[:, 0]), s.psi0)
        span = s.psi1 - s.psi0
        return s.R * np.minimum(psi, span - psi)
    return inf
