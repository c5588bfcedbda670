"""Ground truth on the shared real captures, made by rule (rules in :mod:`.real_target_defs`,
rule language in :mod:`.target_rules`).

Files (``tests/data/targets/<capture>/``): ``targets.json`` — the capture file and its SHA-256,
row count, true up and per target its kind, rule, eye check, label file and hand-placed oracle
anchors; ``<target>.npy`` — ``np.packbits`` of the label per *file row* (little bit order), so
the labels survive a loader that drops rows.

* :func:`capture_frame` — the up-aligned frame of a capture (azimuth 0 looks from +x);
* :func:`evaluation_cameras` — camera-free orbit cameras framed on the target (fill 0.65) at 8
  azimuths 22.5° + k·45° and elevations 20° and 45°, mostly-hidden views left out;
* :func:`oracle_anchors` — the hand-placed anchors with their clicks (640 × 480 pixels).

``python -m divas_engine.evaluation.real_targets write DATA_DIR`` regenerates the files.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..io.load import load_scene
from ..output_paths import save_npy_atomic, write_text_atomic
from ..scene import SurfelScene
from ..views import ViewConfig, framed_camera, scene_frame, scene_points, up_frame
from ..views.framing import SceneLayout, layout_from_points
from .real_target_defs import CAPTURES, CaptureDef, TargetDef
from .target_rules import evaluate_rule, gaussian_features

__all__ = [
    "TARGETS_VERSION",
    "capture_frame",
    "direction",
    "rule_labels",
    "scene_rows",
    "pack_labels",
    "unpack_labels",
    "sha256_file",
    "write_capture",
    "read_targets",
    "target_scene_labels",
    "target_dont_care",
    "capture_layout",
    "evaluation_cameras",
    "oracle_anchors",
    "ANCHOR_INTRINSICS",
]

TARGETS_VERSION = 1
TEST_AZIMUTHS = tuple(22.5 + 45.0 * k for k in range(8))
TEST_ELEVATIONS = (20.0, 45.0)
#: a test view must show at least this fraction of the target (:func:`evaluation_cameras`)
MIN_VISIBLE = 0.5
#: intrinsics of anchors and test views: the camera-free fallback (640 × 480, f = 600)
ANCHOR_INTRINSICS = Camera(640, 480, 600.0, 600.0, 320.0, 240.0)


def capture_frame(true_up) -> np.ndarray:
    """``[3,3]`` columns x, y, z = up of a capture's frame (module docstring)."""
    return up_frame(np.asarray(true_up, np.float64))


