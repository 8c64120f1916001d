"""Pre-flight of untrusted uploads: `python -m tessera_renderer.inspect FILE` in a child
process with a time and memory limit, so that a hostile or broken file cannot crash,
hang or exhaust the API process."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field

from tessera_base.process import limited_child, remove_orphaned_tempdirs

INSPECT_MODULE = "tessera_renderer.inspect"

# What translating a scene costs the inspection process, measured (VmPeak, usd-core 26.11,
# meshes with faceVarying st and smooth normals, the costliest kind): 1.5 GiB with the
# stage open plus 270-290 bytes per triangle. Rounded up, so that a scene under the limit
# these give passes in the memory they were derived from.
TRANSLATION_BASE_BYTES = 2 << 30
TRANSLATION_BYTES_PER_TRIANGLE = 320


def triangle_limit(max_triangles: int, memory_bytes: int) -> int:
    """The triangle limit the inspection enforces: `max_triangles`, lowered to what fits
    in `memory_bytes` of address space (0: no memory limit)."""
    if memory_bytes <= 0:
        return max_triangles
    fits = (memory_bytes - TRANSLATION_BASE_BYTES) // TRANSLATION_BYTES_PER_TRIANGLE
    return max(0, min(max_triangles, fits))


class PreflightRejected(Exception):
    """The scene is unusable; the message says why (meant for the client). `lasting`:
    the file's own fault, remembered for the next upload of it; not for a verdict the
    server's load may have made (a timeout, a kill from outside), which one user's uploads
    could otherwise cause for another's scene."""

    def __init__(self, message: str, lasting: bool = True):
        super().__init__(message)
        self.lasting = lasting


class PreflightBroken(Exception):
    """The inspection itself could not run (a server problem, not the client's)."""


@dataclass
class SceneInfo:
    width: int
    height: int
    warnings: list[str] = field(default_factory=list)
    triangles: int = 0
    curve_segments: int = 0  # Embree round curves: integrators that do not shade them are warned
    linked_lights: int = 0  # lights with UsdLux light or shadow links: integrators that ignore them are warned
    media: bool = False
    lights: int = 0
    # For a stage without any light: the warnings when default lighting is off.
    unlit_warnings: list[str] | None = None
    # The stage's Camera prims (None: an inspection remembered from before they were listed).
    cameras: list[str] | None = None
    camera_note: str | None = None  # the warning naming which of several cameras renders
    # Whether anything of the stage has time samples (False: every frame is the same image;
    # an inspection remembered from before this was recorded says True).
    animated: bool = True
    # The scene's brightest light as a black image's warning names it (SceneData.brightest_light).
    brightest_light: str | None = None
    # Size of the translated scene the workers share through Redis (0: not measured).
    translated_bytes: int = 0


