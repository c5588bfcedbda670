"""``divas render SCENE CAMERA --out PREFIX``: RGB and the depth tuple of one view.

One camera, chosen by exactly one of:

* ``--cameras FILE --index I`` — entry ``I`` of a camera file/folder (any format
  ``load_cameras`` reads);
* ``--camera-json JSON`` — one camera in the ``Camera.to_dict()`` schema, as a JSON
  string or a file holding it;
* ``--orbit AZ,EL`` — degrees around the robust scene centre (median of the
  centres), at 2.5× their P90 radius, looking at the centre; 640×480, fx = 600.
  ``--up`` sets the world up (default ``0,-1,0``, the COLMAP/3DGS convention).

Writes ``PREFIX.png`` (RGB), ``PREFIX_<channel>.png`` (false colour, one shared
depth range across the depth channels, invalid pixels black; ``N_samp`` on its
own scale) and ``PREFIX.npz`` with every buffer under its NOTES name.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError
from ..output_paths import check_output_path, check_outputs, save_npz_atomic, write_image_atomic

__all__ = ["add_parser", "run", "orbit_camera", "parse_camera_json", "write_outputs"]

ORBIT_SIZE = (640, 480)
ORBIT_FX = 600.0
ORBIT_RADIUS = 2.5


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("render", help="render RGB + depth tuple of one view to PNG/NPZ")
    p.add_argument(
        "scene",
        type=Path,
        help="scene file (.ply, compressed .ply, .splat, .spz, .sog, NeRF .npz/.ingp/.msgpack/"
        ".pth/.vdb)",
    )
    cam = p.add_mutually_exclusive_group()
    cam.add_argument(
        "--cameras",
        type=Path,
        help="camera file or folder (use with --index; without it, --index picks one of "
        "the scene file's own cameras: an instant-ngp snapshot's)",
    )
    cam.add_argument(
        "--camera-json", help="one camera as JSON (Camera.to_dict schema) or a file with it"
    )
    cam.add_argument("--orbit", metavar="AZ,EL", help="orbit camera: azimuth,elevation in degrees")
    p.add_argument("--index", type=int, default=None, help="camera index in --cameras")
    p.add_argument("--up", default="0,-1,0", help="world up for --orbit (default 0,-1,0)")
    p.add_argument(
        "--out", type=Path, required=True, help="output prefix (PREFIX.png, PREFIX.npz, …)"
    )
    p.add_argument("--scale", type=float, default=1.0, help="image scale factor (default 1)")
    p.add_argument(
        "--device",
        default="auto",
        choices=("auto", "cpu", "cuda"),
        help="Warp device (auto: CUDA when available)",
    )
    p.set_defaults(func=run)


def _floats(text: str, n: int, what: str) -> np.ndarray:
    try:
        v = np.array([float(x) for x in text.split(",")], dtype=np.float64)
    except ValueError:
        v = np.zeros(0)
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise DivasInputError(None, f"{what} must be {n} comma-separated numbers, got {text!r}")
    return v


def parse_camera_json(text: str) -> Camera:
    """A camera from a JSON string or a file holding one ``Camera.to_dict()`` object."""
    src = None
    path = Path(text)
    try:
        is_file = len(text) < 4096 and path.is_file()
    except OSError:
        is_file = False
    if is_file:
        src = path
        try:
            text = path.read_text()
        except (OSError, UnicodeDecodeError) as e:
            raise DivasInputError(path, f"cannot read camera JSON ({e})") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise DivasInputError(src, f"--camera-json is not valid JSON ({e})") from None
    except (RecursionError, ValueError) as e:  # nested too deeply, an over-long integer
        raise DivasInputError(src, f"--camera-json is not readable JSON ({e})") from None
    if not isinstance(d, dict):
        raise DivasInputError(src, "--camera-json must be one JSON object (Camera.to_dict schema)")
    try:
        return Camera.from_dict(d)
    except (KeyError, TypeError, ValueError) as e:
        raise DivasInputError(src, f"bad camera in --camera-json: {e}") from None


def orbit_camera(scene, az_deg: float, el_deg: float, up=(0.0, -1.0, 0.0)) -> Camera:
    """640×480, fx = 600 camera at 2.5× the P90 radius around the robust centre."""
    from ..scene import DensityGrid
    from ..scene_stats import robust_frame

    if isinstance(scene, DensityGrid):
        D, H, W = scene.density.shape
        vox = scene.voxel_size
        idx = np.argwhere(scene.density > 0)
        if len(idx) == 0:
            raise DivasInputError(None, "--orbit: the density grid is empty")
        pts = scene.aabb[0] + (idx[:, ::-1] + 0.5) * vox
        frame = robust_frame(pts, weights=scene.density[scene.density > 0], percentile=90.0)
    else:
        if len(scene) == 0:
            raise DivasInputError(None, "--orbit: the scene has no primitives")
        frame = robust_frame(scene.means, percentile=90.0)
    up = np.asarray(up, np.float64)
    if np.linalg.norm(up) == 0:
        raise DivasInputError(None, "--up must be a non-zero vector")
    up = up / np.linalg.norm(up)
    # orthonormal frame around up: e1 = "front" (az = 0), e2 = right-handed side
    helper = np.array([0, 0, 1.0]) if abs(up[2]) < 0.9 else np.array([1.0, 0, 0])
    e1 = helper - up * (helper @ up)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    az, el = math.radians(az_deg), math.radians(el_deg)
    direction = math.cos(el) * (math.cos(az) * -e1 + math.sin(az) * e2) + math.sin(el) * up
    r = ORBIT_RADIUS * max(float(frame.radius), 1e-6)
    eye = np.asarray(frame.center, np.float64) + r * direction
    w, h = ORBIT_SIZE
    return Camera.look_at(
        eye, frame.center, up, width=w, height=h, fx=ORBIT_FX, name=f"orbit_{az_deg:g}_{el_deg:g}"
    )


def _colorize(v: np.ndarray, valid: np.ndarray, lo: float, hi: float) -> np.ndarray:
    import cv2

    t = np.clip((v - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    img = cv2.applyColorMap((t * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    img[~valid] = 0
    return img


def output_paths(prefix: Path) -> list[Path]:
    """The files :func:`write_outputs` writes for ``prefix``."""
    from ..render import DEPTH_CHANNELS

    prefix = Path(prefix)
    names = [".png", *(f"_{c}.png" for c in DEPTH_CHANNELS), "_N_samp.png", ".npz"]
    return [prefix.with_name(prefix.name + n) for n in names]


def check_render_outputs(prefix: Path, inputs) -> None:
    """Pre-flight of ``--out PREFIX`` (before loading): its folder may be created; every
    file it names must be writable and none may be an input."""
    prefix = Path(prefix)
    check_output_path(prefix.parent, what="--out folder", folder=True)
    if prefix.parent.is_dir():
        check_outputs([("--out", p) for p in output_paths(prefix)], inputs)


def write_outputs(buffers, prefix: Path) -> list[Path]:
    """Write ``PREFIX.png``, ``PREFIX_<channel>.png`` and ``PREFIX.npz`` (each atomically);
    returns the paths."""
    from ..render import DEPTH_CHANNELS

    prefix = Path(prefix)
    prefix.parent.mkdir(parents=True, exist_ok=True)
    written = []
    rgb = (np.clip(buffers.rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    p = prefix.with_name(prefix.name + ".png")
    write_image_atomic(p, rgb[:, :, ::-1])
    written.append(p)
    depths = [getattr(buffers, c) for c in DEPTH_CHANNELS]
    allv = np.concatenate([d[d > 0] for d in depths])
    lo, hi = np.percentile(allv, [1, 99]) if allv.size else (0.0, 1.0)
    for name, d in zip(DEPTH_CHANNELS, depths):
        p = prefix.with_name(f"{prefix.name}_{name}.png")
        write_image_atomic(p, _colorize(d, d > 0, float(lo), float(hi)))
        written.append(p)
    ns = buffers.N_samp
    p = prefix.with_name(f"{prefix.name}_N_samp.png")
    write_image_atomic(p, _colorize(ns.astype(np.float32), ns > 0, 0.0, float(max(ns.max(), 1))))
    written.append(p)
    p = prefix.with_name(prefix.name + ".npz")
    save_npz_atomic(p, **buffers.as_dict())
    written.append(p)
    return written


def _pick_camera(args, scene) -> Camera:
    if args.orbit is not None:
        az, el = _floats(args.orbit, 2, "--orbit")
        return orbit_camera(scene, az, el, _floats(args.up, 3, "--up"))
    if args.camera_json is not None:
        return parse_camera_json(args.camera_json)
    from ..io.cameras import load_cameras
    from ..io.load import scene_cameras

    if args.cameras is None:
        cams = scene_cameras(scene)
        if not cams or args.index is None:
            raise DivasInputError(
                args.scene,
                "give a camera: --cameras FILE --index I, --camera-json or --orbit"
                + (f" (or --index 0..{len(cams) - 1}: the file's own cameras)" if cams else ""),
            )
        if not 0 <= args.index < len(cams):
            raise DivasInputError(
                args.scene, f"camera index {args.index} out of 0..{len(cams) - 1}"
            )
        return cams[args.index]
    cams = load_cameras(args.cameras)
    if args.index is None:
        raise DivasInputError(args.cameras, f"--cameras needs --index (0..{len(cams) - 1})")
    if not 0 <= args.index < len(cams):
        raise DivasInputError(
            args.cameras,
            f"camera index {args.index} out of range: the file "
            f"has {len(cams)} camera(s) (0..{len(cams) - 1})",
        )
    return cams[args.index]


def run(args: argparse.Namespace) -> int:
    from .. import load_scene
    from ..render import make_renderer

    if args.index is not None and (args.camera_json is not None or args.orbit is not None):
        raise DivasInputError(None, "--index only applies to --cameras or the scene's cameras")
    if not (math.isfinite(args.scale) and args.scale > 0):
        raise DivasInputError(None, f"--scale must be positive, got {args.scale}")
    check_render_outputs(args.out, [args.scene, args.cameras])
    scene = load_scene(args.scene)
    camera = _pick_camera(args, scene)
    if args.device == "cuda":
        from divas_kernels import cuda_device_count

        if cuda_device_count() == 0:
            raise DivasInputError(None, "--device cuda: no CUDA device available")
    renderer = make_renderer(scene, device=args.device)
    t0 = time.perf_counter()
    buf = renderer.render(camera, scale=args.scale)
    dt = time.perf_counter() - t0
    paths = write_outputs(buf, args.out)
    h, w = buf.shape
    print(
        f"rendered {args.scene.name} ({renderer.kind}, {w}x{h}, device {renderer.device}) in "
        f"{dt:.3f} s; coverage {float((buf.alpha > 0.5).mean()):.1%}"
    )
    for p in paths:
        print(f"  {p}")
    return 0
