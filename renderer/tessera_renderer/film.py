"""The renderer's side of splats: a tile rendered by a splatting integrator adds its light
paths' camera connections, wherever they land, to a full-frame int64 fixed-point buffer
(`new_splat_buffer`); summing those buffers over tiles is exact and order-free. Turning
them into an image (the splat normalisation) is written once, in tessera_base.film.resolve_splats.
"""
from __future__ import annotations

import numpy as np



def new_splat_buffer(width: int, height: int) -> np.ndarray:
    return np.zeros((height, width, 3), dtype=np.int64)
