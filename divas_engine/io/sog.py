"""PlayCanvas SOG reader: ``.sog`` bundles and unbundled ``meta.json`` folders.

Defined by PlayCanvas's published SOG format description ("The SOG Format", "SOG version 2")
and the splat-transform reader; containers and layouts are in :mod:`.sog_container`. Per
Gaussian (texel ``i`` of every image): 16-bit positions with the format's log transform
inverted, "smallest three" rotations (a tag outside 252..255 drops the row), log-scales and DC
colour from codebooks (v2) or ranges (original layout), opacity ``A / 255`` (v2) or a sigmoid
of a range (original), SH bands from the ``shN`` palette. SOG stores the 3DGS PLY frame (no
axis change). ``scene.extras`` gets ``sog_version``, ``sog_bundled`` and ``splat_model``.
The decoding formulas: docs/design-notes.md.
"""

from __future__ import annotations

import zipfile
from os import PathLike
from pathlib import Path

import numpy as np

from ..errors import DivasInputError
from ..kinds import SceneKind
from ..scene import SurfelScene
from .gaussians import scene_from_rows, sigmoid, surfels_from_arrays
from .ply import CHUNK_ROWS
from .sog_container import (
    SH_COEFFS,
    SogContainer,
    SogLayout,
    open_sog,
    parse_meta,
    read_texels,
)

__all__ = ["read_sog", "is_sog_zip", "read_sog_texels", "decode_sog_rows", "sog_rows"]

#: what :func:`sog_rows` marks invalid (the dropped rows' count is reported as such).
INVALID_WHAT = "non-finite values or invalid quaternion tags"

_SQRT2 = np.float64(np.sqrt(2.0))
#: for each largest-component index, the indices the three stored values go to.
_SMALL_THREE = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]], dtype=np.int64)


def is_sog_zip(path: str | PathLike) -> bool:
    """True when the ZIP at ``path`` holds a ``meta.json`` (a bundled SOG, not an ``.npz``)."""
    try:
        with zipfile.ZipFile(path) as zf:
            return any(n == "meta.json" or n.endswith("/meta.json") for n in zf.namelist())
    except (zipfile.BadZipFile, OSError, EOFError):
        return False


def read_sog_texels(path: str | PathLike):
    """``(container, meta, layout, texels)`` of a SOG scene, every image decoded and checked."""
    cont, meta = open_sog(path)
    try:
        layout = parse_meta(meta, cont.where("meta.json"))
        layout, tex = read_texels(cont, layout)
    finally:
        cont.close()
    return cont, meta, layout, tex


def _lerp(rng: np.ndarray, b: np.ndarray, full: float) -> np.ndarray:
    return rng[0] + (rng[1] - rng[0]) * (b.astype(np.float64) / full)


def _lookup(codebook: np.ndarray, b: np.ndarray, what: str, where: str) -> np.ndarray:
    if b.size and int(b.max()) >= len(codebook):
        raise DivasInputError(
            where, f"{what} byte {int(b.max())} is past its {len(codebook)}-entry codebook"
        )
    return codebook[b]


def _positions(lo: np.ndarray, hi: np.ndarray, rng: np.ndarray) -> np.ndarray:
    v = lo[:, :3].astype(np.float64) + 256.0 * hi[:, :3]
    span = np.where(rng[1] - rng[0] == 0, 1.0, rng[1] - rng[0])
    n = rng[0] + span * (v / 65535.0)
    return np.sign(n) * np.expm1(np.abs(n))


