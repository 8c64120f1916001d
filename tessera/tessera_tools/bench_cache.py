"""The bench's reference cache outside git (~/.cache/tessera/references/ or
$TESSERA_CACHE_DIR), keyed by the scene's files, the settings and the renderer build."""
from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np


def cache_dir() -> Path:
    base = os.environ.get("TESSERA_CACHE_DIR")
    if base:
        return Path(base) / "references"
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "tessera" / "references"


def _file_digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def scene_digest(path: Path) -> str:
    """The root layer and every file beside it (textures, sublayers next to it)."""
    h = hashlib.sha256()
    for p in sorted(q for q in path.parent.iterdir() if q.is_file()):
        h.update(p.name.encode())
        h.update(_file_digest(p).encode())
    return h.hexdigest()


def tessera_build() -> str:
    """Tessera's version and a digest of the compiled core: a rebuilt core is a new renderer."""
    import tessera_renderer._core as core

    from importlib.metadata import PackageNotFoundError, version
    try:
        v = version("tessera")
    except PackageNotFoundError:
        v = "dev"
    return f"tessera {v} core {_file_digest(Path(core.__file__))[:16]}"


def _read_exr(path: Path) -> np.ndarray:
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(path))
    return np.asarray(buf.get_pixels(oiio.FLOAT), dtype=np.float32)[..., :3]


def _write_exr(path: Path, img: np.ndarray) -> None:
    import OpenImageIO as oiio

    img = np.ascontiguousarray(img[..., :3], dtype=np.float32)
    spec = oiio.ImageSpec(img.shape[1], img.shape[0], 3, oiio.FLOAT)
    tmp = path.with_suffix(".tmp.exr")
    out = oiio.ImageOutput.create(str(tmp))
    if out is None or not out.open(str(tmp), spec):
        raise RuntimeError(f"cannot write {path}: {oiio.geterror()}")
    out.write_image(img)
    out.close()
    os.replace(tmp, path)


def cached_render(key: dict, render, log) -> tuple[np.ndarray, dict]:
    """The image for `key` from the cache, or render() -> image (or (image, extra): a dict
    of JSON values kept in the metadata), stored with its key and render time. Returns
    (image, metadata)."""
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:24]
    directory = cache_dir()
    exr, meta_path = directory / f"{digest}.exr", directory / f"{digest}.json"
    if exr.is_file() and meta_path.is_file():
        meta = json.loads(meta_path.read_text())
        meta["cached"] = True
        return _read_exr(exr), meta
    log(f"  rendering reference {key['renderer']} {key['integrator']} {key['spp']} spp seed {key['seed']} "
        f"({key['scene']}) ...")
    start = time.perf_counter()
    img, extra = render(), {}
    if isinstance(img, tuple):
        img, extra = img
    seconds = time.perf_counter() - start
    directory.mkdir(parents=True, exist_ok=True)
    _write_exr(exr, img)
    meta = {"key": key, "seconds": seconds, "file": str(exr), **extra}
    meta_path.write_text(json.dumps(meta, indent=2) + "\n")
    meta["cached"] = False
    log(f"    {seconds:.1f} s -> {exr}")
    return img, meta


# -- renderers -----------------------------------------------------------------------------
