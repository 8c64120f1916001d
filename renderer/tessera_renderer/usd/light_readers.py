"""The registry of UsdLux light readers: which reader translates which UsdLux schema. A
light kind's reader registers itself with one line, `@reads("SchemaName")`, in its own
module; the translator (usd/lights.py, LightReader.add_light) asks this table and knows
no schema by name. Below the readers, so that they and the translator import it without a
cycle.

A kind the core takes in rows (tessera_renderer._core.light_kinds(): its row columns > 0)
needs nothing else on its route: its reader appends rows with LightReader.add_light_row,
and the translated scene, the scene blob and the binding carry every such kind's rows by
its name (SceneData.light_rows). The first three columns of a row are a position: moving
the scene to the camera (usd/camera.py) moves them."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class LightReaderEntry:
    schema: str                  # the UsdLux type name, e.g. "PortalLight"
    read: Callable               # read(translator, prim): adds the light, or warns and skips it
    finish: Callable | None      # finish(translator): after the walk, for checks across lights


READERS: dict[str, LightReaderEntry] = {}


def reads(schema: str, finish: Callable | None = None):
    """Registers the decorated function as the reader of UsdLux `schema` (one per schema)."""
    def register(read: Callable) -> Callable:
        if schema in READERS:
            raise ValueError(f"two readers for UsdLux {schema}")
        READERS[schema] = LightReaderEntry(schema, read, finish)
        return read
    return register


def row_columns(kind: str) -> int:
    """How many floats a row of core light kind `kind` holds (0: not handed over in rows)."""
    from .. import _core

    for name, _, columns in _core.light_kinds():
        if name == kind:
            return int(columns)
    raise ValueError(f"the renderer core has no light kind {kind!r}")
