"""Pre-flight of an untrusted scene, meant to run in a child process:

    python -m tessera_renderer.inspect FILE

Prints one JSON object: {"ok": true, "width", "height", "warnings", "triangles", "lights"}
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
    print(json.dumps({"ok": True, "width": scene.width, "height": scene.height,
                      "warnings": scene.warnings, "triangles": scene.num_triangles,
                      "lights": scene.num_emitters}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