def direction(frame: np.ndarray, azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit world direction at azimuth/elevation (degrees) in ``frame``."""
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return frame @ np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


def rule_labels(scene: SurfelScene, rule: dict) -> np.ndarray:
    """``[scene.source.num_rows]`` bool: the rule per file row (dropped rows: False)."""
    per_gaussian = evaluate_rule(rule, gaussian_features(scene))
    src = scene.source
    if src is None:
        return per_gaussian
    out = np.zeros(src.num_rows, dtype=bool)
    out[src.kept_rows] = per_gaussian
    return out


def scene_rows(scene: SurfelScene, file_labels: np.ndarray) -> np.ndarray:
    """Per-Gaussian labels of the scene from per-file-row labels."""
    lab = np.asarray(file_labels, bool)
    return lab if scene.source is None else lab[scene.source.kept_rows]


def pack_labels(labels: np.ndarray) -> np.ndarray:
    return np.packbits(np.asarray(labels, bool), bitorder="little")


def unpack_labels(packed: np.ndarray, rows: int) -> np.ndarray:
    return np.unpackbits(np.asarray(packed, np.uint8), count=rows, bitorder="little").astype(bool)


def sha256_file(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _anchor_doc(target: TargetDef) -> list[dict]:
    return [
        {"azimuth": az, "elevation": el, "clicks": [list(c) for c in clicks]}
        for (az, el), clicks in target.anchors
    ]


def write_capture(capture: CaptureDef, data_dir: Path, out_dir: Path) -> dict:
    """Apply the capture's rules and write ``targets.json`` and the label files."""
    src = Path(data_dir) / capture.path
    scene = load_scene(src)
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = {
        "version": TARGETS_VERSION,
        "capture": capture.path,
        "capture_sha256": sha256_file(src),
        "rows": int(scene.source.num_rows),
        "true_up": list(capture.true_up),
        "true_up_note": capture.up_note,
        "frame": "x = world axis least aligned with true_up, z = true_up; azimuth 0 = +x",
        "evaluation_views": {"azimuths": list(TEST_AZIMUTHS), "elevations": list(TEST_ELEVATIONS)},
        "targets": {},
    }
    for t in capture.targets:
        labels = rule_labels(scene, t.rule)
        path = out_dir / f"{t.name}.npy"
        save_npy_atomic(path, pack_labels(labels))
        doc["targets"][t.name] = {
            "kind": t.kind,
            "description": t.description,
            "rule": t.rule,
            "check": t.check,
            "file": path.name,
            "count": int(labels.sum()),
            "sha256": sha256_file(path),
            "anchors": _anchor_doc(t),
        }
    text = json.dumps(doc, indent=1, ensure_ascii=False) + "\n"
    write_text_atomic(out_dir / "targets.json", text)
    return doc


def read_targets(capture_dir: Path) -> dict:
    """``targets.json`` of a capture folder, each target's ``labels`` (per file row) added."""
    d = Path(capture_dir)
    doc = json.loads((d / "targets.json").read_text())
    for t in doc["targets"].values():
        t["labels"] = unpack_labels(np.load(d / t["file"]), doc["rows"])
        if t.get("dont_care_file"):
            t["dont_care"] = unpack_labels(np.load(d / t["dont_care_file"]), doc["rows"])
    return doc


def target_scene_labels(scene: SurfelScene, doc: dict, name: str) -> np.ndarray:
    """Per-Gaussian labels of target ``name`` of a :func:`read_targets` document."""
    return scene_rows(scene, doc["targets"][name]["labels"])


def target_dont_care(scene: SurfelScene, doc: dict, name: str) -> np.ndarray | None:
    """Per-Gaussian don't-care marks of target ``name`` (Gaussians its rule cannot settle:
    left out of the scoring), or None when the target has none."""
    dc = doc["targets"][name].get("dont_care")
    return None if dc is None else scene_rows(scene, dc)


def capture_layout(scene: SurfelScene, true_up, config: ViewConfig | None = None) -> SceneLayout:
    """The camera-free layout of the whole capture with the true up (ground along it)."""
    fr = scene_frame(scene)
    pts, w = scene_points(scene)
    return layout_from_points(pts, w, fr.center, fr.radius, config, np.asarray(true_up, float))


def _target_layout(scene: SurfelScene, labels: np.ndarray, whole: SceneLayout) -> SceneLayout:
    pts = np.asarray(scene.means, np.float64)[labels]
    w = np.asarray(scene.opacities, np.float64)[labels]
    c = np.median(pts, axis=0)
    r = float(np.percentile(np.linalg.norm(pts - c, axis=1), 99.0))
    lay = layout_from_points(pts, w, c, r, None, whole.up.up)
    return dataclasses.replace(lay, floor=whole.floor)


def evaluation_cameras(
    scene: SurfelScene,
    labels: np.ndarray,
    true_up,
    *,
    min_visible: float = MIN_VISIBLE,
    device=None,
) -> list[Camera]:
    """Orbit test cameras around the target (module docstring), 640 × 480.

    A direction that would put the camera below the capture's ground is raised in 5°
    steps until it is above it. A view is kept only when the target is mostly in sight:
    its rendered label coverage (``render_values`` of the labels, so occluders count) is
    ≥ ``min_visible`` of the target's own accumulated opacity rendered alone (quarter
    resolution) — this drops views from behind an occluder or from inside other
    content (the biker's helmet seen through his legs)."""
    from ..render import make_renderer

    lab = np.asarray(labels, bool)
    whole = capture_layout(scene, true_up)
    lay = _target_layout(scene, lab, whole)
    frame = capture_frame(true_up)
    ren, alone = (
        make_renderer(scene, device=device),
        make_renderer(scene.subset(lab), device=device),
    )
    cams = []
    for el in TEST_ELEVATIONS:
        for az in TEST_AZIMUTHS:
            e = el
            while True:
                cam = framed_camera(lay, direction(frame, az, e), ANCHOR_INTRINSICS)
                if whole.floor is None or whole.height(cam.center) > 0 or e >= 85.0:
                    break
                e += 5.0
            seen = float(ren.render_values(cam, lab.astype(np.float32), 0.25).sum())
            full = float(alone.render(cam, 0.25).alpha.sum())
            if full > 0 and seen >= min_visible * full:
                cams.append(cam.with_pose(cam.c2w, f"test_az{az:g}_el{el:g}"))
    return cams


def oracle_anchors(
    scene: SurfelScene, true_up, anchors: list[dict]
) -> list[tuple[Camera, str, int, list[tuple[float, float]]]]:
    """``(camera, "camera", -1, clicks)`` per hand-placed anchor of a target (the
    :func:`~divas_engine.evaluation.pipeline.run_session` ``anchors`` form)."""
    whole = capture_layout(scene, true_up)
    frame = capture_frame(true_up)
    out = []
    for i, a in enumerate(anchors):
        d = direction(frame, a["azimuth"], a["elevation"])
        cam = framed_camera(whole, d, ANCHOR_INTRINSICS, name=f"hand_{i}")
        out.append((cam, "camera", -1, [tuple(map(float, c)) for c in a["clicks"]]))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m divas_engine.evaluation.real_targets")
    p.add_argument("command", choices=("write",))
    p.add_argument("data_dir", type=Path, help="tests/data")
    p.add_argument("--only", nargs="*", default=None, help="capture names")
    args = p.parse_args(argv)
    for name, cap in CAPTURES.items():
        if args.only and name not in args.only:
            continue
        doc = write_capture(cap, args.data_dir, args.data_dir / "targets" / name)
        counts = {k: v["count"] for k, v in doc["targets"].items()}
        print(f"{name}: {doc['rows']} rows, targets {counts}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
