"""In-memory scene types every loader produces and every adapter consumes.

Two representations (paper Sec. 3.1 "Preliminaries"):

* :class:`SurfelScene` — 2DGS surfels (3DGS Gaussians are flattened to surfels
  on load, NOTES "Conventions"), float32 structure-of-arrays with activations
  already applied.
* :class:`DensityGrid` — a NeRF density grid sampled on a regular lattice.

Both keep a :class:`SourceInfo` so exports can write a subset of the *original*
file, row for row.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .geometry import quat_to_rotmat
from .kinds import SceneKind

__all__ = ["SourceInfo", "SurfelScene", "DensityGrid", "Scene", "SH_C0", "sh_coeff_count"]

#: Zeroth-order real spherical-harmonic constant: colour = 0.5 + SH_C0 * f_dc.
SH_C0 = 0.28209479177387814


def sh_coeff_count(degree: int) -> int:
    """Number of SH coefficients per colour channel for ``degree`` (0..3)."""
    return (degree + 1) ** 2


@dataclass(eq=False)
class SourceInfo:
    """Where a scene came from, so exports can reproduce the input file.

    Attributes:
        path: the file that was read.
        format: the :data:`~divas_engine.io.load.SCENE_FORMATS` name it was read as.
        num_rows: primitives stored in the file (before any row was dropped).
        kept: ``[N] int64`` file row of each primitive in the scene, ascending; None when
            every row is kept in order (a density grid: no per-cell index is held, so the
            bookkeeping does not grow with the grid).
        dropped_nonfinite: rows dropped because a value was NaN/Inf.
        file_sh_degree: the SH degree stored in the file when the scene was loaded with
            fewer bands (``load_scene(..., max_sh_degree=…)``); None when it keeps them all.
    """

    path: Path
    format: str
    num_rows: int
    kept: np.ndarray | None
    dropped_nonfinite: int = 0
    file_sh_degree: int | None = None

    @property
    def kept_rows(self) -> np.ndarray:
        """The file row of each primitive (``kept``, or ``arange(num_rows)`` made on
        demand when every row is kept)."""
        if self.kept is None:
            return np.arange(self.num_rows, dtype=np.int64)
        return self.kept

    @property
    def dropped(self) -> int:
        return 0 if self.kept is None else self.num_rows - len(self.kept)


@dataclass(eq=False)
class SurfelScene:
    """Oriented 2D Gaussian surfels (2DGS), float32 structure-of-arrays.

    Attributes:
        means: ``[N,3]`` centres μ_i, world units.
        quats: ``[N,4]`` unit quaternions (w, x, y, z). Rotation column 0/1 are
            the tangent axes t_u, t_v, column 2 the normal.
        scales: ``[N,2]`` tangent standard deviations (s_1, s_2), world units
            (``exp`` of the stored log-scales).
        opacities: ``[N]`` opacity α_i in (0, 1) (``sigmoid`` of the stored logit).
        sh: ``[N,K,3]`` SH coefficients, ``K=(sh_degree+1)^2``; ``sh[:,0]`` is DC.
        sh_degree: 0..3.
        kind: :attr:`SceneKind.GS2D` (native surfels) or ``GS3D`` (flattened Gaussians).
        source: the file it came from (None for generated scenes).
        extras: format-specific facts of the source (e.g. the SPZ version).
        scale_n: ``[N]`` for 3DGS input, the standard deviation s_3 along the normal
            (rotation column 2) that the flattening dropped — the Gaussian is
            ``(quats, scales, scale_n)`` exactly; None for native 2DGS surfels.
    """

    means: np.ndarray
    quats: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray
    sh_degree: int
    kind: SceneKind = SceneKind.GS2D
    source: SourceInfo | None = None
    extras: dict = field(default_factory=dict)
    scale_n: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.kind = SceneKind(self.kind)
        n = len(self.means)
        if self.scale_n is not None and self.scale_n.shape != (n,):
            raise ValueError(f"SurfelScene.scale_n has shape {self.scale_n.shape}, expected {(n,)}")
        for name, shape in (
            ("means", (n, 3)),
            ("quats", (n, 4)),
            ("scales", (n, 2)),
            ("opacities", (n,)),
            ("sh", (n, sh_coeff_count(self.sh_degree), 3)),
        ):
            arr = getattr(self, name)
            if arr.shape != shape:
                raise ValueError(f"SurfelScene.{name} has shape {arr.shape}, expected {shape}")

    def __len__(self) -> int:
        return len(self.means)

    def rotations(self) -> np.ndarray:
        """``[N,3,3]`` rotation matrices (columns: t_u, t_v, normal)."""
        return quat_to_rotmat(self.quats)

    def normals(self) -> np.ndarray:
        return self.rotations()[:, :, 2]

    def base_colors(self) -> np.ndarray:
        """``[N,3]`` view-independent colour from the SH DC term, clipped to [0,1]."""
        return np.clip(0.5 + SH_C0 * self.sh[:, 0, :], 0.0, 1.0)

    def subset(self, keep: np.ndarray) -> SurfelScene:
        """A new scene with the primitives selected by bool mask or index array."""
        src = None
        if self.source is not None:
            src = replace(self.source, kept=self.source.kept_rows[keep])
        return SurfelScene(
            self.means[keep],
            self.quats[keep],
            self.scales[keep],
            self.opacities[keep],
            self.sh[keep],
            self.sh_degree,
            self.kind,
            src,
            dict(self.extras),
            None if self.scale_n is None else self.scale_n[keep],
        )


@dataclass(eq=False)
class DensityGrid:
    """A NeRF density field sampled on a regular grid (paper App. A).

    Attributes:
        density: ``[D,H,W]`` float32 volume density σ ≥ 0 (per world unit), indexed
            ``[iz, iy, ix]``; sample ``(ix, iy, iz)`` sits at the *centre* of its cell:
            ``aabb[0] + (i + 0.5) * voxel_size``.
        aabb: ``[2,3]`` float64 world-space min and max corners (x, y, z).
        rgb: optional ``[D,H,W,3]`` float32 colour in [0,1].
        source: the file it came from.
        extras: format-specific facts (e.g. the snapshot an instant-ngp grid came from).
        network: the radiance field the grid was taken from, when the file holds one
            (e.g. :class:`divas_engine.io.ngp_network.NgpNetwork`): views are then
            rendered from it; the grid stays the occupancy, fusion and export lattice.
    """

    density: np.ndarray
    aabb: np.ndarray
    rgb: np.ndarray | None = None
    source: SourceInfo | None = None
    extras: dict = field(default_factory=dict)
    network: Any = None

    @property
    def shape_xyz(self) -> tuple[int, int, int]:
        d, h, w = self.density.shape
        return (w, h, d)

    @property
    def voxel_size(self) -> np.ndarray:
        """``[3]`` cell edge per axis (x, y, z), world units."""
        return (self.aabb[1] - self.aabb[0]) / np.array(self.shape_xyz, dtype=np.float64)

    def __len__(self) -> int:
        return int(self.density.size)


Scene = SurfelScene | DensityGrid
