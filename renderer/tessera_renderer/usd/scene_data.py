"""The translated scene: everything the core needs from a stage, as plain arrays. Its own
module, below the readers that fill it (stage.py combines them; lights.py adds the default
lighting to it), so none of them imports the translator for its type."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .camera import CameraDesc


@dataclass
class SceneData:
    """Everything the core needs, as plain arrays. Fields after `warnings` are read by the
    core as it grows; the binding reads only what it knows."""

    positions: np.ndarray           # float32 (V, 3), world space
    indices: np.ndarray             # uint32 (T, 3)
    triangle_material: np.ndarray   # uint32 (T,)
    albedo: np.ndarray              # float32 (M, 3)  diffuseColor clamped to [0, 1]
    emission: np.ndarray            # float32 (M, 3)  emitted radiance
    two_sided_emission: np.ndarray  # bool (M,)
    sphere_lights: np.ndarray       # float32 (S, 7): centre, radius, radiance
    camera: CameraDesc
    resolution: tuple[int, int]
    resolution_from_stage: bool
    warnings: list[str] = field(default_factory=list)
    material_params: dict[str, np.ndarray] = field(default_factory=dict)  # per row, see PARAM_KEYS
    shading_normals: np.ndarray | None = None   # float32 (T, 3, 3) world, per corner
    uvs: np.ndarray | None = None               # float32 (T, 3, 2) per corner st
    textures: list[dict] = field(default_factory=list)
    material_textures: dict[tuple[int, str], int] = field(default_factory=dict)
    distant_lights: np.ndarray = field(default_factory=lambda: np.zeros((0, 7), np.float32))
    point_lights: np.ndarray = field(default_factory=lambda: np.zeros((0, 6), np.float32))
    dome_light: dict | None = None
    # The lights of the core kinds handed over in rows (usd/light_readers.py), by kind name:
    # float32 (lights, columns) as the kind's file in renderer/core/lights/ lays a row out.
    light_rows: dict[str, np.ndarray] = field(default_factory=dict)
    prototypes: list[dict] = field(default_factory=list)
    instances: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint32))
    instance_transforms: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4), np.float32))
    # Transform motion (usd/motion.py): instance motion_instances[k] moves through
    # motion_time_steps[k] matrices evenly spaced over the shutter, taken in order from
    # motion_transforms; its instance_transforms entry is the first.
    motion_instances: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint32))
    motion_time_steps: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint32))
    motion_transforms: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4), np.float32))
    # Moving lights (usd/lights.py): light light_motion_indices[k] of kind
    # light_motion_kinds[k] (1 sphere, 2 point, 3 distant, 4 dome) moves rigidly through
    # light_motion_time_steps[k] transforms (row vectors: p(t) = p @ M) taken in order from
    # light_motion_transforms, relative to where its row puts it.
    light_motion_kinds: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint8))
    light_motion_indices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint32))
    light_motion_time_steps: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint32))
    light_motion_transforms: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4), np.float32))
    # Shaped area lights (UsdLux ShapingAPI on Rect, Disk and Cylinder lights): per material row the
    # shaping columns of usd/light_shaping.py (about the emitting normal, or the axis: column 0 = 2), or None.
    material_shaping: np.ndarray | None = None
    # IES tables (tables, 181, 73) the shaping columns name (usd/light_shaping.py), or None.
    ies_tables: np.ndarray | None = None
    # Still curves of the world as Embree round linear curves (usd/curves.py), or None:
    # {"points": (P, 4) x y z radius, "segments": (S,) first point, "flags": (S,) uint8
    # neighbours, "material": (S,) material rows}.
    curves: dict[str, np.ndarray] | None = None
    # Homogeneous media (usd/media.py; docs/media.md), or None: rows sigma_a rgb, sigma_s
    # rgb, g (float32 (K, 7)), and per material row the medium inside and outside it (int32
    # (M, 2), -1 vacuum; grid media numbered after these).
    media: np.ndarray | None = None
    material_media: np.ndarray | None = None
    # UsdLux light and shadow links (usd/light_links.py), or None when no light has any:
    # {"illuminates", "shadows": uint8 (links, groups); "material_group" uint32 and
    # "material_light" int32 per material row; "sphere", "point", "distant" int32 per light
    # row; "dome" int32 (1,)}, -1 for a light that lights everything.
    light_links: dict[str, np.ndarray] | None = None
    # The time code rendered (None: the default time) and the shutter interval around it
    # in absolute time codes (None: no motion blur).
    time_code: float | None = None
    shutter: tuple[float, float] | None = None
    # Whether anything of the stage can change with time (stage_is_animated); False: every
    # frame renders the same image.
    animated: bool = True
    meters_per_unit: float = 0.01
    up_axis: str = "Y"
    # The world-space position of this data's origin: a translated stage is moved so that
    # its camera sits at the origin (float32 precision follows distance from the camera);
    # world = these coordinates + world_offset.
    world_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # Lights for a stage that has none (see default_lighting), not yet part of the light
    # tables above; Scene adds them unless default lighting is switched off. None when the
    # stage has a UsdLux light or emission strong enough to light it (usd/emission.py), or
    # they were applied already.
    default_lights: dict | None = None
    # The light a black image's warning names: the UsdLux light with the largest authored
    # intensity x 2^exposure x luminance(color), as "path (type, intensity I)"; for a
    # light-less stage the default lighting (or its emission), None without either.
    brightest_light: str | None = None
    # The render log's line on subdivision surfaces (levels, stored triangles, geometry
    # bytes; stage._subdivision_summary), None without any. Not carried by the scene blob:
    # the farm refines at the job's fixed level.
    subdivision_summary: str | None = None
    # Grid media (usd/volumes.py, docs/media.md) as (density float32 (nz, ny, nx),
    # world_to_index float32 (3, 4), float32 (7,) sigma_a rgb, sigma_s rgb per unit density,
    # g), numbered after `media` in material_media; and per material row whether it is a pure
    # medium interface (a Volume's box), bool (M,), None without volumes.
    grid_media: list = field(default_factory=list)
    material_interface_only: np.ndarray | None = None
