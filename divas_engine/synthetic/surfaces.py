"""Analytic surfaces that the synthetic scenes are sampled from.

Every primitive lives in its own local frame (``Frame``: rotation columns are
the local axes in world coordinates, plus an origin) and provides

* :meth:`Surface.area` — exact area,
* :meth:`Surface.sample` — area-uniform samples with the analytic normal, a
  unit tangent along the direction of strongest curvature (random for flat
  patches) and that curvature radius,
* :meth:`Surface.distance` — unsigned Euclidean distance from world points to
  the (bounded) surface patch; exact for every primitive except the leaf
  outline of :class:`Cylinder`, where it is the distance to the leaf's bounding
  cylinder patch (a lower bound — safe for free-space and visibility tests),
* :meth:`Surface.normal_at` — the analytic normal at points on the surface,
* :meth:`Surface.bounds` — a conservative world AABB,
* :meth:`Surface.inside` — for closed pieces (full cylinder, sphere patch, tube
  of a torus): whether points are in the enclosed solid; used by the density
  grid for surfaces flagged ``solid``.

All maths is vectorised float64 NumPy; angles are radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "Frame",
    "Surface",
    "Samples",
    "Rect",
    "Disc",
    "Cylinder",
    "Sphere",
    "Torus",
    "box",
    "min_distance",
]

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class Frame:
    """Rigid local→world transform: ``world = R @ local + origin`` (R's columns = local axes)."""

    R: np.ndarray
    origin: np.ndarray

    @staticmethod
    def make(origin, z_axis=(0.0, 0.0, 1.0), x_hint=(1.0, 0.0, 0.0)) -> Frame:
        """Frame whose local +z is ``z_axis`` and local +x is ``x_hint`` made orthogonal to it."""
        z = np.asarray(z_axis, np.float64)
        z = z / np.linalg.norm(z)
        x = np.asarray(x_hint, np.float64)
        x = x - z * (x @ z)
        if np.linalg.norm(x) < 1e-9:
            x = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
            x = x - z * (x @ z)
        x = x / np.linalg.norm(x)
        y = np.cross(z, x)
        return Frame(np.stack([x, y, z], axis=1), np.asarray(origin, np.float64).copy())

    def to_world(self, p: np.ndarray) -> np.ndarray:
        return p @ self.R.T + self.origin

    def vec_to_world(self, v: np.ndarray) -> np.ndarray:
        return v @ self.R.T

    def to_local(self, p: np.ndarray) -> np.ndarray:
        return (np.asarray(p, np.float64) - self.origin) @ self.R


@dataclass
class Samples:
    """World-space samples of one surface (float64)."""

    points: np.ndarray  # [n,3]
    normals: np.ndarray  # [n,3] unit
    tangents: np.ndarray  # [n,3] unit, ⟂ normal: direction of strongest curvature
    curvature_radius: float  # along ``tangents`` (inf for flat patches)


def _in_arc(angle: np.ndarray, a0: float, a1: float) -> np.ndarray:
    if a1 - a0 >= TWO_PI - 1e-12:
        return np.ones(angle.shape, bool)
    return np.mod(angle - a0, TWO_PI) <= (a1 - a0) + 1e-12


class Surface:
    """Base class. Attributes besides the geometry drive the scene builder:

    ``target`` (ground-truth label), ``palette`` and ``tex_scale`` (world units
    per noise cycle) for the procedural colour, ``density`` (relative surfels per
    unit area) or ``share`` (fixed fraction of the surface budget, overrides
    density — used for the far dome), ``part`` (a coarse part name), ``solid``
    (the density grid fills :meth:`inside` as well as the shell).
    """

    type_name = "surface"

    def __init__(
        self,
        name: str,
        frame: Frame,
        *,
        target: bool = False,
        palette: str = "stone",
        tex_scale: float = 0.25,
        density: float = 1.0,
        share: float | None = None,
        part: str | None = None,
        solid: bool = False,
    ):
        self.name = name
        self.frame = frame
        self.target = bool(target)
        self.palette = palette
        self.tex_scale = float(tex_scale)
        self.density = float(density)
        self.share = share
        self.part = part or name
        self.solid = bool(solid)

    # --- to implement -------------------------------------------------------
    def area(self) -> float:
        raise NotImplementedError

    def params(self) -> dict:
        raise NotImplementedError

    def _local_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _sample_local(self, rng: np.random.Generator, n: int):
        """Local ``(points, normals, tangents)`` and the curvature radius."""
        raise NotImplementedError

    def _distance_local(self, q: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _normal_local(self, q: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _inside_local(self, q: np.ndarray) -> np.ndarray:
        return np.zeros(len(q), bool)

    # --- world-space API ------------------------------------------------------
    def sample(self, rng: np.random.Generator, n: int) -> Samples:
        p, nrm, t, rc = self._sample_local(rng, int(n))
        f = self.frame
        return Samples(f.to_world(p), f.vec_to_world(nrm), f.vec_to_world(t), float(rc))

    def distance(self, points: np.ndarray) -> np.ndarray:
        return self._distance_local(self.frame.to_local(points))

    def normal_at(self, points: np.ndarray) -> np.ndarray:
        return self.frame.vec_to_world(self._normal_local(self.frame.to_local(points)))

    def inside(self, points: np.ndarray) -> np.ndarray:
        return self._inside_local(self.frame.to_local(points))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self._local_bounds()
        corners = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])],
            np.float64,
        )
        w = self.frame.to_world(corners)
        return w.min(0), w.max(0)

    def describe(self) -> dict:
        return {
            "name": self.name,
            "type": self.type_name,
            "part": self.part,
            "target": self.target,
            "solid": self.solid,
            "area": self.area(),
            "palette": self.palette,
            "origin": self.frame.origin.tolist(),
            "axes": self.frame.R.T.tolist(),
            "params": self.params(),
        }


