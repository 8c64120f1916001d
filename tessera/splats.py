"""Turning tile results of a splatting integrator into an image: the one place the splat
normalisation is written, used by local renders (through tessera_renderer.film) and by
the farm's merge (through tessera.protocol).

An integrator that splats (tessera.integrators.splats) returns for each tile its own
pixels' camera-side estimate (`rgba`) and adds its light paths' camera connections,
wherever they land, to a full-frame int64 fixed-point buffer. Summing those buffers over
all tiles is exact and order-free, so any tiling on any number of machines gives the same
image. The image is

    rgba + splats * 2^e * pixel_count / (SPLAT_SCALE * light_paths)

with light_paths the total over all tiles (one per pixel sample) and e the scene's
splat_exponent (the fixed point's unit, from its lights' power).
"""
from __future__ import annotations

import math

import numpy as np

# The renderer's fixed-point splat scale (kSplatScale in renderer/core/splat_film.h);
# tests/test_protocol.py pins the two together.
SPLAT_SCALE = float(1 << 24)


def new_splat_buffer(width: int, height: int) -> np.ndarray:
    return np.zeros((height, width, 3), dtype=np.int64)


def resolve_splats(rgba: np.ndarray, splats: np.ndarray | None, light_paths: int,
                   exponent: int) -> np.ndarray:
    """Full-frame float32 RGBA from the camera part and the summed splats (in units of
    2^exponent: Scene.splat_exponent). Without splats or light paths, a copy of rgba."""
    out = np.array(rgba, dtype=np.float32, copy=True)
    if splats is not None and light_paths > 0:
        height, width = out.shape[:2]
        scale = math.ldexp(width * height / (SPLAT_SCALE * light_paths), exponent)
        out[..., :3] += (splats.astype(np.float64) * scale).astype(np.float32)
    return out
