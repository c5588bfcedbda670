"""Seeded fuzzing of every input loader, shared by the CI test
``tests/test_fuzz_loaders.py`` and the large runner ``benchmarks/fuzz_loaders.py``.

Each *family* has small valid seed files (built here from the engine's writers or cut
from the committed real captures) and a loader. A *case* is one mutated copy of a
seed: bit flips, truncation, inserted/deleted bytes, numeric extremes in binary
bodies (NaN, ±Inf, 3.4e38, 0xFFFFFFFF, …), header-line edits for PLY (duplicated
lines, negative / huge counts, ``list`` properties, format swaps) and structural edits
for JSON (a node replaced by ``1e400``, ``Infinity``, a 4,300-digit integer, deep
nesting, a 300-character string, a non-ASCII digit key, …).

Every case runs in a forked child under ``RLIMIT_AS`` (the child's address space
plus a memory budget) and a wall-clock timeout; the outcome is one of

* ``ok`` — loaded, and the result passes the sanity checks (finite, in range);
* ``input`` — :class:`~divas_engine.errors.DivasInputError` (the wanted refusal);
* ``garbage`` — loaded, but the result holds NaN/Inf or out-of-range values;
* ``crash`` — any other exception (or the child died on a signal);
* ``hang`` — the timeout passed; ``memory`` — ``MemoryError`` under the limit.
"""

from __future__ import annotations

import gzip
import json
import os
import random
import re
import resource
import select
import shutil
import signal
import struct
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data"
OUTCOMES = ("ok", "input", "garbage", "crash", "hang", "memory")


@dataclass
class Family:
    """A loader family: its seeds (``name -> path of the file to mutate``) and loader."""

    name: str
    seeds: list[Path]
    load: Callable[[Path], object]  # called on the mutated file
    text: bool = False  # mutate as text (JSON / PLY header) as well as bytes
    check: Callable[[object], str | None] = field(default=lambda r: None)
    #: False: run cases in this process under an alarm, without a memory limit (Warp,
    #: which session replay uses, cannot be forked once started)
    fork: bool = True


# ----------------------------------------------------------------- sanity of results
def check_scene(scene) -> str | None:
    """Why a loaded scene is garbage (``None`` when it is sane)."""
    from divas_engine.scene import DensityGrid

    if isinstance(scene, DensityGrid):
        if not np.isfinite(scene.density).all() or (scene.density < 0).any():
            return "density not finite / negative"
        if not np.isfinite(scene.aabb).all():
            return "aabb not finite"
        return None
    for name in ("means", "quats", "scales", "opacities", "sh"):
        if not np.isfinite(getattr(scene, name)).all():
            return f"{name} not finite"
    if (scene.scales <= 0).any():
        return "non-positive scales"
    if not np.allclose(np.linalg.norm(scene.quats, axis=1), 1.0, atol=1e-3):
        return "quaternions not unit"
    if (scene.opacities < 0).any() or (scene.opacities > 1).any():
        return "opacity outside [0, 1]"
    return None


def check_cameras(cams) -> str | None:
    for c in cams:
        vals = [c.fx, c.fy, c.cx, c.cy]
        if not all(np.isfinite(vals)) or c.fx <= 0 or c.fy <= 0:
            return f"intrinsics {vals}"
        if not (0 < c.width <= 65536 and 0 < c.height <= 65536):
            return f"size {c.width}x{c.height}"
    return None


