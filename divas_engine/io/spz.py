"""Niantic ``.spz``: decoder (versions 2, 3 and 4) and byte-exact subset writer.

Versions 2 and 3: one gzip stream holding a 16-byte header (``'NGSP'``, version, numPoints,
shDegree, fractionalBits, flags) and the attribute columns; version 4: an uncompressed 32-byte
header, a table of contents and one zstd frame per column (needs ``zstandard``). Columns:
24-bit fixed-point positions, alpha bytes ``sigmoid(opacity) · 255``, colours, log-scales,
rotations (v2: three bytes; v3+: "smallest three" u32) and SH bytes ``(b − 128) / 128``.

SPZ stores Right-Up-Back; :func:`read_spz` converts to the 3DGS PLY frame (Right-Down-Front)
like the reference library: ``y, z`` negated, quaternion ``(w, x, −y, −z)``, SH sign flips.
SH degree 4 is cut to 3. The subset writer copies the selected points' bytes of every column
and rewrites only the point count (and v4's table of contents). Layouts in full:
docs/design-notes.md.
"""

from __future__ import annotations

import gzip
import struct
import zlib
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from ..errors import DivasInputError
from ..kinds import SceneKind
from ..output_paths import same_file, write_bytes_atomic
from ..scene import SourceInfo, SurfelScene
from .gaussians import check_file_rows, scene_from_rows, surfels_from_arrays
from .limits import inflate_budget, limits, require_input_file
from .ply import CHUNK_ROWS

__all__ = ["read_spz", "write_spz_subset", "SPZ_MAGIC", "RUB_TO_RDF_SH_SIGNS"]

SPZ_MAGIC = 0x5053474E  # b"NGSP" little-endian
_COLOR_SCALE = 0.15
_FLAG_EXTENSIONS = 0x2
_FLAG_ANTIALIASED = 0x1
_SQRT1_2 = np.float64(np.sqrt(0.5))
_COLUMNS = ("positions", "alphas", "colors", "scales", "rotations", "sh")
#: Sign of SH coefficients 1..15 (bands 1-3, 3DGS order) under (x, y, z) -> (x, -y, -z).
RUB_TO_RDF_SH_SIGNS = np.array(
    [-1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1], dtype=np.float32
)
_OTHERS = np.array([[i for i in range(4) if i != big] for big in range(4)], dtype=np.int64)


def _sh_dim(degree: int) -> int:
    return (degree + 1) ** 2 - 1


@dataclass
class _SpzFile:
    """A parsed SPZ container: header fields and raw per-point column bytes."""

    container: str  # "gzip" (v2/v3) or "ngsp" (v4)
    header: bytes  # 16 (gzip) or 32 (ngsp) header bytes as stored
    extensions: bytes  # raw extension records (may be empty)
    version: int
    n: int
    sh_degree: int
    fractional_bits: int
    flags: int
    columns: dict  # name -> uint8 [n, width]


def _widths(version: int, n_sh_dim: int) -> dict[str, int]:
    return {
        "positions": 9,
        "alphas": 1,
        "colors": 3,
        "scales": 3,
        "rotations": 4 if version >= 3 else 3,
        "sh": n_sh_dim * 3,
    }


def _zstd(path: Path):
    try:
        import zstandard
    except ImportError:  # pragma: no cover - depends on the environment
        raise DivasInputError(
            path,
            "SPZ version 4 files are zstd-compressed; reading or "
            "writing them needs the 'zstandard' package "
            "(pip install zstandard)",
        ) from None
    return zstandard


def _check_common(path: Path, n: int, sh_degree: int) -> None:
    if n == 0:
        raise DivasInputError(path, "empty scene: the SPZ header says 0 points")
    if n > limits().max_rows:
        raise DivasInputError(
            path, f"SPZ header says {n} points, over the {limits().max_rows} limit"
        )
    if sh_degree > 4:
        raise DivasInputError(path, f"SPZ SH degree {sh_degree} is not supported (0..4)")


