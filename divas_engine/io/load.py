"""``load_scene``: one entry point that recognises every supported scene file.

Formats: 2DGS/3DGS PLY, PlayCanvas/SuperSplat compressed PLY, antimatter15
``.splat``, Niantic ``.spz``, PlayCanvas SOG (``.sog`` bundle, or a folder / its
``meta.json``), PlayCanvas streamed LOD (``lod-meta.json`` or its folder, one level at
a time), NeRF density grids: this project's ``.npz``, instant-ngp snapshots
(``.ingp`` gzip'd msgpack, ``.msgpack``), torch-ngp checkpoints (``.pth``, with the torch
extra) and OpenVDB ``.vdb`` (where an OpenVDB module is importable). Detection looks at
the file's magic bytes first and its suffix second, so a misnamed file still loads.
"""

from __future__ import annotations

from dataclasses import replace
from os import PathLike
from pathlib import Path

import numpy as np

from ..errors import DivasInputError
from ..scene import Scene, SurfelScene, sh_coeff_count
from .limits import input_guard, require_input_file

__all__ = ["detect_format", "load_scene", "scene_cameras", "SCENE_FORMATS"]

SCENE_FORMATS = (
    "ply",
    "compressed_ply",
    "splat",
    "spz",
    "sog",
    "lod",
    "npz",
    "ingp",
    "msgpack",
    "torch_ngp",
    "vdb",
)


def detect_format(path: str | PathLike) -> str:
    """Return one of :data:`SCENE_FORMATS` for ``path`` or raise :class:`DivasInputError`."""
    path = require_input_file(path, "scene file", allow_dir=True)
    from .lod import LOD_META, is_lod_meta

    if is_lod_meta(path) or (path.is_dir() and (path / LOD_META).is_file()):
        return "lod"
    if path.is_dir() and (path / "meta.json").is_file():
        require_input_file(path / "meta.json", "SOG meta.json")
        return "sog"
    if path.is_dir():
        raise DivasInputError(path, "is a directory, expected a scene file")
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError as e:
        raise DivasInputError(path, f"cannot read scene file ({e.strerror or e})") from None
    if not head:
        raise DivasInputError(path, "empty file")
    suffix = path.suffix.lower()
    if head.startswith(b"ply"):
        from .compressed_ply import is_compressed_ply
        from .ply import read_ply_header

        return "compressed_ply" if is_compressed_ply(read_ply_header(path)) else "ply"
    if suffix in (".json", ".sog"):
        return "sog"
    if head.startswith(b"PK"):
        from .sog import is_sog_zip

        if is_sog_zip(path):
            return "sog"
        return "torch_ngp" if suffix in (".pth", ".pt") or _is_torch_zip(path) else "npz"
    if head.startswith(b"\x1f\x8b"):
        return "ingp" if _gzip_holds_msgpack(path) else "spz"
    if head.startswith(b"NGSP") or suffix == ".spz":
        return "spz"
    if head.startswith(b" BD") or suffix == ".vdb":
        return "vdb"
    from .instant_ngp import is_ngp_msgpack_head

    if is_ngp_msgpack_head(head) and suffix in (".msgpack", ".ingp", ""):
        return "msgpack"
    if suffix == ".splat":
        return "splat"
    if suffix == ".ply":
        raise DivasInputError(path, "not a PLY file (missing 'ply' magic line)")
    raise DivasInputError(
        path,
        "unknown scene format: expected .ply, .splat, .spz, .sog, .npz, .ingp, .msgpack, "
        ".pth (torch-ngp) or .vdb",
    )


def _gzip_holds_msgpack(path: Path) -> bool:
    """A gzip stream whose first inflated byte opens a msgpack map (instant-ngp's
    ``.ingp``), not Niantic's ``NGSP`` header."""
    import zlib

    from .instant_ngp import is_ngp_msgpack_head

    with open(path, "rb") as f:
        raw = f.read(1 << 16)
    try:
        first = zlib.decompressobj(wbits=31).decompress(raw, 4)
    except zlib.error:
        return False
    return is_ngp_msgpack_head(first) and not first.startswith(b"NGSP")


def _is_torch_zip(path: Path) -> bool:
    """A ZIP laid out as ``torch.save`` writes it (``<name>/data.pkl``)."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as zf:
            return any(n.endswith("/data.pkl") or n == "data.pkl" for n in zf.namelist())
    except (zipfile.BadZipFile, OSError):
        return False


def load_scene(
    path: str | PathLike,
    *,
    fmt: str | None = None,
    max_sh_degree: int | None = None,
    lod: int | None = None,
) -> Scene:
    """Load a scene file into a :class:`SurfelScene` or :class:`DensityGrid`.

    Args:
        path: the scene file.
        fmt: force a format from :data:`SCENE_FORMATS` instead of detecting it.
        max_sh_degree: keep the SH bands up to this degree only (a standard PLY never
            allocates the others; other formats drop them after decoding). The same
            rows are kept; ``scene.source.file_sh_degree`` records the file's degree.
        lod: the level of a streamed LOD scene (None: 0, the finest); refused for
            other formats.
    """
    path = Path(path)
    with input_guard(path, "scene file"):
        fmt = fmt or detect_format(path)
        if fmt == "lod":
            from .lod import LOD_META, read_lod

            scene = read_lod(path / LOD_META if path.is_dir() else path, lod)
        elif lod is not None:
            raise DivasInputError(path, f"--lod applies to lod-meta.json scenes, not {fmt}")
        else:
            scene = _load(path, fmt, max_sh_degree)
    if max_sh_degree is not None and isinstance(scene, SurfelScene):
        scene = _keep_sh_bands(scene, max_sh_degree)
    return scene


def scene_cameras(scene: Scene) -> list:
    """The training cameras a scene file holds itself (an instant-ngp snapshot's dataset),
    in the scene's frame; ``[]`` for every other format."""
    return list(getattr(scene, "extras", {}).get("cameras") or [])


def _keep_sh_bands(scene: SurfelScene, max_degree: int) -> SurfelScene:
    """``scene`` with its SH cut to ``max_degree`` (itself when it has no more)."""
    deg = max(0, int(max_degree))
    if scene.sh_degree <= deg:
        return scene
    src = scene.source
    if src is not None:
        src = replace(src, file_sh_degree=scene.sh_degree)
    sh = np.ascontiguousarray(scene.sh[:, : sh_coeff_count(deg)])
    return replace(scene, sh=sh, sh_degree=deg, source=src)


def _load(path: Path, fmt: str, max_sh_degree: int | None = None) -> Scene:
    if fmt == "ply":
        from .ply import read_gaussian_ply

        return read_gaussian_ply(path, max_sh_degree=max_sh_degree)
    if fmt == "compressed_ply":
        from .compressed_ply import read_compressed_ply
        from .ply import read_ply_header

        return read_compressed_ply(path, read_ply_header(path))
    if fmt == "splat":
        from .splat import read_splat

        return read_splat(path)
    if fmt == "spz":
        from .spz import read_spz

        return read_spz(path)
    if fmt == "sog":
        from .sog import read_sog

        return read_sog(path)
    if fmt == "npz":
        from .density_grid import read_density_grid

        return read_density_grid(path)
    if fmt in ("ingp", "msgpack"):
        from .instant_ngp import read_instant_ngp

        return read_instant_ngp(path)
    if fmt == "torch_ngp":
        from .torch_ngp import read_torch_ngp

        return read_torch_ngp(path)
    if fmt == "vdb":
        from .openvdb_grid import read_vdb

        return read_vdb(path)
    raise DivasInputError(path, f"unknown format {fmt!r}; expected one of {SCENE_FORMATS}")