# ----------------------------------------------------------------- seeds
def _tiny_surfel_scene(n: int, deg: int, seed: int):
    from divas_engine.kinds import SceneKind
    from divas_engine.scene import SurfelScene, sh_coeff_count

    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4)).astype(np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return SurfelScene(
        rng.normal(size=(n, 3)).astype(np.float32),
        q,
        rng.uniform(0.01, 0.1, (n, 2)).astype(np.float32),
        rng.uniform(0.1, 0.9, n).astype(np.float32),
        rng.normal(0, 0.3, (n, sh_coeff_count(deg), 3)).astype(np.float32),
        deg,
        SceneKind.GS2D,
    )


def _ascii_ply(n: int, seed: int) -> bytes:
    rng = np.random.default_rng(seed)
    props = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1"]
    props += ["scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    head = ["ply", "format ascii 1.0", f"element vertex {n}"]
    head += [f"property float {p}" for p in props] + ["end_header"]
    rows = [" ".join(f"{v:.4g}" for v in rng.normal(size=len(props))) for _ in range(n)]
    return ("\n".join(head + rows) + "\n").encode()


def _spz_v4(src: Path, out: Path) -> None:
    """Re-pack a version 2/3 SPZ as version 4 (plain header, zstd column streams)."""
    import zstandard

    from divas_engine.io.spz import _COLUMNS, _parse

    f = _parse(src)
    cols = [np.ascontiguousarray(f.columns[c]).tobytes() for c in _COLUMNS]
    cols = [c for c in cols if c]
    z = zstandard.ZstdCompressor(level=3)
    streams = [z.compress(c) for c in cols]
    head = struct.pack(
        "<IIIBBBBI", 0x5053474E, 4, f.n, f.sh_degree, f.fractional_bits, 0, len(cols), 32
    )
    toc = b"".join(struct.pack("<QQ", len(s), len(c)) for s, c in zip(streams, cols))
    out.write_bytes(head + b"\0" * 12 + toc + b"".join(streams))


def _cameras(n: int = 3):
    from divas_engine.camera import Camera

    return [
        Camera.look_at(
            [3 * np.cos(a), 0.5, 3 * np.sin(a)],
            [0, 0, 0],
            [0, -1, 0],
            width=64,
            height=48,
            fx=60.0,
            name=f"img_{i:03d}",
        )
        for i, a in enumerate(np.linspace(0, 2, n))
    ]


#: every loader family :func:`build_seeds` knows, in the order the tables list them
FAMILIES = [
    "ply",
    "ply_ascii",
    "compressed_ply",
    "splat",
    "spz",
    "sog",
    "lod",
    "npz",
    "ingp",
    "ngp_msgpack",
    "vdb",
    "cameras_json",
    "transforms_json",
    "colmap",
    "prompts",
    "session",
]


def build_seeds(work: Path, families: list[str] | None = None) -> dict[str, Family]:
    """Write the seed files under ``work`` and return the families (all by default)."""
    from divas_engine.io.cameras import load_cameras, save_cameras
    from divas_engine.io.compressed_ply import write_compressed_ply_subset
    from divas_engine.io.density_grid import write_density_grid
    from divas_engine.io.load import load_scene
    from divas_engine.io.ply import write_surfel_ply
    from divas_engine.io.splat import SPLAT_DTYPE
    from divas_engine.io.spz import write_spz_subset
    from divas_engine.scene import DensityGrid
    from divas_engine.session.prompts import load_prompts, resolve_anchors

    want = set(families) if families else None
    fams: dict[str, Family] = {}
    work.mkdir(parents=True, exist_ok=True)

    def need(name: str) -> bool:
        if want is not None and name not in want:
            return False
        (work / name).mkdir(exist_ok=True)
        return True

    if need("ply"):
        seeds = []
        for deg, kind in ((0, "2dgs"), (1, "3dgs")):
            p = work / "ply" / f"seed_{kind}_{deg}.ply"
            sc = _tiny_surfel_scene(40, deg, deg)
            if kind == "3dgs":
                from divas_engine.io.ply import surfel_rows, write_ply_rows

                write_ply_rows(p, {"vertex": surfel_rows(sc, flat_axis=0.2)})
            else:
                write_surfel_ply(p, sc)
            seeds.append(p)
        fams["ply"] = Family("ply", seeds, load_scene, text=True, check=check_scene)
    if need("ply_ascii"):
        p = work / "ply_ascii" / "seed_ascii.ply"
        p.write_bytes(_ascii_ply(30, 1))
        fams["ply_ascii"] = Family("ply_ascii", [p], load_scene, text=True, check=check_scene)
    if need("compressed_ply"):
        src = load_scene(DATA / "playcanvas-splats" / "guitar.compressed.ply")
        p = work / "compressed_ply" / "seed.compressed.ply"
        write_compressed_ply_subset(src.source, np.arange(0, 600, 2), p)
        fams["compressed_ply"] = Family("compressed_ply", [p], load_scene, True, check_scene)
    if need("splat"):
        rng = np.random.default_rng(3)
        rows = np.zeros(50, SPLAT_DTYPE)
        rows["pos"] = rng.normal(size=(50, 3))
        rows["scale"] = rng.uniform(0.01, 0.1, (50, 3))
        rows["rgba"] = rng.integers(0, 256, (50, 4))
        rows["rot"] = rng.integers(0, 256, (50, 4))
        p = work / "splat" / "seed.splat"
        rows.tofile(p)
        fams["splat"] = Family("splat", [p], load_scene, check=check_scene)
    if need("spz"):
        src = load_scene(DATA / "playcanvas-splats" / "biker.spz")
        p = work / "spz" / "seed_v3.spz"
        write_spz_subset(src.source, np.arange(0, 300, 3), p)
        p4 = work / "spz" / "seed_v4.spz"
        _spz_v4(p, p4)
        # the gzip payload itself, uncompressed-mutated then re-gzipped, is a third seed
        fams["spz"] = Family("spz", [p, p4], load_scene, check=check_scene)
    if need("sog"):
        from divas_engine.io.sog_subset import write_sog_subset

        src = load_scene(DATA / "playcanvas-sog" / "playbot_lod3" / "meta.json")
        p = work / "sog" / "seed.sog"
        write_sog_subset(src.source, np.arange(0, 64), p)
        fams["sog"] = Family("sog", [p], load_scene, check=check_scene)
    if need("lod"):
        from divas_engine.io.lod_subset import write_lod_subset

        src = load_scene(DATA / "splat-transform-lod" / "lod-meta.json")
        rows = np.concatenate([np.arange(0, 24), np.arange(3000, 3024), np.arange(6800, 6824)])
        p = write_lod_subset(src.source, 0, rows, work / "lod" / "seed")
        fams["lod"] = Family("lod", [p], load_scene, text=True, check=check_scene)
    if need("npz"):
        rng = np.random.default_rng(5)
        dens = rng.uniform(0, 5, (6, 5, 4)).astype(np.float32)
        rgb = rng.uniform(0, 1, (6, 5, 4, 3)).astype(np.float32)
        g = DensityGrid(dens, np.array([[-1.0, -1, -1], [1, 1, 1]]), rgb, None)
        p = work / "npz" / "seed_grid.npz"
        write_density_grid(p, g)
        p2 = work / "npz" / "seed_grid_stored.npz"
        np.savez(p2, density=dens, aabb=g.aabb)
        fams["npz"] = Family("npz", [p, p2], load_scene, check=check_scene)
    ngp_wanted = [n for n in ("ingp", "ngp_msgpack") if need(n)]
    if ngp_wanted:
        from divas_engine.io.instant_ngp import write_ngp_document

        from .ngp_cases import small_config, sphere_snapshot
        from .ngp_reference import random_network

        cfg = small_config(levels=2, log2_t=8, width=16)
        net, _ = random_network(cfg, 1, seed=1)
        doc, _ = sphere_snapshot(radius_world=0.2, network=net, config=cfg)
        for name, comp in (("ingp", True), ("ngp_msgpack", False)):
            if name in ngp_wanted:
                p = work / name / ("seed.ingp" if comp else "seed.msgpack")
                write_ngp_document(p, doc, comp)
                fams[name] = Family(name, [p], load_scene, check=check_scene)
    if need("vdb"):
        from divas_engine.io.openvdb_grid import openvdb_module, write_vdb

        rng = np.random.default_rng(6)
        dens = (rng.uniform(0, 5, (6, 5, 4)) * (rng.random((6, 5, 4)) > 0.4)).astype(np.float32)
        rgb = rng.uniform(0, 1, (6, 5, 4, 3)).astype(np.float32)
        g = DensityGrid(dens, np.array([[-1.0, -1, -1], [1, 1, 1]]), rgb, None)
        if openvdb_module() is not None:
            from divas_engine.io.vdb_writer import write_vdb_numpy

            p = write_vdb(work / "vdb" / "seed.vdb", g)
            # the same grid uncompressed (the NumPy writer): raw node values to mutate
            (work / "vdb_plain").mkdir(exist_ok=True)
            plain = write_vdb_numpy(
                work / "vdb_plain" / "seed.vdb",
                [("density", dens.transpose(2, 1, 0)), ("color", rgb.transpose(2, 1, 0, 3))],
                np.full(3, -1.0) + 1 / 8,
                np.array([0.5, 0.4, 1 / 3]),
            )
            fams["vdb"] = Family("vdb", [p, plain], load_scene, check=check_scene)
    cams = _cameras()
    if need("cameras_json"):
        p = save_cameras(work / "cameras_json" / "cameras.json", cams, "cameras_json")
        fams["cameras_json"] = Family("cameras_json", [p], load_cameras, True, check_cameras)
    if need("transforms_json"):
        d = work / "transforms_json"
        p = save_cameras(d / "transforms.json", cams, "transforms_json")
        doc = json.loads(p.read_text())
        for fr in doc["frames"][:1]:  # one frame sized by its image header
            for k in ("w", "h"):
                fr.pop(k, None)
            img = d / (fr["file_path"] + ("" if Path(fr["file_path"]).suffix else ".png"))
            img.parent.mkdir(parents=True, exist_ok=True)
            import cv2

            cv2.imwrite(str(img), np.zeros((48, 64, 3), np.uint8))
        p.write_text(json.dumps(doc, indent=1))
        fams["transforms_json"] = Family("transforms_json", [p], load_cameras, True, check_cameras)
    if need("colmap"):
        seeds = []
        for binary in (False, True):
            d = save_cameras(
                work / "colmap" / ("bin" if binary else "txt"),
                cams,
                "colmap" if binary else "colmap_text",
            )
            seeds += sorted(q for q in d.rglob("*") if q.is_file() and "points3D" not in q.name)
        fams["colmap"] = Family("colmap", seeds, load_cameras, True, check_cameras)
    if need("prompts"):
        cam = cams[0]
        doc = {
            "version": 1,
            "anchors": [
                {
                    "camera": cam.to_dict(),
                    "clicks": [{"xy": [30.5, 20.5]}, {"xy": [5, 5], "positive": False}],
                },
                {"training_camera": "img_001", "clicks": [{"xy": [10, 10]}]},
                {"fibonacci": 1, "clicks": [{"xy": [12, 40]}]},
            ],
            "centroid_prompts": {"0:0": [{"xy": [3, 4], "positive": False}]},
            "points": [{"xyz": [0.1, -0.2, 1.5]}, {"xyz": [0, 0, 2], "positive": False}],
        }
        p = work / "prompts" / "prompts.json"
        p.write_text(json.dumps(doc, indent=1))

        def load_p(path: Path):
            return resolve_anchors(load_prompts(path), cams, lambda: cams)

        fams["prompts"] = Family("prompts", [p], load_p, True)
    if need("session"):
        fams["session"] = _session_family(work)
    return fams


def _session_family(work: Path) -> Family:
    """A saved session of one accepted view on a tiny synthetic scene; loaded with replay."""
    from divas_engine.io.load import load_scene
    from divas_engine.segment import OracleSegmenter
    from divas_engine.session import Session, SessionConfig
    from divas_engine.synthetic import generate_scene

    out = work / "session_scene"
    sc = generate_scene("ribs", out, size=2000, seed=0, grid_resolution=16)
    scene = load_scene(out / "scene.ply")
    click = sc.metadata["clicks"][0]
    names = [c.name for c in sc.cameras]
    cam = sc.cameras[names.index(click["visible_in"][0])]
    s = Session.open(
        scene,
        sc.cameras,
        SessionConfig(render_scale=0.25),
        OracleSegmenter(),
        "cpu",
        anchors=[cam],
        gt_values=sc.labels,
        render_anchors=False,
    )
    uv, _ = s.anchors[0].camera.project(np.asarray(click["xyz"])[None])
    v = s.click(0, uv[0])
    s.accept(v)
    path = work / "session" / "s" / "s.json"
    s.save(path)

    def load_s(p: Path):
        return Session.load(p, scene, device="cpu")

    return Family("session", [path], load_s, text=True, fork=False)


# ----------------------------------------------------------------- mutations
_F32 = [float("nan"), float("inf"), -float("inf"), 3.4e38, -3.4e38, 1e-45, 0.0, -0.0, 1e30]
_U32 = [0, 0xFFFFFFFF, 0x7FFFFFFF, 0x80000000, 0x40000000, 1 << 24]
_JSON_BAD = [
    "1e400",
    "-1e400",
    "Infinity",
    "-Infinity",
    "NaN",
    "9" * 5000,
    "-1",
    "0",
    "1e300",
    "18446744073709551616",
    "null",
    "[]",
    "{}",
    "true",
    '"x"',
    '"' + "a" * 300 + '"',
    "[" * 5000 + "]" * 5000,
    '{"\u0663:0": []}',
    "[1e400, 1e400, 1e400]",
    "2.5",
    '"../../../../etc/passwd"',
    "[" + ",".join(["0"] * 4) + "]",
]


def _bytes_mutation(data: bytes, rng: random.Random) -> bytes:
    b = bytearray(data)
    op = rng.randrange(7)
    if not b:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64)))
    if op == 0:  # bit flips
        for _ in range(rng.choice((1, 1, 2, 4, 16))):
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
    elif op == 1:  # truncation
        return bytes(b[: rng.randrange(len(b))])
    elif op == 2:  # random bytes overwritten
        i = rng.randrange(len(b))
        for j in range(i, min(len(b), i + rng.randrange(1, 32))):
            b[j] = rng.randrange(256)
    elif op == 3:  # float32 extremes at aligned words
        for _ in range(rng.choice((1, 3, 20))):
            i = rng.randrange(max(1, len(b) // 4)) * 4
            b[i : i + 4] = struct.pack("<f", rng.choice(_F32))[: len(b) - i]
    elif op == 4:  # integer extremes anywhere (header fields, counts, offsets)
        i = rng.randrange(len(b))
        b[i : i + 4] = struct.pack("<I", rng.choice(_U32))
    elif op == 5:  # insert / delete a block
        i = rng.randrange(len(b))
        if rng.random() < 0.5:
            del b[i : i + rng.randrange(1, 64)]
        else:
            b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64)))
    else:  # duplicate a block
        i = rng.randrange(len(b))
        j = min(len(b), i + rng.randrange(1, 256))
        b[j:j] = b[i:j]
    return bytes(b)