def _gunzip(path: Path, data: bytes, budget: int) -> bytes:
    """Decompress the gzip stream(s) of ``data`` into at most ``budget`` bytes."""
    out, rest = [], data
    size = 0
    try:
        while rest:
            if rest[:2] != b"\x1f\x8b":
                if out and not rest.strip(b"\0"):
                    break  # zero padding after the last member (gzip.decompress allows it)
                raise DivasInputError(path, "corrupt gzip stream in SPZ file (trailing garbage)")
            d = zlib.decompressobj(16 + zlib.MAX_WBITS)
            chunk = d.decompress(rest, budget - size + 1)
            size += len(chunk)
            out.append(chunk)
            if size > budget:
                raise DivasInputError(
                    path,
                    f"gzip stream inflates past {budget} bytes, the limit for a file of "
                    f"{len(data)} bytes (LoadLimits)",
                )
            if not d.eof:
                raise DivasInputError(path, "corrupt gzip stream in SPZ file (truncated)")
            rest = d.unused_data
    except zlib.error as e:
        raise DivasInputError(path, f"corrupt gzip stream in SPZ file ({e})") from None
    return b"".join(out)


def _parse_gzip(path: Path, data: bytes) -> _SpzFile:
    payload = _gunzip(path, data, inflate_budget(len(data)))
    if len(payload) < 16:
        raise DivasInputError(path, "truncated SPZ: the payload is shorter than its 16-byte header")
    magic, version, n, deg, frac, flags = struct.unpack_from("<IIIBBB", payload, 0)
    if magic != SPZ_MAGIC:
        raise DivasInputError(path, f"not an SPZ file (magic 0x{magic:08x}, expected 'NGSP')")
    if version not in (2, 3):
        raise DivasInputError(
            path,
            f"unsupported SPZ version {version} in a gzip container "
            "(supported: 2, 3; version 4 is not gzipped)",
        )
    _check_common(path, n, deg)
    widths = _widths(version, _sh_dim(deg))
    need = n * sum(widths.values())
    if len(payload) - 16 < need:
        raise DivasInputError(
            path,
            f"truncated SPZ: {n} points need {need} bytes of "
            f"columns, the payload has {len(payload) - 16}",
        )
    start = 16
    ext = b""
    if flags & _FLAG_EXTENSIONS:  # records of unknown layout: the columns end the payload
        start = len(payload) - need
        ext = payload[16:start]
    cols, off = {}, start
    for name in _COLUMNS:
        w = widths[name]
        cols[name] = np.frombuffer(payload, np.uint8, n * w, off).reshape(n, w)
        off += n * w
    return _SpzFile("gzip", payload[:16], ext, version, n, deg, frac, flags, cols)


