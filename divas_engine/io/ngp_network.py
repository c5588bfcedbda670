"""The radiance network of an instant-ngp snapshot, unpacked from ``params_binary``.

instant-ngp's ``NerfNetwork`` (``include/neural-graphics-primitives/nerf_network.h``): a
tiny-cuda-nn multiresolution ``HashGrid`` position encoding, a density MLP whose first output
is the log density, a degree-4 ``SphericalHarmonics`` direction encoding and an RGB MLP fed
``[density MLP outputs, direction encoding]``. Its parameters are one flat array in
``NerfNetwork::set_params_impl`` order (l. 357-372): density MLP, RGB MLP, position encoding,
direction encoding. MLPs are bias-free, one row-major ``[out, in]`` matrix per layer, ReLU
between layers, widths padded to 16; σ = exp(raw density), colour = logistic(raw rgb) (exp
for HDR). tiny-cuda-nn's layouts (MLP, grid encoding, SH) and instant-ngp's input warps, with
their upstream files and lines: docs/design-notes.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "HashGridSpec",
    "NgpNetwork",
    "NetworkLayoutError",
    "network_from_snapshot",
    "pack_params",
    "grid_level_sizes",
    "SH_DEGREE",
    "describe",
]

#: tiny-cuda-nn's ``degree`` (number of SH bands) the readers support.
SH_DEGREE = 4
_ALIGN = 16  # FullyFusedMLP / CutlassMLP REQUIRED_ALIGNMENT


class NetworkLayoutError(ValueError):
    """The snapshot's network is not one this reader can evaluate (why in the message)."""


def _next_multiple(v: int, m: int) -> int:
    return (int(v) + m - 1) // m * m


@dataclass(frozen=True)
class HashGridSpec:
    """tiny-cuda-nn grid encoding: ``n_levels`` levels of ``n_features`` features.

    ``grid_type``: ``Hash``, ``Dense`` or ``Tiled``; ``offsets``: ``[n_levels + 1]``
    first entry of each level (entries, not features).
    """

    n_levels: int
    n_features: int
    log2_hashmap_size: int
    base_resolution: int
    per_level_scale: float
    grid_type: str
    offsets: tuple[int, ...]

    def level_scale(self, level: int) -> np.float32:
        """``grid_scale`` in float32, as tiny-cuda-nn computes it."""
        l2 = np.float32(math.log2(self.per_level_scale))
        return np.float32(np.exp2(np.float32(level) * l2) * np.float32(self.base_resolution)) - (
            np.float32(1.0)
        )

    def level_resolution(self, level: int) -> int:
        return int(math.ceil(float(self.level_scale(level)))) + 1


def grid_level_sizes(spec_wo_offsets: dict) -> list[int]:
    """Entries per level for ``n_levels, log2_hashmap_size, base_resolution,
    per_level_scale, grid_type`` (``grid.h`` l. 699-722)."""
    s = HashGridSpec(
        spec_wo_offsets["n_levels"],
        1,
        spec_wo_offsets["log2_hashmap_size"],
        spec_wo_offsets["base_resolution"],
        spec_wo_offsets["per_level_scale"],
        spec_wo_offsets["grid_type"],
        (),
    )
    sizes = []
    max_params = np.iinfo(np.uint32).max // 2
    for lv in range(s.n_levels):
        res = s.level_resolution(lv)
        n = max_params if float(res) ** 3 > max_params else res**3
        n = _next_multiple(n, 8)
        if s.grid_type == "Tiled":
            n = min(n, s.base_resolution**3)
        elif s.grid_type == "Hash":
            n = min(n, 1 << s.log2_hashmap_size)
        sizes.append(int(n))
    return sizes