def inspect_scene(path: str, *, timeout: float, memory_bytes: int,
                  max_triangles: int | None = None, variants: Sequence[tuple[str, str, str]] = (),
                  subdivision_level: int | None = None, dicing: dict | None = None) -> SceneInfo:
    """Inspects the scene in a child process; `max_triangles`: its triangle limit
    (default: the renderer's own, TESSERA_MAX_TRIANGLES); `variants`: (prim path, set,
    variant) selections the stage is composed with, as the render will; translated at the
    job's `subdivision_level` (default: the renderer's) or diced as its `dicing` asks
    (protocol.dicing_of and its "camera"), as the render will be."""
    # One malloc arena per thread reserves 64 MB of address space each, up to 8 per core:
    # on a many-core host that alone would eat the limit. Two arenas cost nothing here.
    env = {**os.environ, "MALLOC_ARENA_MAX": "2"}
    if max_triangles is not None:
        env["TESSERA_MAX_TRIANGLES"] = str(max_triangles)
    try:
        extra = [json.dumps([list(v) for v in variants])]
        if subdivision_level is not None or dicing is not None:
            extra.append("-" if subdivision_level is None else str(int(subdivision_level)))
        if dicing is not None:
            extra.append(json.dumps(dicing))
        proc = subprocess.run([sys.executable, "-m", INSPECT_MODULE, path, *extra],
                              stdin=subprocess.DEVNULL, capture_output=True, env=env,
                              timeout=timeout, preexec_fn=limited_child(memory_bytes))
    except subprocess.TimeoutExpired:
        raise PreflightRejected(f"scene inspection timed out after {timeout:g} s", lasting=False) from None
    finally:
        # An inspection killed by a signal (a crash, its memory limit, the timeout) cannot
        # remove the bundle it unpacked (203 MB for one upload measured); its pid is gone now.
        remove_orphaned_tempdirs("bundle")

    def public(text: str) -> str:
        return bundle_relative(text, os.path.dirname(os.path.abspath(path)))

    result = _parse(proc.stdout)
    if result is not None and proc.returncode in (0, 2):
        if not result.get("ok"):
            raise PreflightRejected(public(str(result.get("error") or "the scene was rejected")))
        try:
            return SceneInfo(width=int(result["width"]), height=int(result["height"]),
                             warnings=[public(str(w)) for w in result.get("warnings", [])],
                             triangles=int(result.get("triangles", 0)),
                             curve_segments=int(result.get("curve_segments", 0)),
                             linked_lights=int(result.get("linked_lights", 0)),
                             media=bool(result.get("media", False)),
                             lights=int(result.get("lights", 0)),
                             unlit_warnings=([public(str(w)) for w in result["unlit_warnings"]]
                                             if result.get("unlit_warnings") is not None else None),
                             cameras=([str(c) for c in result["cameras"]]
                                      if result.get("cameras") is not None else None),
                             camera_note=(public(str(result["camera_note"])) if result.get("camera_note") else None),
                             animated=bool(result.get("animated", True)),
                             brightest_light=(str(result["brightest_light"]) if result.get("brightest_light")
                                              else None),
                             translated_bytes=int(result.get("translated_bytes", 0)))
        except (KeyError, TypeError, ValueError) as e:
            raise PreflightBroken(f"scene inspection returned an unexpected answer: {result!r}") from e

    stderr = proc.stderr.decode(errors="replace").strip()
    if proc.returncode < 0:
        name = signal.Signals(-proc.returncode).name if -proc.returncode in signal.valid_signals() \
            else f"signal {-proc.returncode}"
        # SIGKILL comes from outside (the OOM killer of a loaded host); a SIGSEGV is the file's.
        raise PreflightRejected(f"scene inspection crashed ({name})",
                                lasting=-proc.returncode != signal.SIGKILL)
    if "MemoryError" in stderr or "bad_alloc" in stderr:
        raise PreflightRejected("scene inspection ran out of memory "
                                f"(limit {memory_bytes / (1 << 20):.0f} MiB)")
    tail = stderr.splitlines()[-5:]
    raise PreflightBroken(public(f"scene inspection failed with exit code {proc.returncode}: "
                                 + " | ".join(tail)))


# A directory the server made for an upload: the API's upload folder, the inspection's
# unpacked bundle, a worker's (tessera_base.process.private_tempdir and the renderer's
# mkdtemp prefixes), with whatever absolute path leads to it.
_SERVER_DIR = re.compile(r"(?:/[^/\s'\"@<>\[\]]+)*?/tessera-(?:upload|bundle|blob|worker)-[^/\s'\"@<>]*(/|\b)")


def bundle_relative(text: str, upload_dir: str) -> str:
    """An inspection's message in the uploader's terms: paths relative to the bundle,
    without the server's temporary folders (a self-referencing layer's error named
    /tmp/tessera-upload-<pid>-.../scene.usda; an unpacking error the tessera-bundle-...
    folder). A bare folder left at the end becomes '.', the bundle's root."""
    for base in dict.fromkeys((upload_dir, os.path.realpath(upload_dir))):
        text = text.replace(base.rstrip("/") + "/", "")
    return _SERVER_DIR.sub(lambda m: "" if m.group(1) == "/" else ".", text)


def _parse(stdout: bytes) -> dict | None:
    """The JSON object on stdout (or on its last line, should anything else print first)."""
    text = stdout.decode(errors="replace").strip()
    lines = text.splitlines()
    for candidate in (text, lines[-1] if lines else ""):
        try:
            value = json.loads(candidate)
        except ValueError:
            continue
        if isinstance(value, dict):
            return value
    return None
