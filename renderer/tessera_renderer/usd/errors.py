"""The one error of scene translation, raised wherever a stage cannot be rendered, and the
reads that turn what a malformed stage makes USD do into it."""

import numpy as np


class SceneError(Exception):
    """The scene cannot be rendered; the message says why, for the person who sent it."""


def read_float(attr, time, fallback: float = 0.0) -> float:
    """The attribute's value at `time` as a float, `fallback` when it has none. USD accepts
    any value in a scalar attribute's place (`float x = </Path>` composes), so a value that
    is not a number is the sender's error, named here rather than a TypeError deep inside."""
    value = attr.Get(time)
    if value is None:
        return float(fallback)
    try:
        return float(value)
    except (TypeError, ValueError):
        raise SceneError(f"{attr.GetPath()}: expected a number, got {value!r}") from None


def local_to_world(xform_cache, prim) -> np.ndarray:
    """The prim's 4x4 world matrix (float64, USD's row-vector convention) from an
    XformCache. An xformOp holding a value of the wrong kind (`xformOp:scale = </Path>`)
    makes USD raise; that is the sender's error, named with the prim."""
    from pxr import Tf

    try:
        return np.array(xform_cache.GetLocalToWorldTransform(prim), dtype=np.float64)
    except Tf.ErrorException as exc:
        detail = str(exc).strip().splitlines()[-1].strip()
        raise SceneError(f"{prim.GetPath()}: its transform cannot be evaluated ({detail})") from None


def read_floats(attr, time, fallback: tuple[float, ...]) -> np.ndarray:
    """The attribute's tuple value at `time` (float64, as long as `fallback`), `fallback`
    when it has none; a value of another kind or length is the sender's error."""
    value = attr.Get(time)
    if value is None:
        return np.array(fallback, np.float64)
    try:
        out = np.array(value, np.float64).reshape(-1)
    except (TypeError, ValueError):
        out = None
    if out is None or out.shape != (len(fallback),):
        raise SceneError(f"{attr.GetPath()}: expected {len(fallback)} numbers, got {value!r}")
    return out
