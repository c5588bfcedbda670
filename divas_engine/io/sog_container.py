"""PlayCanvas SOG containers: find ``meta.json`` and its textures, check them, decode them.

A SOG scene ("spatially ordered Gaussians") is a ``meta.json`` plus 8-bit images (lossless WebP
by default), *unbundled* (a folder) or *bundled* (``scene.sog``, a ZIP with the same files at
its root). Every per-Gaussian image is ``W x H``; Gaussian ``i`` is texel ``(i % W, i // W)``;
``count <= W*H``. ``shN_centroids`` is the SH palette, 64 entries per row, ``coeffs`` texels
each.

Two ``meta.json`` layouts (:class:`SogLayout` keeps what decoding needs): the **original**
(no ``version``: per-attribute ``shape``, ``mins``/``maxs`` ranges, SH band count from the
palette width) and **version 2** (``count``, ``means.mins/maxs``, 256-entry codebooks for
``scales``, ``sh0``, ``shN``, and ``shN.count`` / ``shN.bands``).

Memory is bounded by the declared count: image sizes are read from the headers and checked
against it before any pixel is decoded.
"""

from __future__ import annotations

import json
import math
import struct
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import cv2
import numpy as np

from ..errors import DivasInputError
from .limits import inflate_budget, limits

__all__ = [
    "SogContainer",
    "SogLayout",
    "open_sog",
    "parse_meta",
    "image_size",
    "decode_rgba",
    "read_texels",
    "PER_GAUSSIAN",
    "SH_COEFFS",
]

#: texture roles stored one texel per Gaussian, in meta order.
PER_GAUSSIAN = ("means_l", "means_u", "quats", "scales", "sh0", "shN_labels")
#: SH coefficients per colour channel beyond DC for 1, 2, 3 bands.
SH_COEFFS = {1: 3, 2: 8, 3: 15}
_MAX_META_BYTES = 64 << 20
_MAX_PALETTE = 1 << 16  # labels are 16-bit


@dataclass
class SogContainer:
    """Where a SOG scene's files live.

    Attributes:
        path: the scene as it is named for errors and exports: the ``.sog`` file
            (bundled) or the ``meta.json`` path (unbundled).
        bundled: True for a ``.sog`` ZIP.
        base: the folder of ``meta.json`` (unbundled) or its directory inside the ZIP.
    """

    path: Path
    bundled: bool
    base: str
    _zip: zipfile.ZipFile | None = field(default=None, repr=False)

    def where(self, name: str) -> str:
        """How a member is named in errors: ``folder/name`` or ``scene.sog:name``."""
        if self.bundled:
            return f"{self.path}:{self.base}{name}"
        return str(self.path.parent / name)

    def read(self, name: str, max_bytes: int) -> bytes:
        """The bytes of member ``name`` (relative to ``meta.json``), at most ``max_bytes``."""
        where = self.where(name)
        p = PurePosixPath(name)
        if not name or p.is_absolute() or ".." in p.parts or "\\" in name:
            raise DivasInputError(self.path, f"bad meta.json: file name {name!r} leaves the scene")
        try:
            if self._zip is not None:
                try:
                    info = self._zip.getinfo(self.base + name)
                except KeyError:
                    raise DivasInputError(where, "missing: meta.json names it") from None
                if info.file_size > max_bytes:
                    raise DivasInputError(
                        where, f"{info.file_size} bytes, more than the {max_bytes} this scene needs"
                    )
                return self._zip.read(info)
            f = self.path.parent / name
            if not f.is_file():
                raise DivasInputError(where, "missing: meta.json names it")
            size = f.stat().st_size
            if size > max_bytes:
                raise DivasInputError(
                    where, f"{size} bytes, more than the {max_bytes} this scene needs"
                )
            return f.read_bytes()
        except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError) as e:
            raise DivasInputError(where, f"corrupt ZIP member ({e})") from None
        except OSError as e:
            raise DivasInputError(where, f"cannot read ({e})") from None

    def close(self) -> None:
        if self._zip is not None:
            self._zip.close()