def _rotations(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``([n,4] (w, x, y, z) float64, [n] valid tag)`` from ``quats`` texels."""
    big = q[:, 3].astype(np.int64) - 252
    ok = (big >= 0) & (big <= 3)
    big = np.where(ok, big, 0)
    small = (q[:, :3].astype(np.float64) / 255.0 * 2.0 - 1.0) / _SQRT2
    out = np.zeros((len(q), 4), np.float64)
    rows = np.arange(len(q))[:, None]
    out[rows, _SMALL_THREE[big]] = small
    out[rows[:, 0], big] = np.sqrt(np.maximum(0.0, 1.0 - (small * small).sum(1)))
    return out, ok


def _sh_rest(layout: SogLayout, labels: np.ndarray, palette: np.ndarray, where: str) -> np.ndarray:
    """``[n, coeffs, 3]`` SH coefficients 1.. of the rows' palette entries."""
    coeffs = SH_COEFFS[layout.sh_bands]
    label = labels[:, 0].astype(np.int64) + 256 * labels[:, 1].astype(np.int64)
    if label.size and int(label.max()) >= layout.sh_palette:
        raise DivasInputError(
            where, f"SH label {int(label.max())} is past the {layout.sh_palette}-entry palette"
        )
    entries = palette[..., :3].reshape(-1, coeffs, 3)  # entry e = row e // 64, slot e % 64
    b = entries[label]
    if layout.version == 2:
        return _lookup(layout.sh_values, b, "shN centroid", where)
    return _lerp(layout.sh_values, b, 255.0)


def decode_sog_rows(layout: SogLayout, tex: dict, rows: slice, where: dict) -> dict:
    """Stored-space values of Gaussians ``rows``: positions, (w,x,y,z) rotations, log-scales,
    DC, activated opacity, SH rest (or None) and the valid-tag mask, all float64."""
    t = {k: v[rows] for k, v in tex.items() if k != "shN_centroids"}
    quats, ok = _rotations(t["quats"])
    s, c = t["scales"][:, :3], t["sh0"]
    if layout.version == 2:
        log_s = _lookup(layout.scales, s, "scales", where["scales"])
        dc = _lookup(layout.sh0, c[:, :3], "sh0", where["sh0"])
        opacity = c[:, 3].astype(np.float64) / 255.0
    else:
        log_s = _lerp(layout.scales, s, 255.0)
        dc = _lerp(layout.sh0[:, :3], c[:, :3], 255.0)
        opacity = sigmoid(_lerp(layout.sh0[:, 3], c[:, 3], 255.0)).astype(np.float64)
    rest = None
    if layout.sh_bands:
        rest = _sh_rest(layout, t["shN_labels"], tex["shN_centroids"], where["shN_labels"])
    pos = _positions(t["means_l"], t["means_u"], layout.means_range)
    return {
        "means": pos,
        "quats": quats,
        "log_scales": log_s,
        "dc": dc,
        "opacity": opacity,
        "sh_rest": rest,
        "valid_tag": ok,
    }


def sog_rows(path: str | PathLike) -> tuple[SogContainer, dict, SogLayout, tuple, np.ndarray]:
    """``(container, meta, layout, (means, quats, scales, opacities, sh, scale_n), valid)``
    of every Gaussian of a SOG scene, decoded and flattened to surfels (file order)."""
    cont, meta, layout, tex = read_sog_texels(Path(path))
    n, deg = layout.count, layout.sh_bands
    where = {role: cont.where(name) for role, name in layout.files.items()}
    means = np.empty((n, 3), np.float32)
    quats = np.empty((n, 4), np.float32)
    scales = np.empty((n, 2), np.float32)
    scale_n = np.empty(n, np.float32)
    opac = np.empty(n, np.float32)
    sh = np.zeros((n, (deg + 1) ** 2, 3), np.float32)
    valid = np.empty(n, bool)
    for start in range(0, n, CHUNK_ROWS):
        sl = slice(start, min(n, start + CHUNK_ROWS))
        d = decode_sog_rows(layout, tex, sl, where)
        s3 = np.exp(d["log_scales"]).astype(np.float32)
        pos = d["means"].astype(np.float32)
        ok = d["valid_tag"] & np.isfinite(pos).all(1) & np.isfinite(s3).all(1) & (s3 > 0).all(1)
        s3 = np.where(ok[:, None], s3, np.float32(1.0))
        quats[sl], scales[sl] = surfels_from_arrays(d["quats"].astype(np.float32), s3)
        scale_n[sl] = s3.min(1)
        means[sl] = pos
        opac[sl] = d["opacity"]
        sh[sl, 0, :] = d["dc"]
        if deg:
            sh[sl, 1:, :] = d["sh_rest"]
        valid[sl] = ok
    return cont, meta, layout, (means, quats, scales, opac, sh, scale_n), valid


def read_sog(path: str | PathLike) -> SurfelScene:
    """Load a SOG scene (a ``.sog`` file, a SOG folder or its ``meta.json``).

    Raises:
        DivasInputError: missing or undecodable files, a bad ``meta.json``, an unknown
        version, image sizes that do not fit the count, bytes past a codebook or palette.
    """
    cont, meta, layout, (*arrays, scale_n), valid = sog_rows(path)
    extras = {
        "sog_version": layout.version or 1,
        "sog_bundled": cont.bundled,
        "splat_model": str(meta.get("model", "default")),
    }
    return scene_from_rows(
        cont.path,
        "sog",
        tuple(arrays),
        valid,
        layout.sh_bands,
        SceneKind.GS3D,
        extras,
        invalid_what=INVALID_WHAT,
        scale_n=scale_n,
    )
