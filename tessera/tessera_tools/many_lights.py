"""A scene of many small emitters, for the light BVH's tests and benchmark.

A 20 x 20 grey floor (albedo 0.5) under `n` small one-sided triangles (edge 0.1) at random
heights 0.3 to 3 over it, each facing down with one of eight emitted radiances, seen from
straight above. Every floor point is lit by all of them, but mostly by the few just above
it: a power-proportional light choice spends nearly every shadow ray on far-away lights,
a choice by position and orientation does not. The triangles' backs are black, so light
does not bounce between them; the floor is the only reflector.
"""
from __future__ import annotations

import numpy as np

FLOOR_HALF = 10.0
EDGE = 0.1
# Radiances of the emitter materials (rows 1..8): spread over a factor 8 so power matters too.
RADIANCE = np.array([[2, 2, 2], [4, 3, 2], [1, 2, 4], [8, 6, 4], [3, 3, 3], [6, 2, 2], [2, 6, 2], [16, 14, 12]],
                    np.float32)


def build(n: int = 10000, seed: int = 1, res: int = 64, light_selection: str = "auto"):
    from tessera_renderer import Scene
    from tessera_renderer.usd import CameraDesc, SceneData

    rng = np.random.default_rng(seed)
    h = FLOOR_HALF
    floor = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], np.float32)
    centres = np.column_stack([rng.uniform(-h, h, n), rng.uniform(-h, h, n), rng.uniform(0.3, 3.0, n)])
    angle = rng.uniform(0, 2 * np.pi, n)
    corners = []
    for k in range(3):
        a = angle + k * 2 * np.pi / 3
        corners.append(centres + EDGE / np.sqrt(3) * np.column_stack([np.cos(a), np.sin(a), np.zeros(n)]))
    # Clockwise seen from above: Cross(p1 - p0, p2 - p0) points down (-z), toward the floor.
    tri = np.stack([corners[0], corners[2], corners[1]], axis=1).reshape(-1, 3).astype(np.float32)
    positions = np.concatenate([floor, tri])
    indices = np.concatenate([np.array([[0, 1, 2], [0, 2, 3]], np.uint32),
                              4 + np.arange(3 * n, dtype=np.uint32).reshape(-1, 3)])
    material = np.concatenate([[0, 0], 1 + rng.integers(0, len(RADIANCE), n)]).astype(np.uint32)
    albedo = np.zeros((1 + len(RADIANCE), 3), np.float32)
    albedo[0] = 0.5
    emission = np.concatenate([np.zeros((1, 3), np.float32), RADIANCE])
    # A pinhole 30 units above the centre, seeing the middle 16 x 16 of the floor.
    cam = CameraDesc(origin=(0.0, 0.0, 30.0), right=(1.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), forward=(0.0, 0.0, -1.0),
                     horizontal_aperture=16.0 / 30.0, vertical_aperture=16.0 / 30.0, focal_length=1.0,
                     source="many_lights")
    data = SceneData(positions=positions, indices=indices, triangle_material=material, albedo=albedo,
                     emission=emission, two_sided_emission=np.zeros(len(albedo), bool),
                     sphere_lights=np.zeros((0, 7), np.float32), camera=cam, resolution=(res, res),
                     resolution_from_stage=True)
    return Scene(data, light_selection=light_selection)
