"""The render child: the only process of a worker that runs the renderer.

The worker (the supervisor) starts it with an address-space limit and talks to it over a
socket: one request, one reply. A segfault, abort, runaway allocation or endless loop in
the renderer ends only this process; the supervisor reports that attempt as failed and
starts a new child. It knows nothing of Redis.

On start it sends ("hello", blob_version): the renderer's translated-scene blob version
(None if this renderer has no blob API). Then, per request:

Request: dict(serial, scene_key, scene_path, blob_path, blob_out, settings (RenderSettings
JSON), tile (TileRect fields), pass_index, threads, variance, batches, default_light, subdivision_level, dicing (Dicing.to_json), camera, frame, shutter, variants, fault). The scene
comes from the blob file `blob_path` if given (no USD involved), else is translated from
`scene_path`; with `blob_out`, the translation is also written there as a blob for other
workers. The pass is rendered by tessera_base.film.render_tile_pass, as local renders do.
Reply: ("ok", TileResult, seconds, serial) or ("error", kind, message, serial) with kind
"scene" | "memory" | "other"; the serial lets the supervisor check that a reply answers
its latest request.
"""
from __future__ import annotations

import argparse
import os
import signal
import socket
import sys
import time
from collections import OrderedDict
from multiprocessing.connection import Connection

from tessera_base.film import render_tile_pass, run_scene_pass
from tessera_base.protocol import RenderSettings, TileRect

SCENE_CACHE_SIZE = 4


def _inject(fault: str) -> None:
    """Fault injection for drills and tests (see TESSERA_WORKER_FAULTS in docs/farm.md)."""
    if fault == "segv":
        os.kill(os.getpid(), signal.SIGSEGV)
    elif fault == "abort":
        os.abort()
    elif fault == "hang":
        while True:
            time.sleep(3600)
    elif fault == "oom":
        # Far beyond any machine: fails at once under the address-space limit.
        _ = bytearray(1 << 44)
    elif fault == "exit":
        os._exit(7)


def _blob_api():
    try:
        from tessera_renderer import scene_blob
        return scene_blob, scene_blob.format_tag()
    except ImportError:
        return None, None


def _load(req: dict, blob_api):
    from tessera_renderer import load_scene
    from tessera_renderer.usd.dicing import Dicing

    lit, level, camera = req.get("default_light", True), req.get("subdivision_level"), req.get("camera")
    frame, shutter = req.get("frame"), req.get("shutter")
    shutter = None if shutter is None else tuple(shutter)
    variants = [tuple(v) for v in req.get("variants") or ()]  # (prim path, set, variant), parsed
    dicing = Dicing.from_json(req["dicing"]) if req.get("dicing") else None
    if blob_api is None:
        return load_scene(req["scene_path"], frame, default_light=lit, subdivision_level=level, camera=camera,
                          shutter=shutter, variants=variants, dicing=dicing)
    if req.get("blob_path"):
        with open(req["blob_path"], "rb") as f:
            return blob_api.scene_from_blob(f.read(), default_light=lit)
    blob = blob_api.translate_to_blob(req["scene_path"], frame, subdivision_level=level, camera=camera,
                                      shutter=shutter, variants=variants, dicing=dicing)
    if req.get("blob_out"):
        tmp = req["blob_out"] + ".part"
        with open(tmp, "wb") as f:
            f.write(blob)
        os.replace(tmp, req["blob_out"])
    return blob_api.scene_from_blob(blob, default_light=lit)


def serve(conn: Connection) -> None:
    from tessera_renderer import SceneError

    blob_api, blob_version = _blob_api()
    conn.send(("hello", blob_version))
    scenes: OrderedDict[str, object] = OrderedDict()
    while True:
        try:
            req = conn.recv()
        except (EOFError, OSError):
            return
        try:
            if req.get("fault"):
                _inject(req["fault"])
            # One translation (blob) serves both; the built Scene differs.
            path = req["scene_key"] + ("" if req.get("default_light", True) else ":unlit")
            scene = scenes.get(path)
            if scene is None:
                scene = _load(req, blob_api)
                scenes[path] = scene
                while len(scenes) > SCENE_CACHE_SIZE:
                    scenes.popitem(last=False)
            scenes.move_to_end(path)
            # `auto` resolves from the scene alone, so every worker picks the same method.
            settings = RenderSettings.model_validate_json(req["settings"])
            integrator = scene.resolve_integrator(settings.integrator)
            if req.get("scene_pass"):
                started = time.perf_counter()
                product = run_scene_pass(scene, settings, req["pass_index"], integrator=integrator,
                                         threads=req["threads"])
                reply = ("ok", product, time.perf_counter() - started)
            else:
                result, seconds = render_tile_pass(scene, settings, TileRect(**req["tile"]),
                                                   req["pass_index"], integrator=integrator,
                                                   threads=req["threads"], variance=req["variance"],
                                                   batches=req["batches"],
                                                   scene_product=req.get("scene_product"))
                reply = ("ok", result, seconds)
        except SceneError as e:
            reply = ("error", "scene", str(e))
        except MemoryError as e:
            reply = ("error", "memory", str(e) or "out of memory")
        except Exception as e:  # noqa: BLE001 - a renderer bug fails this attempt only
            reply = ("error", "other", f"{type(e).__name__}: {e}")
        serial = req.get("serial") if isinstance(req, dict) else None
        try:
            conn.send((*reply, serial))
        except (OSError, EOFError):
            return
        except MemoryError:
            conn.send(("error", "memory", "out of memory sending the tile", serial))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m tessera_worker.render_child")
    parser.add_argument("--fd", type=int, required=True, help="socket to the supervisor")
    args = parser.parse_args(argv)
    # The supervisor handles stop requests; a terminal's Ctrl-C must not kill a render.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    sock = socket.socket(fileno=args.fd)
    serve(Connection(sock.detach()))
    sys.exit(0)


if __name__ == "__main__":
    main()