_PLY_COUNTS = ["-5", "1000000000", "0", "4294967296", str(10**30)]


def _ply_header_mutation(data: bytes, rng: random.Random) -> bytes:
    end = data.find(b"end_header\n")
    if end < 0:
        return _bytes_mutation(data, rng)
    lines = data[:end].decode("latin-1").split("\n")[:-1]
    body = data[end + len(b"end_header\n") :]
    i = rng.randrange(1, len(lines))
    op = rng.randrange(8)
    if op == 0:
        lines.insert(i, lines[i])  # duplicate property / element line
    elif op == 1:
        lines = [
            re.sub(
                r"^(element \w+) \d+",
                lambda m: f"{m.group(1)} {rng.choice(_PLY_COUNTS)}",
                ln,
            )
            for ln in lines
        ]
    elif op == 2:
        lines[i] = re.sub(r"^property (\w+) ", "property list uchar \\1 ", lines[i])
    elif op == 3:
        lines[1] = rng.choice(
            [
                "format ascii 1.0",
                "format binary_big_endian 1.0",
                "format binary_little_endian 1.0",
                "format binary_little_endian 9.0",
            ]
        )
    elif op == 4:
        del lines[i]
    elif op == 5:
        lines[i] = re.sub(
            r"^property \w+ ",
            f"property {rng.choice(['double', 'uchar', 'int', 'short', 'float64', 'bogus'])} ",
            lines[i],
        )
    elif op == 6:
        lines.insert(
            i,
            rng.choice(
                [
                    "element face 3",
                    "property list uchar int vertex_indices",
                    "element vertex 2",
                    "comment x",
                    "obj_info y",
                ]
            ),
        )
    else:
        j = rng.randrange(1, len(lines))
        lines[i], lines[j] = lines[j], lines[i]
    return ("\n".join(lines) + "\nend_header\n").encode("latin-1") + body