@dataclass(eq=False)
class NgpNetwork:
    """An instant-ngp radiance network, float32, ready to evaluate.

    Attributes:
        grid: the position encoding; table: ``[entries, F]`` its features.
        density_layers / rgb_layers: row-major ``[out, in]`` weight matrices.
        density_out: padded width of the density MLP output (the RGB MLP reads all of it).
        rgb_in: padded input width of the RGB MLP (``density_out + 16`` SH).
        aabb: ``[2,3]`` the box positions are warped from (instant-ngp's NeRF frame).
        hdr: colour through exp instead of the logistic.
    """

    grid: HashGridSpec
    table: np.ndarray
    density_layers: list[np.ndarray]
    rgb_layers: list[np.ndarray]
    density_out: int
    rgb_in: int
    aabb: np.ndarray
    hdr: bool = False

    @property
    def pos_width(self) -> int:
        """Padded width of the encoding output (the density MLP's input)."""
        return int(self.density_layers[0].shape[1])


def _mlp_shapes(cfg: dict, n_in: int, n_out: int, what: str) -> list[tuple[int, int]]:
    otype = str(cfg.get("otype", "FullyFusedMLP"))
    if otype.lower() not in ("fullyfusedmlp", "cutlassmlp", "megakernelmlp"):
        raise NetworkLayoutError(f"{what}: MLP type {otype!r} is not supported")
    if str(cfg.get("activation", "ReLU")).lower() != "relu":
        raise NetworkLayoutError(f"{what}: activation {cfg.get('activation')!r} is not ReLU")
    if str(cfg.get("output_activation", "None")).lower() != "none":
        raise NetworkLayoutError(f"{what}: output activation {cfg.get('output_activation')!r}")
    width = int(cfg.get("n_neurons", 128))
    hidden = int(cfg.get("n_hidden_layers", 5))
    if not (1 <= width <= 256) or not (0 <= hidden <= 16):
        raise NetworkLayoutError(f"{what}: {width} neurons × {hidden} hidden layers")
    out_p = _next_multiple(n_out, _ALIGN)
    if hidden == 0:
        return [(out_p, n_in)]
    return [(width, n_in)] + [(width, width)] * (hidden - 1) + [(out_p, width)]