def _random_tangent(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.random(n) * TWO_PI
    return np.stack([np.cos(a), np.sin(a), np.zeros(n)], 1)


class Rect(Surface):
    """Planar rectangle ``|x| <= a, |y| <= b`` in the local plane z = 0, normal +z."""

    type_name = "rect"

    def __init__(self, name, frame, a: float, b: float, **kw):
        super().__init__(name, frame, **kw)
        self.a, self.b = float(a), float(b)

    def area(self):
        return 4.0 * self.a * self.b

    def params(self):
        return {"half_x": self.a, "half_y": self.b}

    def _local_bounds(self):
        return np.array([-self.a, -self.b, 0.0]), np.array([self.a, self.b, 0.0])

    def _sample_local(self, rng, n):
        u = rng.random((n, 2))
        p = np.stack([(2 * u[:, 0] - 1) * self.a, (2 * u[:, 1] - 1) * self.b, np.zeros(n)], 1)
        nrm = np.tile([0.0, 0.0, 1.0], (n, 1))
        return p, nrm, _random_tangent(rng, n), math.inf

    def _distance_local(self, q):
        dx = np.maximum(np.abs(q[:, 0]) - self.a, 0.0)
        dy = np.maximum(np.abs(q[:, 1]) - self.b, 0.0)
        return np.sqrt(q[:, 2] ** 2 + dx * dx + dy * dy)

    def _normal_local(self, q):
        return np.tile([0.0, 0.0, 1.0], (len(q), 1))


class Disc(Surface):
    """Planar annulus ``r_in <= rho <= r_out`` in the local plane z = 0, normal +z."""

    type_name = "disc"

    def __init__(self, name, frame, r_out: float, r_in: float = 0.0, **kw):
        super().__init__(name, frame, **kw)
        self.r_out, self.r_in = float(r_out), float(r_in)

    def area(self):
        return math.pi * (self.r_out**2 - self.r_in**2)

    def params(self):
        return {"r_out": self.r_out, "r_in": self.r_in}

    def _local_bounds(self):
        r = self.r_out
        return np.array([-r, -r, 0.0]), np.array([r, r, 0.0])

    def _sample_local(self, rng, n):
        u = rng.random((n, 2))
        rho = np.sqrt(self.r_in**2 + u[:, 0] * (self.r_out**2 - self.r_in**2))
        a = u[:, 1] * TWO_PI
        p = np.stack([rho * np.cos(a), rho * np.sin(a), np.zeros(n)], 1)
        return p, np.tile([0.0, 0.0, 1.0], (n, 1)), _random_tangent(rng, n), math.inf

    def _distance_local(self, q):
        rho = np.hypot(q[:, 0], q[:, 1])
        d = np.maximum(np.maximum(self.r_in - rho, rho - self.r_out), 0.0)
        return np.sqrt(q[:, 2] ** 2 + d * d)

    def _normal_local(self, q):
        return np.tile([0.0, 0.0, 1.0], (len(q), 1))


class Cylinder(Surface):
    """Open lateral cylinder patch around local z: radius ``r``, ``z0 <= z <= z1``,
    angle ``th0 <= theta <= th1``; normal radial (outward, or inward if ``inward``).

    ``leaf=True`` trims the developed patch (arc length s ∈ [0, L], axial w) to a
    leaf outline ``|w - w_c| <= (z1 - z0)/2 · sin(π s / L)`` — a curved thin leaf
    whose area is the rectangle's times 2/π.
    """

    type_name = "cylinder"

    def __init__(
        self,
        name,
        frame,
        r: float,
        z0: float,
        z1: float,
        th0: float = 0.0,
        th1: float = TWO_PI,
        *,
        inward: bool = False,
        leaf: bool = False,
        **kw,
    ):
        super().__init__(name, frame, **kw)
        self.r, self.z0, self.z1 = float(r), float(z0), float(z1)
        self.th0, self.th1 = float(th0), float(th1)
        self.inward, self.leaf = bool(inward), bool(leaf)
        self.full = (self.th1 - self.th0) >= TWO_PI - 1e-12

    def area(self):
        a = self.r * (self.th1 - self.th0) * (self.z1 - self.z0)
        return a * 2.0 / math.pi if self.leaf else a

    def params(self):
        return {
            "r": self.r,
            "z0": self.z0,
            "z1": self.z1,
            "th0": self.th0,
            "th1": self.th1,
            "inward": self.inward,
            "leaf": self.leaf,
        }

    def _local_bounds(self):
        if self.full:
            r = self.r
            return np.array([-r, -r, self.z0]), np.array([r, r, self.z1])
        th = np.linspace(self.th0, self.th1, 257)
        xs, ys = self.r * np.cos(th), self.r * np.sin(th)
        return (np.array([xs.min(), ys.min(), self.z0]), np.array([xs.max(), ys.max(), self.z1]))

    def _sample_uv(self, rng, n):
        if not self.leaf:
            u = rng.random((n, 2))
            return u[:, 0], u[:, 1]
        out_s, out_w, have = [], [], 0
        while have < n:  # rejection from the bounding rectangle (acceptance 2/π)
            m = int((n - have) * 1.7) + 16
            u = rng.random((m, 2))
            ok = np.abs(2 * u[:, 1] - 1) <= np.sin(math.pi * u[:, 0])
            out_s.append(u[ok, 0])
            out_w.append(u[ok, 1])
            have += int(ok.sum())
        return np.concatenate(out_s)[:n], np.concatenate(out_w)[:n]

    def _sample_local(self, rng, n):
        us, uz = self._sample_uv(rng, n)
        th = self.th0 + us * (self.th1 - self.th0)
        z = self.z0 + uz * (self.z1 - self.z0)
        c, s = np.cos(th), np.sin(th)
        p = np.stack([self.r * c, self.r * s, z], 1)
        sign = -1.0 if self.inward else 1.0
        nrm = sign * np.stack([c, s, np.zeros(n)], 1)
        t = np.stack([-s, c, np.zeros(n)], 1)
        return p, nrm, t, self.r

    def _distance_local(self, q):
        rho = np.hypot(q[:, 0], q[:, 1])
        dz = np.maximum(np.maximum(self.z0 - q[:, 2], q[:, 2] - self.z1), 0.0)
        d_in = np.sqrt((rho - self.r) ** 2 + dz * dz)
        if self.full:
            return d_in
        th = np.arctan2(q[:, 1], q[:, 0])
        ends = []
        for te in (self.th0, self.th1):
            ex, ey = self.r * math.cos(te), self.r * math.sin(te)
            ends.append(np.hypot(q[:, 0] - ex, q[:, 1] - ey))
        d_xy = np.minimum(*ends)
        d_out = np.sqrt(d_xy * d_xy + dz * dz)
        return np.where(_in_arc(th, self.th0, self.th1), d_in, d_out)

    def _normal_local(self, q):
        rho = np.maximum(np.hypot(q[:, 0], q[:, 1]), 1e-300)
        n = np.stack([q[:, 0] / rho, q[:, 1] / rho, np.zeros(len(q))], 1)
        return -n if self.inward else n

    def _inside_local(self, q):
        if not self.full:
            return np.zeros(len(q), bool)
        return (np.hypot(q[:, 0], q[:, 1]) < self.r) & (q[:, 2] >= self.z0) & (q[:, 2] <= self.z1)


class Sphere(Surface):
    """Sphere patch of radius ``r`` around the local origin with polar angle (from
    local +z) in ``[pol0, pol1]``; normal radial (outward, or inward if ``inward``)."""

    type_name = "sphere"

    def __init__(
        self,
        name,
        frame,
        r: float,
        pol0: float = 0.0,
        pol1: float = math.pi,
        *,
        inward: bool = False,
        **kw,
    ):
        super().__init__(name, frame, **kw)
        self.r, self.pol0, self.pol1, self.inward = float(r), float(pol0), float(pol1), bool(inward)

    def area(self):
        return TWO_PI * self.r**2 * (math.cos(self.pol0) - math.cos(self.pol1))

    def params(self):
        return {"r": self.r, "pol0": self.pol0, "pol1": self.pol1, "inward": self.inward}

    def _local_bounds(self):
        r = self.r
        zs = r * np.cos(np.linspace(self.pol0, self.pol1, 257))
        rho = r * np.sin(np.linspace(self.pol0, self.pol1, 257)).max()
        return np.array([-rho, -rho, zs.min()]), np.array([rho, rho, zs.max()])

    def _sample_local(self, rng, n):
        u = rng.random((n, 2))
        c0, c1 = math.cos(self.pol0), math.cos(self.pol1)
        cz = c0 + u[:, 0] * (c1 - c0)
        sz = np.sqrt(np.maximum(1.0 - cz * cz, 0.0))
        a = u[:, 1] * TWO_PI
        e = np.stack([sz * np.cos(a), sz * np.sin(a), cz], 1)
        t = np.stack([-np.sin(a), np.cos(a), np.zeros(n)], 1)
        return self.r * e, (-e if self.inward else e), t, self.r

    def _distance_local(self, q):
        rho3 = np.linalg.norm(q, axis=1)
        pol = np.arccos(np.clip(q[:, 2] / np.maximum(rho3, 1e-300), -1.0, 1.0))
        d_in = np.abs(rho3 - self.r)
        if self.pol0 <= 0.0 and self.pol1 >= math.pi:
            return d_in
        rxy = np.hypot(q[:, 0], q[:, 1])
        d_out = np.full(len(q), np.inf)
        for pe in (self.pol0, self.pol1):
            d_out = np.minimum(
                d_out, np.hypot(rxy - self.r * math.sin(pe), q[:, 2] - self.r * math.cos(pe))
            )
        inside = (pol >= self.pol0 - 1e-12) & (pol <= self.pol1 + 1e-12)
        return np.where(inside, d_in, d_out)

    def _normal_local(self, q):
        n = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-300)
        return -n if self.inward else n

    def _inside_local(self, q):
        r3 = np.linalg.norm(q, axis=1)
        pol = np.arccos(np.clip(q[:, 2] / np.maximum(r3, 1e-300), -1.0, 1.0))
        return (r3 < self.r) & (pol >= self.pol0) & (pol <= self.pol1)


