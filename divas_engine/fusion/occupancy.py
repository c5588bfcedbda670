"""2DGS occupancy grid: Morton-scattered surfel opacity (paper Sec. 3.5 "Occupancy by
Morton-scattered opacity", eq:scene-norm, eq:voxel-size; App. B; NOTES "Occupancy").

Frame (eq:scene-norm): ``c_scene`` = coordinate-wise median of the finite centres, ``r_fg`` =
P99 radial distance, half-extent ``b = 1.05 r_fg``. Voxel edge (eq:voxel-size):
``h_v = max(α_v s̄, β_v r_fg / g_0)`` with ``s̄`` the median of ``max(s₁, s₂)``; ``g`` = smallest
power of two ≥ 2b/h_v, capped at g_max, then ``h_v = 2b/g``.

Storage ∝ active voxels, never a dense g³ array: ``codes [A] int64`` (ascending Morton),
``density [A] float32``, ``count [A] int32`` and an open-addressing hash code → active index
(load ≤ ½). Not the paper's packed bitfield: a g³-bit field is 128 MiB at g = 1024 whatever the
scene and gives no active *index* (per-voxel P and bitmasks live in active-index order); a
two-level brick table costs a fixed 8 MiB top level. Pass 1 reads ``seg[active_index]``.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from divas_kernels import (
    Device,
    DeviceArray,
    GridGeom,
    build_active,
    device_synchronize,
    device_zeros,
    hash_build,
    hash_query,
    is_device_array,
    make_grid_geom,
    resolve_device,
    surfel_codes,
    to_device,
)

from ..scene import SurfelScene
from ..scene_stats import robust_frame
from .config import GridConfig
from .morton import morton_decode

__all__ = [
    "GridGeometry",
    "grid_geometry",
    "aabb_filter",
    "resolve_resolution",
    "OccupancyGrid",
    "BuildReport",
    "build_occupancy",
    "surfel_voxel_codes",
    "voxel_codes_numpy",
]


def _next_pow2_at_least(x: float) -> int:
    g = 1
    while g < x:
        g *= 2
    return g


@dataclass(frozen=True)
class GridGeometry:
    """The grid frame (eq:scene-norm, eq:voxel-size).

    Attributes:
        center: c_scene ``[3]`` float64.
        half_extent: b = pad · r_fg.
        voxel_size: h_v (after the cap rule).
        resolution: g (power of two).
        r_fg: P99 radius; s_bar: median max(s₁,s₂) of kept surfels.
        capped: whether g hit g_max (then h_v = 2b/g).
    """

    center: np.ndarray
    half_extent: float
    voxel_size: float
    resolution: int
    r_fg: float
    s_bar: float
    capped: bool

    @property
    def bits(self) -> int:
        return self.resolution.bit_length() - 1

    @property
    def origin(self) -> np.ndarray:
        return self.center - self.half_extent

    def device_geom(self) -> GridGeom:
        return make_grid_geom(self.center, self.half_extent, self.voxel_size, self.resolution)

    def voxel_centers(self, codes: np.ndarray) -> np.ndarray:
        """``[A,3]`` float64 world centres of Morton ``codes``."""
        return self.origin + (morton_decode(codes) + 0.5) * self.voxel_size


def resolve_resolution(half_extent: float, h_raw: float, g_max: int) -> tuple[float, int, bool]:
    """eq:voxel-size tail: g = smallest 2^k ≥ 2b/h_v, capped at g_max (then h_v = 2b/g)."""
    if not (h_raw > 0 and np.isfinite(h_raw)):
        raise ValueError(f"voxel size h_v={h_raw} must be positive and finite")
    g = _next_pow2_at_least(2.0 * half_extent / h_raw)
    if g > g_max:
        return 2.0 * half_extent / g_max, g_max, True
    return h_raw, g, False


def grid_geometry(
    means: np.ndarray, scales: np.ndarray, config: GridConfig = GridConfig()
) -> GridGeometry:
    """c_scene, r_fg, b, s̄, h_v and g from surfel centres ``[N,3]`` and scales ``[N,2]``."""
    means = np.asarray(means)
    finite = np.all(np.isfinite(means), axis=1)
    if not finite.any():
        raise ValueError("occupancy: the scene has no finite surfel centre")
    frame = robust_frame(means[finite], percentile=config.percentile)
    b = config.pad * frame.radius
    if not b > 0:
        raise ValueError("occupancy: degenerate scene (P99 radius is 0)")
    keep = aabb_filter(means, frame.center, b)
    smax = np.asarray(scales, dtype=np.float64)[keep].max(axis=1)
    s_bar = float(np.median(smax)) if smax.size else 0.0
    h_raw = max(config.alpha_v * s_bar, config.beta_v * frame.radius / config.g0)
    h, g, capped = resolve_resolution(b, h_raw, config.g_max)
    return GridGeometry(
        frame.center, float(b), float(h), int(g), float(frame.radius), s_bar, capped
    )


def aabb_filter(means: np.ndarray, center: np.ndarray, half: float) -> np.ndarray:
    """``[N] bool``: ``¬NaN(μ) ∧ ‖μ − c‖_∞ < b`` in float64 (alg:vox2surfel Pass 1)."""
    p = np.asarray(means, dtype=np.float32).astype(np.float64)
    with np.errstate(invalid="ignore"):
        r = p - np.asarray(center, dtype=np.float64)
        return np.all(np.isfinite(p), axis=1) & np.all(np.abs(r) < half, axis=1)


def voxel_codes_numpy(
    means: np.ndarray, center: np.ndarray, half: float, h: float, g: int
) -> np.ndarray:
    """NumPy twin of ``divas_kernels.occupancy.point_voxel_code`` (−1 = filtered).

    Same float64 operations in the same order, so voxel assignments agree bit for bit.
    """
    from .morton import morton_encode

    p = np.asarray(means, dtype=np.float32).astype(np.float64)
    ok = aabb_filter(p, center, half)
    r = p[ok] - np.asarray(center, dtype=np.float64)
    q = np.floor((r + half) / h).astype(np.int64)
    out = np.full(len(p), -1, dtype=np.int64)
    out[ok] = morton_encode(np.clip(q, 0, g - 1))
    return out


@dataclass
class BuildReport:
    """What :func:`build_occupancy` did (printed by ``divas info``/benchmarks)."""

    g: int
    h_v: float
    b: float
    s_bar: float
    r_fg: float
    capped: bool
    n_surfels: int
    n_kept: int
    n_occupied: int
    n_active: int
    active_fraction: float
    surfels_per_active: float
    build_time_s: float
    peak_bytes: int
    resident_bytes: int

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(eq=False)
class OccupancyGrid:
    """The 2DGS occupancy grid on ``device`` (see module docstring).

    Attributes:
        geometry: the frame and resolution.
        codes: ``[A] int64`` ascending Morton codes of the active voxels.
        density: ``[A] float32`` summed opacity ρ (≥ τ_TF).
        count: ``[A] int32`` surfels per active voxel.
        hash_keys, hash_vals, hash_shift: code → active-index table.
    """

    geometry: GridGeometry
    config: GridConfig
    codes: DeviceArray
    density: DeviceArray
    count: DeviceArray
    hash_keys: DeviceArray
    hash_vals: DeviceArray
    hash_shift: int
    device: Device
    report: BuildReport

    def __len__(self) -> int:
        return self.codes.shape[0]

    @property
    def nbytes(self) -> int:
        return sum(
            a.capacity
            for a in (self.codes, self.density, self.count, self.hash_keys, self.hash_vals)
        )

    @classmethod
    def from_codes(
        cls,
        geometry: GridGeometry,
        codes: np.ndarray,
        density: np.ndarray,
        config: GridConfig = GridConfig(),
        device=None,
    ) -> OccupancyGrid:
        """A grid over given active ``codes`` (sorted ascending here) and their density
        (tests, hand-made grids)."""
        device = resolve_device(device)
        codes = np.asarray(codes, dtype=np.int64)
        order = np.argsort(codes, kind="stable")
        c = to_device(codes[order], device)
        d = to_device(np.asarray(density, dtype=np.float32)[order], device)
        cnt = device_zeros(len(codes), np.int32, device)
        keys, vals, shift = hash_build(c, device=device)
        g = geometry.resolution
        rep = BuildReport(
            g,
            geometry.voxel_size,
            geometry.half_extent,
            geometry.s_bar,
            geometry.r_fg,
            geometry.capped,
            0,
            0,
            len(codes),
            len(codes),
            len(codes) / float(g) ** 3,
            0.0,
            0.0,
            0,
            0,
        )
        grid = cls(geometry, config, c, d, cnt, keys, vals, shift, device, rep)
        grid.report.resident_bytes = grid.nbytes
        return grid

    def centers(self) -> np.ndarray:
        """``[A,3]`` float64 world centres of the active voxels."""
        return self.geometry.voxel_centers(self.codes.numpy())

    def lookup(self, codes: np.ndarray | DeviceArray) -> np.ndarray:
        """``[M] int32`` active index of each Morton code (−1 absent/filtered)."""
        c = codes if is_device_array(codes) else to_device(codes, self.device, dtype=np.int64)
        return hash_query(
            self.hash_keys, self.hash_vals, self.hash_shift, c, device=self.device
        ).numpy()

    def surfel_active_index(self, means: np.ndarray | DeviceArray) -> np.ndarray:
        """``[N] int32`` active index of each surfel's voxel (−1: filtered or inactive)."""
        codes = surfel_voxel_codes(means, self.geometry, device=self.device)
        return hash_query(
            self.hash_keys, self.hash_vals, self.hash_shift, codes, device=self.device
        ).numpy()