def _json_mutation(data: bytes, rng: random.Random) -> bytes:
    try:
        doc = json.loads(data)
    except Exception:
        return _bytes_mutation(data, rng)
    slots: list[tuple[object, object]] = []

    def walk(node):
        if isinstance(node, dict):
            for k in list(node):
                slots.append((node, k))
                walk(node[k])
        elif isinstance(node, list):
            for k in range(len(node)):
                slots.append((node, k))
                walk(node[k])

    walk(doc)
    if not slots:
        return _bytes_mutation(data, rng)
    for _ in range(rng.choice((1, 1, 2, 3))):
        parent, key = rng.choice(slots)
        op = rng.random()
        if op < 0.12 and isinstance(parent, dict):
            parent.pop(key, None)
        elif op < 0.2 and isinstance(parent, dict):
            parent[rng.choice(["bogus", "\u0663:0", "0:\u00b2", "1:0", "w", "fl_x"])] = 1
        elif op < 0.28 and isinstance(parent, list):
            parent.extend([parent[key]] * rng.choice((1, 50, 2000)))
        else:
            parent[key] = "@@FUZZ@@"
    text = json.dumps(doc)
    while '"@@FUZZ@@"' in text:
        text = text.replace('"@@FUZZ@@"', rng.choice(_JSON_BAD), 1)
    return text.encode()


