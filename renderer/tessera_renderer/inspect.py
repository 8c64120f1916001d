"""Pre-flight of an untrusted scene, meant to run in a child process:

    python -m tessera_renderer.inspect FILE

Prints one JSON object: {"ok": true, "width", "height", "warnings", "triangles", "lights",
"unlit_warnings"}, the last present for a stage without any light: the warnings of a
render with default lighting off (the job setting default_light=false),
and exits 0, or {"ok": false, "error": "..."} and exits 2. A crash of the USD parser takes
only this process with it.
"""
from __future__ import annotations

import json
import sys


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print(json.dumps({"ok": False, "error": "usage: python -m tessera_renderer.inspect FILE"}))
        return 2
    from . import SceneError, load_scene

    try:
        scene = load_scene(argv[0])
    except SceneError as exc:
        print(json.dumps({"ok": False, "error": str(exc)}))
        return 2
    except Exception as exc:  # a parser bug is still the file's fault to the user
        print(json.dumps({"ok": False, "error": f"cannot translate the scene: {type(exc).__name__}: {exc}"}))
        return 2
    info = {"ok": True, "width": scene.width, "height": scene.height, "warnings": scene.warnings,
            "triangles": scene.num_triangles, "lights": scene.num_emitters}
    if scene.lit_by_default:
        info["unlit_warnings"] = scene.unlit_warnings
    print(json.dumps(info))
    return 0


if __name__ == "__main__":
    sys.exit(main())
