"""What a loose USD layer needs to travel: every layer and asset file it depends on, laid
out relative to one folder (their common ancestor), so that the same relative paths
resolve inside a bundle on another machine.

This is the client's side of a submit: it reads the user's own files, so it trusts the
local filesystem (references may leave the layer's folder). It walks the layers the way
the bundle sandbox's pre-flight does (bundle.preflight: breadth-first, every authored
asset path of every layer listed by UsdUtils.ModifyAssetPaths, so unselected variants,
payloads, clips and textures are all included), but follows `..` instead of refusing it.
Nothing in the user's files is rewritten: the layout keeps every relative path as it is,
and the entry layer is named beside it, wherever it lies in the layout.

Paths that cannot travel are reported, not packed: URIs, absolute paths (the farm's
sandbox refuses them) and files that do not exist.
"""
from __future__ import annotations

import glob
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from .errors import SceneError

_URI = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*:")
# Files whose own asset paths are walked too. A .usdz is packed whole (its members are
# package-relative and travel inside it), so it is not opened.
_WALKED = {".usda", ".usdc", ".usd", ".sdf"}
_LAYERS = _WALKED | {".usdz"}


@dataclass
class Pack:
    """The files a scene needs. `root`: the folder every path in `files` is relative to;
    `entry`: the root layer's path in that layout (POSIX separators)."""

    root: Path
    entry: str
    files: dict[str, Path] = field(default_factory=dict)   # relative path -> file on disk
    missing: list[str] = field(default_factory=list)       # "authored (in layer)": not found
    unportable: list[str] = field(default_factory=list)    # "authored (in layer): why"

    @property
    def total_bytes(self) -> int:
        return sum(p.stat().st_size for p in self.files.values())


def gather(entry: str | Path) -> Pack:
    """The dependency closure of the layer `entry`. Raises SceneError when the entry itself
    cannot be read."""
    from pxr import Sdf, Tf, UsdUtils

    entry_path = Path(os.path.abspath(entry))
    if not entry_path.is_file():
        raise SceneError(f"scene file not found: {entry}")
    if entry_path.suffix.lower() not in _LAYERS:
        raise SceneError(f"{entry_path.name}: not a USD layer (.usda, .usdc, .usd, .usdz)")
    found: dict[str, None] = {str(entry_path): None}   # absolute paths, in discovery order
    missing: list[str] = []
    unportable: list[str] = []
    queue = [str(entry_path)] if entry_path.suffix.lower() in _WALKED else []
    opened: set[str] = set(queue)
    while queue:
        current = queue.pop(0)
        where = os.path.relpath(current, entry_path.parent)
        try:
            layer = Sdf.Layer.FindOrOpen(current)
        except Tf.ErrorException as exc:
            if current == str(entry_path):
                raise SceneError(f"cannot read USD file {entry_path.name}: "
                                 f"{str(exc).strip().splitlines()[0][:300]}") from None
            unportable.append(f"{where}: cannot be read as USD, packed as it is")
            continue
        if layer is None:
            if current == str(entry_path):
                raise SceneError(f"cannot read USD file {entry_path.name}")
            unportable.append(f"{where}: cannot be read as USD, packed as it is")
            continue
        authored_paths: list[str] = []
        UsdUtils.ModifyAssetPaths(layer, lambda p: (authored_paths.append(p), p)[1])
        anchor = os.path.dirname(current)
        for authored in dict.fromkeys(authored_paths):
            if not authored:
                continue
            label = f"{authored} (in {where})"
            if _URI.match(authored):
                unportable.append(f"{label}: a URI; the farm resolves only files in the bundle")
                continue
            if os.path.isabs(authored) or authored.startswith(("/", "\\")):
                unportable.append(f"{label}: an absolute path; the farm resolves only relative "
                                  f"paths inside the bundle (make it relative to its layer)")
                continue
            outer = authored.split("[", 1)[0]   # pkg.usdz[inner.png]: the package travels whole
            target = os.path.normpath(os.path.join(anchor, outer.replace("\\", "/")))
            if "<UDIM>" in target:
                tiles = sorted(glob.glob(glob.escape(target).replace("<UDIM>", "1[0-9][0-9][0-9]")))
                if not tiles:
                    missing.append(label)
                for tile in tiles:
                    found.setdefault(tile)
                continue
            if not os.path.isfile(target):
                missing.append(label)
                continue
            found.setdefault(target)
            suffix = os.path.splitext(target)[1].lower()
            if suffix in _WALKED and target not in opened:
                opened.add(target)
                queue.append(target)
            elif suffix == ".mtlx" and target not in opened:
                opened.add(target)
                _mtlx_textures(target, entry_path.parent, found, missing, unportable)
    root = Path(os.path.commonpath([os.path.dirname(p) for p in found]))
    files = {Path(p).relative_to(root).as_posix(): Path(p) for p in found}
    return Pack(root=root, entry=entry_path.relative_to(root).as_posix(), files=files,
                missing=list(dict.fromkeys(missing)), unportable=list(dict.fromkeys(unportable)))


def _mtlx_textures(path: str, base: Path, found: dict, missing: list, unportable: list) -> None:
    """The image files a MaterialX document names (its `filename` inputs, with fileprefix
    applied), anchored at its folder as the translator reads them (mtlx.py)."""
    import MaterialX as mx

    where = os.path.relpath(path, base)
    doc = mx.createDocument()
    opts = mx.XmlReadOptions()
    opts.readXIncludeFunction = None   # as the translator reads it: includes are not followed
    try:
        with open(path, encoding="utf-8") as f:
            mx.readFromXmlString(doc, f.read(), mx.FileSearchPath(), opts)
    except (OSError, UnicodeDecodeError, mx.Exception) as exc:
        unportable.append(f"{where}: cannot be read as MaterialX ({exc}), packed as it is")
        return
    for element in doc.traverseTree():
        if not element.isA(mx.Input) or element.getType() != "filename":
            continue
        authored = element.getResolvedValueString()
        if not authored:
            continue
        label = f"{authored} (in {where})"
        if _URI.match(authored) or os.path.isabs(authored):
            unportable.append(f"{label}: not a relative path; the farm resolves only relative paths "
                              f"inside the bundle")
            continue
        target = os.path.normpath(os.path.join(os.path.dirname(path), authored))
        if "<UDIM>" in target:
            tiles = sorted(glob.glob(glob.escape(target).replace("<UDIM>", "1[0-9][0-9][0-9]")))
            for tile in tiles:
                found.setdefault(tile)
            if not tiles:
                missing.append(label)
        elif os.path.isfile(target):
            found.setdefault(target)
        else:
            missing.append(label)
