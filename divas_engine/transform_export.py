"""Export a selection with an affine transform applied (Blender's "apply object transform" on
export), in the input's own format.

A Gaussian ``(μ, Σ = R S² Rᵀ, opacity, SH)`` under ``x ↦ A x + t`` becomes
``(A μ + t, A Σ Aᵀ, opacity, SH rotated by Q)`` with ``Q`` the rotation of ``A`` (polar
decomposition ``A = Q P``). ``A = s·Q`` composes quaternions exactly; any other ``A`` (mirrors
included) re-factorises the covariance (3DGS: eigen-decomposition; 2DGS: SVD of the tangent
frame). SH rotate band by band, ``c'_l = D_l(Q) c_l`` (:mod:`.sh_rotation`).

Formats: standard PLY, compressed PLY (re-encoded), ``.splat`` and generated scenes; ``.spz``
and SOG are not re-encoded (their quantisers are not reproduced here) and raise
:class:`~.errors.DivasInputError` naming the format. Details: docs/design-notes.md.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np

from .errors import DivasInputError
from .export import ExportResult, file_labels
from .geometry import normalize_quats, quat_to_rotmat, rotmat_to_quat
from .output_paths import check_outputs, save_npy_atomic, write_bytes_atomic
from .scene import Scene, SurfelScene
from .sh_rotation import rotate_sh

__all__ = [
    "TRANSFORM_FORMATS",
    "rotation_part",
    "transform_points",
    "transform_frames",
    "transform_sh_rest",
    "transform_scene",
    "export_transformed_selection",
]

#: source formats an export with a transform can write.
TRANSFORM_FORMATS = ("ply", "compressed_ply", "splat")


def _affine(matrix) -> tuple[np.ndarray, np.ndarray]:
    m = np.asarray(matrix, np.float64)
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise ValueError("transform must be a finite 4x4 matrix")
    a = m[:3, :3]
    if abs(np.linalg.det(a)) < 1e-12:
        raise ValueError("transform is singular (a zero scale)")
    return a, m[:3, 3]


def rotation_part(a: np.ndarray) -> np.ndarray:
    """``Q`` of the polar decomposition ``A = Q P`` (orthogonal; det −1 for a mirror)."""
    u, _, vt = np.linalg.svd(np.asarray(a, np.float64))
    return u @ vt


def _uniform_scale(a: np.ndarray) -> float | None:
    """``s`` when ``A = s·R`` with ``R`` a proper rotation, else None."""
    g = a.T @ a
    s2 = np.trace(g) / 3.0
    # 1e-6: object matrices come from Blender in float32
    if np.allclose(g, s2 * np.eye(3), rtol=0, atol=1e-6 * s2) and np.linalg.det(a) > 0:
        return float(np.sqrt(s2))
    return None


def transform_points(points: np.ndarray, matrix) -> np.ndarray:
    """``[N,3]`` ``A p + t`` (float64)."""
    a, t = _affine(matrix)
    return np.asarray(points, np.float64) @ a.T + t


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def transform_frames(
    quats: np.ndarray, scales: np.ndarray, matrix
) -> tuple[np.ndarray, np.ndarray]:
    """New ``(quats [N,4] (w,x,y,z) unit, scales [N,k])`` of Gaussians (k = 3) or surfels
    (k = 2: columns 0, 1 of the rotation are the tangents) under the transform's linear
    part (module docstring). Scales are activated standard deviations."""
    a, _ = _affine(matrix)
    q = normalize_quats(np.asarray(quats, np.float32)).astype(np.float64)
    s = np.asarray(scales, np.float64)
    k = s.shape[1]
    if k not in (2, 3):
        raise ValueError(f"scales must have 2 or 3 columns, got {k}")
    uni = _uniform_scale(a)
    if uni is not None:
        qa = rotmat_to_quat((a / uni)[None].astype(np.float64))[0].astype(np.float64)
        q2 = _quat_mul(np.broadcast_to(qa, q.shape), q)
        q2 /= np.linalg.norm(q2, axis=1, keepdims=True)
        return q2, s * uni
    r = quat_to_rotmat(q)
    if k == 3:
        cov = np.einsum("ij,njk,nk,nlk,ml->nim", a, r, s * s, r, a)
        lam, vec = np.linalg.eigh(cov)  # ascending
        lam, vec = lam[:, ::-1], vec[:, :, ::-1]
        # a vanishing axis (σ below the eigen-solver's precision) stays tiny but finite,
        # so its log-scale can be written
        floor = 1e-12 * np.sqrt(np.maximum(lam[:, :1], 0.0)) + 1e-30
        new_s = np.maximum(np.sqrt(np.maximum(lam, 0.0)), floor)
    else:
        frame = a @ (r[:, :, :2] * s[:, None, :])  # [N,3,2]
        u, sv, _ = np.linalg.svd(frame, full_matrices=False)
        vec = np.concatenate([u, np.cross(u[:, :, 0], u[:, :, 1])[:, :, None]], axis=2)
        new_s = np.maximum(sv, 1e-12 * sv[:, :1] + 1e-30)
    flip = np.linalg.det(vec) < 0
    vec[flip, :, -1] *= -1.0
    return rotmat_to_quat(vec).astype(np.float64), new_s


def transform_sh_rest(sh_rest: np.ndarray, matrix) -> np.ndarray:
    """``[N, K−1, 3]`` view-dependent SH coefficients rotated with the transform."""
    a, _ = _affine(matrix)
    rest = np.asarray(sh_rest)
    if rest.shape[1] == 0:
        return rest.copy()
    full = np.concatenate([np.zeros_like(rest[:, :1]), rest], axis=1)
    return rotate_sh(full, rotation_part(a))[:, 1:]


def transform_scene(scene: SurfelScene, matrix) -> SurfelScene:
    """The engine scene transformed (the surfels as the engine keeps them; a 3DGS scene's
    dropped normal σ ``scale_n`` is carried through the full covariance)."""
    a, _ = _affine(matrix)
    if scene.scale_n is not None:
        s3 = np.concatenate([scene.scales, scene.scale_n[:, None]], axis=1)
        q, s = transform_frames(scene.quats, s3, matrix)
        r = quat_to_rotmat(q)
        order = np.argsort(-s, axis=1, kind="stable")  # the two largest axes are the tangents
        idx = np.arange(len(s))
        r = np.stack([r[idx, :, order[:, 0]], r[idx, :, order[:, 1]]], axis=2)
        n = np.cross(r[:, :, 0], r[:, :, 1])
        q2 = rotmat_to_quat(np.concatenate([r, n[:, :, None]], axis=2))
        s2 = np.stack([s[idx, order[:, 0]], s[idx, order[:, 1]]], axis=1)
        scale_n = s[idx, order[:, 2]].astype(np.float32)
    else:
        q2, s2 = transform_frames(scene.quats, scene.scales, matrix)
        scale_n = None
    sh = np.array(scene.sh, copy=True)
    sh[:, 1:] = transform_sh_rest(scene.sh[:, 1:], matrix)
    return SurfelScene(
        transform_points(scene.means, matrix).astype(np.float32),
        np.asarray(q2, np.float32),
        np.asarray(s2, np.float32),
        scene.opacities.copy(),
        sh.astype(np.float32),
        scene.sh_degree,
        scene.kind,
        None,
        dict(scene.extras),
        scale_n,
    )


# ----------------------------------------------------------------------------- formats
def _ply_transformed(src: Path, rows: np.ndarray, matrix, out: Path) -> None:
    from .io.ply import iter_vertex_chunks, read_ply_header, write_ply_rows

    layout = read_ply_header(src)
    if any(e.name != "vertex" for e in layout.elements):
        others = [e.name for e in layout.elements if e.name != "vertex"]
        raise DivasInputError(src, f"cannot apply a transform to a PLY with elements {others}")
    dtype = layout.vertex_dtype()
    data = np.empty(len(rows), dtype=dtype.newbyteorder("<"))
    for start, chunk in iter_vertex_chunks(layout):
        lo, hi = np.searchsorted(rows, [start, start + len(chunk)])
        if hi > lo:
            data[lo:hi] = chunk[rows[lo:hi] - start]
    names = set(dtype.names)

    def cols(keys):
        return np.stack([data[k].astype(np.float64) for k in keys], axis=1)

    def put(keys, values):
        for i, k in enumerate(keys):
            data[k] = values[:, i]

    if not {"x", "y", "z"} <= names:
        raise DivasInputError(src, "PLY vertex element has no x, y, z")
    put("xyz", transform_points(cols("xyz"), matrix))
    a, _ = _affine(matrix)
    if {"nx", "ny", "nz"} <= names:
        nrm = cols(["nx", "ny", "nz"])
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        m = nrm @ np.linalg.inv(a)  # rows of A⁻ᵀ n
        m *= np.where(
            length > 0, length / np.maximum(np.linalg.norm(m, axis=1, keepdims=True), 1e-30), 0
        )
        put(["nx", "ny", "nz"], m)
    rot = [f"rot_{i}" for i in range(4)]
    scl = [f"scale_{i}" for i in range(3) if f"scale_{i}" in names]
    if set(rot) <= names and len(scl) >= 2:
        q, s = transform_frames(cols(rot), np.exp(cols(scl)), matrix)
        put(rot, q)
        with np.errstate(divide="ignore"):
            put(scl, np.log(s))
    rest = sorted((n for n in names if n.startswith("f_rest_")), key=lambda n: int(n[7:]))
    if rest:
        if len(rest) % 3:
            raise DivasInputError(src, f"{len(rest)} f_rest properties is not 3 channels' worth")
        k1 = len(rest) // 3  # channel-major: f_rest_{ch*k1 + j}
        v = cols(rest).reshape(len(rows), 3, k1).transpose(0, 2, 1)
        put(rest, transform_sh_rest(v, matrix).transpose(0, 2, 1).reshape(len(rows), -1))
    write_ply_rows(out, {"vertex": data}, comments=["divas_engine transformed subset"])


def _quantize_sh_bytes(v: np.ndarray) -> np.ndarray:
    """Inverse of the compressed PLY's SH dequantisation ``((b + 0.5)/256 − 0.5)·8``."""
    return np.clip(np.floor((v / 8.0 + 0.5) * 256.0), 0, 255).astype(np.uint8)