def mutate(data: bytes, rng: random.Random, text: bool) -> bytes:
    """One random mutation of ``data`` (text-aware when the family is text/JSON/PLY)."""
    if data.startswith(b"ply") and rng.random() < 0.5:
        return _ply_header_mutation(data, rng)
    if text and data[:1] in (b"{", b"[") and rng.random() < 0.7:
        return _json_mutation(data, rng)
    if text and data[:1] not in (b"{", b"[") and rng.random() < 0.3:  # COLMAP text lines
        lines = data.split(b"\n")
        i = rng.randrange(len(lines))
        toks = lines[i].split(b" ")
        j = rng.randrange(len(toks))
        toks[j] = rng.choice(
            [b"1e400", b"nan", b"-1", b"99999999999", b"inf", b"0", b"\xd9\xa3", b""]
        )
        lines[i] = b" ".join(toks)
        return b"\n".join(lines)
    if data[:2] == b"\x1f\x8b" and rng.random() < 0.4:  # mutate inside the gzip stream
        try:
            inner = gzip.decompress(data)
        except (OSError, EOFError, zlib.error):  # an earlier mutation broke the stream
            return _bytes_mutation(data, rng)
        return gzip.compress(_bytes_mutation(inner, rng), mtime=0)
    return _bytes_mutation(data, rng)