def _parse_ngsp(path: Path, data: bytes) -> _SpzFile:
    if len(data) < 32:
        raise DivasInputError(path, "truncated SPZ: shorter than the 32-byte version-4 header")
    magic, version, n, deg, frac, flags, n_streams, toc = struct.unpack_from("<IIIBBBBI", data, 0)
    if version != 4:
        raise DivasInputError(
            path,
            f"unsupported SPZ version {version} with a plain 'NGSP' "
            "header (supported: 4; versions 2-3 are gzipped)",
        )
    _check_common(path, n, deg)
    widths = _widths(version, _sh_dim(deg))
    present = [c for c in _COLUMNS if widths[c] > 0]
    if n_streams != len(present):
        raise DivasInputError(
            path, f"SPZ v4 header lists {n_streams} streams; SH degree {deg} needs {len(present)}"
        )
    if toc < 32 or toc + 16 * n_streams > len(data):
        raise DivasInputError(
            path,
            f"truncated or corrupt SPZ v4: table of contents at "
            f"{toc} does not fit in {len(data)} bytes",
        )
    declared = n * sum(widths[c] for c in present)
    if declared > inflate_budget(len(data)):
        raise DivasInputError(
            path,
            f"SPZ v4 header declares {n} points ({declared} bytes of columns), over the "
            f"{inflate_budget(len(data))}-byte limit for a file of {len(data)} bytes (LoadLimits)",
        )
    zstandard = _zstd(path)
    dctx = zstandard.ZstdDecompressor()
    cols, off = {}, toc + 16 * n_streams
    for i, name in enumerate(present):
        csize, usize = struct.unpack_from("<QQ", data, toc + 16 * i)
        want = n * widths[name]
        if usize != want:
            raise DivasInputError(
                path, f"SPZ v4 {name} stream holds {usize} bytes; {n} points need {want}"
            )
        if off + csize > len(data):
            raise DivasInputError(
                path,
                f"truncated SPZ v4: the {name} stream ends at byte "
                f"{off + csize}, the file has {len(data)}",
            )
        try:
            raw = dctx.decompress(data[off : off + csize], max_output_size=want)
        except zstandard.ZstdError as e:
            raise DivasInputError(path, f"corrupt zstd stream for SPZ {name} ({e})") from None
        if len(raw) != want:
            raise DivasInputError(
                path, f"SPZ v4 {name} stream decompressed to {len(raw)} bytes, expected {want}"
            )
        cols[name] = np.frombuffer(raw, np.uint8).reshape(n, widths[name])
        off += csize
    cols.setdefault("sh", np.zeros((n, 0), np.uint8))
    return _SpzFile("ngsp", data[:32], data[32:toc], version, n, deg, frac, flags, cols)


def _parse(path: Path) -> _SpzFile:
    require_input_file(path, "SPZ file")
    try:
        data = path.read_bytes()
    except OSError as e:
        raise DivasInputError(path, f"cannot read SPZ file ({e})") from None
    if data[:2] == b"\x1f\x8b":
        return _parse_gzip(path, data)
    if len(data) >= 4 and struct.unpack_from("<I", data, 0)[0] == SPZ_MAGIC:
        return _parse_ngsp(path, data)
    raise DivasInputError(
        path,
        "not an SPZ file: neither a gzip stream (versions 2-3) nor an 'NGSP' header (version 4)",
    )


def _decode_rotations(rot: np.ndarray, version: int) -> np.ndarray:
    """``[n,4]`` float64 quaternions in SPZ's (x, y, z, w) order."""
    n = len(rot)
    if version < 3:
        xyz = rot.astype(np.float64) / 127.5 - 1.0
        w = np.sqrt(np.maximum(0.0, 1.0 - np.sum(xyz * xyz, axis=1)))
        return np.concatenate([xyz, w[:, None]], axis=1)
    word = np.ascontiguousarray(rot).view("<u4").reshape(n).astype(np.int64)
    big = word >> 30
    q = np.empty((n, 4), np.float64)
    rows = np.arange(n)
    others = _OTHERS[big]
    ss = np.zeros(n, np.float64)
    for j in range(3):  # others[:, 0] sits in bits 20..29, others[:, 2] in bits 0..9
        bits = (word >> (10 * (2 - j))) & 0x3FF
        v = _SQRT1_2 * (bits & 0x1FF) / 511.0
        v = np.where(bits & 0x200, -v, v)
        q[rows, others[:, j]] = v
        ss += v * v
    q[rows, big] = np.sqrt(np.maximum(0.0, 1.0 - ss))
    return q


