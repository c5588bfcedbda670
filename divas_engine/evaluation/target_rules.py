"""Per-Gaussian selection rules of the real-capture ground truth.

A rule is a small JSON tree evaluated on every Gaussian of a scene, giving one bool per file
row. Leaves test the centre μ, the opacity α or the base colour (``0.5 + SH_C0 · f_dc`` clipped
to [0, 1], in HSV with H in degrees):

* ``{"box": {"center", "axes", "half"}}`` — ``|(μ − c)·a_k| ≤ h_k`` for unit axes a_k;
* ``{"halfspace": {"normal": n, "offset": d}}`` — ``μ·n̂ ≥ d``;
* ``{"sphere": {"center", "radius"}}``, ``{"ellipsoid": {"center", "axes", "radii"}}`` —
  ``Σ ((μ − c)·a_k / r_k)² ≤ 1``;
* ``{"cylinder": {"p0", "p1", "radius"}}`` — within r of the segment, between its end planes;
* ``{"opacity": {"min", "max"}}`` (either bound optional); ``{"hsv": {"min", "max"}}`` — each
  channel in range, a hue range with min > max wraps through 0°; ``{"all": true}``.

Nodes: ``{"and": [r, …]}``, ``{"or": [r, …]}``, ``{"not": r}``. Unknown keys are errors (a typo
must not silently select nothing).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..scene import SurfelScene

__all__ = ["GaussianFeatures", "gaussian_features", "evaluate_rule", "RULE_KEYS"]


class GaussianFeatures:
    """What rules read: centres ``[N,3]``, opacities ``[N]``, base colour RGB and HSV."""

    def __init__(self, means: np.ndarray, opacities: np.ndarray, rgb: np.ndarray):
        self.means = np.asarray(means, np.float64)
        self.opacities = np.asarray(opacities, np.float64)
        self.rgb = np.clip(np.asarray(rgb, np.float64), 0.0, 1.0)
        self.hsv = _rgb_to_hsv(self.rgb)

    def __len__(self) -> int:
        return len(self.means)


def gaussian_features(scene: SurfelScene) -> GaussianFeatures:
    """The :class:`GaussianFeatures` of a scene (base colour = the DC SH term)."""
    return GaussianFeatures(scene.means, scene.opacities, scene.base_colors())


def _rgb_to_hsv(rgb: np.ndarray) -> np.ndarray:
    r, g, b = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    mx, mn = rgb.max(1), rgb.min(1)
    delta = mx - mn
    h = np.zeros(len(rgb))
    nz = delta > 1e-12
    rm = nz & (mx == r)
    gm = nz & (mx == g) & ~rm
    bm = nz & ~rm & ~gm
    h[rm] = (60.0 * (g[rm] - b[rm]) / delta[rm]) % 360.0
    h[gm] = 60.0 * (b[gm] - r[gm]) / delta[gm] + 120.0
    h[bm] = 60.0 * (r[bm] - g[bm]) / delta[bm] + 240.0
    s = np.where(mx > 1e-12, delta / np.maximum(mx, 1e-12), 0.0)
    return np.stack([h, s, mx], axis=1)


def _vec(x, n: int = 3) -> np.ndarray:
    v = np.asarray(x, np.float64)
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise ValueError(f"rule: expected {n} finite numbers, got {x!r}")
    return v


def _axes(x) -> np.ndarray:
    a = np.asarray(x, np.float64)
    if a.shape != (3, 3):
        raise ValueError(f"rule: axes must be 3 vectors of 3, got {x!r}")
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def _keys(d: dict, allowed: set[str], what: str) -> None:
    extra = set(d) - allowed
    if extra:
        raise ValueError(f"rule {what}: unknown keys {sorted(extra)} (allowed {sorted(allowed)})")


def _box(p: dict, f: GaussianFeatures) -> np.ndarray:
    _keys(p, {"center", "axes", "half"}, "box")
    rel = f.means - _vec(p["center"])
    return np.all(np.abs(rel @ _axes(p["axes"]).T) <= _vec(p["half"]), axis=1)


def _halfspace(p: dict, f: GaussianFeatures) -> np.ndarray:
    _keys(p, {"normal", "offset"}, "halfspace")
    n = _vec(p["normal"])
    return f.means @ (n / np.linalg.norm(n)) >= float(p["offset"])


def _sphere(p: dict, f: GaussianFeatures) -> np.ndarray:
    _keys(p, {"center", "radius"}, "sphere")
    return np.linalg.norm(f.means - _vec(p["center"]), axis=1) <= float(p["radius"])


def _ellipsoid(p: dict, f: GaussianFeatures) -> np.ndarray:
    _keys(p, {"center", "axes", "radii"}, "ellipsoid")
    q = (f.means - _vec(p["center"])) @ _axes(p["axes"]).T / _vec(p["radii"])
    return (q * q).sum(1) <= 1.0


def _cylinder(p: dict, f: GaussianFeatures) -> np.ndarray:
    _keys(p, {"p0", "p1", "radius"}, "cylinder")
    p0, p1 = _vec(p["p0"]), _vec(p["p1"])
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    axis /= length
    t = (f.means - p0) @ axis
    radial = np.linalg.norm(f.means - p0 - t[:, None] * axis, axis=1)
    return (t >= 0) & (t <= length) & (radial <= float(p["radius"]))


def _opacity(p: dict, f: GaussianFeatures) -> np.ndarray:
    _keys(p, {"min", "max"}, "opacity")
    lo, hi = float(p.get("min", -np.inf)), float(p.get("max", np.inf))
    return (f.opacities >= lo) & (f.opacities <= hi)


def _hsv(p: dict, f: GaussianFeatures) -> np.ndarray:
    _keys(p, {"min", "max"}, "hsv")
    lo, hi = _vec(p["min"]), _vec(p["max"])
    h, s, v = f.hsv[:, 0], f.hsv[:, 1], f.hsv[:, 2]
    hue = (h >= lo[0]) & (h <= hi[0]) if lo[0] <= hi[0] else (h >= lo[0]) | (h <= hi[0])
    return hue & (s >= lo[1]) & (s <= hi[1]) & (v >= lo[2]) & (v <= hi[2])


_LEAVES: dict[str, Callable[[dict, GaussianFeatures], np.ndarray]] = {
    "box": _box,
    "halfspace": _halfspace,
    "sphere": _sphere,
    "ellipsoid": _ellipsoid,
    "cylinder": _cylinder,
    "opacity": _opacity,
    "hsv": _hsv,
}

#: Every key a rule node may have.
RULE_KEYS = frozenset(_LEAVES) | {"and", "or", "not", "all"}


def evaluate_rule(rule: dict, features: GaussianFeatures) -> np.ndarray:
    """``[N]`` bool: the Gaussians ``rule`` selects (module docstring)."""
    if not isinstance(rule, dict) or len(rule) != 1:
        raise ValueError(f"rule: each node is a one-key object, got {rule!r}")
    ((key, arg),) = rule.items()
    if key in _LEAVES:
        if not isinstance(arg, dict):
            raise ValueError(f"rule {key}: expected an object, got {arg!r}")
        return _LEAVES[key](arg, features)
    if key == "all":
        return np.full(len(features), bool(arg))
    if key == "not":
        return ~evaluate_rule(arg, features)
    if key in ("and", "or"):
        if not isinstance(arg, list) or not arg:
            raise ValueError(f"rule {key}: expected a non-empty list, got {arg!r}")
        parts = [evaluate_rule(r, features) for r in arg]
        return np.logical_and.reduce(parts) if key == "and" else np.logical_or.reduce(parts)
    raise ValueError(f"rule: unknown node {key!r} (allowed {sorted(RULE_KEYS)})")
