"""torch-ngp checkpoints (``.pth``, the paper's NeRF backbone), read with the torch extra.

torch-ngp (``ashawkey/torch-ngp``, ``nerf/renderer.py`` l. 61-95, ``nerf/utils.py``
``save_checkpoint``) saves ``{"model": state_dict, "mean_density": …, …}`` with ``torch.save``;
the model's buffers hold ``density_grid`` ``[C, 128³]`` (σ per unit of its frame, −1 where no
camera sees it, Morton order: ``raymarching/src/raymarching.cu`` ``__morton3D``) and
``aabb_train`` ``[−b, −b, −b, b, b, b]``. Cascade ``c`` covers ``±min(2^c, bound)``
(``raymarching.cu`` l. 368-378, ``renderer.py`` l. 414-418); cells at or below
``min(mean_density, 0.01)`` are empty to its marcher (``renderer.py`` l. 522-527). Its frame
is its dataset loader's (``nerf/provider.py`` ``nerf_matrix_to_ngp``):
``ngp = (y·s + o₀, z·s + o₁, x·s + o₂)`` of a ``transforms.json`` point, with ``--scale``
(0.33) and ``--offset`` (0) options the checkpoint does not keep: they are arguments here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from ..errors import DivasInputError
from ..scene import DensityGrid, SourceInfo
from .limits import inflate_budget, limits, require_input_file
from .ngp_cascades import (
    CascadeLayout,
    LatticeBox,
    cascade_mask,
    dense_to_morton,
    merge_cascades,
    morton_to_dense,
)

__all__ = ["TorchNgpFrame", "read_torch_ngp", "write_masked_torch_ngp", "TorchNgpSource"]


@dataclass(frozen=True)
class TorchNgpFrame:
    """torch-ngp's ``--scale`` and ``--offset`` (its ``nerf_matrix_to_ngp``)."""

    scale: float = 0.33
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def to_world(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, np.float64) - np.asarray(self.offset)
        return q[..., [2, 0, 1]] / self.scale

    def lattice_to_density(self, lat: np.ndarray) -> np.ndarray:
        # ngp axis i holds world axis (1, 2, 0)[i]
        return np.ascontiguousarray(lat.transpose(2, 0, 1).transpose(2, 1, 0))

    def density_to_lattice(self, dens: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(dens.transpose(2, 1, 0).transpose(1, 2, 0))


@dataclass(eq=False)
class TorchNgpSource:
    checkpoint: dict
    key: str
    layout: CascadeLayout
    box: LatticeBox
    frame: TorchNgpFrame


def _torch():
    try:
        import torch
    except ImportError:
        return None
    return torch


def _load(path: Path) -> dict:
    torch = _torch()
    if torch is None:
        raise DivasInputError(
            path,
            "torch-ngp checkpoints need PyTorch: pip install -e '.[torch]' (the CPU wheel)",
        )
    import zipfile

    size = path.stat().st_size
    try:
        with zipfile.ZipFile(path) as zf:
            total = sum(i.file_size for i in zf.infolist())
    except zipfile.BadZipFile:
        raise DivasInputError(path, "not a torch.save ZIP archive") from None
    if total > inflate_budget(size):
        raise DivasInputError(path, f"declares {total} bytes, over the LoadLimits budget")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for foreign or unsafe pickles
        raise DivasInputError(
            path, f"not a readable torch checkpoint ({type(e).__name__}: {e})"
        ) from None
    if not isinstance(ckpt, dict):
        raise DivasInputError(path, "checkpoint is not a dict")
    return ckpt


def read_torch_ngp(
    path: str | PathLike, frame: TorchNgpFrame | None = None, max_side: int = 256
) -> DensityGrid:
    """A torch-ngp checkpoint's density grid on one lattice in the training frame."""
    path = require_input_file(path, "torch-ngp checkpoint")
    frame = frame or TorchNgpFrame()
    ckpt = _load(path)
    model = ckpt.get("model", ckpt)
    key = "model" if "model" in ckpt else ""
    if not isinstance(model, dict) or "density_grid" not in model:
        raise DivasInputError(path, "no 'density_grid' in the checkpoint (not a cuda_ray model)")
    grid = model["density_grid"].detach().float().cpu().numpy()
    if grid.ndim != 2 or grid.shape[0] < 1:
        raise DivasInputError(path, f"density_grid must be [C, H³], got {list(grid.shape)}")
    res = round(grid.shape[1] ** (1 / 3))
    if res**3 != grid.shape[1] or res & (res - 1) or res > 1024:
        raise DivasInputError(path, f"density_grid has {grid.shape[1]} cells, not H³")
    if grid.size > limits().max_rows:
        raise DivasInputError(path, f"{grid.size} cells, over the limit")
    aabb = model.get("aabb_train")
    bound = float(aabb.abs().max()) if aabb is not None else float(2 ** (grid.shape[0] - 1))
    if not (math.isfinite(bound) and bound > 0):
        raise DivasInputError(path, f"bad bound {bound}")
    layout = CascadeLayout(grid.shape[0], res, (0.0, 0.0, 0.0), 1.0, bound)
    dense = morton_to_dense(grid, res).astype(np.float32)
    dense[~np.isfinite(dense)] = 0
    mean = float(np.maximum(dense, 0).mean())  # renderer.py: clamp(min=0) over all cascades
    mean = float(ckpt.get("mean_density", mean)) if np.isscalar(ckpt.get("mean_density")) else mean
    occupied = dense > min(mean, 0.01)
    dense[~occupied] = 0
    lat, box = merge_cascades(dense, layout, occupied, max_side)
    if not np.any(lat > 0):
        raise DivasInputError(path, "empty scene: every density-grid cell is empty")
    density = frame.lattice_to_density(lat * np.float32(frame.scale))
    corners = np.stack([frame.to_world(box.lo), frame.to_world(box.hi)])
    out = DensityGrid(
        density,
        np.stack([corners.min(0), corners.max(0)]),
        None,
        SourceInfo(path, "torch_ngp", int(density.size), None, 0),
    )
    out.extras["torch_ngp"] = TorchNgpSource(ckpt, key, layout, box, frame)
    return out


def write_masked_torch_ngp(grid: DensityGrid, selection: np.ndarray, path: str | PathLike) -> Path:
    """The checkpoint with every positive ``density_grid`` cell that no selected voxel
    overlaps set to 0 and its ``density_bitfield`` bit cleared (``torch.save``)."""
    src = grid.extras.get("torch_ngp")
    torch = _torch()
    if not isinstance(src, TorchNgpSource) or torch is None:
        raise DivasInputError(path, "this grid was not read from a torch-ngp checkpoint")
    from ..output_paths import atomic_path

    sel = src.frame.density_to_lattice(np.asarray(selection, bool))
    keep = dense_to_morton(cascade_mask(sel, src.layout, src.box))
    ckpt = dict(src.checkpoint)
    model = dict(ckpt[src.key]) if src.key else ckpt
    dg = model["density_grid"]
    # positive cells no selected voxel overlaps become 0; unseen (−1) and 0 cells stay
    keep_t = torch.from_numpy(keep).to(dg.device) | ~(dg > 0)
    model["density_grid"] = torch.where(keep_t, dg, torch.zeros_like(dg))
    if "density_bitfield" in model:
        kept = keep_t.cpu().numpy().reshape(-1, 8)
        bits = np.packbits(kept, axis=1, bitorder="little").ravel()
        bf = model["density_bitfield"]
        model["density_bitfield"] = bf & torch.from_numpy(bits).to(bf.device)
    if src.key:
        ckpt[src.key] = model
    with atomic_path(path) as tmp:
        torch.save(ckpt, tmp)
    return Path(path)
