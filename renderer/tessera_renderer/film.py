"""Turning tile results into an image, for callers of the renderer: the splat
normalisation itself is written once, in tessera/splats.py, which the farm's merge uses
too. Which integrators splat is a capability in the core's registry
(tessera.integrators.splats), not a list here.
"""
from __future__ import annotations

from tessera.splats import new_splat_buffer, resolve_splats as resolve_image

__all__ = ["new_splat_buffer", "resolve_image"]
