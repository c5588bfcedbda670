"""Views of an instant-ngp snapshot drawn from its radiance network
(``divas_kernels.raymarch_ngp``).

The density grid the snapshot was read into (:mod:`divas_engine.io.instant_ngp`) stays
the occupancy, fusion and export lattice; this renderer draws RGB and the depth tuple
from the network itself, like instant-ngp renders it (its step size and occupancy
cascades; depths planar, in the training cameras' units). ``render_values`` composites
per-voxel values of that lattice with the network's weights.
"""

from __future__ import annotations

import numpy as np

from divas_kernels import (
    NgpMarchSettings,
    eval_ngp_points,
    raymarch_ngp,
    resolve_device,
    upload_ngp_network,
    upload_ngp_occupancy,
)

from ..camera import Camera
from ..scene import DensityGrid
from .config import RenderConfig
from .nerf_renderer import MarchedViews

__all__ = ["NgpRenderer", "has_ngp_network", "bake_network_colors", "upload_network"]

_GRID_TYPES = {"Hash": 0, "Dense": 1, "Tiled": 2}


def has_ngp_network(grid: DensityGrid) -> bool:
    """Whether ``grid`` carries an instant-ngp network (``io.instant_ngp.NgpField``)."""
    return getattr(grid.network, "kind", None) == "instant-ngp"


#: directions the baked colour averages over: the six axes of the NeRF frame
_BAKE_DIRS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)


def upload_network(net, device):
    """Copy an :class:`~divas_engine.io.ngp_network.NgpNetwork` to ``device``."""
    spec = net.grid
    return upload_ngp_network(
        net.table,
        np.asarray(spec.offsets),
        np.array([spec.level_scale(lv) for lv in range(spec.n_levels)]),
        np.array([spec.level_resolution(lv) for lv in range(spec.n_levels)]),
        _GRID_TYPES[spec.grid_type],
        net.density_layers,
        net.rgb_layers,
        net.density_out,
        net.aabb,
        net.hdr,
        device,
    )


def bake_network_colors(grid: DensityGrid, device=None, min_density: float = 0.0) -> np.ndarray:
    """``[D,H,W,3]`` float32: the network's colour at the centre of every voxel denser than
    ``min_density``, averaged over the six axis directions (a view-independent colour for
    displays that cannot evaluate the network, e.g. a Blender volume); 0 elsewhere."""
    if not has_ngp_network(grid):
        raise ValueError("bake_network_colors: the grid carries no instant-ngp network")
    field = grid.network
    buf = upload_network(field.network, resolve_device(device))
    iz, iy, ix = np.nonzero(grid.density > min_density)
    centres = grid.aabb[0] + (np.stack([ix, iy, iz], 1) + 0.5) * grid.voxel_size
    scale, offset, axes = field.frame
    q = (centres * scale + offset)[:, list(axes)]
    acc = np.zeros((len(q), 3), np.float64)
    for d in _BAKE_DIRS:
        acc += eval_ngp_points(buf, q, np.broadcast_to(d, q.shape))[:, :3]
    out = np.zeros(grid.density.shape + (3,), np.float32)
    out[iz, iy, ix] = (acc / len(_BAKE_DIRS)).astype(np.float32)
    return out


class NgpRenderer(MarchedViews):
    """Renders an instant-ngp snapshot's network; uploaded to ``device`` once.

    Settled here: instant-ngp's step ``STEPSIZE = √3/1024`` NeRF units (cone stepping
    ``1/256`` for ``aabb_scale > 1``, as instant-ngp picks it), samples at step midpoints,
    colour only for samples of weight ≥ ``COLOR_MIN_WEIGHT`` (``kernels/raymarch_ngp.py``).
    """

    stats = {"source": "network"}

    def __init__(self, grid: DensityGrid, device=None, config: RenderConfig | None = None):
        if not has_ngp_network(grid):
            raise ValueError("NgpRenderer: the grid carries no instant-ngp network")
        self.config = config or RenderConfig()
        self.device = resolve_device(device)
        self.grid_shape = tuple(grid.density.shape)
        self.grid_aabb = np.asarray(grid.aabb, np.float64)
        field = grid.network
        self._net = upload_network(field.network, self.device)
        self._occ = upload_ngp_occupancy(field.occupancy(), self.device)
        self._frame = field.frame
        self._box = field.box
        self._n_casc = field.n_cascades
        self._step, self._cone, self._max_step = field.stepping

    def _settings(self, cam: Camera) -> NgpMarchSettings:
        c = self.config
        return NgpMarchSettings(
            step=self._step,
            cone=self._cone,
            max_step=self._max_step,
            tau_sig=c.tau_sig,
            tau_cw=c.tau_cw,
            t_min=c.t_min,
            alpha_min=c.alpha_min,
            near=cam.clip_near(c.near),
            threads=c.threads,
        )

    def _run(self, cam: Camera, values: np.ndarray | None):
        return raymarch_ngp(
            self._net,
            self._occ,
            self._frame,
            self._box,
            self._n_casc,
            cam.c2w,
            cam.fx,
            cam.fy,
            cam.cx,
            cam.cy,
            cam.width,
            cam.height,
            self._settings(cam),
            values=values,
            values_aabb=self.grid_aabb,
            background=self.config.background,
        )
