"""``divas sam-export CHECKPOINT --model-type T --out DIR``: an official SAM checkpoint
→ the ONNX encoder/decoder pair ``--segmenter sam-onnx`` and the add-on use.

Needs the ``torch`` extra (``pip install -e ".[torch]"``); the pair it writes does not.
The export is checked by one prediction through the pair and through the PyTorch
model (:func:`divas_engine.segment.sam_export.convert_checkpoint`); the two paths
are printed last, one per line.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import DivasInputError
from ..output_paths import check_output_path


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sam-export",
        help="convert an official SAM / MobileSAM checkpoint to the ONNX pair sam-onnx uses",
    )
    p.add_argument("checkpoint", type=Path, help="sam_vit_{b,l,h}_*.pth or mobile_sam.pt")
    p.add_argument(
        "--model-type",
        required=True,
        choices=("vit_b", "vit_l", "vit_h", "mobile_sam"),
        help="the checkpoint's model (a mismatch is reported with the type it holds)",
    )
    p.add_argument("--out", type=Path, required=True, help="folder for the two .onnx files")
    p.add_argument(
        "--encoder-layout",
        choices=("preprocessed", "raw"),
        default="preprocessed",
        help="encoder input: preprocessed [1,3,1024,1024] (default) or the raw resized "
        "image [h,w,3] with normalisation and padding inside the graph",
    )
    p.add_argument(
        "--no-check",
        action="store_true",
        help="skip the check prediction against the PyTorch model",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        from ..segment.sam_export import convert_checkpoint
        from ..segment.sam_models import import_torch

        import_torch("divas sam-export")
        if args.out.exists() and not args.out.is_dir():
            raise DivasInputError(args.out, "--out must be a folder")
        check_output_path(args.out, what="--out", folder=True)
        print(f"converting {args.checkpoint} ({args.model_type}) …", flush=True)
        result = convert_checkpoint(
            args.checkpoint,
            args.model_type,
            args.out,
            layout=args.encoder_layout,
            check=not args.no_check,
        )
    except ImportError as e:
        raise DivasInputError(None, str(e)) from None
    c = result.check
    if c is not None:
        print(
            f"check on a {c.image_hw[1]}x{c.image_hw[0]} picture: scores ONNX "
            f"{', '.join(f'{s:.3f}' for s in c.onnx_scores)} vs PyTorch "
            f"{', '.join(f'{s:.3f}' for s in c.torch_scores)} (max diff "
            f"{c.max_score_diff:.2e}), mask IoU {c.mask_iou:.4f}; encoder "
            f"{c.onnx_encode_s:.1f} s ONNX / {c.torch_encode_s:.1f} s PyTorch"
        )
    print(result.encoder)
    print(result.decoder)
    return 0
