"""Write a row subset of a SOG scene back as SOG, in the source's own layout.

Rule: the kept Gaussians decode bit-identically. Nothing is re-quantised: the source's
``meta.json`` is kept and each kept Gaussian's texels are copied, in source order, to texels
``0..n-1`` of new images; only the count, the image size (splat-transform's rule), the SH
palette (cut to the used entries, labels renumbered), the file names and the alpha of
alpha-free images change. Bounds stay the source's (not tight) and the order is a subsequence
of the source's Morton order. libwebp may rewrite RGB under alpha 0, so only a zero-opacity
Gaussian's colour may change; every image is decoded again and compared. Outputs are atomic
(a ``.sog`` via a temporary file, a folder swapped in); the output may not be the input.
Details: docs/design-notes.md.
"""

from __future__ import annotations

import copy
import io
import json
import math
import os
import shutil
import tempfile
import uuid
import zipfile
from os import PathLike
from pathlib import Path

import cv2
import numpy as np

from ..errors import DivasInputError
from ..output_paths import dir_mode, write_bytes_atomic
from ..scene import SourceInfo
from .gaussians import check_file_rows
from .sog import read_sog_texels
from .sog_container import PER_GAUSSIAN, SH_COEFFS, decode_rgba

__all__ = [
    "write_sog_subset",
    "sog_subset_files",
    "sog_texture_size",
    "encode_webp_lossless",
    "write_folder_atomic",
]

#: roles whose alpha channel holds data (quats: the largest-component tag, sh0: opacity).
_ALPHA_ROLES = ("quats", "sh0")
_ATTR_FILES = {
    "means": ("means_l", "means_u"),
    "quats": ("quats",),
    "scales": ("scales",),
    "sh0": ("sh0",),
    "shN": ("shN_centroids", "shN_labels"),
}


def sog_texture_size(n: int) -> tuple[int, int]:
    """``(W, H)`` of the per-Gaussian images for ``n`` Gaussians, as splat-transform sizes them."""
    w = math.ceil(math.sqrt(n) / 4) * 4
    return w, math.ceil(n / w / 4) * 4


def encode_webp_lossless(rgba: np.ndarray, what: str) -> bytes:
    """Lossless WebP bytes of ``[H,W,4]`` RGBA (OpenCV, quality > 100), checked by decoding:
    alpha everywhere and RGB wherever alpha > 0 must come back unchanged.

    Raises:
        RuntimeError: OpenCV cannot encode WebP, or the decoded pixels differ.
    """
    ok, buf = cv2.imencode(".webp", rgba[..., [2, 1, 0, 3]], [cv2.IMWRITE_WEBP_QUALITY, 101])
    data = buf.tobytes() if ok else b""
    back = decode_rgba(data, what, rgba.shape[1::-1]) if ok else None
    seen = rgba[..., 3] > 0
    if back is None or not (
        np.array_equal(back[..., 3], rgba[..., 3]) and np.array_equal(back[seen], rgba[seen])
    ):
        raise RuntimeError(f"{what}: OpenCV's WebP encoder did not store the texels losslessly")
    return data


def _output_target(out: Path, source_bundled: bool) -> tuple[bool, Path]:
    """``(bundled, target)``: ``.sog`` → bundle; ``meta.json`` or a folder → unbundled."""
    if out.suffix.lower() == ".sog":
        return True, out
    if out.name.lower() == "meta.json":
        return False, out.parent
    if out.is_dir():
        return False, out
    return source_bundled, out


def _check_target(bundled: bool, target: Path, source: Path, source_bundled: bool) -> None:
    src = source.resolve() if source_bundled else source.parent.resolve()
    if target.resolve() == src:
        raise DivasInputError(target, "refusing to overwrite the input scene with the export")
    if bundled:
        if target.is_dir():
            raise DivasInputError(target, "is a folder; a bundled SOG export needs a file path")
        return
    if target.exists() and not target.is_dir():
        raise DivasInputError(target, "exists and is not a folder (unbundled SOG export)")
    if target.is_dir():
        foreign = [
            p.name
            for p in target.iterdir()
            if not (
                p.is_file() and (p.name == "meta.json" or p.suffix.lower() in (".webp", ".png"))
            )
        ]
        if foreign:
            raise DivasInputError(
                target,
                "refusing to replace a folder that holds more than a SOG scene "
                f"({', '.join(sorted(foreign)[:3])})",
            )


def _gaussian_images(tex: dict, rows: np.ndarray, size: tuple[int, int]) -> dict[str, np.ndarray]:
    w, h = size
    out = {}
    for role in PER_GAUSSIAN:
        if role not in tex:
            continue
        img = np.zeros((w * h, 4), np.uint8)
        img[: len(rows)] = tex[role][rows]
        if role not in _ALPHA_ROLES:
            img[: len(rows), 3] = 255
        out[role] = img.reshape(h, w, 4)
    return out