class Torus(Surface):
    """Torus around local z: major radius ``R``, tube radius ``r``, major angle
    ``psi0 <= psi <= psi1`` (a partial torus is an arc-shaped tube, e.g. a rib);
    outward normal. Tube angle θ:
    point = ((R + r cos θ) cos ψ, (R + r cos θ) sin ψ, r sin θ)."""

    type_name = "torus"

    def __init__(
        self, name, frame, R: float, r: float, psi0: float = 0.0, psi1: float = TWO_PI, **kw
    ):
        super().__init__(name, frame, **kw)
        self.R, self.r, self.psi0, self.psi1 = float(R), float(r), float(psi0), float(psi1)
        if self.r >= self.R:
            raise ValueError("Torus needs r < R")
        self.full = (self.psi1 - self.psi0) >= TWO_PI - 1e-12

    def area(self):
        return TWO_PI * self.r * self.R * (self.psi1 - self.psi0)

    def params(self):
        return {"R": self.R, "r": self.r, "psi0": self.psi0, "psi1": self.psi1}

    def _local_bounds(self):
        if self.full:
            e = self.R + self.r
            return np.array([-e, -e, -self.r]), np.array([e, e, self.r])
        psi = np.linspace(self.psi0, self.psi1, 257)
        cx, cy = self.R * np.cos(psi), self.R * np.sin(psi)
        return (
            np.array([cx.min() - self.r, cy.min() - self.r, -self.r]),
            np.array([cx.max() + self.r, cy.max() + self.r, self.r]),
        )

    def _sample_local(self, rng, n):
        u = rng.random((n, 2))
        psi = self.psi0 + u[:, 0] * (self.psi1 - self.psi0)
        # tube angle with density ∝ (R + r cos θ): invert F(θ) = θ + (r/R) sin θ = 2π u
        k = self.r / self.R
        target = u[:, 1] * TWO_PI
        th = target.copy()
        for _ in range(30):
            step = (th + k * np.sin(th) - target) / (1.0 + k * np.cos(th))
            th -= step
            if np.max(np.abs(step)) < 1e-14:
                break
        ct, st, cp, sp = np.cos(th), np.sin(th), np.cos(psi), np.sin(psi)
        rr = self.R + self.r * ct
        p = np.stack([rr * cp, rr * sp, self.r * st], 1)
        nrm = np.stack([ct * cp, ct * sp, st], 1)
        t = np.stack([-st * cp, -st * sp, ct], 1)
        return p, nrm, t, self.r

    def _distance_local(self, q):
        rho = np.hypot(q[:, 0], q[:, 1])
        d_in = np.abs(np.hypot(rho - self.R, q[:, 2]) - self.r)
        if self.full:
            return d_in
        psi = np.arctan2(q[:, 1], q[:, 0])
        d_out = np.full(len(q), np.inf)
        for pe in (self.psi0, self.psi1):
            c = np.array([self.R * math.cos(pe), self.R * math.sin(pe), 0.0])
            tdir = np.array([-math.sin(pe), math.cos(pe), 0.0])
            v = q - c
            h = v @ tdir
            inplane = np.linalg.norm(v - h[:, None] * tdir, axis=1)
            d_out = np.minimum(d_out, np.hypot(h, inplane - self.r))
        return np.where(_in_arc(psi, self.psi0, self.psi1), d_in, d_out)

    def _normal_local(self, q):
        rho = np.maximum(np.hypot(q[:, 0], q[:, 1]), 1e-300)
        c = np.stack([self.R * q[:, 0] / rho, self.R * q[:, 1] / rho, np.zeros(len(q))], 1)
        v = q - c
        return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)

    def _inside_local(self, q):
        rho = np.hypot(q[:, 0], q[:, 1])
        return (np.hypot(rho - self.R, q[:, 2]) < self.r) & _in_arc(
            np.arctan2(q[:, 1], q[:, 0]), self.psi0, self.psi1
        )