def _grid_spec(enc: dict, aabb_scale: int) -> HashGridSpec:
    otype = str(enc.get("otype", ""))
    kinds = {"hashgrid": "Hash", "grid": None, "densegrid": "Dense", "tiledgrid": "Tiled"}
    if otype.lower() not in kinds:
        raise NetworkLayoutError(f"position encoding {otype!r} is not a grid encoding")
    gtype = str(enc.get("type", kinds[otype.lower()] or "Hash"))
    if gtype not in ("Hash", "Dense", "Tiled"):
        raise NetworkLayoutError(f"grid type {gtype!r}")
    if str(enc.get("interpolation", "Linear")) != "Linear":
        raise NetworkLayoutError(f"grid interpolation {enc.get('interpolation')!r}")
    if str(enc.get("hash", "CoherentPrime")) != "CoherentPrime":
        raise NetworkLayoutError(f"grid hash {enc.get('hash')!r}")
    f = int(enc.get("n_features_per_level", 2))
    if f not in (1, 2, 4, 8):
        raise NetworkLayoutError(f"{f} features per level")
    n_levels = int(enc["n_features"]) // f if "n_features" in enc else int(enc.get("n_levels", 16))
    log2_t = int(enc.get("log2_hashmap_size", 19))
    # testbed.cu reset_network: base resolution and per-level scale when not given
    base = int(enc.get("base_resolution", 0)) or (1 << (log2_t // 3))
    pls = float(enc.get("per_level_scale", 0.0))
    if pls <= 0.0:
        pls = (
            math.exp(math.log(2048.0 * aabb_scale / base) / (n_levels - 1)) if n_levels > 1 else 2.0
        )
    if not (1 <= n_levels <= 32 and 1 <= log2_t <= 28 and 1 <= base <= 4096 and pls > 0):
        raise NetworkLayoutError(f"grid of {n_levels} levels, 2^{log2_t} entries, base {base}")
    d = dict(
        n_levels=n_levels,
        log2_hashmap_size=log2_t,
        base_resolution=base,
        per_level_scale=pls,
        grid_type=gtype,
    )
    sizes = grid_level_sizes(d)
    offsets = tuple(int(v) for v in np.concatenate([[0], np.cumsum(sizes)]))
    return HashGridSpec(n_levels, f, log2_t, base, pls, gtype, offsets)


def _dir_width(enc: dict, n_extra_dims: int) -> int:
    otype = str(enc.get("otype", ""))
    if otype == "Composite":
        nested = enc.get("nested") or []
        sh = [n for n in nested if str(n.get("otype")) == "SphericalHarmonics"]
        other = [n for n in nested if str(n.get("otype")) not in ("SphericalHarmonics",)]
        if len(sh) != 1 or any(str(n.get("otype")) != "Identity" for n in other):
            raise NetworkLayoutError("direction encoding: Composite other than SH + Identity")
        if n_extra_dims:
            raise NetworkLayoutError(f"{n_extra_dims} extra (latent) dimensions")
        enc = sh[0]
    elif otype != "SphericalHarmonics":
        raise NetworkLayoutError(f"direction encoding {otype!r}")
    if int(enc.get("degree", 4)) != SH_DEGREE:
        raise NetworkLayoutError(f"SH degree {enc.get('degree')} (only {SH_DEGREE} is read)")
    return SH_DEGREE**2


def _layouts(doc: dict, aabb_scale: int, n_extra_dims: int):
    grid = _grid_spec(doc.get("encoding") or {}, aabb_scale)
    dens_cfg, rgb_cfg = doc.get("network") or {}, doc.get("rgb_network") or {}
    pos_w = _next_multiple(grid.n_levels * grid.n_features, _ALIGN)
    n_dens_out = int(dens_cfg.get("n_output_dims", 16))
    dens = _mlp_shapes(dens_cfg, pos_w, n_dens_out, "density network")
    dens_out_p = dens[-1][0]
    dir_w = _dir_width(doc.get("dir_encoding") or {}, n_extra_dims)
    rgb_in = _next_multiple(dens_out_p + dir_w, _ALIGN)
    if rgb_in != dens_out_p + dir_w:
        raise NetworkLayoutError("RGB input padding other than none")
    rgb = _mlp_shapes(rgb_cfg, rgb_in, 3, "RGB network")
    return grid, dens, rgb, dens_out_p, rgb_in


def network_from_snapshot(
    doc: dict, params: np.ndarray, aabb: np.ndarray, aabb_scale: int, n_extra_dims: int, hdr: bool
) -> NgpNetwork:
    """Unpack ``params`` (the float16/float32 ``params_binary``) by ``doc``'s config.

    Raises :class:`NetworkLayoutError` when the config is not a layout this module reads
    (docs/design-notes.md) or the parameter count does not match it.
    """
    grid, dens, rgb, dens_out_p, rgb_in = _layouts(doc, aabb_scale, n_extra_dims)
    n_grid = grid.offsets[-1] * grid.n_features
    want = sum(a * b for a, b in dens) + sum(a * b for a, b in rgb) + n_grid
    if params.size != want:
        raise NetworkLayoutError(
            f"params_binary holds {params.size} parameters, the config needs {want}"
        )
    p = np.asarray(params, np.float32)
    off, mats = 0, []
    for shp in dens + rgb:
        n = shp[0] * shp[1]
        mats.append(np.ascontiguousarray(p[off : off + n].reshape(shp)))
        off += n
    table = np.ascontiguousarray(p[off : off + n_grid].reshape(-1, grid.n_features))
    return NgpNetwork(
        grid,
        table,
        mats[: len(dens)],
        mats[len(dens) :],
        dens_out_p,
        rgb_in,
        np.asarray(aabb, np.float64).reshape(2, 3),
        bool(hdr),
    )


def pack_params(net: NgpNetwork) -> np.ndarray:
    """The flat parameter array of ``net`` in ``NerfNetwork`` order (float32)."""
    parts = [m.ravel() for m in net.density_layers + net.rgb_layers] + [net.table.ravel()]
    return np.concatenate(parts).astype(np.float32)


def describe(net: NgpNetwork | None) -> dict[str, Any]:
    """A short summary for ``divas info``."""
    if net is None:
        return {}
    g = net.grid
    return {
        "encoding": f"{g.grid_type} grid {g.n_levels}×{g.n_features}, 2^{g.log2_hashmap_size}",
        "density_mlp": [list(m.shape) for m in net.density_layers],
        "rgb_mlp": [list(m.shape) for m in net.rgb_layers],
    }
