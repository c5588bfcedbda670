"""Standard 3DGS / 2DGS PLY files: chunked structured read, exact subset write.

The header is parsed by ``plyfile`` (a well-kept PLY library). The bulk vertex
data of binary files is then read in row chunks (``readinto`` one reused buffer) and
gathered into the preallocated float32 output arrays: one gather per output from a
float32 view of the chunk, the SH straight into its rows. plyfile's whole-element
read (or memmap, whose touched pages count toward RSS) would hold the raw file *and*
the converted arrays at once — 6M SH-3 Gaussians are 1.5 GB raw — while a chunked
read peaks at the outputs plus one chunk. ASCII files go through plyfile's own
reader (they are small in practice).

Layout (2DGS trainer): ``x y z nx ny nz f_dc_0..2 f_rest_0..(3(K-1)-1) opacity
scale_0 scale_1 rot_0..3`` with ``K=(d+1)^2``; 3DGS adds ``scale_2``. ``f_rest`` is
channel-major: ``f_rest[c*(K-1) + k]`` is coefficient ``k+1`` of channel ``c``.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np
import plyfile

from ..errors import DivasInputError
from ..geometry import normalize_quats
from ..kinds import SceneKind
from ..output_paths import atomic_file
from ..scene import SurfelScene, sh_coeff_count
from .gaussians import scene_from_rows, sigmoid, surfels_from_arrays
from .limits import limits, require_input_file

__all__ = [
    "PlyLayout",
    "read_ply_header",
    "read_gaussian_ply",
    "write_surfel_ply",
    "surfel_rows",
    "write_ply_rows",
    "CHUNK_ROWS",
]

#: Rows converted per chunk: bounds the transient memory of a load.
CHUNK_ROWS = 1 << 18

_REQUIRED = (
    "x",
    "y",
    "z",
    "opacity",
    "scale_0",
    "scale_1",
    "rot_0",
    "rot_1",
    "rot_2",
    "rot_3",
    "f_dc_0",
    "f_dc_1",
    "f_dc_2",
)


class PlyLayout:
    """Parsed header of a PLY file: elements, vertex dtype and data offset."""

    def __init__(self, path: Path, ply: plyfile.PlyData, data_offset: int | None):
        self.path = path
        self.ply = ply
        self.text = ply.text
        self.byte_order = ply.byte_order
        self.elements = ply.elements
        self.data_offset = data_offset

    def element(self, name: str) -> plyfile.PlyElement | None:
        for e in self.elements:
            if e.name == name:
                return e
        return None

    @property
    def vertex(self) -> plyfile.PlyElement:
        v = self.element("vertex")
        if v is None:
            raise DivasInputError(self.path, "PLY has no 'vertex' element")
        return v

    def vertex_dtype(self) -> np.dtype:
        return np.dtype(self.vertex.dtype(self.byte_order))

    @property
    def property_names(self) -> list[str]:
        return [p.name for p in self.vertex.properties]


def read_ply_header(path: str | PathLike) -> PlyLayout:
    """Parse the header; validate that the file is long enough for its binary data."""
    path = require_input_file(path, "PLY file")
    try:
        with open(path, "rb") as f:
            magic = f.read(4)
            if magic[:3] != b"ply":
                raise DivasInputError(path, "not a PLY file (missing 'ply' magic line)")
            f.seek(0)
            header = plyfile.PlyData._parse_header(f)  # header only, no data read
            offset = f.tell()
    except DivasInputError:
        raise
    except (plyfile.PlyHeaderParseError, ValueError, KeyError, TypeError) as e:
        # plyfile raises ValueError for duplicate element / property names
        raise DivasInputError(path, f"malformed PLY header ({e})") from None
    except (OSError, UnicodeDecodeError) as e:
        raise DivasInputError(path, f"cannot read PLY header ({e})") from None
    layout = PlyLayout(path, header, None if header.text else offset)
    _check_counts(path, header, offset)
    if not header.text:
        need = offset
        for e in header.elements:
            if any(isinstance(p, plyfile.PlyListProperty) for p in e.properties):
                need = None  # variable-length rows: size unknown without reading
                break
            need += e.count * np.dtype(e.dtype(header.byte_order)).itemsize
        size = path.stat().st_size
        if need is not None and size < need:
            raise DivasInputError(
                path, f"truncated PLY: header promises {need} bytes, file has {size}"
            )
    return layout


def _check_counts(path: Path, header: plyfile.PlyData, offset: int) -> None:
    """Element counts that the file can hold: non-negative, within
    :class:`~divas_engine.io.limits.LoadLimits`, and — for ASCII rows and list rows,
    whose size is not fixed — no more rows than the body has room for (an ASCII value
    takes at least two bytes, a binary list row at least its fixed part)."""
    body = max(0, path.stat().st_size - offset)
    names = [e.name for e in header.elements]
    if len(set(names)) != len(names):
        raise DivasInputError(path, f"malformed PLY header: duplicate element names {names}")
    for e in header.elements:
        props = [p.name for p in e.properties]
        if len(set(props)) != len(props):
            raise DivasInputError(path, f"malformed PLY header: duplicate properties in {e.name!r}")
        if e.count < 0:
            raise DivasInputError(path, f"PLY element {e.name!r} has a negative count {e.count}")
        if e.count > limits().max_rows:
            raise DivasInputError(
                path, f"PLY element {e.name!r} declares {e.count} rows (limit {limits().max_rows})"
            )
        lists = [p for p in e.properties if isinstance(p, plyfile.PlyListProperty)]
        if header.text:
            min_row = 2 * max(1, len(e.properties))
        elif lists:
            fixed = [p for p in e.properties if not isinstance(p, plyfile.PlyListProperty)]
            min_row = sum(np.dtype(p.val_dtype).itemsize for p in fixed)
            min_row += sum(np.dtype(p.len_dtype).itemsize for p in lists)
        else:
            continue  # fixed-size rows: the file length is checked below
        if e.count * min_row > body:
            raise DivasInputError(
                path,
                f"truncated PLY: element {e.name!r} declares {e.count} rows, "
                f"the {body}-byte body cannot hold them",
            )


def _vertex_offset(layout: PlyLayout) -> int:
    """Byte offset of the vertex element (elements before it are skipped)."""
    off = layout.data_offset
    for e in layout.elements:
        if e.name == "vertex":
            return off
        if any(isinstance(p, plyfile.PlyListProperty) for p in e.properties):
            raise DivasInputError(layout.path, "list properties before 'vertex' are not supported")
        off += e.count * np.dtype(e.dtype(layout.byte_order)).itemsize
    raise DivasInputError(layout.path, "PLY has no 'vertex' element")


def iter_vertex_chunks(layout: PlyLayout, chunk: int = CHUNK_ROWS, *, reuse: bool = False):
    """Yield ``(start, structured_rows)`` chunks of the vertex element, file order.

    Binary rows are read with ``readinto``; with ``reuse`` every chunk is read into the
    same buffer (a chunk is then valid only until the next one is read)."""
    v = layout.vertex
    if layout.text or any(isinstance(p, plyfile.PlyListProperty) for p in v.properties):
        try:
            data = plyfile.PlyData.read(str(layout.path))["vertex"].data
        except Exception as e:  # plyfile raises several types for bad bodies
            raise DivasInputError(layout.path, f"cannot parse PLY body ({e})") from None
        yield 0, data
        return
    dtype = layout.vertex_dtype()
    start_off = _vertex_offset(layout)
    buf = np.empty(min(chunk, v.count) * dtype.itemsize, np.uint8)
    with open(layout.path, "rb") as f:
        f.seek(start_off)
        for start in range(0, v.count, chunk):
            n = min(chunk, v.count - start)
            nbytes = n * dtype.itemsize
            if not reuse and start:
                buf = np.empty(nbytes, np.uint8)
            if f.readinto(memoryview(buf)[:nbytes]) != nbytes:
                raise DivasInputError(layout.path, "truncated PLY vertex data")
            yield start, buf[:nbytes].view(dtype)


def _float32_columns(rows: np.ndarray) -> np.ndarray | None:
    """``rows`` as a ``[n, properties]`` float32 view when every property is a
    little-endian float32 (the trainers' layout), else None."""
    dt = rows.dtype
    f4 = np.dtype("<f4")
    if dt.names is None or any(dt.fields[nm][0] != f4 for nm in dt.names):
        return None
    if dt.itemsize != 4 * len(dt.names) or not rows.flags.c_contiguous:
        return None
    return rows.view(f4).reshape(len(rows), len(dt.names))


def _sh_layout(path: Path, names: list[str]) -> int:
    n_rest = sum(1 for n in names if n.startswith("f_rest_"))
    for deg in range(4):
        if n_rest == 3 * (sh_coeff_count(deg) - 1):
            expected = {f"f_rest_{i}" for i in range(n_rest)}
            if not expected <= set(names):
                raise DivasInputError(path, "f_rest_* properties are not numbered 0..N-1")
            return deg
    raise DivasInputError(
        path, f"{n_rest} f_rest_* properties match no SH degree 0-3 (expected 0, 9, 24 or 45)"
    )


def read_gaussian_ply(
    path: str | PathLike, layout: PlyLayout | None = None, *, max_sh_degree: int | None = None
) -> SurfelScene:
    """Load a 2DGS (``scale_0,1``) or 3DGS (``scale_0..2``) PLY into a :class:`SurfelScene`.

    Activations are applied (``exp`` scales, ``sigmoid`` opacity, normalised
    quaternions); 3DGS Gaussians are flattened to surfels. Rows with a NaN/Inf in
    any used property are dropped and counted in ``scene.source.dropped_nonfinite``.

    ``max_sh_degree``: keep only the SH bands up to this degree (``divas info`` keeps
    the DC: the SH rest of 6M SH-3 Gaussians is 1.1 GB it never reads). The other
    bands are still read and checked, so the same rows are dropped; the file's degree
    is kept in ``scene.source.file_sh_degree``.
    """
    path = Path(path)
    layout = layout or read_ply_header(path)
    names = layout.property_names
    missing = [p for p in _REQUIRED if p not in names]
    if missing:
        raise DivasInputError(path, f"missing required Gaussian properties {missing}")
    lists = [p.name for p in layout.vertex.properties if isinstance(p, plyfile.PlyListProperty)]
    used = [n for n in lists if n in _REQUIRED or n.startswith(("f_rest_", "scale_"))]
    if used:
        raise DivasInputError(path, f"properties {used} are lists; Gaussian properties are scalars")
    kind = SceneKind.GS3D if "scale_2" in names else SceneKind.GS2D
    file_deg = _sh_layout(path, names)
    deg = file_deg if max_sh_degree is None else max(0, min(file_deg, int(max_sh_degree)))
    k, k_file = sh_coeff_count(deg), sh_coeff_count(file_deg)
    n_scale = 3 if kind == SceneKind.GS3D else 2
    total = layout.vertex.count
    if total == 0:
        raise DivasInputError(path, "empty scene: the PLY has 0 vertices")

    means = np.empty((total, 3), np.float32)
    quats = np.empty((total, 4), np.float32)
    scales = np.empty((total, 2), np.float32)
    scale_n = np.empty(total, np.float32) if kind == SceneKind.GS3D else None
    opac = np.empty(total, np.float32)
    sh = np.empty((total, k, 3), np.float32)
    finite = np.empty(total, bool)
    rest_names = [f"f_rest_{i}" for i in range(3 * (k_file - 1))]

    # column positions of each output, so a chunk is converted with one gather per
    # output (SH straight into its rows) instead of a copy per property
    pos = {nm: i for i, nm in enumerate(names)}
    idx_m = [pos[c] for c in ("x", "y", "z")]
    idx_q = [pos[f"rot_{i}"] for i in range(4)]
    idx_s = [pos[f"scale_{i}"] for i in range(n_scale)]
    sh_names = [
        [f"f_dc_{ch}" if j == 0 else rest_names[ch * (k_file - 1) + j - 1] for ch in range(3)]
        for j in range(k_file)
    ]  # sh[:, j, ch] comes from sh_names[j][ch]
    idx_sh = np.array([[pos[nm] for nm in row] for row in sh_names[:k]]).reshape(-1)
    unkept = [nm for row in sh_names[k:] for nm in row]  # read for the finite check only
    idx_unkept = np.array(sorted(pos[nm] for nm in unkept), np.intp)
    if len(idx_unkept) and idx_unkept[-1] - idx_unkept[0] + 1 == len(idx_unkept):
        idx_unkept = slice(int(idx_unkept[0]), int(idx_unkept[-1]) + 1)  # a view, no gather

    for start, rows in iter_vertex_chunks(layout, CHUNK_ROWS, reuse=True):
        n = len(rows)
        sl = slice(start, start + n)
        table = _float32_columns(rows)
        if table is not None:
            m, q, s = table[:, idx_m], table[:, idx_q], table[:, idx_s]
            o = table[:, pos["opacity"]]
            np.take(table, idx_sh, axis=1, out=sh[sl].reshape(n, 3 * k))
            rest_ok = _finite_rows(table[:, idx_unkept]) if unkept else None
        else:  # other property types: converted one property at a time

            def cols(want: list[str]) -> np.ndarray:
                return np.stack([rows[nm].astype(np.float32, copy=False) for nm in want], 1)  # noqa: B023

            m = cols(["x", "y", "z"])
            q = cols([f"rot_{i}" for i in range(4)])
            s = cols([f"scale_{i}" for i in range(n_scale)])
            o = rows["opacity"].astype(np.float32)
            sh[sl] = cols([nm for row in sh_names[:k] for nm in row]).reshape(n, k, 3)
            rest_ok = _finite_rows(cols(unkept)) if unkept else None
        ok = (
            np.isfinite(m).all(1)
            & np.isfinite(q).all(1)
            & np.isfinite(s).all(1)
            & np.isfinite(o)
            & np.isfinite(sh[sl]).all((1, 2))
        )
        if rest_ok is not None:
            ok &= rest_ok
        with np.errstate(over="ignore", invalid="ignore"):
            s_act = np.exp(np.clip(s, -80.0, 80.0)).astype(np.float32)
        ok &= np.linalg.norm(q, axis=1) > 0
        s_act = np.where(ok[:, None], s_act, np.float32(1.0))
        q2, s2 = surfels_from_arrays(np.where(ok[:, None], q, 1.0), s_act)
        if scale_n is not None:
            scale_n[sl] = s_act.min(1)
        means[sl], quats[sl], scales[sl], opac[sl], finite[sl] = m, q2, s2, sigmoid(o), ok

    return scene_from_rows(
        path,
        "ply",
        (means, quats, scales, opac, sh),
        finite,
        deg,
        kind,
        scale_n=scale_n,
        file_sh_degree=file_deg if deg < file_deg else None,
    )


def _finite_rows(values: np.ndarray) -> np.ndarray:
    """``[n]`` True where every value of the row is finite (one float64 row sum: finite
    iff every float32 value is, as :func:`~.gaussians.sane_rows` checks)."""
    with np.errstate(invalid="ignore", over="ignore"):
        return np.isfinite(np.add.reduce(values, axis=1, dtype=np.float64))


def write_surfel_ply(path: str | PathLike, scene: SurfelScene) -> None:
    """Write a scene as a 2DGS-trainer binary little-endian PLY (stored-space values).

    Inverse of :func:`read_gaussian_ply` for 2DGS scenes: log scales, logit
    opacity, channel-major ``f_rest``, normals zero (as the trainers write them).
    """
    write_ply_rows(path, {"vertex": surfel_rows(scene)})


def surfel_rows(scene: SurfelScene, *, flat_axis: float | None = None) -> np.ndarray:
    """Structured Gaussian-PLY rows (stored-space values) of ``scene``.

    Without ``flat_axis``: the 2DGS trainer layout (``scale_0, scale_1``). With it: the
    3DGS layout, the surfel's dropped normal axis written as ``scale_2 = log(flat_axis ·
    min(s_1, s_2))`` (the thickness is lost when 3DGS is flattened on load).
    """
    n = len(scene)
    k = sh_coeff_count(scene.sh_degree)
    fields = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    fields += [f"f_rest_{i}" for i in range(3 * (k - 1))]
    fields += ["opacity", "scale_0", "scale_1"] + (["scale_2"] if flat_axis else [])
    fields += ["rot_0", "rot_1", "rot_2", "rot_3"]
    rows = np.zeros(n, dtype=[(f, "<f4") for f in fields])
    for i, a in enumerate("xyz"):
        rows[a] = scene.means[:, i]
    for ch in range(3):
        rows[f"f_dc_{ch}"] = scene.sh[:, 0, ch]
        for j in range(k - 1):
            rows[f"f_rest_{ch * (k - 1) + j}"] = scene.sh[:, j + 1, ch]
    o = np.clip(scene.opacities.astype(np.float64), 1e-7, 1 - 1e-7)
    rows["opacity"] = np.log(o / (1 - o))
    s = np.maximum(scene.scales.astype(np.float64), 1e-30)
    rows["scale_0"], rows["scale_1"] = np.log(s[:, 0]), np.log(s[:, 1])
    if flat_axis:
        rows["scale_2"] = np.log(flat_axis * s.min(1))
    q = normalize_quats(scene.quats)
    for i in range(4):
        rows[f"rot_{i}"] = q[:, i]
    return rows


def write_ply_rows(
    path: str | PathLike, elements: dict[str, np.ndarray], comments: list[str] | None = None
) -> None:
    """Write structured arrays as a binary little-endian PLY, one element per entry.

    Field order and types are kept exactly; big-endian fields are converted.
    """
    type_names = {
        "i1": "char",
        "u1": "uchar",
        "i2": "short",
        "u2": "ushort",
        "i4": "int",
        "u4": "uint",
        "f4": "float",
        "f8": "double",
    }
    lines = ["ply", "format binary_little_endian 1.0"]
    lines += [f"comment {c}" for c in (comments or [])]
    bodies = []
    for name, rows in elements.items():
        lines.append(f"element {name} {len(rows)}")
        le = []
        for f in rows.dtype.names:
            dt = rows.dtype[f]
            key = dt.kind + str(dt.itemsize)
            if key not in type_names or dt.shape:
                raise ValueError(f"cannot write PLY property {f} of dtype {dt}")
            lines.append(f"property {type_names[key]} {f}")
            le.append((f, dt.newbyteorder("<")))
        bodies.append(np.asarray(rows, dtype=np.dtype(le)))
    header = ("\n".join(lines) + "\nend_header\n").encode("ascii")
    with atomic_file(path) as f:
        f.write(header)
        for b in bodies:
            b.tofile(f)
