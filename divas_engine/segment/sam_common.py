"""SAM pre-/post-processing shared by the ONNX and PyTorch back ends (own implementation).

Image: resize the longest side to ``S = 1024`` (new size ``int(x + 0.5)``, like
segment-anything's ``ResizeLongestSide``) with an antialiased bilinear filter, kept in float;
normalise with mean ``(123.675, 116.28, 103.53)`` / std ``(58.395, 57.12, 57.375)`` on the
0..255 scale; zero-pad bottom/right to ``S×S`` after normalisation.

Prompt coordinates: SAM's prompt encoder adds ``0.5`` to every input point, i.e. reads it as a
pixel index of the resized frame. Our points are continuous (pixel centre at ``+0.5``) and a
position ``u`` sits at ``u · s`` in the resized frame (``s = new_w / W`` per axis), so the
decoder sees ``x_sam = u · s − 0.5``. The padding point added when there is no box is
``(0, 0)`` with label ``−1``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy import sparse

__all__ = [
    "SAM_PIXEL_MEAN",
    "SAM_PIXEL_STD",
    "SAM_IMAGE_SIZE",
    "SAM_CACHE_VIEWS",
    "preprocess_shape",
    "resize_antialiased",
    "resize_longest_side",
    "normalize_pad",
    "sam_point_coords",
    "decoder_prompts",
    "upscale_low_res_masks",
    "sigmoid",
]

#: SAM's normalisation on the 0..255 scale (segment-anything ``Sam.pixel_mean/std``).
SAM_PIXEL_MEAN = np.array([123.675, 116.28, 103.53], dtype=np.float32)
SAM_PIXEL_STD = np.array([58.395, 57.12, 57.375], dtype=np.float32)
#: Encoder input side S.
SAM_IMAGE_SIZE = 1024
#: Views whose image embeddings a SAM segmenter keeps (4 MiB each): every view of an
#: object within the paper's view budget (≤ 20), so a click that corrects a fused view
#: runs the decoder only.
SAM_CACHE_VIEWS = 20


def preprocess_shape(h: int, w: int, long_side: int = SAM_IMAGE_SIZE) -> tuple[int, int]:
    """``(new_h, new_w)`` with the longest side ``long_side`` (rounded half up)."""
    scale = long_side * 1.0 / max(h, w)
    return int(h * scale + 0.5), int(w * scale + 0.5)


def _triangle_weights(n_in: int, n_out: int) -> sparse.csr_matrix:
    """``[n_out, n_in]`` row-normalised antialiased bilinear weights (half-pixel centres)."""
    scale = n_in / n_out
    support = max(scale, 1.0)  # triangle half-width in input pixels
    centres = (np.arange(n_out) + 0.5) * scale
    lo = np.floor(centres - support).astype(np.int64)
    taps = int(np.ceil(2 * support)) + 2
    j = lo[:, None] + np.arange(taps)[None, :]
    w = np.maximum(0.0, 1.0 - np.abs((j + 0.5 - centres[:, None]) / support))
    w[(j < 0) | (j >= n_in)] = 0.0  # out-of-range taps dropped, row renormalised (PIL/torch)
    w /= np.maximum(w.sum(axis=1, keepdims=True), 1e-12)
    rows = np.repeat(np.arange(n_out), taps)
    keep = w.reshape(-1) > 0
    return sparse.csr_matrix(
        (w.reshape(-1)[keep], (rows[keep], np.clip(j, 0, n_in - 1).reshape(-1)[keep])),
        shape=(n_out, n_in),
    )


def resize_antialiased(img: np.ndarray, out_hw: tuple[int, int]) -> np.ndarray:
    """Separable antialiased bilinear resize of ``[H,W,C]`` float to ``[h,w,C]`` float32."""
    h_in, w_in, c = img.shape
    h_out, w_out = out_hw
    a = np.asarray(img, dtype=np.float64)
    if h_out != h_in:
        a = (_triangle_weights(h_in, h_out) @ a.reshape(h_in, w_in * c)).reshape(h_out, w_in, c)
    if w_out != w_in:
        t = a.transpose(1, 0, 2).reshape(w_in, h_out * c)
        a = (_triangle_weights(w_in, w_out) @ t).reshape(w_out, h_out, c).transpose(1, 0, 2)
    return np.ascontiguousarray(a, dtype=np.float32)


def resize_longest_side(rgb01: np.ndarray, long_side: int = SAM_IMAGE_SIZE) -> np.ndarray:
    """``[h,w,3]`` float32 on the 0..255 scale, longest side ``long_side``."""
    h, w = rgb01.shape[:2]
    return resize_antialiased(rgb01 * np.float32(255.0), preprocess_shape(h, w, long_side))


def normalize_pad(resized255: np.ndarray, size: int = SAM_IMAGE_SIZE) -> np.ndarray:
    """``[1,3,size,size]`` float32: ``(x − mean) / std``, zero-padded bottom/right."""
    h, w = resized255.shape[:2]
    out = np.zeros((1, 3, size, size), dtype=np.float32)
    out[0, :, :h, :w] = ((resized255 - SAM_PIXEL_MEAN) / SAM_PIXEL_STD).transpose(2, 0, 1)
    return out


def sam_point_coords(
    points: np.ndarray, orig_hw: tuple[int, int], long_side: int = SAM_IMAGE_SIZE
) -> np.ndarray:
    """Our continuous points ``[P,2]`` → SAM decoder coordinates ``u · s − 0.5`` (module doc)."""
    h, w = orig_hw
    new_h, new_w = preprocess_shape(h, w, long_side)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return np.stack([pts[:, 0] * (new_w / w) - 0.5, pts[:, 1] * (new_h / h) - 0.5], axis=1)


def decoder_prompts(
    points: np.ndarray,
    labels: np.ndarray,
    orig_hw: tuple[int, int],
    long_side: int = SAM_IMAGE_SIZE,
) -> tuple[np.ndarray, np.ndarray]:
    """ONNX decoder ``point_coords [1,P+1,2]``, ``point_labels [1,P+1]`` (padding point too)."""
    coords = np.concatenate(
        [sam_point_coords(points, orig_hw, long_side), np.zeros((1, 2))], axis=0
    )
    labs = np.concatenate([np.asarray(labels, dtype=np.float64).reshape(-1), [-1.0]])
    return coords[None].astype(np.float32), labs[None].astype(np.float32)


def _linear_weights(n_in: int, n_out: int) -> np.ndarray:
    """``[n_out, n_in]`` bilinear weights, half-pixel centres, no antialiasing.

    PyTorch's ``F.interpolate(mode="bilinear", align_corners=False)`` rule: source
    ``(i + 0.5)·n_in/n_out − 0.5`` clamped at 0, the upper neighbour clamped at the edge.
    """
    src = np.maximum((np.arange(n_out) + 0.5) * (n_in / n_out) - 0.5, 0.0)
    i0 = np.minimum(np.floor(src).astype(np.int64), n_in - 1)
    i1 = np.minimum(i0 + 1, n_in - 1)
    lam = src - i0
    w = np.zeros((n_out, n_in))
    rows = np.arange(n_out)
    w[rows, i0] = 1.0 - lam
    w[rows, i1] += lam  # i1 == i0 at the last row: the weights still sum to 1
    return w


@lru_cache(maxsize=16)
def _upscale_matrices(
    orig_hw: tuple[int, int], low_hw: tuple[int, int], long_side: int
) -> tuple[np.ndarray, np.ndarray]:
    h, w = orig_hw
    new_h, new_w = preprocess_shape(h, w, long_side)
    a = _linear_weights(new_h, h) @ _linear_weights(low_hw[0], long_side)[:new_h]
    b = _linear_weights(new_w, w) @ _linear_weights(low_hw[1], long_side)[:new_w]
    return a.astype(np.float32), np.ascontiguousarray(b.T, dtype=np.float32)


def upscale_low_res_masks(
    low_res: np.ndarray, orig_hw: tuple[int, int], long_side: int = SAM_IMAGE_SIZE
) -> np.ndarray:
    """Decoder logits ``[C,h,w]`` (``low_res_masks``, 256²) → ``[C,H,W]`` at the image size.

    SAM's ``postprocess_masks``: bilinear up to ``S×S``, crop the padding away (keep the
    resized ``new_h × new_w``), bilinear to ``H×W`` — here as one ``[H,h]`` and one
    ``[W,w]`` matrix, so ``masks = A · low · Bᵀ``. Used instead of the decoder's own
    ``masks`` output: segment-anything 1.0's ``SamOnnxModel`` casts the crop size to a
    Python int, which the exporter freezes at the export dummy's size (1500×2250), so
    every decoder exported with that release crops wrongly for other aspect ratios.
    """
    low = np.asarray(low_res, dtype=np.float32)
    a, bt = _upscale_matrices(tuple(orig_hw), low.shape[-2:], int(long_side))
    return np.matmul(a, low @ bt)


def sigmoid(x: np.ndarray) -> np.ndarray:
    """Numerically stable float32 logistic function."""
    x = np.asarray(x, dtype=np.float32)
    e = np.exp(-np.abs(x))
    return np.where(x >= 0, 1.0 / (1.0 + e), e / (1.0 + e)).astype(np.float32)
