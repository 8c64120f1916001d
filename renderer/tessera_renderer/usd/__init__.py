"""USD -> the flat arrays of the C++ core. One concept per file: the stage walk (stage), the
translated scene (scene_data), the layer an asset path resolves against (authoring), meshes/gprims/curves (meshes, gprims, curves, subdivision),
instancing, materials (materials, mtlx), lights (lights, light_shaping), the camera, the
bundle sandbox (bundle) and the pre-flight census (census). The translator class in stage
combines the per-concept readers."""
from .camera import CameraDesc
from .errors import SceneError
from .lights import NO_LIGHT_OFF_WARNING, NO_LIGHT_WARNING, apply_default_lighting, default_lighting
from .scene_data import SceneData
from .stage import translate_opened_stage, translate_stage

__all__ = ["CameraDesc", "SceneData", "SceneError", "NO_LIGHT_OFF_WARNING", "NO_LIGHT_WARNING",
           "apply_default_lighting", "default_lighting", "translate_opened_stage", "translate_stage"]
