"""What the farm and the local renderer need to know about an integrator, asked in one
place (so that it can come from the renderer's own registry)."""
from __future__ import annotations


def integrator_splats(name: str) -> bool:
    """Whether the integrator `name` splats light paths onto other tiles' pixels (light,
    bdpt). `auto` counts as splatting: it may resolve to bdpt, and the farm schedules a job
    before any worker has loaded the scene (the local renderer follows the same rule)."""
    return name in ("light", "bdpt", "auto")
