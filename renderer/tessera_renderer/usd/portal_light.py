"""UsdLux PortalLight: a rectangle (inputs:width x inputs:height in its XY plane, centred)
through which the dome's light enters; its light travels along its -Z, so the interior it
lights is on its -Z side. The core's portal kind (renderer/core/lights/portal_light.h)
samples the dome through it; with a portal in the scene the dome lights only through
portals (docs/scene-translation.md)."""
from __future__ import annotations

import numpy as np

from .errors import read_float
from .light_readers import reads


def _no_dome(tr) -> None:
    if tr.light_rows.get("portal") and tr.dome_light is None:
        tr.warn(f"{len(tr.light_rows['portal'])} PortalLight(s) without a DomeLight: a portal carries a dome's "
                f"light and lights nothing alone")


@reads("PortalLight", finish=_no_dome)
def read_portal_light(tr, prim) -> None:
    from pxr import UsdLux

    portal = UsdLux.PortalLight(prim)
    w = read_float(portal.GetWidthAttr(), tr.time, 1.0)
    h = read_float(portal.GetHeightAttr(), tr.time, 1.0)
    m = tr.world_matrix(prim)  # row vectors: p_world = p @ m[:3, :3] + m[3, :3]
    half_u, half_v = m[0, :3] * (w / 2.0), m[1, :3] * (h / 2.0)
    # The core's outward normal is Cross(half_u, half_v): it must be the portal's +Z in the
    # world (toward the dome), also under a mirroring transform.
    if np.dot(np.cross(half_u, half_v), m[2, :3]) < 0:
        half_v = -half_v
    if not (np.linalg.norm(np.cross(half_u, half_v)) > 0) or not np.isfinite(m).all():
        tr.warn(f"{prim.GetPath()}: PortalLight has no area; skipped")
        return
    if tr.motion_steps(prim, np.zeros((1, 3))) is not None:
        tr.warn(f"{prim.GetPath()}: a moving PortalLight stands where it is at the frame")
    tr.add_light_row("portal", [*m[3, :3], *half_u, *half_v])