def read_spz(path: str | PathLike) -> SurfelScene:
    """Load an ``.spz`` file (v2, v3 or v4) into a :class:`SurfelScene`, in the PLY (RDF) frame.

    ``scene.extras`` gets ``spz_version`` and ``antialiased`` (header flag 0x1:
    the scene was trained with mip-splatting antialiasing).
    """
    path = Path(path)
    f = _parse(path)
    n, c = f.n, f.columns
    deg = min(f.sh_degree, 3)
    k = (deg + 1) ** 2
    means = np.empty((n, 3), np.float32)
    quats = np.empty((n, 4), np.float32)
    scales = np.empty((n, 2), np.float32)
    scale_n = np.empty(n, np.float32)
    opac = np.empty(n, np.float32)
    sh = np.empty((n, k, 3), np.float32)
    for start in range(0, n, CHUNK_ROWS):
        sl = slice(start, min(n, start + CHUNK_ROWS))
        m = sl.stop - start
        p = c["positions"][sl].reshape(m, 3, 3).astype(np.int32)
        fixed = p[..., 0] | (p[..., 1] << 8) | (p[..., 2] << 16)
        fixed = (fixed ^ 0x800000) - 0x800000  # sign-extend 24 -> 32 bits
        pos = (fixed.astype(np.float64) / float(1 << f.fractional_bits)).astype(np.float32)
        q = _decode_rotations(c["rotations"][sl], f.version)[:, [3, 0, 1, 2]].astype(np.float32)
        # RUB -> RDF is a rotation by pi about x: negate y and z of positions and of
        # the quaternion's vector part.
        pos[:, 1:] *= -1.0
        q[:, 2:] *= -1.0
        s3 = np.exp(c["scales"][sl].astype(np.float32) / 16.0 - 10.0)
        means[sl] = pos
        quats[sl], scales[sl] = surfels_from_arrays(q, s3)
        scale_n[sl] = s3.min(1)
        opac[sl] = c["alphas"][sl, 0].astype(np.float32) / 255.0
        sh[sl, 0, :] = (c["colors"][sl].astype(np.float32) / 255.0 - 0.5) / _COLOR_SCALE
        if deg:
            rest = c["sh"][sl].reshape(m, _sh_dim(f.sh_degree), 3)[:, : k - 1, :]
            sh[sl, 1:, :] = (
                (rest.astype(np.float32) - 128.0) / 128.0 * RUB_TO_RDF_SH_SIGNS[: k - 1, None]
            )
    ok = np.isfinite(means).all(1)  # every byte decodes finite; kept for the contract
    extras = {"spz_version": f.version, "antialiased": bool(f.flags & _FLAG_ANTIALIASED)}
    return scene_from_rows(
        path,
        "spz",
        (means, quats, scales, opac, sh),
        ok,
        deg,
        SceneKind.GS3D,
        extras,
        scale_n=scale_n,
    )


def write_spz_subset(source: SourceInfo, file_rows: np.ndarray, out_path: str | PathLike) -> None:
    """Write points ``file_rows`` (in that order) of ``source`` as an SPZ of the same version.

    Every column's bytes for those points are copied unchanged; the header is
    kept except for the point count, extension records are kept verbatim.
    Versions 2-3 are re-gzipped, version 4 streams re-compressed with zstd.
    """
    path = Path(source.path)
    if same_file(path, out_path):
        raise DivasInputError(out_path, "the output is the input; refusing to overwrite the input")
    f = _parse(path)
    rows = check_file_rows(path, file_rows, f.n)
    if rows.size == 0:
        raise ValueError("nothing to write: file_rows is empty")
    m = len(rows)
    header = f.header[:8] + struct.pack("<I", m) + f.header[12:]
    cols = [np.ascontiguousarray(f.columns[name][rows]).tobytes() for name in _COLUMNS]
    if f.container == "gzip":
        out = gzip.compress(header + f.extensions + b"".join(cols), mtime=0)
    else:
        zstandard = _zstd(path)
        cctx = zstandard.ZstdCompressor(level=9)
        streams = [cctx.compress(b) for b in cols if b]
        toc = b"".join(
            struct.pack("<QQ", len(z), len(b)) for z, b in zip(streams, [b for b in cols if b])
        )
        out = header + f.extensions + toc + b"".join(streams)
    write_bytes_atomic(out_path, out)