def box(name: str, center, half, *, bottom: bool = False, top: bool = True, **kw) -> list[Rect]:
    """Axis-aligned box (world z up) as outward-facing rectangles ``name/+x`` …

    The bottom face is omitted unless ``bottom`` (boxes usually stand on something).
    """
    c = np.asarray(center, np.float64)
    hx, hy, hz = (float(v) for v in half)
    faces = []
    spec = [
        ("+x", (1, 0, 0), (0, 1, 0), hy, hz, hx),
        ("-x", (-1, 0, 0), (0, -1, 0), hy, hz, hx),
        ("+y", (0, 1, 0), (-1, 0, 0), hx, hz, hy),
        ("-y", (0, -1, 0), (1, 0, 0), hx, hz, hy),
        ("+z", (0, 0, 1), (1, 0, 0), hx, hy, hz),
        ("-z", (0, 0, -1), (1, 0, 0), hx, hy, hz),
    ]
    for tag, nrm, xh, _a, _b, off in spec:
        if tag == "+z" and not top or tag == "-z" and not bottom:
            continue
        nrm = np.asarray(nrm, np.float64)
        fr = Frame.make(c + nrm * off, nrm, xh)
        # local x = xh, local y = z × x: choose extents along those axes
        ax = fr.R[:, 0]
        ext_x = hx * abs(ax[0]) + hy * abs(ax[1]) + hz * abs(ax[2])
        ay = fr.R[:, 1]
        ext_y = hx * abs(ay[0]) + hy * abs(ay[1]) + hz * abs(ay[2])
        faces.append(Rect(f"{name}/{tag}", fr, ext_x, ext_y, **kw))
    return faces


def min_distance(
    surfaces: list[Surface], points: np.ndarray, cutoff: float, skip: set[int] | None = None
) -> np.ndarray:
    """``min(cutoff, distance to the nearest surface)`` per point.

    Only points inside a surface's AABB grown by ``cutoff`` are evaluated for it,
    so small surfaces cost little.
    """
    points = np.asarray(points, np.float64)
    out = np.full(len(points), float(cutoff))
    for j, s in enumerate(surfaces):
        if skip and j in skip:
            continue
        lo, hi = s.bounds()
        lo, hi = lo - cutoff, hi + cutoff
        sel = np.flatnonzero((points[:, 0] >= lo[0]) & (points[:, 0] <= hi[0]))
        for ax in (1, 2):  # narrow axis by axis: cheap when the box is small
            c = points[sel, ax]
            sel = sel[(c >= lo[ax]) & (c <= hi[ax])]
        if len(sel):
            out[sel] = np.minimum(out[sel], s.distance(points[sel]))
    return out
