"""The render child: the only process of a worker that runs the renderer.

The worker (the supervisor) starts it with an address-space limit and talks to it over a
socket: one request, one reply. A segfault, abort, runaway allocation or endless loop in
the renderer ends only this process; the supervisor reports that attempt as failed and
starts a new child. It knows nothing of Redis.

On start it sends ("hello", blob_version): the renderer's translated-scene blob version
(None if this renderer has no blob API). Then, per request:

Request: dict(serial, scene_path, blob_path, blob_out, x0, y0, w, h, width, height, spp,
sample_start, seed, max_depth, threads, variance, aovs, fault). The scene comes from the blob
file `blob_path` if given (no USD involved), else is translated from `scene_path`; with
`blob_out`, the translation is also written there as a blob for other workers. Reply: ("ok", rgba, variance | None, seconds, splat | None, aovs | None, serial), splat =
(rect, int64 layer, light paths, unit exponent) for integrators that splat, aovs = {name: layer}
for the requested AOVs other than variance
or ("error", kind, message, serial) with kind "scene" | "memory" | "other"; the serial
lets the supervisor check that a reply answers its latest request.
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

import numpy as np

from tessera import integrators
from tessera.protocol import splat_layer

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

    if blob_api is None:
        return load_scene(req["scene_path"])
    if req.get("blob_path"):
        with open(req["blob_path"], "rb") as f:
            return blob_api.scene_from_blob(f.read())
    blob = blob_api.translate_to_blob(req["scene_path"])
    if req.get("blob_out"):
        tmp = req["blob_out"] + ".part"
        with open(tmp, "wb") as f:
            f.write(blob)
        os.replace(tmp, req["blob_out"])
    return blob_api.scene_from_blob(blob)


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
            path = req["scene_key"]
            scene = scenes.get(path)
            if scene is None:
                scene = _load(req, blob_api)
                scenes[path] = scene
                while len(scenes) > SCENE_CACHE_SIZE:
                    scenes.popitem(last=False)
            scenes.move_to_end(path)
            kwargs = dict(width=req["width"], height=req["height"], spp=req["spp"],
                          seed=req["seed"], max_depth=req["max_depth"], threads=req["threads"])
            if req["variance"] or req["sample_start"]:
                kwargs.update(sample_start=req["sample_start"], return_variance=req["variance"])
            aovs = [a for a in req.get("aovs", ()) if a != "variance"]  # variance: req["variance"]
            # `auto` resolves from the scene alone, so every worker picks the same method.
            integrator = scene.resolve_integrator(req.get("integrator") or integrators.default())
            splats = None
            if integrators.splats(integrator):
                splats = np.zeros((req["height"], req["width"], 3), dtype=np.int64)
            started = time.perf_counter()
            out = scene.render_tile(req["x0"], req["y0"], req["w"], req["h"], integrator=integrator,
                                    splats=splats, aovs=aovs, **kwargs)
            seconds = time.perf_counter() - started
            layers = None
            if aovs:
                rgba, layers = out
                variance = layers.pop("variance", None)
            else:
                rgba, variance = out if req["variance"] else (out, None)
            splat = None
            if splats is not None:
                rect, layer = splat_layer(splats)
                # One light path per sample; the scene's fixed-point unit goes with the layer.
                splat = (rect, layer, req["w"] * req["h"] * req["spp"], scene.splat_exponent)
            batches = None
            if splats is not None and req.get("batches"):
                batches = _variance_batches(scene, req, integrator, kwargs)
            seconds = time.perf_counter() - started
            reply = ("ok", rgba, variance, seconds, splat, layers, batches)
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


def _variance_batches(scene, req: dict, integrator: str, kwargs: dict) -> list:
    """The pass's samples again as protocol.batch_ranges, each with its own splats: the
    SplatBatch list of the tile result (protocol.VARIANCE_BATCHES)."""
    from tessera.protocol import SplatBatch, batch_ranges

    out = []
    for start, n in batch_ranges(req["sample_start"], req["spp"]):
        splats = np.zeros((req["height"], req["width"], 3), dtype=np.int64)
        args = dict(kwargs, spp=n, sample_start=start, return_variance=False)
        rgba = scene.render_tile(req["x0"], req["y0"], req["w"], req["h"], integrator=integrator,
                                 splats=splats, **args)
        rect, layer = splat_layer(splats)
        out.append(SplatBatch(n, np.ascontiguousarray(rgba[..., :3]), rect, layer, req["w"] * req["h"] * n))
    return out


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
