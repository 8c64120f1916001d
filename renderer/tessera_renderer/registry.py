"""The core's integrator registry as plain data, and `python -m tessera_renderer.registry`,
which prints it as JSON for processes that must not load the renderer (the service, the
worker's main process: see tessera/tessera_base/integrators.py).

The list is the core's (renderer/core/integrators/registry.cpp): no Python file names an
integrator. Each entry is a dict of name, description, the capabilities (splats,
scene_passes, stop_per_tile, complete, delta_caustics, shades_curves) and params (extra setting ->
description). The first entry is the default integrator.
"""
from __future__ import annotations

import json
import sys

from . import _core


def describe() -> dict:
    """{"integrators": [entry, ...], "auto": [what `auto` picks without, and with, a scene
    whose delta lights form caustics]}."""
    return {"integrators": [dict(i) for i in _core.integrators()],
            "auto": [_core.auto_integrator(False), _core.auto_integrator(True)]}


if __name__ == "__main__":
    json.dump(describe(), sys.stdout)
    sys.exit(0)
