"""Procedural colour: multi-octave 3D value noise mapped through shared palettes.

The noise is a function of the *world* position only, so a target and the
background surface it touches continue the same pattern, and several surfaces
(target and background alike) draw from one palette: colour alone does not
separate the objects.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PALETTES", "value_noise", "surface_colors"]

#: name → (base, second, accent) RGB in [0,1].
PALETTES: dict[str, tuple[tuple[float, float, float], ...]] = {
    "stone": ((0.74, 0.70, 0.62), (0.50, 0.47, 0.42), (0.33, 0.31, 0.29)),
    "wood": ((0.60, 0.43, 0.28), (0.43, 0.29, 0.18), (0.72, 0.56, 0.39)),
    "terracotta": ((0.68, 0.41, 0.28), (0.52, 0.31, 0.21), (0.76, 0.58, 0.44)),
    "foliage": ((0.30, 0.48, 0.20), (0.17, 0.33, 0.12), (0.52, 0.60, 0.28)),
    "ceramic": ((0.36, 0.48, 0.62), (0.78, 0.76, 0.70), (0.22, 0.28, 0.38)),
    "plaster": ((0.80, 0.78, 0.74), (0.66, 0.64, 0.61), (0.52, 0.50, 0.48)),
    "sky": ((0.62, 0.72, 0.84), (0.42, 0.56, 0.36), (0.86, 0.88, 0.90)),
    "floater": ((0.55, 0.55, 0.55), (0.35, 0.33, 0.30), (0.80, 0.78, 0.72)),
}

_M1, _M2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)


_C = (np.uint64(0x9E3779B97F4A7C15), np.uint64(0xC2B2AE3D27D4EB4F), np.uint64(0x165667B19E3779F9))


def _mix01(h: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser → uniform [0,1) float32."""
    h = h ^ (h >> np.uint64(30))
    h *= _M1
    h ^= h >> np.uint64(27)
    h *= _M2
    h ^= h >> np.uint64(31)
    return (h >> np.uint64(40)).astype(np.float32) * np.float32(1.0 / (1 << 24))


def value_noise(
    points: np.ndarray, seed: int, *, octaves: int = 4, scale: float = 0.25, gain: float = 0.5
) -> np.ndarray:
    """Fractal 3D value noise in [0,1] at world ``points`` ``[N,3]``.

    ``scale`` is the world size of one lattice cell of the first octave; each
    further octave halves it and multiplies the amplitude by ``gain``.
    """
    p = np.asarray(points, np.float64)
    total = np.zeros(len(p), np.float32)
    amp, norm = 1.0, 0.0
    with np.errstate(over="ignore"):
        for o in range(octaves):
            q = p / (scale / 2**o) + 17.31 * (o + 1)
            i = np.floor(q)
            f = (q - i).astype(np.float32)
            u = f * f * (3.0 - 2.0 * f)
            i = i.astype(np.int64)
            s = np.uint64(
                (((seed * 131 + o) & 0xFFFFFFFFFFFF) * 0xD6E8FEB86659FD93) & 0xFFFFFFFFFFFFFFFF
            )
            # per-axis hashed lattice terms for the two corners along each axis
            hx = [(i[:, 0] + d).astype(np.uint64) * _C[0] ^ s for d in (0, 1)]
            hy = [(i[:, 1] + d).astype(np.uint64) * _C[1] for d in (0, 1)]
            hz = [(i[:, 2] + d).astype(np.uint64) * _C[2] for d in (0, 1)]
            acc = np.zeros(len(p), np.float32)
            for dx in (0, 1):
                wx = u[:, 0] if dx else 1.0 - u[:, 0]
                for dy in (0, 1):
                    wxy = wx * (u[:, 1] if dy else 1.0 - u[:, 1])
                    hxy = hx[dx] ^ hy[dy]
                    for dz in (0, 1):
                        wz = u[:, 2] if dz else 1.0 - u[:, 2]
                        acc += wxy * wz * _mix01(hxy ^ hz[dz])
            total += np.float32(amp) * acc
            norm += amp
            amp *= gain
    return total / np.float32(norm)


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def surface_colors(points: np.ndarray, palette: str, tex_scale: float, seed: int) -> np.ndarray:
    """``[N,3]`` float32 RGB in [0,1]: palette blend driven by two noise fields
    (broad blotches and fine veins) plus a brightness field."""
    c = np.asarray(PALETTES[palette], np.float32)
    n1 = value_noise(points, seed, octaves=4, scale=tex_scale)
    n2 = value_noise(points, seed + 7, octaves=3, scale=tex_scale * 0.35)
    n3 = value_noise(points, seed + 13, octaves=2, scale=tex_scale * 2.0)
    t1 = _smoothstep(0.3, 0.7, n1)[:, None]
    rgb = c[0] * (1 - t1) + c[1] * t1
    t2 = (0.8 * _smoothstep(0.58, 0.72, n2))[:, None]
    rgb = rgb * (1 - t2) + c[2] * t2
    rgb *= (0.82 + 0.36 * n3)[:, None]
    return np.clip(rgb, 0.0, 1.0).astype(np.float32)
