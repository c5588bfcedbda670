"""Analytic solids of the synthetic scenes: the volumes a trained 3DGS fills with Gaussians.

A trained 3DGS keeps Gaussians inside solid parts (densification pushes them there and no view
removes them); the 3DGS variant (:mod:`.gaussians3d`) puts its *interior* Gaussians in these.
Each solid is an exact analytic volume with :meth:`Solid.depth` (signed distance to its
boundary, positive inside: an intersection of a ball / cylinder / tube with slabs, exact as
the minimum over the pieces) and ``label`` / ``surface`` (target flag, owning surface index).

:func:`scene_solids` builds them from the scene's own surfaces:

* ``ribs`` — every surface flagged ``solid`` (spine, skull, rib tubes: target; stand:
  background);
* ``plant`` — the pot filled up to the soil (target; wall and stems are thinner than two
  interior Gaussians), table top, legs and book (background); the mug stays hollow;
* ``occluded`` — the vase's foot and body (target; the open neck stays hollow), plinth, pillar,
  plank and fence posts (background).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .surfaces import Cylinder, Frame, Rect, Sphere, Surface, Torus

__all__ = ["Solid", "SolidBall", "SolidBox", "SolidCylinder", "SolidTube", "scene_solids"]


@dataclass
class Solid:
    """Base: a named volume in a local frame, with its ground truth."""

    name: str
    frame: Frame
    label: bool
    surface: int

    def depth(self, points: np.ndarray) -> np.ndarray:
        """Signed distance to the boundary, positive inside (world points ``[N,3]``)."""
        return self._depth_local(self.frame.to_local(points))

    def _depth_local(self, q: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _local_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self._local_bounds()
        c = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )
        w = self.frame.to_world(c)
        return w.min(0), w.max(0)

    def volume(self) -> float:
        raise NotImplementedError

    def sample(self, rng: np.random.Generator, n: int, min_depth: float) -> np.ndarray:
        """``[n,3]`` world points uniform in the part of the solid at depth ≥ ``min_depth``
        (rejection from the local bounding box; empty if that part has no volume)."""
        lo, hi = self._local_bounds()
        out, have, tries = [], 0, 0
        while have < n and tries < 60:
            tries += 1
            m = max(256, 3 * (n - have))
            q = lo + rng.random((m, 3)) * (hi - lo)
            ok = self._depth_local(q) >= min_depth
            out.append(q[ok])
            have += int(ok.sum())
        if have < n:
            return np.zeros((0, 3))
        return self.frame.to_world(np.concatenate(out)[:n])

    def deep_volume(self, min_depth: float, rng: np.random.Generator, m: int = 20_000) -> float:
        """Monte-Carlo volume of the part at depth ≥ ``min_depth``."""
        lo, hi = self._local_bounds()
        q = lo + rng.random((m, 3)) * (hi - lo)
        return float(np.prod(hi - lo) * np.mean(self._depth_local(q) >= min_depth))

    def describe(self) -> dict:
        return {
            "name": self.name,
            "type": type(self).__name__,
            "label": self.label,
            "surface": self.surface,
            "origin": self.frame.origin.tolist(),
            "axes": self.frame.R.T.tolist(),
            "params": self.params(),
        }

    def params(self) -> dict:
        raise NotImplementedError


@dataclass
class SolidCylinder(Solid):
    """``ρ ≤ r``, ``z0 ≤ z ≤ z1`` around local z."""

    r: float = 0.0
    z0: float = 0.0
    z1: float = 0.0

    def _depth_local(self, q):
        rho = np.hypot(q[:, 0], q[:, 1])
        return np.minimum(self.r - rho, np.minimum(q[:, 2] - self.z0, self.z1 - q[:, 2]))

    def _local_bounds(self):
        return np.array([-self.r, -self.r, self.z0]), np.array([self.r, self.r, self.z1])

    def volume(self):
        return math.pi * self.r**2 * (self.z1 - self.z0)

    def params(self):
        return {"r": self.r, "z0": self.z0, "z1": self.z1}


@dataclass
class SolidBall(Solid):
    """Ball ``|q| ≤ r`` cut to the slab ``zlo ≤ z ≤ zhi`` (a cap, a hemisphere, a body)."""

    r: float = 0.0
    zlo: float = 0.0
    zhi: float = 0.0

    def _depth_local(self, q):
        d = self.r - np.linalg.norm(q, axis=1)
        return np.minimum(d, np.minimum(q[:, 2] - self.zlo, self.zhi - q[:, 2]))

    def _local_bounds(self):
        r = self.r
        return np.array([-r, -r, max(-r, self.zlo)]), np.array([r, r, min(r, self.zhi)])

    def volume(self):
        def f(z):  # ∫ π (r² − z²) dz
            return math.pi * (self.r**2 * z - z**3 / 3)

        a, b = max(-self.r, self.zlo), min(self.r, self.zhi)
        return f(b) - f(a) if b > a else 0.0

    def params(self):
        return {"r": self.r, "zlo": self.zlo, "zhi": self.zhi}


@dataclass
class SolidTube(Solid):
    """Solid torus tube: distance ≤ ``r`` from the core circle of radius ``R`` around local
    z, over the major angle ``psi0 ≤ ψ ≤ psi1`` (cut flat at the arc ends; an arc may
    exceed a half turn — the ribs span 300°)."""

    R: float = 0.0
    r: float = 0.0
    psi0: float = 0.0
    psi1: float = 2 * math.pi

    def _depth_local(self, q):
        rho = np.hypot(q[:, 0], q[:, 1])
        d = self.r - np.hypot(rho - self.R, q[:, 2])
        span = self.psi1 - self.psi0
        if span >= 2 * math.pi - 1e-12:
            return d
        # angle from the first end; the distance to an end plane is ρ sin(angle) within a
        # quarter turn of it (farther away it exceeds ρ > r and the tube term decides)
        a = np.mod(np.arctan2(q[:, 1], q[:, 0]) - self.psi0, 2 * math.pi)
        quarter = math.pi / 2
        d = np.minimum(d, rho * np.sin(np.minimum(a, quarter)))
        d = np.minimum(d, rho * np.sin(np.minimum(np.maximum(span - a, 0.0), quarter)))
        return np.where(a <= span, d, -np.abs(d) - 1e-9)

    def _local_bounds(self):
        e = self.R + self.r
        return np.array([-e, -e, -self.r]), np.array([e, e, self.r])

    def volume(self):
        return (self.psi1 - self.psi0) * self.R * math.pi * self.r**2

    def params(self):
        return {"R": self.R, "r": self.r, "psi0": self.psi0, "psi1": self.psi1}


@dataclass
class SolidBox(Solid):
    """``|x| ≤ hx, |y| ≤ hy, |z| ≤ hz`` in the local frame."""

    half: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def _depth_local(self, q):
        return np.min(np.asarray(self.half) - np.abs(q), axis=1)

    def _local_bounds(self):
        h = np.asarray(self.half, np.float64)
        return -h, h

    def volume(self):
        return 8.0 * float(np.prod(self.half))

    def params(self):
        return {"half": list(self.half)}


# ----------------------------------------------------------------------- per scene
def _index(surfaces: list[Surface]) -> dict[str, int]:
    return {s.name: j for j, s in enumerate(surfaces)}


def _from_surface(s: Surface, j: int) -> Solid | None:
    """The solid a closed surface piece bounds (full cylinder, sphere cap, tube)."""
    if isinstance(s, Cylinder) and s.full and not s.leaf:
        return SolidCylinder(s.name, s.frame, s.target, j, s.r, s.z0, s.z1)
    if isinstance(s, Sphere):
        return SolidBall(
            s.name, s.frame, s.target, j, s.r, s.r * math.cos(s.pol1), s.r * math.cos(s.pol0)
        )
    if isinstance(s, Torus):
        return SolidTube(s.name, s.frame, s.target, j, s.R, s.r, s.psi0, s.psi1)
    return None


def _box(surfaces: list[Surface], prefix: str) -> Solid:
    """The axis-aligned box whose faces are the ``prefix/±x…`` rectangles of ``box()``."""
    faces = [(j, s) for j, s in enumerate(surfaces) if s.name.startswith(prefix + "/")]
    if not faces or not all(isinstance(s, Rect) for _, s in faces):
        raise ValueError(f"no box faces named {prefix}/…")
    lo = np.min([s.bounds()[0] for _, s in faces], axis=0)
    hi = np.max([s.bounds()[1] for _, s in faces], axis=0)
    j, s = faces[0]
    frame = Frame(np.eye(3), (lo + hi) / 2)
    return SolidBox(prefix, frame, s.target, j, tuple(float(v) for v in (hi - lo) / 2))


def scene_solids(name: str, surfaces: list[Surface]) -> list[Solid]:
    """The solids of scene ``name`` (module docstring), built from its surfaces."""
    ix = _index(surfaces)
    if name == "ribs":
        return [sol for j, s in enumerate(surfaces) if s.solid and (sol := _from_surface(s, j))]
    if name == "plant":
        pot, soil = surfaces[ix["pot_outer"]], surfaces[ix["soil"]]
        soil_z = float(pot.frame.to_local(soil.frame.origin[None])[0, 2])
        out: list[Solid] = [
            SolidCylinder("pot", pot.frame, True, ix["pot_outer"], pot.r, pot.z0, soil_z),
            _box(surfaces, "table"),
            _box(surfaces, "book"),
        ]
        out += [_from_surface(surfaces[j], j) for n, j in ix.items() if n.startswith("table_leg_")]
        return out
    if name == "occluded":
        out = [_from_surface(surfaces[ix[n]], ix[n]) for n in ("vase_foot", "vase_body")]
        out += [
            _box(surfaces, p) for p in ("plinth", "pillar", "plank", "fence_post_0", "fence_post_1")
        ]
        return out
    if name == "wheel":
        parts = ["rim", "hub"] + [n for n in ix if n.startswith("spoke_")]
        return [_from_surface(surfaces[ix[n]], ix[n]) for n in parts]
    if name == "pedestal":
        parts = ("statue_base", "statue_body", "statue_shoulders", "statue_neck", "statue_head")
        out = [_from_surface(surfaces[ix[n]], ix[n]) for n in parts]
        return out + [_box(surfaces, "pedestal"), _box(surfaces, "cornice")]
    raise ValueError(f"no solids defined for scene {name!r}")