def open_sog(path: str | Path) -> tuple[SogContainer, dict]:
    """Open a ``.sog`` file, a SOG folder or its ``meta.json``; return it and the parsed meta.

    Raises:
        DivasInputError: nothing SOG-like there, a corrupt ZIP, or a meta.json that is
        not a JSON object.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "meta.json"
        if not path.is_file():
            raise DivasInputError(path.parent, "not a SOG folder: no meta.json in it")
    if not path.is_file():
        raise DivasInputError(path, "file does not exist")
    if path.name.lower().endswith(".json"):
        cont = SogContainer(path, False, "")
        raw = cont.read(path.name, _MAX_META_BYTES)
    else:
        cont = _open_zip(path)
        raw = cont.read("meta.json", _MAX_META_BYTES)
    try:
        meta = json.loads(raw)
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        cont.close()
        raise DivasInputError(cont.where("meta.json"), f"bad meta.json: not JSON ({e})") from None
    if not isinstance(meta, dict):
        cont.close()
        raise DivasInputError(cont.where("meta.json"), "bad meta.json: not a JSON object")
    return cont, meta


def _open_zip(path: Path) -> SogContainer:
    try:
        zf = zipfile.ZipFile(path)
        names = zf.namelist()
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        raise DivasInputError(path, f"not a readable .sog (ZIP) file ({e})") from None
    metas = [n for n in names if n == "meta.json" or n.endswith("/meta.json")]
    if "meta.json" in metas:
        base = ""
    elif len(metas) == 1:  # tolerated: the files one folder deep
        base = metas[0][: -len("meta.json")]
    else:
        zf.close()
        what = "no meta.json" if not metas else f"{len(metas)} meta.json files and none at the root"
        raise DivasInputError(path, f"not a SOG bundle: {what} in the ZIP")
    return SogContainer(path, True, base, zf)


@dataclass(frozen=True)
class SogLayout:
    """What decoding needs from ``meta.json``, checked.

    Attributes:
        version: None for the original layout, else 2.
        count: Gaussians in the scene.
        files: texture role (``means_l`` … ``shN_labels``) → file name.
        means_range: ``[2,3]`` mins/maxs of the log-transformed positions.
        scales: ``[256]`` codebook (v2) or ``[2,3]`` mins/maxs of log-scales (original).
        sh0: ``[256]`` codebook (v2) or ``[2,4]`` mins/maxs of DC and opacity logit.
        sh_bands: 0..3.
        sh_palette: palette entries a label may name: v2 ``shN.count`` (after
            :func:`read_texels`: at most what the palette image holds); original: the image's.
        sh_values: ``[256]`` codebook (v2) or ``[2]`` scalar mins/maxs (original).
    """

    version: int | None
    count: int
    files: dict[str, str]
    means_range: np.ndarray
    scales: np.ndarray
    sh0: np.ndarray
    sh_bands: int = 0
    sh_palette: int = 0
    sh_values: np.ndarray | None = None


def _get(obj: dict, key: str, where: str, kind=dict):
    v = obj.get(key) if isinstance(obj, dict) else None
    if not isinstance(v, kind) or isinstance(v, bool):
        raise DivasInputError(where, f"bad meta.json: {key!r} missing or not a {kind.__name__}")
    return v


def _numbers(v, n: int | None, what: str, where: str) -> np.ndarray:
    ok = isinstance(v, list) and all(
        isinstance(x, int | float) and not isinstance(x, bool) for x in v
    )
    a = np.asarray(v, dtype=np.float64) if ok else None
    if a is None or a.ndim != 1 or (n is not None and len(a) != n) or not len(a):
        need = f"{n} numbers" if n is not None else "a list of numbers"
        raise DivasInputError(where, f"bad meta.json: {what} must be {need}")
    if not np.isfinite(a).all():
        raise DivasInputError(where, f"bad meta.json: {what} holds NaN/Inf")
    return a


def _files(attr: dict, key: str, roles: tuple[str, ...], where: str) -> dict[str, str]:
    names = attr.get("files")
    if not (
        isinstance(names, list)
        and len(names) >= len(roles)
        and all(isinstance(s, str) for s in names)
    ):
        raise DivasInputError(where, f"bad meta.json: {key}.files must list {len(roles)} file(s)")
    return dict(zip(roles, names))


def _range(attr: dict, key: str, n: int, where: str) -> np.ndarray:
    return np.stack(
        [_numbers(attr.get(k), n, f"{key}.{k}", where) for k in ("mins", "maxs")]
    ).astype(np.float64)


def parse_meta(meta: dict, where: str) -> SogLayout:
    """Check ``meta`` against the SOG definition (either layout) and return its layout.

    ``shN`` of the original layout gets its band count later, from the palette width.
    """
    version = meta.get("version")
    if version is not None and (version != 2 or isinstance(version, bool)):
        raise DivasInputError(
            where,
            f"unsupported SOG version {version!r} (readable: the original layout "
            "without 'version', and version 2)",
        )
    attrs = {k: _get(meta, k, where) for k in ("means", "quats", "scales", "sh0")}
    files = _files(attrs["means"], "means", ("means_l", "means_u"), where)
    for key in ("quats", "scales", "sh0"):
        files.update(_files(attrs[key], key, (key,), where))
    means_range = _range(attrs["means"], "means", 3, where)
    shn = meta.get("shN")
    if shn is not None and not isinstance(shn, dict):
        raise DivasInputError(where, "bad meta.json: 'shN' is not an object")
    if shn is not None:
        files.update(_files(shn, "shN", ("shN_centroids", "shN_labels"), where))
    if version == 2:
        count = _get(meta, "count", where, int)
        scales = _numbers(attrs["scales"].get("codebook"), None, "scales.codebook", where)
        sh0 = _numbers(attrs["sh0"].get("codebook"), None, "sh0.codebook", where)
        bands = palette = 0
        values = None
        if shn is not None:
            bands = _get(shn, "bands", where, int)
            palette = _get(shn, "count", where, int)
            values = _numbers(shn.get("codebook"), None, "shN.codebook", where)
            if bands not in (0, *SH_COEFFS):
                raise DivasInputError(where, f"bad meta.json: shN.bands = {bands}, expected 0..3")
            if not 0 < palette <= _MAX_PALETTE:
                raise DivasInputError(
                    where, f"bad meta.json: shN.count = {palette}, expected 1..{_MAX_PALETTE}"
                )
        for name, cb in (("scales", scales), ("sh0", sh0), ("shN", values)):
            if cb is not None and len(cb) > 256:
                raise DivasInputError(where, f"bad meta.json: {name}.codebook has {len(cb)} > 256")
        if not bands:
            files = {k: v for k, v in files.items() if not k.startswith("shN")}
    else:
        count = _original_count(attrs, shn, where)
        scales = _range(attrs["scales"], "scales", 3, where)
        sh0 = _range(attrs["sh0"], "sh0", 4, where)
        bands = palette = 0  # set from the palette image (read_texels)
        values = None
        if shn is not None:
            values = np.array(
                [_numbers([shn.get(k)], 1, f"shN.{k}", where)[0] for k in ("mins", "maxs")]
            )
    if count <= 0:
        raise DivasInputError(where, f"empty scene: meta.json declares {count} Gaussians")
    if count > limits().max_rows:
        raise DivasInputError(
            where, f"meta.json declares {count} Gaussians, over the {limits().max_rows} limit"
        )
    return SogLayout(version, count, files, means_range, scales, sh0, bands, palette, values)


def _original_count(attrs: dict, shn: dict | None, where: str) -> int:
    shape = attrs["means"].get("shape")
    if not (isinstance(shape, list) and shape and isinstance(shape[0], int)):
        raise DivasInputError(where, "bad meta.json: means.shape must start with the count")
    count = shape[0]
    for key, attr in (*attrs.items(), ("shN", shn or {})):
        s = attr.get("shape")
        if isinstance(s, list) and s and s[0] != count:
            raise DivasInputError(
                where, f"bad meta.json: {key}.shape[0] = {s[0]}, but means.shape[0] = {count}"
            )
    return count


def image_size(data: bytes, where: str) -> tuple[int, int]:
    """``(width, height)`` from a lossless WebP (``VP8L``/``VP8X``) or PNG header.

    Raises:
        DivasInputError: another image format, a lossy WebP, or a truncated header.
    """
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24:
        w, h = struct.unpack_from(">II", data, 16)
        return w, h
    if len(data) < 30 or data[:4] != b"RIFF" or data[8:12] != b"WEBP":
        raise DivasInputError(where, "not a WebP (or PNG) image")
    chunk = data[12:16]
    if chunk == b"VP8L":
        if data[20] != 0x2F:
            raise DivasInputError(where, "corrupt lossless WebP header")
        bits = int.from_bytes(data[21:25], "little")
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if chunk == b"VP8X":
        if _first_image_chunk(data) != b"VP8L":
            raise DivasInputError(where, "lossy WebP: SOG textures must be lossless")
        return int.from_bytes(data[24:27], "little") + 1, int.from_bytes(data[27:30], "little") + 1
    if chunk == b"VP8 ":
        raise DivasInputError(where, "lossy WebP: SOG textures must be lossless")
    raise DivasInputError(where, f"unknown WebP chunk {chunk!r}")


def _first_image_chunk(data: bytes) -> bytes | None:
    """The fourcc of the first ``VP8``/``VP8L`` chunk of an extended (``VP8X``) WebP."""
    off = 12
    while off + 8 <= len(data):
        fourcc, size = data[off : off + 4], int.from_bytes(data[off + 4 : off + 8], "little")
        if fourcc in (b"VP8 ", b"VP8L"):
            return fourcc
        off += 8 + size + (size & 1)
    return None


def decode_rgba(data: bytes, where: str, size: tuple[int, int]) -> np.ndarray:
    """``[H,W,4]`` uint8 RGBA of an 8-bit image (OpenCV; a missing alpha reads as 255)."""
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DivasInputError(where, "corrupt image: OpenCV cannot decode it")
    if img.dtype != np.uint8:
        raise DivasInputError(where, f"{img.dtype} pixels: SOG textures are 8-bit")
    if img.shape[1::-1] != size:
        raise DivasInputError(where, f"decoded size {img.shape[1::-1]} differs from header {size}")
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    out = np.empty(img.shape[:2] + (4,), np.uint8)
    out[..., :3] = img[..., 2::-1]  # OpenCV gives BGR(A)
    out[..., 3] = img[..., 3] if img.shape[2] == 4 else 255
    return out


def read_texels(cont: SogContainer, layout: SogLayout) -> tuple[SogLayout, dict[str, np.ndarray]]:
    """Decode every texture of ``layout``; per-Gaussian ones as ``[count,4]`` RGBA texels.

    ``shN_centroids`` comes back as the whole ``[H,W,4]`` palette image. For the
    original layout the returned layout gets ``sh_bands``/``sh_palette`` from it.

    Raises:
        DivasInputError: a missing or undecodable file, images of different sizes,
        one too small for the count or far larger than it needs, a palette whose
        width matches no band count.
    """
    n = layout.count
    max_texels = 2 * n + 65536  # splat-transform pads to a multiple of 4 in each direction
    sizes, blobs = {}, {}
    for role, name in layout.files.items():
        blobs[role] = cont.read(name, 16 * max_texels + (1 << 20))
        sizes[role] = image_size(blobs[role], cont.where(name))
    w, h = sizes["means_l"]
    for role in PER_GAUSSIAN:
        if role not in sizes:
            continue
        where = cont.where(layout.files[role])
        if sizes[role] != (w, h):
            raise DivasInputError(
                where, f"{sizes[role][0]}x{sizes[role][1]} texels, but means_l is {w}x{h}"
            )
        if w * h < n:
            raise DivasInputError(where, f"{w}x{h} texels cannot hold the {n} Gaussians declared")
        if w * h > max_texels:
            raise DivasInputError(where, f"{w}x{h} texels, far more than {n} Gaussians need")
    side = limits().max_image_side
    for role, (iw, ih) in sizes.items():
        if iw > side or ih > side:
            raise DivasInputError(
                cont.where(layout.files[role]), f"{iw}x{ih} image, over the {side}-pixel side limit"
            )
    decoded = sum(4 * iw * ih for iw, ih in sizes.values())
    budget = inflate_budget(sum(len(b) for b in blobs.values()))
    if decoded > budget:
        raise DivasInputError(
            cont.path, f"textures decode to {decoded} bytes, over the {budget}-byte limit"
        )
    if "shN_centroids" in sizes:
        layout = _palette_layout(layout, sizes["shN_centroids"], cont)
    tex = {}
    for role, blob in blobs.items():
        if role == "shN_centroids" and not layout.sh_bands:
            continue
        img = decode_rgba(blob, cont.where(layout.files[role]), sizes[role])
        tex[role] = img if role == "shN_centroids" else img.reshape(-1, 4)[:n]
    return layout, tex


def _palette_layout(layout: SogLayout, size: tuple[int, int], cont: SogContainer) -> SogLayout:
    where = cont.where(layout.files["shN_centroids"])
    cw, ch = size
    if layout.version is None:
        bands = {64 * c: b for b, c in SH_COEFFS.items()}.get(cw)
        if bands is None:
            raise DivasInputError(
                where, f"palette width {cw} matches no SH band count (192/512/960)"
            )
        declared = _MAX_PALETTE
    else:
        bands, declared = layout.sh_bands, layout.sh_palette
        if cw != 64 * SH_COEFFS[bands]:
            raise DivasInputError(
                where, f"palette width {cw}, but {bands} SH bands need {64 * SH_COEFFS[bands]}"
            )
    if ch > math.ceil(declared / 64):
        raise DivasInputError(where, f"palette {cw}x{ch} texels, more than {declared} entries need")
    palette = min(declared, 64 * ch)  # entries a label may name
    return SogLayout(**{**layout.__dict__, "sh_bands": bands, "sh_palette": palette})