def _pack_rotation(q: np.ndarray) -> np.ndarray:
    """``packed_rotation`` words: largest component's index, the other three in 10 bits
    each as ``(c·sign(largest)/√2 + ½)``."""
    from .io import compressed_ply as cp

    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    big = np.argmax(np.abs(q), axis=1)
    rows = np.arange(len(q))
    q = q * np.sign(q[rows, big])[:, None]
    others = cp._OTHERS[big]
    word = big.astype(np.uint32) << np.uint32(30)
    for j, shift in enumerate((20, 10, 0)):
        t = q[rows, others[:, j]] / cp._SQRT2 + 0.5
        word |= cp._pack_unorm(t, 10) << np.uint32(shift)
    return word


def _compressed_ply_transformed(src: Path, rows: np.ndarray, matrix, out: Path) -> None:
    from .io import compressed_ply as cp
    from .io.ply import read_ply_header, write_ply_rows

    layout = read_ply_header(src)
    cl = cp._Layout(layout)
    f = cp.decode_compressed_ply_rows(src, rows, layout)
    pos = transform_points(f["pos"], matrix)
    q, s = transform_frames(f["quat"], np.exp(f["log_scale"]), matrix)
    with np.errstate(divide="ignore"):
        log_s = np.log(s)
    pmin, pmax = cp._chunk_bounds(pos)
    smin, smax = (np.clip(b, -20.0, 20.0) for b in cp._chunk_bounds(log_s))
    n = len(rows)
    ci = np.arange(n) // cp.SPLATS_PER_CHUNK
    packed = np.asarray(cl.vertex_memmap()[rows])
    out_v = np.empty(n, dtype=[(p, "<u4") for p in cp._PACKED])
    out_v["packed_position"] = cp._pack_111011(cp._normalize(pos, pmin[ci], pmax[ci]))
    out_v["packed_scale"] = cp._pack_111011(cp._normalize(log_s, smin[ci], smax[ci]))
    out_v["packed_rotation"] = _pack_rotation(q)
    out_v["packed_color"] = packed["packed_color"]
    names, bounds = list(cp._CHUNK_BASE), [pmin, pmax, smin, smax]
    if cl.has_color:  # colours unchanged, re-encoded against the kept rows' chunk bounds
        rgb = f["rgb"]
        nmin, nmax = cp._chunk_bounds(rgb)
        t = cp._normalize(rgb, nmin[ci], nmax[ci])
        cw = packed["packed_color"].astype(np.uint32)
        out_v["packed_color"] = (
            (cp._pack_unorm(t[:, 0], 8) << np.uint32(24))
            | (cp._pack_unorm(t[:, 1], 8) << np.uint32(16))
            | (cp._pack_unorm(t[:, 2], 8) << np.uint32(8))
            | (cw & np.uint32(0xFF))
        )
        names += list(cp._CHUNK_COLOR)
        bounds += [nmin, nmax]
    cb = np.concatenate(bounds, axis=1).astype(np.float32)
    out_c = np.empty(len(cb), dtype=[(nm, "<f4") for nm in names])
    for j, nm in enumerate(names):
        out_c[nm] = cb[:, j]
    elements = {"chunk": out_c, "vertex": out_v}
    if cl.sh_names:
        k1 = len(cl.sh_names) // 3
        v = f["f_rest"].astype(np.float64).reshape(n, 3, k1).transpose(0, 2, 1)
        b = _quantize_sh_bytes(transform_sh_rest(v, matrix).transpose(0, 2, 1).reshape(n, -1))
        out_sh = np.empty(n, dtype=[(nm, "u1") for nm in cl.sh_names])
        for j, nm in enumerate(cl.sh_names):
            out_sh[nm] = b[:, j]
        elements["sh"] = out_sh
    write_ply_rows(out, elements, comments=["divas_engine transformed subset of a compressed PLY"])


