"""Real SAM architectures with random weights, and segment-anything's own predictor as
the reference the DivAS segmenters are compared with.

Nothing is downloaded: the models are built from the family's package
(``segment-anything``'s ``ImageEncoderViT``, ``PromptEncoder``, ``MaskDecoder``) and
seeded. :func:`tiny_sam` is the CI size: the ViT at width 64 and depth 2 keeps the
official graph structure (patch embedding, absolute and relative position terms, one
windowed block and one global-attention block, the neck) while the prompt encoder and
mask decoder are the official ones, full size.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from divas_engine.segment.sam_upstream import sam_package


def tiny_sam(seed: int = 0, iou_bias: float = 0.0):
    """A seeded ``Sam`` with a reduced ViT (module docstring).

    ``iou_bias`` is added to the IoU head's output bias: random weights predict scores
    near 0, below DivAS's 0.5 view acceptance, so an end-to-end run sets it to accept views.
    """
    import torch

    sam_package()  # segment-anything without torchvision (divas_engine.segment.sam_upstream)
    from segment_anything.modeling import (
        ImageEncoderViT,
        MaskDecoder,
        PromptEncoder,
        Sam,
        TwoWayTransformer,
    )

    torch.manual_seed(seed)
    enc = ImageEncoderViT(
        depth=2,
        embed_dim=64,
        img_size=1024,
        mlp_ratio=4,
        norm_layer=partial(torch.nn.LayerNorm, eps=1e-6),
        num_heads=2,
        patch_size=16,
        qkv_bias=True,
        use_rel_pos=True,
        global_attn_indexes=(1,),
        window_size=14,
        out_chans=256,
    )
    sam = Sam(
        image_encoder=enc,
        prompt_encoder=PromptEncoder(
            embed_dim=256,
            image_embedding_size=(64, 64),
            input_image_size=(1024, 1024),
            mask_in_chans=16,
        ),
        mask_decoder=MaskDecoder(
            num_multimask_outputs=3,
            transformer=TwoWayTransformer(depth=2, embedding_dim=256, mlp_dim=2048, num_heads=8),
            transformer_dim=256,
            iou_head_depth=3,
            iou_head_hidden_dim=256,
        ),
        pixel_mean=[123.675, 116.28, 103.53],
        pixel_std=[58.395, 57.12, 57.375],
    )
    with torch.no_grad():
        # random init leaves rel-pos tables at 0; fill them so the term is exercised
        for name, p in sam.image_encoder.named_parameters():
            if "rel_pos" in name:
                p.normal_(0, 0.02)
        sam.mask_decoder.iou_prediction_head.layers[-1].bias += iou_bias
    return sam.eval()


def reference_predict(
    sam, rgb8: np.ndarray, points: np.ndarray, labels: np.ndarray, package="segment_anything"
):
    """segment-anything's ``SamPredictor`` on the same image and clicks.

    Independent of DivAS's preprocessing: the image is resized by PyTorch's
    antialiased bilinear ``F.interpolate`` to ``ResizeLongestSide.get_preprocess_shape``
    and handed to ``set_torch_image`` (normalise, pad, encode: the package's code);
    the clicks go through ``predict`` → ``ResizeLongestSide.apply_coords``. DivAS's
    continuous point ``u`` is SAM's pixel index ``u − 0.5/s`` (``sam_common`` docstring).

    ``package``: the family's package (``mobile_sam`` for MobileSAM).

    Returns logits ``[3,H,W]``, scores ``[3]``, the image embedding ``[1,256,64,64]``.
    """
    import torch
    import torch.nn.functional as F

    pred = sam_package(package).SamPredictor(sam)
    h, w = rgb8.shape[:2]
    new_h, new_w = pred.transform.get_preprocess_shape(h, w, sam.image_encoder.img_size)
    img = torch.from_numpy(rgb8.astype(np.float32).transpose(2, 0, 1))[None]
    img = F.interpolate(img, (new_h, new_w), mode="bilinear", align_corners=False, antialias=True)
    with torch.no_grad():
        pred.set_torch_image(img, (h, w))
    s = np.array([new_w / w, new_h / h])
    sam_points = np.asarray(points, np.float64) - 0.5 / s
    masks, scores, _ = pred.predict(
        sam_points, np.asarray(labels), multimask_output=True, return_logits=True
    )
    return masks, scores, pred.features.numpy()


def sample_picture(h: int, w: int, seed: int = 0) -> np.ndarray:
    """A smooth picture with two coloured discs, uint8 ``[h,w,3]``."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32) + 0.5
    img = np.stack([xx / w, yy / h, 0.5 + 0.3 * np.sin(xx / 17.0)], -1)
    for _ in range(2):
        cx, cy, r = rng.uniform(0.2, 0.8) * w, rng.uniform(0.2, 0.8) * h, 0.2 * min(h, w)
        img[(xx - cx) ** 2 + (yy - cy) ** 2 < r * r] = rng.uniform(0, 1, 3)
    return np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)
