"""The scene's primitives as graph nodes: position, colour, normal, opacity.

One :class:`ScenePrimitives` per scene, built once when the segmenter is bound: a surfel
scene's Gaussian centres (SH DC colour in CIE-Lab, normal with a confidence κ, opacity)
or a density grid's occupied shell cells (grid colour, normal ``−∇σ``). A surfel scene's
per-primitive features are computed for the rows a prompt reads, bit for bit as over the
whole scene, so only the scene's own arrays stay resident; the segmenter's warm-up may
keep every primitive's colour (and κ) (:meth:`ScenePrimitives.cache_features`). It also
finds the scene's ground plane once and turns a per-primitive array into what the
renderer's ``render_values`` takes. The node definitions in full: docs/design-notes.md.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.ndimage import binary_erosion

from ...geometry import quat_to_rotmat
from ...scene import SH_C0, DensityGrid, Scene, SurfelScene
from ...scene_stats import RobustFrame, robust_frame
from ...views.config import ViewConfig
from ...views.ground import GroundPlane, ground_candidates, scene_points
from ...views.up_direction import UpSource, estimate_scene_up

__all__ = ["ScenePrimitives", "surfel_frame"]

_GREY = np.float32(0.8)
_REACH_SIGMAS = 4.0  # ≥ the 3.33 σ cutoff disc of α ≥ 1/255 (down to α_min ≈ 1/3000)


def _lab(rgb: np.ndarray, clipped: bool = False) -> np.ndarray:
    """``[N,3]`` CIE-Lab (L 0–100) of ``[N,3]`` RGB in [0,1] (sRGB, no linearisation);
    ``clipped``: ``rgb`` is in [0,1] already (clipping again changes nothing)."""
    a = rgb if clipped else np.clip(rgb, 0.0, 1.0)
    a = np.ascontiguousarray(a, dtype=np.float32).reshape(-1, 1, 3)
    if len(a) == 0:  # (a region without primitives)
        return np.zeros((0, 3), np.float32)
    return cv2.cvtColor(a, cv2.COLOR_RGB2Lab).reshape(-1, 3)


def surfel_frame(means: np.ndarray, block: int = 1 << 18) -> RobustFrame:
    """:func:`~divas_engine.scene_stats.robust_frame` of the surfel centres ``means``
    (eq:scene-norm: median centre, P99 radius), bit for bit, without its float64
    ``[N,3]`` copies (large transients at millions of splats, in the warm-up): the
    median of each coordinate from its own contiguous float64 column (the same order
    statistics and the same mean of the middle two), the distances by the same
    ``np.linalg.norm`` on ``block`` rows at a time (row by row the same sums)."""
    p = np.asarray(means)
    n = len(p)
    if n == 0:
        return robust_frame(np.asarray(p, np.float64).reshape(0, 3))
    c = np.array([np.median(np.asarray(p[:, k], np.float64)) for k in range(3)])
    d = np.empty(n)
    for i in range(0, n, block):
        d[i : i + block] = np.linalg.norm(np.asarray(p[i : i + block], np.float64) - c, axis=1)
    return RobustFrame(c, float(np.percentile(d, 99.0)))


@dataclass(eq=False)
class ScenePrimitives:
    """Graph-node features of every primitive of a scene (docs/design-notes.md).

    Attributes:
        points: ``[M,3]`` float32 positions; lab: ``[M,3]`` float32 colour;
        normals: ``[M,3]`` float32 unit normals (sign meaningless); kappa: ``[M]`` normal
            confidence in [0,1]; mass: ``[M]`` float32 opacity. ``lab``, ``normals``,
            ``kappa``, ``reach`` and ``sigma`` are None for a surfel scene: read them
            for some rows with :meth:`lab_of` etc. (computed from the scene's arrays).
        index: ``[M]`` int64 primitive index in the scene (surfel row, or flat cell
            index); None when primitive ``i`` is surfel ``i`` (every surfel kept).
        center, radius: the robust frame ``c_scene``, ``r_fg`` (eq:scene-norm).
        grounds: the scene's ground plane (none, or one: the up's).
        up: the scene up (None when unknown: no local supports then).
        cell: the grid's largest cell edge for a density grid (the graph's voxels are
            never finer: a finer voxel grid would leave the occupied cells unconnected),
            0 for surfels.
        reach: ``[M]`` radius around each position beyond which the primitive draws
            nothing (:mod:`.render_box`): ``_REACH_SIGMAS`` × its largest scale for a
            surfel (its cutoff disc, α ≥ 1/255, is 3.33 σ), two cell edges for a grid
            cell (its value is interpolated trilinearly from the neighbouring centres).
        sigma: ``[M]`` each surfel's largest standard deviation (None for a grid, whose
            cells have no extent beyond their own voxel-sized cell); the voxel graph gives
            a primitive wider than its voxel every voxel its extent covers
            (:func:`extent_axes`).
        scene: the scene.
    """

    points: np.ndarray
    lab: np.ndarray | None
    normals: np.ndarray | None
    kappa: np.ndarray | None
    mass: np.ndarray
    index: np.ndarray | None
    center: np.ndarray
    radius: float
    grounds: tuple[GroundPlane, ...]
    scene: Scene

    up: np.ndarray | None = None
    cell: float = 0.0
    reach: np.ndarray | None = None
    sigma: np.ndarray | None = None
    #: a surfel scene's ``(lab [M,3], kappa [M] or None)`` of every primitive once
    #: :meth:`cache_features` made them, else None (computed per row)
    features: tuple[np.ndarray, np.ndarray | None] | None = None

    @classmethod
    def from_scene(
        cls, scene: Scene, min_opacity: float = 0.0, up: np.ndarray | None = None
    ) -> ScenePrimitives:
        """Features of ``scene``; ``up``: the scene up the session planned its anchors
        with (training cameras, or estimated), else estimated here."""
        if isinstance(scene, SurfelScene):
            out = cls._from_surfels(scene, min_opacity)
        elif isinstance(scene, DensityGrid):
            out = cls._from_grid(scene, max(min_opacity, 1.0 / 255.0))
        else:
            raise TypeError(f"3D graph segmenter: unsupported scene {type(scene).__name__}")
        out._find_ground(up)
        return out

    @classmethod
    def _from_surfels(cls, scene: SurfelScene, min_opacity: float) -> ScenePrimitives:
        keep = np.flatnonzero(scene.opacities >= min_opacity)
        if len(keep) == len(scene):  # every surfel: the scene's own arrays, read only
            pts = np.asarray(scene.means, np.float32)
            mass = np.asarray(scene.opacities, np.float32)
            index = None  # primitive i is surfel i (no [N] int64 arange)
        else:
            pts = np.asarray(scene.means[keep], np.float32)
            mass = np.asarray(scene.opacities[keep], np.float32)
            index = keep
        # colour, normal, κ, σ and reach are computed per row when a prompt reads them;
        # OpenCV builds its Lab tables at its first conversion (a one-off cost): here, in the
        # session's warm-up, not in the first click's prompt
        _lab(np.full((1, 3), 0.5, np.float32))
        return cls._finish(scene, pts, None, None, None, mass, index)

    @classmethod
    def _from_grid(cls, grid: DensityGrid, min_opacity: float) -> ScenePrimitives:
        h = float(np.mean(grid.voxel_size))
        alpha = 1.0 - np.exp(-grid.density.astype(np.float64) * h)
        occ = alpha >= min_opacity
        # the shell: an occupied cell with an empty face neighbour (what a view sees, like
        # a surfel); a solid interior would make a cut across an object as cheap per
        # volume as around it, and renders nothing anyway
        occ &= ~binary_erosion(occ, iterations=1, border_value=0)
        flat = np.flatnonzero(occ.reshape(-1))
        iz, iy, ix = np.unravel_index(flat, grid.density.shape)
        pts = grid.aabb[0] + (np.stack([ix, iy, iz], 1) + 0.5) * grid.voxel_size
        gz, gy, gx = np.gradient(grid.density.astype(np.float32))
        g = -np.stack([gx[occ], gy[occ], gz[occ]], 1) / np.asarray(grid.voxel_size, np.float32)
        gn = np.linalg.norm(g, axis=1)
        normals = g / np.maximum(gn, 1e-12)[:, None]
        sig = grid.density[occ].astype(np.float32)
        kappa = np.clip(gn * h / np.maximum(sig, 1e-12), 0.0, 1.0)  # relative change per cell
        if grid.rgb is not None:
            rgb = grid.rgb.reshape(-1, 3)[flat]
        else:
            rgb = np.full((len(flat), 3), _GREY, np.float32)
        out = cls._finish(
            grid,
            pts.astype(np.float32),
            _lab(rgb),
            normals.astype(np.float32),
            kappa.astype(np.float32),
            alpha[occ].astype(np.float32),
            flat.astype(np.int64),
        )
        out.cell = float(np.max(grid.voxel_size))
        out.reach = np.full(len(flat), 2.0 * out.cell, np.float32)
        return out

    @classmethod
    def _finish(cls, scene, pts, lab, normals, kappa, mass, index) -> ScenePrimitives:
        if isinstance(scene, SurfelScene):
            frame = surfel_frame(scene.means)
        else:
            frame = robust_frame(scene_points(scene)[0])
        return cls(
            pts, lab, normals, kappa, mass, index, frame.center, float(frame.radius), (), scene
        )

    def _find_ground(self, up: np.ndarray | None) -> None:
        """The ground plane and up: with a known ``up``, the strongest supporting plane
        within ``ground_convention_deg`` of it; else the shared scene-up estimate's ground
        (a one-sided dense plane elsewhere, such as the top of a box, is not a ground)."""
        if up is not None and isinstance(self.scene, SurfelScene):
            # the scene's own float32 centres: ground_candidates takes the float64 of the
            # rows it uses, the same values as scene_points' (no [N,3] float64 copy)
            p, w = self.scene.means, self.scene.opacities
        else:
            p, w = scene_points(self.scene)
        # the shared ground search on a lighter sample than the anchor planner's (the
        # floor / table plane is dense; 1500 directions × 20k points take seconds)
        cfg = replace(ViewConfig(), ground_points=6000, ground_directions=500)
        if up is None:
            est = estimate_scene_up(p, w, self.center, self.radius, cfg)
            self.grounds = () if est.source != UpSource.GROUND else (est.ground,)
            self.up = None if not self.grounds else np.asarray(est.up, np.float64)
            return
        u = np.asarray(up, np.float64) / np.linalg.norm(up)
        cos = np.cos(np.radians(cfg.ground_convention_deg))
        cands = [
            g
            for g in ground_candidates(p, w, self.center, self.radius, cfg)
            if g.support >= cfg.ground_min_support
            and g.sharpness >= cfg.ground_min_sharpness
            and float(g.normal @ u) >= cos
        ]
        self.grounds = (max(cands, key=lambda g: g.support),) if cands else ()
        # the floor's own normal is the finer up (a camera-rig up is good to a few
        # degrees; a table top 40 cm wide tilted 3° spans a voxel of height)
        self.up = np.asarray(self.grounds[0].normal, np.float64) if self.grounds else u

    def __len__(self) -> int:
        return len(self.points)

    def rows_of(self, idx: np.ndarray) -> np.ndarray:
        """The scene rows (surfel rows, or flat cell indices) of primitives ``idx``."""
        idx = np.asarray(idx)
        idx = np.flatnonzero(idx) if idx.dtype == bool else idx.astype(np.int64, copy=False)
        return idx if self.index is None else self.index[idx]

    def cache_features(self, block: int = 1 << 18) -> int:
        """Compute a surfel scene's Lab colour (and κ, for 3DGS input) for every primitive
        once and keep them (:attr:`features`): :meth:`lab_of` and :meth:`kappa_of` then
        gather their rows instead of computing them from the scene's arrays — the same
        element-wise arithmetic on the same values (OpenCV's Lab conversion is per pixel),
        so the same bits (a click's region can hold a million primitives, and gathering
        each one's SH DC row, 192 bytes apart, and converting it is a large share of the
        click's cut). The scene-only part of the cut, made once per scene (the
        segmenter's warm-up), ``block`` rows at a time (little transient memory). Held: 12
        bytes a primitive (16 with κ); the normals are not kept (as much memory again,
        and :meth:`normals_of` is cheap). Returns the bytes held (0 for a density grid,
        whose features are stored already)."""
        if not isinstance(self.scene, SurfelScene):
            return 0
        if self.features is None:
            m = len(self)
            lab = np.empty((m, 3), np.float32)
            kap = None if self.scene.scale_n is None else np.empty(m, np.float32)
            for s in range(0, m, block):
                rows = np.arange(s, min(s + block, m))
                lab[rows] = self.lab_of(rows)
                if kap is not None:
                    kap[rows] = self.kappa_of(rows)
            self.features = (lab, kap)  # one assignment: readers see all or none
        return sum(0 if a is None else a.nbytes for a in self.features)

    def drop_features(self) -> None:
        """Forget :meth:`cache_features`' arrays (the rows are computed again)."""
        self.features = None

    def lab_of(self, idx: np.ndarray) -> np.ndarray:
        """``[n,3]`` float32 CIE-Lab colour of primitives ``idx``: a surfel's SH DC
        colour (:meth:`~divas_engine.scene.SurfelScene.base_colors`' arithmetic on its
        rows), a grid cell's RGB."""
        if self.lab is not None:
            return self.lab[idx]
        feats = self.features
        if feats is not None:
            return feats[0][idx]
        g = self.scene.sh[self.rows_of(idx), 0, :]  # a gathered copy: worked in place
        g *= SH_C0  # clip(0.5 + SH_C0 · f_dc, 0, 1) in the SH's dtype, as base_colors
        g += 0.5
        np.clip(g, 0.0, 1.0, out=g)
        return _lab(g, clipped=True)

    def normals_of(self, idx: np.ndarray) -> np.ndarray:
        """``[n,3]`` float32 unit normals of primitives ``idx``: a surfel's rotation
        column 2 (:func:`~divas_engine.geometry.quat_to_rotmat`'s arithmetic)."""
        if self.normals is not None:
            return self.normals[idx]
        q = self.scene.quats
        if q.dtype != np.float32:  # (the loaders' dtype; others: the plain expressions)
            q = q[self.rows_of(idx)]
            w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
            out = np.empty((len(q), 3), np.float32)  # column 2, each entry in q's dtype
            out[:, 0] = 2 * (x * z + w * y)
            out[:, 1] = 2 * (y * z - w * x)
            out[:, 2] = 1 - 2 * (x * x + y * y)
            return out
        # the same float32 operations in the same order — 2·(xz + wy), 2·(yz − wx),
        # 1 − 2·(xx + yy) — on contiguous columns (faster than strided ones over a
        # click's region of a million rows)
        w, x, y, z = (np.ascontiguousarray(c) for c in np.take(q, self.rows_of(idx), axis=0).T)
        n = len(w)
        out = np.empty((3, n), np.float32)
        a = np.empty(n, np.float32)
        np.multiply(x, z, out=out[0])
        out[0] += np.multiply(w, y, out=a)
        out[0] *= 2
        np.multiply(y, z, out=out[1])
        out[1] -= np.multiply(w, x, out=a)
        out[1] *= 2
        np.multiply(x, x, out=out[2])
        out[2] += np.multiply(y, y, out=a)
        out[2] *= 2
        np.subtract(1, out[2], out=out[2])
        return np.ascontiguousarray(out.T)  # [n,3] rows, as before (BLAS reads them so)

    def kappa_of(self, idx: np.ndarray) -> np.ndarray | None:
        """``[n]`` float32 normal confidence κ of primitives ``idx``; None when it is 1
        for every primitive (native 2DGS surfels)."""
        if self.kappa is not None:
            return self.kappa[idx]
        scene = self.scene
        if scene.scale_n is None:
            return None
        feats = self.features
        if feats is not None and feats[1] is not None:
            return feats[1][idx]
        i = self.rows_of(idx)
        s_min = np.maximum(scene.scales[i].min(axis=1), 1e-12)
        return np.clip(1.0 - scene.scale_n[i] / s_min, 0.0, 1.0).astype(np.float32)

    def _sigma_rows(self, idx: np.ndarray) -> np.ndarray:
        scene = self.scene
        i = self.rows_of(idx)
        sigma = scene.scales[i].max(axis=1)
        if scene.scale_n is not None:
            sigma = np.maximum(sigma, scene.scale_n[i])
        return sigma

    def sigma_of(self, idx: np.ndarray) -> np.ndarray | None:
        """``[n]`` float32 largest standard deviation of surfels ``idx`` (attribute
        ``sigma``); None for a density grid."""
        if not isinstance(self.scene, SurfelScene):
            return None if self.sigma is None else self.sigma[idx]
        return self._sigma_rows(idx).astype(np.float32)

    def reach_of(self, idx: np.ndarray) -> np.ndarray:
        """``[n]`` float32 reach of primitives ``idx`` (attribute ``reach``)."""
        if self.reach is not None:
            return self.reach[idx]
        return (_REACH_SIGMAS * self._sigma_rows(idx)).astype(np.float32)

    def in_box(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Indices (into these arrays) of the primitives inside the box ``[lo, hi]``."""
        p = self.points
        m = (p[:, 0] >= lo[0]) & (p[:, 0] <= hi[0])
        m &= (p[:, 1] >= lo[1]) & (p[:, 1] <= hi[1])
        m &= (p[:, 2] >= lo[2]) & (p[:, 2] <= hi[2])
        return np.flatnonzero(m)

    def extent_axes(self, rows: np.ndarray) -> np.ndarray:
        """``[n,3,3]`` float64: row ``k`` of each is the primitive's ``k``-th principal
        axis scaled by its standard deviation (tangents ``s_1 t_u``, ``s_2 t_v``, then
        ``s_n n`` for a 3DGS Gaussian, 0 for a flat 2DGS surfel), for the primitives
        ``rows`` (indices into these arrays) of a surfel scene."""
        scene = self.scene
        assert isinstance(scene, SurfelScene)
        i = self.rows_of(rows)
        rot = quat_to_rotmat(np.asarray(scene.quats[i], np.float64))  # columns: t_u, t_v, n
        s = np.zeros((len(i), 3))
        s[:, :2] = scene.scales[i]
        if scene.scale_n is not None:
            s[:, 2] = scene.scale_n[i]
        return np.ascontiguousarray((rot * s[:, None, :]).transpose(0, 2, 1))

    def render_array(self, values: np.ndarray) -> np.ndarray:
        """Per-primitive ``values [M,C]`` (these primitives' order) as the renderer's
        ``render_values`` input: ``[N,C]`` per surfel, or ``[D,H,W,C]`` per grid cell
        (primitives left out of the graph get 0)."""
        v = np.asarray(values, np.float32)
        if isinstance(self.scene, SurfelScene):
            out = np.zeros((len(self.scene), v.shape[1]), np.float32)
            out[self.rows_of(np.arange(len(v)))] = v
            return out
        shape = self.scene.density.shape
        out = np.zeros((int(np.prod(shape)), v.shape[1]), np.float32)
        out[self.index] = v
        return out.reshape(*shape, v.shape[1])
