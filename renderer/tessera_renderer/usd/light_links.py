"""UsdLux light linking and shadow linking: which geometry a light illuminates
(`collection:lightLink`) and which casts its shadows (`collection:shadowLink`), as the
core's link table (renderer/core/lights/light_links.h).

Only lights whose collections leave something out get a link: a collection with
includeRoot true (the schema's fallback), no excludes and no membership expression holds
every prim. Surfaces are sorted into link groups by the prims they come from: a group is
the surfaces every linked light's two collections treat alike, group 0 those that are in
all of them. The group rides on the material row (SceneData.light_links["material_group"]),
so triangles, curves and instance prototypes need no table of their own.
"""
from __future__ import annotations

import numpy as np


def _holds_everything(collection) -> bool:
    """Whether the collection includes every prim, as its fallbacks do."""
    if not collection.GetIncludeRootAttr().Get():
        return False
    if collection.GetExcludesRel().GetTargets():
        return False
    expression = collection.GetMembershipExpressionAttr()
    return not (expression and expression.HasAuthoredValue())


class LightLinks:
    """The stage's linked lights and the link groups of the prims asked about."""

    def __init__(self, stage) -> None:
        from pxr import UsdLux

        self.paths: list[str] = []
        self._queries: list = []  # per linked light: (light-link query, shadow-link query)
        for prim in stage.Traverse():
            if not prim.HasAPI(UsdLux.LightAPI):
                continue
            api = UsdLux.LightAPI(prim)
            light, shadow = api.GetLightLinkCollectionAPI(), api.GetShadowLinkCollectionAPI()
            if _holds_everything(light) and _holds_everything(shadow):
                continue
            self.paths.append(str(prim.GetPath()))
            self._queries.append((light.ComputeMembershipQuery(), shadow.ComputeMembershipQuery()))
        self._index = {p: i for i, p in enumerate(self.paths)}
        # Membership signature -> group; the signature of a prim in every collection is 0.
        self._groups: dict[tuple[bool, ...], int] = {}
        if self.paths:
            self._groups[(True,) * (2 * len(self.paths))] = 0
        self._group_of_path: dict[str, int] = {}

    def __bool__(self) -> bool:
        return bool(self.paths)

    def link_of(self, path) -> int:
        """The link number of the light at `path`; -1 when its collections hold everything."""
        return self._index.get(str(path), -1)

    def group_of(self, path) -> int:
        """The link group of the prim at `path` (0 without linked lights)."""
        if not self.paths:
            return 0
        key = str(path)
        group = self._group_of_path.get(key)
        if group is None:
            from pxr import Sdf

            p = Sdf.Path(key)
            signature = tuple(q.IsPathIncluded(p) for pair in self._queries for q in pair)
            group = self._groups.setdefault(signature, len(self._groups))
            self._group_of_path[key] = group
        return group

    def tables(self) -> tuple[np.ndarray, np.ndarray]:
        """(illuminates, shadows): uint8 (links, groups) flags."""
        links, groups = len(self.paths), len(self._groups)
        illuminates = np.ones((links, groups), np.uint8)
        shadows = np.ones((links, groups), np.uint8)
        for signature, g in self._groups.items():
            flags = np.asarray(signature, bool).reshape(links, 2)
            illuminates[:, g] = flags[:, 0]
            shadows[:, g] = flags[:, 1]
        return illuminates, shadows
