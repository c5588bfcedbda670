"""The one home of the renderers' default constants (paper Sec. 3.1, NOTES "Depth tuple").

:class:`~divas_kernels.RasterSettings`, :class:`~divas_kernels.MarchSettings`,
``divas_engine.render.RenderConfig`` and the mapping's near plane all take their
defaults from here, so a default changes in one place.
"""

from __future__ import annotations

import math

__all__ = [
    "TAU_SIG",
    "TAU_CW",
    "T_MIN",
    "ALPHA_MIN",
    "ALPHA_MAX",
    "LOWPASS_SIGMA",
    "NEAR",
    "TILE",
    "MAX_DUPLICATES",
    "BLEND",
    "NERF_STEP_SCALE",
]

#: τ_sig: ``D_min`` is the depth of the first element with weight ``w_k ≥ τ_sig``.
TAU_SIG = 0.05
#: τ_cw: ``D_max`` is where ``1 − T`` first reaches τ_cw (paper's NeRF table, 0.75).
TAU_CW = 0.75
#: Early termination once the transmittance ``T < T_MIN``.
T_MIN = 1e-4
#: α_min = 1/255: smaller opacities are skipped (2DGS) / not counted in ``N_samp``.
ALPHA_MIN = 1.0 / 255.0
#: 2DGS opacity clamp ``α = min(α_max, opacity · G)``.
ALPHA_MAX = 0.99
#: σ of the 2DGS screen-space low-pass Gaussian, pixels (√2/2).
LOWPASS_SIGMA = math.sqrt(0.5)
#: Near plane, planar camera depth in world units.
NEAR = 0.01
#: Rasterizer tile edge, pixels.
TILE = 16
#: Soft cap on (tile, surfel) pairs held at once (the image is rendered in bands above it).
MAX_DUPLICATES = 1 << 25
#: Blend kernel: ``"auto"`` (``tile`` on CPU, ``pixel`` on CUDA), ``"tile"`` or ``"pixel"``.
BLEND = "auto"
#: NeRF step = NERF_STEP_SCALE × the smallest voxel edge.
NERF_STEP_SCALE = 0.5
