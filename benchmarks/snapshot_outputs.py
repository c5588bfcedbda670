"""Bit-identity check across a refactor or an optimisation.

``snapshot`` writes renders (RGB + depth tuple), value renders, FlashSplat-style
contributions, session selections/overlays and ``divas segment`` labels of a few
synthetic scenes and real captures into one ``.npz``; ``compare`` reports every array
that differs between two snapshots (``np.array_equal``, NaN-aware: bit-identity).

    python benchmarks/snapshot_outputs.py snapshot OUT.npz
    python benchmarks/snapshot_outputs.py compare BEFORE.npz AFTER.npz
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = (
    ROOT / "tests/data/playcanvas-splats/biker.compressed.ply",
    ROOT / "tests/data/gaussiansplats3d-lod/lod3_tile_0.ply",
)


def _renders(out: dict, tag: str, scene, cams) -> None:
    from divas_engine.render import make_renderer

    r = make_renderer(scene, device="cpu")
    n = len(scene) if hasattr(scene, "means") else None
    for k, cam in enumerate(cams):
        b = r.render(cam)
        for ch, a in b.as_dict().items():
            out[f"{tag}/render{k}/{ch}"] = a
        if n is not None:
            v = np.random.default_rng(k).random(n, dtype=np.float32)
            out[f"{tag}/values{k}"] = r.render_values(cam, v)
            out[f"{tag}/values{k}_2ch"] = r.render_values(cam, np.stack([v, 1 - v], 1))
            half = r.render(cam, scale=0.25)
            out[f"{tag}/render{k}_quarter/D_med"] = half.D_med
            out[f"{tag}/render{k}_quarter/rgb"] = half.rgb
            _contrib(out, f"{tag}/contrib{k}", r, cam, b.D_med > np.median(b.D_med))


def _contrib(out: dict, tag: str, renderer, cam, mask) -> None:
    try:
        from divas_kernels import accumulate_contributions
    except ImportError:  # older checkouts do not export it from the package
        from divas_kernels.contrib import accumulate_contributions

    c = accumulate_contributions(
        renderer._buf,
        cam.w2c,
        cam.fx,
        cam.fy,
        cam.cx,
        cam.cy,
        cam.width,
        cam.height,
        mask,
        renderer.config.raster_settings(cam),
    )
    out[f"{tag}/a1"], out[f"{tag}/a0"] = c.a1.numpy(), c.a0.numpy()


def _session(out: dict, tag: str, scene, cameras, gt=None) -> None:
    """Open a session, click the centre-most surface pixel of anchor 0, accept twice."""
    from divas_engine.segment import ClassicSegmenter
    from divas_engine.segment.oracle import OracleSegmenter
    from divas_engine.session import Session, SessionConfig

    seg = OracleSegmenter() if gt is not None else ClassicSegmenter()
    s = Session.open(scene, cameras, SessionConfig(), seg, "cpu", gt_values=gt)
    a = s.anchors[0]
    b = a.buffers
    ys, xs = np.nonzero(b.alpha > 0.5)
    c = np.array([b.alpha.shape[1] / 2, b.alpha.shape[0] / 2])
    order = np.argsort((xs - c[0]) ** 2 + (ys - c[1]) ** 2)
    for k, j in enumerate(order[:: max(1, len(order) // 3)][:2]):
        v = s.click(0, (xs[j] + 0.5, ys[j] + 0.5))
        out[f"{tag}/view{k}/camera"] = v.camera.w2c
        out[f"{tag}/view{k}/D_med"] = v.buffers.D_med
        res = s.accept(v)
        out[f"{tag}/view{k}/selection"] = np.asarray(res.selection)
        if res.overlay is not None:
            out[f"{tag}/view{k}/overlay"] = res.overlay.image
            out[f"{tag}/view{k}/coverage"] = res.overlay.coverage
        if res.next_overlay is not None:
            out[f"{tag}/view{k}/next_overlay"] = res.next_overlay.image
    s.close()


def snapshot(path: Path) -> None:
    from divas_engine.cli.segment import segment_scene
    from divas_engine.evaluation import demo_prompts
    from divas_engine.io.load import load_scene
    from divas_engine.segment_request import SegmentRequest
    from divas_engine.session import anchor_plan
    from divas_engine.synthetic import generate_scene

    out: dict[str, np.ndarray] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, size in (("ribs", 30_000), ("plant", 60_000), ("occluded", 30_000)):
            d = Path(tmp) / name
            sc = generate_scene(name, d, size=size, seed=1)
            demo_prompts(sc.metadata, sc.cameras).write(d / "prompts.json")
            _renders(out, name, sc.scene, sc.cameras[:2])
            for seg in ("oracle", "classic"):
                rep, _ = segment_scene(
                    SegmentRequest(
                        d / "scene.ply",
                        d / "prompts.json",
                        cameras=d / "cameras.json",
                        out=d / f"{seg}.ply",
                        labels_out=d / f"{seg}.npy",
                        segmenter=seg,
                        gt_labels=d / "labels.npy",
                        device="cpu",
                    ),
                    progress=False,
                )
                out[f"{name}/segment_{seg}"] = np.load(d / f"{seg}.npy")
            gt = np.load(d / "labels.npy").astype(np.float32)
            _session(out, f"{name}/session", sc.scene, sc.cameras, gt)
            grid = d / "grid.npz"
            if grid.exists():
                g = load_scene(grid)
                _renders(out, f"{name}/nerf", g, sc.cameras[:1])
        for p in REAL:
            sc = load_scene(p)
            cams = [a.camera for a in anchor_plan(sc, []).anchors[:2]]
            _renders(out, p.stem, sc, cams)
            _session(out, f"{p.stem}/session", sc, [])
    np.savez_compressed(path, **out)
    print(f"{len(out)} arrays → {path}")


def compare(a: Path, b: Path) -> int:
    x, y = np.load(a), np.load(b)
    bad = 0
    for k in sorted(set(x.files) | set(y.files)):
        if k not in x.files or k not in y.files:
            print(f"MISSING {k}")
            bad += 1
        elif not np.array_equal(x[k], y[k], equal_nan=x[k].dtype.kind == "f"):
            d = np.abs(x[k].astype(np.float64) - y[k].astype(np.float64))
            print(f"DIFF {k}: {int((d > 0).sum())} elements, max |Δ| {d.max():.3g}")
            bad += 1
    print(f"{len(x.files)} arrays compared, {bad} differ")
    return 1 if bad else 0


if __name__ == "__main__":
    if sys.argv[1] == "snapshot":
        snapshot(Path(sys.argv[2]))
    else:
        sys.exit(compare(Path(sys.argv[2]), Path(sys.argv[3])))
