"""The worker's scene cache: where the render process gets a task's scene (a translated
blob another worker shared through the data store, else the scene file, translated here
and shared), the scene files and blobs kept on local disk, and the scene-pass products
kept in memory."""
from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
from pathlib import PurePosixPath

import redis

from tessera_base import integrators, protocol
from tessera_queue import redis_schema as rdb
from tessera_queue.data_store import ObjectMissing, is_digest
from tessera_queue.tasks import TileTask

from .child import Abandoned, RenderFailed
from .redis_values import text as _text

log = logging.getLogger("tessera.worker")

SCENE_FILES = 8            # scene files kept on local disk (least recently used go)
PRODUCTS_KEPT = 4          # scene-pass products kept in memory (least recently used go)


class SceneCache:
    """Worker's part that caches scenes (a mixin: it uses the Worker's redis, data and
    _tmpdir, and keeps _scene_files and _products)."""

    def _scene_product(self, task: TileTask) -> bytes | None:
        """The product a tile pass of a scene-pass integrator reads (None for the others):
        fetched once per worker and iteration, kept by its content hash."""
        if not integrators.scene_passes(task.settings.integrator):
            return None
        digest = _text(self.redis.hget(rdb.job_key(task.job_id), rdb.product_field(task.pass_index)))
        product = self._products.get(digest) if digest else None
        if product is None and digest:
            product = self.redis.hget(rdb.job_products_key(task.job_id), digest)
        if product is None:
            decided = _text(self.redis.hget(rdb.job_key(task.job_id), "decided_pass"))
            if decided is not None and int(decided) >= task.pass_index:
                # A late duplicate of a tile its pass already holds (decide_pass.lua dropped
                # the pass's product with the barrier): nothing to render.
                raise Abandoned(f"pass {task.pass_index} is complete")
            raise RenderFailed(f"the scene pass {task.pass_index} product is missing", fatal=True)
        self._products[digest] = self._products.pop(digest, product)  # most recently used last
        while len(self._products) > PRODUCTS_KEPT:
            self._products.pop(next(iter(self._products)))
        return product

    def _scene_source(self, task: TileTask, blob_version: str | None) -> dict:
        """Where the render process gets the task's scene: the translated blob another
        worker stored in the data store (no USD parsing), else the scene file, translated
        here and written as a blob (`blob_out`) that _share_blob then stores for the others."""
        suffix = PurePosixPath(task.scene_name).suffix.lower()
        level, camera = task.settings.subdivision_level, task.settings.camera
        # A subdivision level other than the default translates to other triangles, another
        # camera to other camera-relative coordinates: each its own blob (and cached Scene),
        # never the default one.
        variant = "" if level is None else f".subdiv{level}"
        # Dicing (without a fixed level) chooses levels from the camera at the job's full
        # frame size, never a tile's: every worker translates the same triangles.
        dicing = protocol.dicing_of(task.settings)
        if dicing is not None:
            variant += ".dice" + hashlib.sha256(json.dumps(dicing, sort_keys=True).encode()).hexdigest()[:16]
        # The same bytes as a .usdz and as a .zip may have different root layers (the
        # package's first member; the zip's named or only top-level one): never share.
        if suffix == ".usdz":
            variant = ".usdz" + variant
        if camera is not None:
            variant += ".cam" + hashlib.sha256(camera.encode()).hexdigest()[:16]
        # Another time code or shutter: other positions and motion steps.
        frame, shutter = task.settings.frame, task.settings.shutter
        if frame is not None or shutter is not None:
            variant += ".t" + hashlib.sha256(repr((frame, shutter)).encode()).hexdigest()[:16]
        # Other variant selections: another composed stage.
        selections = [list(protocol.parse_variant(v)) for v in task.settings.variants or ()]
        if selections:
            variant += ".v" + hashlib.sha256(repr(selections).encode()).hexdigest()[:16]
        source = {"scene_key": f"{task.scene_hash}{variant}{suffix}", "scene_path": None,
                  "blob_path": None, "blob_out": None, "subdivision_level": level, "dicing": dicing,
                  "camera": camera,
                  "frame": frame, "shutter": None if shutter is None else list(shutter),
                  "variants": selections}
        if blob_version is None:
            source["scene_path"] = self._scene_file(task)
            return source
        blob_version += variant
        name = f"{task.scene_hash}.{blob_version}.blob"
        path = self._scene_files.get(name)
        if path is not None and os.path.exists(path):
            self._scene_files[name] = self._scene_files.pop(name)
            source["blob_path"] = path
            return source
        named = self.redis.hget(rdb.scene_key(task.scene_hash), rdb.translated_field(blob_version))
        if named is not None and not is_digest(named):
            # The blob itself, as farms before the data store kept it (until the scene expires).
            path = os.path.join(self._tmpdir, name)
            with open(path, "wb") as f:
                f.write(named)
            self._remember_file(name, path)
            source["blob_path"] = path
            return source
        digest = _text(named)
        if digest:
            path = os.path.join(self._tmpdir, name)
            try:
                self.data.copy_to(digest, path)
                self._remember_file(name, path)
                source["blob_path"] = path
                return source
            except ObjectMissing as exc:
                log.warning("translating %s here: its translated scene is not usable: %s",
                            task.scene_name, exc)
        source["scene_path"] = self._scene_file(task)
        source["blob_out"] = os.path.join(self._tmpdir, name)
        return source

    def _share_blob(self, task: TileTask, path: str) -> None:
        """Stores a blob this worker translated in the data store, named once (HSETNX
        semantics) in the scene's hash, which then holds it."""
        if not os.path.exists(path):
            return
        self.redis.hincrby(rdb.STATS, "scene_translations", 1)
        name = os.path.basename(path)
        self._remember_file(name, path)
        blob_version = name[len(task.scene_hash) + 1:-len(".blob")]
        hasher = hashlib.sha256()
        with open(path, "rb") as f:
            while chunk := f.read(1 << 20):
                hasher.update(chunk)
        digest, size = hasher.hexdigest(), os.path.getsize(path)
        # Held by the scene's own hash, so that it lives exactly as long as the scene; only
        # if the scene is still there (a blob of an expired scene would be swept at once).
        key, field = rdb.scene_key(task.scene_hash), rdb.translated_field(blob_version)
        with self.redis.pipeline(transaction=True) as pipe:
            try:
                pipe.watch(key)
                if not pipe.exists(key):
                    return
                named = _text(pipe.hget(key, field))
                if named:
                    pipe.unwatch()
                    if named == digest:  # the same bytes: restores a file that went missing
                        self.data.write_file(digest, path)
                    return
                pipe.multi()
                pipe.hset(key, field, digest)
                self.data.hold(pipe, digest, size, key)  # index first: see data_store
                pipe.execute()
            except redis.WatchError:
                return  # the scene changed meanwhile (another blob, an expiry): skip sharing
        self.data.write_file(digest, path)

    def _remember_file(self, name: str, path: str) -> None:
        self._scene_files[name] = path
        while len(self._scene_files) > SCENE_FILES:
            old = next(iter(self._scene_files))
            path = self._scene_files.pop(old)
            with contextlib.suppress(OSError):
                os.unlink(path)
                if os.path.dirname(path) != self._tmpdir:  # a scene's own directory
                    os.rmdir(os.path.dirname(path))

    def _scene_file(self, task: TileTask) -> str:
        """A local file with the task's scene, alone in a directory of its own under the
        name the API's pre-flight gave it (protocol.scene_file_name): the bundle a loose
        layer sees here is the one that passed pre-flight, and holds no other scene."""
        suffix = PurePosixPath(task.scene_name).suffix.lower()
        key = f"{task.scene_hash}{suffix}"
        path = self._scene_files.get(key)
        if path is not None and os.path.exists(path):
            self._scene_files[key] = self._scene_files.pop(key)  # most recently used last
            return path
        if not self.redis.exists(rdb.scene_key(task.scene_hash)):
            raise RenderFailed(f"cannot load scene {task.scene_name!r}: scene "
                               f"{task.scene_hash} is missing from the store", fatal=True)
        os.makedirs(os.path.join(self._tmpdir, task.scene_hash), exist_ok=True)
        path = os.path.join(self._tmpdir, task.scene_hash, protocol.scene_file_name(suffix))
        try:
            try:
                self.data.copy_to(task.scene_hash, path)
            except ObjectMissing:
                if not self._adopt_legacy_scene(task.scene_hash):
                    raise
                self.data.copy_to(task.scene_hash, path)
        except ObjectMissing as exc:
            # This worker's data directory, not the scene: another worker may render it.
            raise RenderFailed(f"cannot read scene {task.scene_name!r}: {exc}", fatal=False) from None
        self._remember_file(key, path)
        return path

    def _adopt_legacy_scene(self, scene_hash: str) -> bool:
        """Moves a scene's bytes that a farm before the data store kept in its hash (field
        `data`) into the data store; False if there are none."""
        key = rdb.scene_key(scene_hash)
        data = self.redis.hget(key, "data")
        if data is None or hashlib.sha256(data).hexdigest() != scene_hash:
            return False
        with self.redis.pipeline(transaction=True) as pipe:
            self.data.hold(pipe, scene_hash, len(data), key)  # index first: see data_store
            pipe.hset(key, "size", len(data))
            pipe.execute()
        self.data.write_bytes(scene_hash, data)
        self.redis.hdel(key, "data")
        return True