def _cut_palette(
    layout, labels_img: np.ndarray, palette: np.ndarray, n: int
) -> tuple[np.ndarray, int]:
    """Keep the palette entries the first ``n`` labels use; relabel ``labels_img`` in place."""
    coeffs = SH_COEFFS[layout.sh_bands]
    flat = labels_img.reshape(-1, 4)
    label = flat[:n, 0].astype(np.int64) + 256 * flat[:n, 1].astype(np.int64)
    used, new = np.unique(label, return_inverse=True)
    flat[:n, 0], flat[:n, 1], flat[:n, 2] = new & 255, new >> 8, 0
    k = len(used)
    rows = math.ceil(k / 64)
    entries = np.zeros((rows * 64, coeffs, 4), np.uint8)
    entries[:k] = palette.reshape(-1, coeffs, 4)[used]
    entries[:k, :, 3] = 255
    return entries.reshape(rows, 64 * coeffs, 4), k


def _meta_for(meta: dict, layout, n: int, palette_count: int | None) -> dict:
    out = copy.deepcopy(meta)
    for attr, roles in _ATTR_FILES.items():
        if attr in out and all(r in layout.files for r in roles):
            out[attr]["files"] = [f"{r}.webp" for r in roles]
    if layout.sh_bands == 0:
        out.pop("shN", None)
    if layout.version == 2:
        was = out.get("asset", {}).get("generator") if isinstance(out.get("asset"), dict) else None
        out["asset"] = {"generator": "DivAS subset export" + (f" of {was}" if was else "")}
        out["count"] = n
        if palette_count is not None:
            out["shN"]["count"] = palette_count
    else:
        for attr in _ATTR_FILES:
            shape = out.get(attr, {}).get("shape")
            if isinstance(shape, list) and shape:
                shape[0] = n
    return out


def write_folder_atomic(target: Path, files: dict[str, bytes]) -> None:
    """Write ``files`` (names relative to ``target``, ``/`` for sub-folders) as the folder
    ``target``: built beside it, then swapped in; a failure leaves the old folder."""
    try:
        _swap_folder(target, files)
    except OSError as e:  # one clear error; the previous folder is back in place
        raise DivasInputError(target, f"cannot write the output: {e.strerror or e}") from None


def _swap_folder(target: Path, files: dict[str, bytes]) -> None:
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    old = None
    try:
        tmp.chmod(dir_mode())
        for name, data in files.items():
            f = tmp / name
            if f.parent != tmp:
                f.parent.mkdir(parents=True, exist_ok=True, mode=dir_mode())
            f.write_bytes(data)
        if target.exists():
            old = target.with_name(f".{target.name}.old-{uuid.uuid4().hex[:8]}")
            os.replace(target, old)
        try:
            os.replace(tmp, target)
        except BaseException:
            if old is not None:
                os.replace(old, target)
                old = None
            raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def write_sog_subset(source: SourceInfo, file_rows: np.ndarray, out_path: str | PathLike) -> Path:
    """Write Gaussians ``file_rows`` (in that order) of the SOG ``source`` to ``out_path``.

    ``out_path`` ending in ``.sog`` gives a bundle; ``…/meta.json`` or an existing
    folder gives an unbundled folder; any other path the source's own layout.

    Returns:
        the written ``.sog`` file, or the ``meta.json`` of the written folder.

    Raises:
        DivasInputError: the output is the input, or a folder holding other files; the
        source is unreadable or changed since it was loaded.
    """
    out = Path(out_path)
    cont, meta, layout, tex = read_sog_texels(source.path)
    if layout.count != source.num_rows:
        raise DivasInputError(
            cont.path, f"holds {layout.count} Gaussians, {source.num_rows} when it was loaded"
        )
    rows = check_file_rows(cont.path, file_rows, layout.count)
    if rows.size == 0:
        raise ValueError("nothing to write: file_rows is empty")
    bundled, target = _output_target(out, cont.bundled)
    _check_target(bundled, target, cont.path, cont.bundled)
    files = sog_subset_files(meta, layout, tex, rows, str(target))
    target.parent.mkdir(parents=True, exist_ok=True)
    if bundled:
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as zf:
            for name, data in files.items():
                zf.writestr(name, data)
        write_bytes_atomic(target, buf.getvalue())
        return target
    write_folder_atomic(target, files)
    return target / "meta.json"


def sog_subset_files(
    meta: dict, layout, tex: dict, rows: np.ndarray, what: str
) -> dict[str, bytes]:
    """The files (``meta.json`` and the WebP images) of SOG Gaussians ``rows`` (module
    docstring); ``what`` names the output in errors."""
    images = _gaussian_images(tex, rows, sog_texture_size(len(rows)))
    palette_count = None
    if layout.sh_bands:
        images["shN_centroids"], palette_count = _cut_palette(
            layout, images["shN_labels"], tex["shN_centroids"], len(rows)
        )
    files = {"meta.json": json.dumps(_meta_for(meta, layout, len(rows), palette_count)).encode()}
    for role, img in images.items():
        files[f"{role}.webp"] = encode_webp_lossless(img, f"{what}: {role}.webp")
    return files