def _splat_transformed(src: Path, rows: np.ndarray, matrix, out: Path) -> None:
    from .io.splat import SPLAT_DTYPE

    total = Path(src).stat().st_size // SPLAT_DTYPE.itemsize
    rec = np.array(np.memmap(src, dtype=SPLAT_DTYPE, mode="r", shape=(total,))[rows])
    q_raw = (rec["rot"].astype(np.float64) - 128.0) / 128.0
    q, s = transform_frames(q_raw, rec["scale"].astype(np.float64), matrix)
    rec["pos"] = transform_points(rec["pos"], matrix)
    rec["scale"] = s
    rec["rot"] = np.clip(np.rint(q * 128.0 + 128.0), 0, 255).astype(np.uint8)
    write_bytes_atomic(out, rec.tobytes())


def export_transformed_selection(
    scene: Scene,
    selection: np.ndarray,
    out_path: str | PathLike,
    matrix,
    *,
    labels_path: str | PathLike | None = None,
) -> ExportResult:
    """Like :func:`.export.export_selection`, with ``matrix`` ([4,4]) applied to every
    exported Gaussian (module docstring)."""
    from .export import _check_selection

    out_path = Path(out_path)
    if not isinstance(scene, SurfelScene):
        raise DivasInputError(out_path, "a transform can only be applied to splat scenes")
    sel = _check_selection(scene, selection)
    if not sel.any():
        raise DivasInputError(out_path, "nothing to export: the selection is empty")
    try:
        _affine(matrix)
    except ValueError as e:
        raise DivasInputError(out_path, str(e)) from None
    src = scene.source
    fmt = "ply" if src is None else src.format
    if src is not None and fmt not in TRANSFORM_FORMATS:
        raise DivasInputError(
            src.path,
            f"cannot apply a transform when exporting {fmt!r} (re-encoding is supported for "
            f"{', '.join(TRANSFORM_FORMATS)}); export without applying the transform",
        )
    inputs = [] if src is None else [src.path]
    check_outputs([("export", out_path), ("labels output", labels_path)], inputs)
    # every writer below is atomic (output_paths): a failed export never leaves a
    # partial file and keeps the previous one
    if src is None:
        from .io.ply import write_surfel_ply

        write_surfel_ply(out_path, transform_scene(scene.subset(sel), matrix))
    else:
        writer = {
            "ply": _ply_transformed,
            "compressed_ply": _compressed_ply_transformed,
            "splat": _splat_transformed,
        }[fmt]
        writer(Path(src.path), src.kept_rows[sel], matrix, out_path)
    lp = None
    if labels_path is not None:
        lp = save_npy_atomic(labels_path, file_labels(scene, sel))
    return ExportResult(out_path, fmt, int(sel.sum()), lp)
