"""Pre-flight of an untrusted scene, meant to run in a child process:

    python -m tessera_renderer.inspect FILE [VARIANTS [SUBDIVISION_LEVEL [DICING]]]

VARIANTS: a JSON list of [prim path, variant set, variant] selections the stage is composed
with, as the render will compose it (the missing layers that matter are the ones the
selection uses). SUBDIVISION_LEVEL: the job's level, or - for the renderer's. DICING: the
job's screen-space dicing as JSON (tessera_base.protocol.dicing_of, plus "camera": the job's
camera prim or null), so that the translated size is measured at the levels the workers
will choose.

Prints one JSON object: {"ok": true, "width", "height", "warnings", "triangles", "curve_segments", "lights",
"cameras", "camera_note", "animated", "translated_bytes" (scene_blob.blob_size), "unlit_warnings"}, the last present for a stage without any light: the warnings of a
render with default lighting off (the job setting default_light=false),
and exits 0, or {"ok": false, "error": "..."} and exits 2. A crash of the USD parser takes
only this process with it.

Before anything is translated, the census (census.py) counts what the scene declares from
its face counts alone, under an address-space limit of CENSUS_HEADROOM above what the
process already uses (raised again to the parent's limit afterwards): a scene over the
triangle limit is refused in about a second at a few hundred MB, instead of being built.
"""
from __future__ import annotations

import json
import resource
import sys
from contextlib import contextmanager

# Room the census may allocate beyond the opened stage: the largest faceVertexCounts it
# accepts (4 bytes a face, faces <= the triangle limit) and numpy's temporaries.
CENSUS_HEADROOM = 512 << 20


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    try:
        if len(argv) not in (1, 2, 3, 4):
            raise ValueError("wrong number of arguments")
        variants = [tuple(str(x) for x in v) for v in json.loads(argv[1])] if len(argv) >= 2 else []
        if any(len(v) != 3 for v in variants):
            raise ValueError("each variant selection is [prim path, variant set, variant]")
        # The job's subdivision level: the translated size it is held to is that level's.
        level = int(argv[2]) if len(argv) >= 3 and argv[2] != "-" else None
        dicing = json.loads(argv[3]) if len(argv) == 4 else None
        if dicing is not None and not (isinstance(dicing, dict) and "rate" in dicing):
            raise ValueError("DICING is a JSON object with a rate")
    except ValueError as exc:
        print(json.dumps({"ok": False, "error": f"usage: python -m tessera_renderer.inspect FILE [VARIANTS [SUBDIVISION_LEVEL [DICING]]] ({exc})"}))
        return 2
    from . import Scene, SceneError
    from .usd.bundle import open_bundle, open_stage
    from .usd.census import take_census
    from .usd import translate_stage
    from .usd.camera import CAMERA_CHOICE_NOTE, camera_paths
    from .scene_blob import blob_size
    from .usd.dicing import Dicing

    try:
        bundle = open_bundle(argv[0])
        warnings = list(bundle.warnings)
        stage = open_stage(bundle, variants)  # kept open: the translation reuses its layers
        try:
            with _address_space(CENSUS_HEADROOM + 8 * bundle.limits.triangles):
                take_census(stage, bundle.limits)
        except MemoryError:
            raise SceneError("the scene's face counts are too large to count within the "
                             f"pre-flight's memory (triangle limit {bundle.limits.triangles})") from None
        bundle.warnings[:] = warnings  # translate_stage opens the stage again and adds its own
        diced = {} if dicing is None or level is not None else \
            {"dicing": Dicing.from_json(dicing), "camera": dicing.get("camera")}
        data = translate_stage(argv[0], bundle=bundle, instancing="auto", variants=variants,
                               **({} if level is None else {"subdivision_level": level}), **diced)
        translated_bytes = blob_size(data)
        scene = Scene(data)
        del data
        cameras = camera_paths(stage)
        del stage
    except SceneError as exc:
        print(json.dumps({"ok": False, "error": str(exc)}))
        return 2
    except MemoryError:
        raise  # the parent reports it as running out of memory, with its limit
    except Exception as exc:  # a parser bug is still the file's fault to the user
        print(json.dumps({"ok": False, "error": f"cannot translate the scene: {type(exc).__name__}: {exc}"}))
        return 2
    info = {"ok": True, "width": scene.width, "height": scene.height, "warnings": scene.warnings,
            "triangles": scene.num_triangles, "curve_segments": scene.num_curve_segments,
            "linked_lights": scene.num_linked_lights, "media": scene.has_media,
            "lights": scene.num_emitters, "cameras": cameras, "translated_bytes": translated_bytes,
            # The warning naming the camera chosen among several: void for a job naming its own.
            "camera_note": next((w for w in scene.warnings if CAMERA_CHOICE_NOTE in w), None),
            "animated": bool(getattr(scene.data, "animated", True))}
    # What a black image's warning names (the service finishes images without the renderer).
    info["brightest_light"] = getattr(scene.data, "brightest_light", None)
    if scene.lit_by_default:
        info["unlit_warnings"] = scene.unlit_warnings
    print(json.dumps(info))
    return 0


@contextmanager
def _address_space(extra: int):
    """Lowers the soft RLIMIT_AS to `extra` bytes above the current size for the block
    (never above the hard limit), then restores it. Linux only; elsewhere a no-op."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    size = _vm_size()
    if size is None:
        yield
        return
    cap = size + extra
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def _vm_size() -> int | None:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


if __name__ == "__main__":
    sys.exit(main())
