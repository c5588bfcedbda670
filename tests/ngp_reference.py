"""A float64 NumPy evaluation of an instant-ngp network, written from tiny-cuda-nn's
formulas (not from the kernels): the reference the Warp network kernels are checked
against, and a way to build small snapshots with known networks.

Hash grid (``tiny-cuda-nn/include/tiny-cuda-nn/common_device.h``): level scale
``2^(l·log2 b)·N_min − 1`` (float32), resolution ``⌈scale⌉ + 1``, position
``scale·x + 0.5``; corner index dense ``x + y·r + z·r²`` when ``r³`` (uint32) fits the
level, else ``x ⊕ y·2654435761 ⊕ z·805459861`` (uint32 wrap), modulo the level size.
SH: ``sh_enc`` degree 4, tiny-cuda-nn's signs.
"""

from __future__ import annotations

import numpy as np

from divas_engine.io.ngp_network import NgpNetwork

__all__ = ["reference_eval", "sh16_reference", "random_network"]


def _index(res: int, size: int, hashed: bool, c: np.ndarray) -> np.ndarray:
    c = c.astype(np.uint64)
    m32 = np.uint64(0xFFFFFFFF)
    stride = (res**3) & 0xFFFFFFFF if res <= 0x659 else 0xFFFFFFFF
    if res <= 0x659:
        idx = (c[:, 0] + c[:, 1] * np.uint64(res) + c[:, 2] * np.uint64(res * res)) & m32
    else:
        idx = np.zeros(len(c), np.uint64)
    if hashed and size < stride:
        idx = (
            (c[:, 0] * np.uint64(1))
            ^ ((c[:, 1] * np.uint64(2654435761)) & m32)
            ^ ((c[:, 2] * np.uint64(805459861)) & m32)
        ) & m32
    return (idx % np.uint64(size)).astype(np.int64)


def sh16_reference(d: np.ndarray) -> np.ndarray:
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    s = np.sqrt
    pi = np.pi
    return np.stack(
        [
            np.full_like(x, 1 / (2 * s(pi))),
            -s(3) * y / (2 * s(pi)),
            s(3) * z / (2 * s(pi)),
            -s(3) * x / (2 * s(pi)),
            s(15) * x * y / (2 * s(pi)),
            -s(15) * y * z / (2 * s(pi)),
            s(5) * (3 * z * z - 1) / (4 * s(pi)),
            -s(15) * x * z / (2 * s(pi)),
            s(15) * (x * x - y * y) / (4 * s(pi)),
            s(70) * y * (-3 * x * x + y * y) / (8 * s(pi)),
            s(105) * x * y * z / (2 * s(pi)),
            s(42) * y * (1 - 5 * z * z) / (8 * s(pi)),
            s(7) * z * (5 * z * z - 3) / (4 * s(pi)),
            s(42) * x * (1 - 5 * z * z) / (8 * s(pi)),
            s(105) * z * (x * x - y * y) / (4 * s(pi)),
            s(70) * x * (-x * x + 3 * y * y) / (8 * s(pi)),
        ],
        1,
    )


def reference_eval(net: NgpNetwork, points: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """``[N, 4]``: RGB after the activation and raw log density (float64)."""
    p = np.asarray(points, np.float64)
    g = net.grid
    u = (p - net.aabb[0]) / (net.aabb[1] - net.aabb[0])
    feats = np.zeros((len(p), net.pos_width))
    for lv in range(g.n_levels):
        scale = np.float64(g.level_scale(lv))
        res = g.level_resolution(lv)
        size = g.offsets[lv + 1] - g.offsets[lv]
        q = (scale * u.astype(np.float32).astype(np.float64) + 0.5).astype(np.float32)
        q = q.astype(np.float64)
        base = np.floor(q)
        w = q - base
        base = base.astype(np.int64)
        for c in range(8):
            bits = np.array([(c >> k) & 1 for k in range(3)])
            wc = np.prod(np.where(bits, w, 1 - w), axis=1)
            e = g.offsets[lv] + _index(res, size, g.grid_type == "Hash", base + bits)
            sl = slice(lv * g.n_features, (lv + 1) * g.n_features)
            feats[:, sl] += wc[:, None] * net.table[e].astype(np.float64)
    x = feats
    for i, m in enumerate(net.density_layers):
        x = x @ m.astype(np.float64).T
        if i < len(net.density_layers) - 1:
            x = np.maximum(x, 0)
    dens = x
    d = np.asarray(dirs, np.float64)
    x = np.concatenate([dens, sh16_reference(d)], 1)
    for i, m in enumerate(net.rgb_layers):
        x = x @ m.astype(np.float64).T
        if i < len(net.rgb_layers) - 1:
            x = np.maximum(x, 0)
    rgb = np.exp(np.clip(x[:, :3], -10, 10)) if net.hdr else 1 / (1 + np.exp(-x[:, :3]))
    return np.concatenate([rgb, dens[:, :1]], 1)


def random_network(config: dict, aabb_scale: int = 1, seed: int = 0, scale: float = 0.5):
    """A network of ``config`` with random parameters (float16-representable)."""
    from divas_engine.io.ngp_network import network_from_snapshot

    probe = network_from_snapshot.__globals__["_layouts"](config, aabb_scale, 0)
    grid, dens, rgb = probe[0], probe[1], probe[2]
    n = sum(a * b for a, b in dens) + sum(a * b for a, b in rgb)
    n += grid.offsets[-1] * grid.n_features
    rng = np.random.default_rng(seed)
    params = (rng.standard_normal(n) * scale).astype(np.float16)
    half = 0.5 * aabb_scale
    aabb = np.array([[0.5 - half] * 3, [0.5 + half] * 3])
    return network_from_snapshot(config, params, aabb, aabb_scale, 0, False), params
