"""The metrics users feel: weighted IoU, PSNR, alpha fidelity and the
extracted-object PSNR on hand-computed cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from divas_engine.camera import Camera
from divas_engine.evaluation.fidelity import FidelityEvaluator, psnr, weighted_iou
from divas_engine.scene import SurfelScene

CPU = "cpu"


def _square(cx: float, z: float, opacity: float, colour: float, n: int = 12) -> dict:
    """A 1×1 square of camera-facing surfels centred at (cx, 0, z)."""
    g = np.arange(-0.5 + 0.5 / n, 0.5, 1.0 / n)
    xs, ys = np.meshgrid(g + cx, g)
    k = xs.size
    return {
        "means": np.stack([xs.ravel(), ys.ravel(), np.full(k, z)], 1),
        "scales": np.full((k, 2), 0.6 / n),
        "opacities": np.full(k, opacity),
        "colour": np.full(k, colour),
    }


def _scene(*parts) -> SurfelScene:
    means = np.concatenate([p["means"] for p in parts]).astype(np.float32)
    n = len(means)
    c = np.concatenate([p["colour"] for p in parts])
    sh = np.repeat(((c - 0.5) / 0.28209479177387814)[:, None, None], 3, axis=2)
    return SurfelScene(
        means,
        np.tile([1.0, 0, 0, 0], (n, 1)).astype(np.float32),
        np.concatenate([p["scales"] for p in parts]).astype(np.float32),
        np.concatenate([p["opacities"] for p in parts]).astype(np.float32),
        sh.astype(np.float32),
        0,
    )


def _cam() -> Camera:
    return Camera(96, 64, 60.0, 60.0, 48.0, 32.0, np.eye(4), "front")


def test_weighted_iou_and_psnr_by_hand():
    s = np.array([1, 1, 0, 0], bool)
    g = np.array([0, 1, 1, 0], bool)
    w = np.array([1.0, 2.0, 3.0, 4.0])
    assert weighted_iou(s, g, w) == pytest.approx(2.0 / 6.0)
    assert weighted_iou(np.zeros(2, bool), np.zeros(2, bool), np.ones(2)) == 1.0
    assert psnr(0.0, 10) == math.inf
    assert psnr(0.01 * 4, 4) == pytest.approx(20.0)  # MSE 0.01 → 20 dB
    with pytest.raises(ValueError):
        weighted_iou(s, g, w[:3])


def test_alpha_fidelity_and_psnr_two_identical_squares():
    """Two identical opaque squares side by side: selecting one of them captures
    exactly half of the true weight inside the silhouette; the selection equal to the
    truth renders like the scene (PSNR ∞ when nothing else is in the scene)."""
    a = _square(-0.75, 4.0, 0.95, 0.8)
    b = _square(0.75, 4.0, 0.95, 0.8)
    scene = _scene(a, b)
    n = len(a["means"])
    gt = np.ones(len(scene), bool)
    half = np.zeros(len(scene), bool)
    half[:n] = True
    ev = FidelityEvaluator(scene, [_cam()], gt, device=CPU)
    r = ev.score({"all": gt, "half": half, "none": np.zeros_like(gt)})
    assert r["all"]["alpha_fidelity"] == pytest.approx(1.0)
    assert r["half"]["alpha_fidelity"] == pytest.approx(0.5, abs=1e-6)
    assert r["none"]["alpha_fidelity"] == 0.0
    assert r["all"]["psnr"] == math.inf and r["all"]["psnr_ceiling"] == math.inf
    assert r["half"]["opacity_weighted_iou"] == pytest.approx(0.5)
    # half: the missing square renders black where the scene shows colour 0.8 (its
    # silhouette pixels are half of the true silhouette): MSE = 0.5 · (0.8)² exactly up
    # to the edge pixels' partial coverage, which is the same for both squares
    sil = ev.sil[0]
    rgb = ev.rgb[0]
    left = np.zeros_like(sil)
    left[:, :48] = True
    miss = rgb[~left[sil]]
    expect = psnr(float((miss**2).sum()), rgb.size)
    assert r["half"]["psnr"] == pytest.approx(expect, rel=1e-6)


def test_alpha_fidelity_counts_what_the_scene_shows():
    """A translucent front square over an opaque back square, both true: leaving the
    back one out keeps the front one's weight only — α_f · 1 of α_f + (1 − α_f) α_b."""
    front = _square(0.0, 4.0, 0.4, 0.8)
    back = _square(0.0, 5.0, 0.95, 0.3)
    scene = _scene(front, back)
    n = len(front["means"])
    gt = np.ones(len(scene), bool)
    sel = np.zeros(len(scene), bool)
    sel[:n] = True
    ev = FidelityEvaluator(scene, [_cam()], gt, device=CPU)
    r = ev.score({"front": sel})["front"]
    # per pixel in the interior: w_front = 0.4·G-sum… measured through the renderer's own
    # weights; the ratio must equal the front's share of the total accumulated opacity
    vals = np.stack([gt, sel], 1).astype(np.float32)
    img = ev.renderer.render_values(_cam(), vals)[ev.sil[0]]
    assert r["alpha_fidelity"] == pytest.approx(img[:, 1].sum() / img[:, 0].sum(), rel=1e-6)
    assert 0.4 < r["alpha_fidelity"] < 0.8
    assert r["opacity_weighted_iou"] == pytest.approx(0.4 / (0.4 + 0.95), rel=1e-6)
    # the truth alone equals the scene here (nothing else in it)
    assert r["psnr_ceiling"] == math.inf and r["psnr_vs_truth"] == pytest.approx(r["psnr"])


def test_flashsplat_background_bias_by_hand():
    """FlashSplat's rule on the L2-normalised pair: A₁ − A₀ > γ √(A₀² + A₁²)."""
    from divas_engine.evaluation.baselines import flashsplat_foreground

    a1 = np.array([3.0, 3.0, 1.0, 0.0, 2.0])
    a0 = np.array([1.0, 1.0, 1.0, 0.0, 0.0])
    # 2 > 0.5·√10 = 1.58 yes; 2 > 0.7·√10 = 2.21 no; tie no; no weight no; 2 > γ·2
    assert flashsplat_foreground(a1, a0, 0.5).tolist() == [True, True, False, False, True]
    assert flashsplat_foreground(a1, a0, 0.7).tolist() == [False, False, False, False, True]
    assert flashsplat_foreground(a1, a0, 0.0).tolist() == [True, True, False, False, True]
    assert flashsplat_foreground(a1, a0, -0.5)[2]  # a negative bias favours the object
