"""SAM on the CPU: encoder time per view and decoder time per prompt.

Real-size architectures with random weights (speed does not depend on the weights):
ViT-B from ``segment-anything``, MobileSAM's TinyViT from its own package when it
imports (it needs ``timm`` → torchvision: run this with the venv ``make test-sam-full``
builds to get both side by side). For each model: the ONNX pair is written by
``export_onnx_pair`` (preprocessed encoder layout), then on one ``H×W`` view

* ``preprocess``: DivAS's resize + normalise + pad (``SamOnnxSegmenter.preprocess``);
* ``encode onnx``: ``SamOnnxSegmenter.set_image`` (preprocess + onnxruntime encoder);
* ``encode torch``: ``SamTorchSegmenter.set_image`` (same preprocessing, PyTorch encoder);
* ``decode onnx`` / ``decode torch``: ``predict`` with 1 and with 3 clicks (decoder plus
  upscaling to the view size and the sigmoid), the per-prompt cost of an interactive click.

Median of ``--repeats`` runs each, wall time and process CPU time (all threads: on an
idle machine wall ≈ CPU / threads used); peak RSS of the process. Wall times depend on
the machine's load: the models run in one process, one after the other, so ratios compare.

    .venv/bin/python benchmarks/bench_sam.py [--models vit_b,mobile_sam] [--size 768x1024]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from divas_engine.segment import SamOnnxSegmenter, SamTorchSegmenter  # noqa: E402
from divas_engine.segment.sam_export import export_onnx_pair  # noqa: E402
from divas_engine.segment.sam_models import build_sam_model  # noqa: E402
from divas_engine.segment.sam_upstream import sam_package  # noqa: E402


def _median(fn, repeats: int) -> tuple[float, float]:
    """Median wall time and median process CPU time (all threads) of ``fn``."""
    wall, cpu = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return statistics.median(wall), statistics.median(cpu)


def bench_model(model_type: str, hw: tuple[int, int], repeats: int, tmp: Path) -> dict:
    import torch

    torch.manual_seed(0)
    model = build_sam_model(model_type)
    params = sum(p.numel() for p in model.image_encoder.parameters()) / 1e6
    t = time.perf_counter()
    enc, dec = export_onnx_pair(model, tmp / model_type)
    export_s = time.perf_counter() - t
    rng = np.random.default_rng(0)
    rgb = (rng.uniform(0, 1, (*hw, 3)) * 255).astype(np.uint8)
    one = (np.array([[hw[1] * 0.4, hw[0] * 0.5]]), np.array([1]))
    three = (
        np.array([[hw[1] * 0.4, hw[0] * 0.5], [hw[1] * 0.6, hw[0] * 0.4], [10.0, 10.0]]),
        np.array([1, 1, 0]),
    )
    onnx_seg = SamOnnxSegmenter(enc, dec, cache_size=0)
    pkg = "mobile_sam" if model_type == "mobile_sam" else "segment_anything"
    torch_seg = SamTorchSegmenter.from_predictor(sam_package(pkg).SamPredictor(model), 0)
    rgbf = rgb.astype(np.float32) / 255
    row = {"model": model_type, "encoder params (M)": params, "export s": export_s}
    for name, fn in (
        ("preprocess", lambda: onnx_seg.preprocess(rgbf)),
        ("encode onnx", lambda: onnx_seg.set_image(rgb)),
        ("encode torch", lambda: torch_seg.set_image(rgb)),
    ):
        row[f"{name} s"], row[f"{name} cpu-s"] = _median(fn, repeats)
    onnx_seg.set_image(rgb)
    torch_seg.set_image(rgb)
    for name, (p, lab) in (("1 click", one), ("3 clicks", three)):
        onnx_seg.predict(p, lab)  # warm-up (session, upscale matrices)
        for back, seg in (("onnx", onnx_seg), ("torch", torch_seg)):
            wall, cpu = _median(lambda: seg.predict(p, lab), repeats)
            row[f"decode {back} {name} ms"], row[f"decode {back} {name} cpu-ms"] = (
                1e3 * wall,
                1e3 * cpu,
            )
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default="vit_b,mobile_sam")
    ap.add_argument("--size", default="768x1024", help="view HxW (default 768x1024)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    hw = tuple(int(x) for x in args.size.split("x"))
    import onnxruntime
    import torch

    print(
        f"torch {torch.__version__} ({torch.get_num_threads()} threads), onnxruntime "
        f"{onnxruntime.__version__}, {os.cpu_count()} CPUs, load {os.getloadavg()}, "
        f"view {hw[0]}x{hw[1]}, median of {args.repeats}"
    )
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for m in args.models.split(","):
            try:
                rows.append(bench_model(m, hw, args.repeats, Path(tmp)))
            except ImportError as e:
                print(f"{m}: not installed here ({e})")
                continue
            print(
                " ".join(
                    f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}"
                    for k, v in rows[-1].items()
                ),
                flush=True,
            )
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    print(f"load at the end {os.getloadavg()}, peak RSS {peak:.1f} GiB")
    if rows:
        keys = list(rows[0])
        print("| " + " | ".join(keys) + " |")
        print("|" + "---|" * len(keys))
        for r in rows:
            print(
                "| "
                + " | ".join(f"{r[k]:.2f}" if isinstance(r[k], float) else str(r[k]) for k in keys)
                + " |"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