def _as_vec3(means, device) -> DeviceArray:
    if is_device_array(means):
        return means
    return to_device(means, device, vec3=True)


def surfel_voxel_codes(
    means: np.ndarray | DeviceArray, geometry: GridGeometry, device=None
) -> DeviceArray:
    """``[N] int64`` Morton code of each surfel's voxel, −1 where the AABB/NaN filter
    drops it — the exact filter and encoding of the build (alg:vox2surfel Pass 1)."""
    device = resolve_device(device)
    m = _as_vec3(means, device)
    codes, _, _ = surfel_codes(m, geometry.device_geom(), filtered=-1, device=device)
    return codes


def build_occupancy(
    scene: SurfelScene,
    config: GridConfig = GridConfig(),
    device=None,
    geometry: GridGeometry | None = None,
) -> OccupancyGrid:
    """Build the active-voxel list of ``scene`` on ``device`` (App. B, four passes).

    ``geometry``: ``grid_geometry(scene.means, scene.scales, config)`` when already known
    (the session computes it at open, to fail early, and builds the rest later)."""
    device = resolve_device(device)
    t0 = time.perf_counter()
    geo = geometry or grid_geometry(scene.means, scene.scales, config)
    mem = {"cur": 0, "peak": 0}

    def track(nbytes: int) -> None:
        mem["cur"] += int(nbytes)
        mem["peak"] = max(mem["peak"], mem["cur"])

    means = _as_vec3(scene.means, device)
    opac = to_device(scene.opacities, device, dtype=np.float32)
    track(means.capacity + opac.capacity)
    res = build_active(
        means, opac, geo.device_geom(), geo.bits, config.tau_tf, device=device, mem=track
    )
    keys, vals, shift = hash_build(res["codes"], device=device)
    track(keys.capacity + vals.capacity)
    device_synchronize(device)
    n_act = res["codes"].shape[0]
    in_active = int(res["count"].numpy().sum()) if n_act else 0
    grid = OccupancyGrid(
        geo, config, res["codes"], res["density"], res["count"], keys, vals, shift, device, None
    )  # type: ignore[arg-type]
    grid.report = BuildReport(
        g=geo.resolution,
        h_v=geo.voxel_size,
        b=geo.half_extent,
        s_bar=geo.s_bar,
        r_fg=geo.r_fg,
        capped=geo.capped,
        n_surfels=len(scene),
        n_kept=res["n_kept"],
        n_occupied=res["n_occupied"],
        n_active=n_act,
        active_fraction=n_act / float(geo.resolution) ** 3,
        surfels_per_active=in_active / n_act if n_act else 0.0,
        build_time_s=time.perf_counter() - t0,
        peak_bytes=mem["peak"],
        resident_bytes=grid.nbytes,
    )
    return grid