# ----------------------------------------------------------------- running a case
def _classify(load, check, path: Path) -> tuple[str, str]:
    from divas_engine.errors import DivasInputError

    try:
        res = load(path)
        why = check(res) if check else None
        return ("garbage", why) if why else ("ok", "")
    except DivasInputError as e:
        return "input", str(e)[:300]
    except MemoryError as e:
        return "memory", repr(e)[:300]
    except Exception as e:  # noqa: BLE001 - the point is to classify everything
        return "crash", f"{type(e).__name__}: {e}"[:300]


def _serve(families: dict[str, Family], mem_bytes: int, rfd: int, wfd: int) -> None:
    """Worker loop: read ``family\tpath`` lines, answer one JSON line per case."""
    import warnings

    warnings.simplefilter("ignore")  # overflow warnings of hostile values: noise here
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    try:
        with open("/proc/self/statm") as f:
            vm = int(f.read().split()[0]) * resource.getpagesize()
        resource.setrlimit(resource.RLIMIT_AS, (vm + mem_bytes, vm + mem_bytes))
    except (OSError, ValueError):
        pass
    rf = os.fdopen(rfd, "rb")
    while True:
        line = rf.readline()
        if not line:
            os._exit(0)
        name, path = line.decode().rstrip("\n").split("\t", 1)
        fam = families[name]
        msg = json.dumps(_classify(fam.load, fam.check, Path(path))).encode() + b"\n"
        os.write(wfd, msg)


class Worker:
    """A forked worker that runs many cases (a fork per case costs ~50 ms here) under
    ``RLIMIT_AS``; restarted after a hang (killed), a death, a ``MemoryError`` (the case
    is retried once in a fresh worker, whose address space has not grown) and every
    ``recycle`` cases."""

    def __init__(self, families: dict[str, Family], mem_bytes: int, recycle: int = 300):
        self.families, self.mem_bytes, self.recycle = families, mem_bytes, recycle
        self.pid: int | None = None
        self.served = 0

    def _start(self) -> None:
        r1, w1 = os.pipe()
        r2, w2 = os.pipe()
        pid = os.fork()
        if pid == 0:
            os.close(w1)
            os.close(r2)
            try:
                _serve(self.families, self.mem_bytes, r1, w2)
            finally:
                os._exit(1)
        os.close(r1)
        os.close(w2)
        self.pid, self.wfd, self.rfd, self.buf, self.served = pid, w1, r2, b"", 0

    def stop(self, kill: bool = False) -> int:
        if self.pid is None:
            return 0
        os.close(self.wfd)
        if kill:
            os.kill(self.pid, signal.SIGKILL)
        _, status = os.waitpid(self.pid, 0)
        os.close(self.rfd)
        self.pid = None
        return status

    def run(self, name: str, path: Path, timeout: float, retry: bool = True) -> tuple[str, str]:
        if self.pid is None or self.served >= self.recycle:
            self.stop()
            self._start()
        self.served += 1
        os.write(self.wfd, f"{name}\t{path}\n".encode())
        deadline = time.monotonic() + timeout
        while b"\n" not in self.buf:
            left = deadline - time.monotonic()
            if left <= 0:
                self.stop(kill=True)
                return "hang", f"no answer in {timeout:g} s"
            ready, _, _ = select.select([self.rfd], [], [], left)
            if not ready:
                continue
            chunk = os.read(self.rfd, 65536)
            if not chunk:  # the worker died
                status = self.stop()
                if os.WIFSIGNALED(status):
                    sig = os.WTERMSIG(status)
                    out = "memory" if sig == signal.SIGKILL else "crash"
                    return out, f"worker killed by signal {sig}"
                return "crash", f"worker exited with status {status}"
            self.buf += chunk
        line, self.buf = self.buf.split(b"\n", 1)
        out, detail = json.loads(line)
        if out == "memory":
            self.stop()
            if retry:
                return self.run(name, path, timeout, retry=False)
        return out, detail


class _Alarm(BaseException):
    pass


def _in_process(load, check, path: Path, timeout: float) -> tuple[str, str]:
    """One case in this process under a SIGALRM timeout (no memory limit)."""

    def ring(signum, frame):
        raise _Alarm()

    old = signal.signal(signal.SIGALRM, ring)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        return _classify(load, check, path)
    except _Alarm:
        return "hang", f"no answer in {timeout:g} s"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def run_case(
    load, check, path: Path, timeout: float, mem_bytes: int, fork: bool = True
) -> tuple[str, str]:
    """Load one file in a fresh worker (or in process); ``(outcome, detail)``."""
    if not fork:
        return _in_process(load, check, path, timeout)
    w = Worker({"case": Family("case", [path], load, check=check)}, mem_bytes)
    try:
        return w.run("case", path, timeout)
    finally:
        w.stop()


def make_case(fam: Family, k: int, seed: int, work: Path) -> Path:
    """Write case ``k`` of ``fam`` (deterministic in ``seed``) and return the path to load.

    The mutated file replaces the seed in a per-case copy of the seed's folder, so a
    family whose input is a folder (COLMAP, SOG folders, sessions) stays consistent.
    """
    rng = random.Random(f"{fam.name}:{seed}:{k}")
    src = rng.choice(fam.seeds)
    case_dir = work / "case"
    if case_dir.exists():
        shutil.rmtree(case_dir)
    shutil.copytree(src.parent, case_dir, symlinks=True)
    target = case_dir / src.name
    data = src.read_bytes()
    for _ in range(rng.choice((1, 1, 1, 2, 3))):
        data = mutate(data, rng, fam.text)
    target.write_bytes(data)
    return target


def run_family(
    fam: Family,
    n: int,
    seed: int,
    work: Path,
    *,
    timeout: float = 20.0,
    mem_bytes: int = 1536 << 20,
    on_case=None,
) -> dict[str, list]:
    """Run ``n`` cases of ``fam``: outcome -> list of (case, detail)."""
    res: dict[str, list] = {o: [] for o in OUTCOMES}
    worker = Worker({fam.name: fam}, mem_bytes) if fam.fork else None
    try:
        for k in range(n):
            path = make_case(fam, k, seed, work)
            if worker is None:
                out, detail = _in_process(fam.load, fam.check, path, timeout)
            else:
                out, detail = worker.run(fam.name, path, timeout)
            res[out].append((k, detail))
            if on_case:
                on_case(k, out, detail)
    finally:
        if worker is not None:
            worker.stop()
    return res
