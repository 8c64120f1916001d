"""The job's bundle is a sandbox: every asset a scene names must resolve inside it.

A bundle is one of
- a loose .usda/.usdc/.usd file: the bundle is the directory holding it (or `root`),
- a .usdz package or a .zip archive: unpacked into a fresh private directory first.

`open_bundle` unpacks (with a zip-bomb guard) and pre-flights every dependency with our
own breadth-first walk (`preflight`): each authored asset path is checked before the layer
it names is opened; a path that is a URI, absolute, escapes the bundle (`..`, or a symlink
on disk), or needs a search-path lookup is refused, so no file outside the bundle is ever
opened. `open_stage` then opens the stage with resolver search paths cleared and checks
again that every layer the stage used lies inside; `Bundle.resolve_texture` does the same
for each texture the translator reads, reading textures inside referenced (or nested)
packages from their zip members.

Every rejection is a SceneError whose message names the offending path.
"""
from __future__ import annotations

from collections.abc import Sequence

import os
import re
import shutil
import stat
import tempfile
import weakref
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from .errors import SceneError

USD_SUFFIXES = (".usda", ".usdc", ".usd", ".usdz")
BUNDLE_SUFFIXES = USD_SUFFIXES + (".zip",)
_URI = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*:")   # also catches Windows drives (C:)
_LAYER_EXTENSIONS = {".usda", ".usdc", ".usd", ".usdz", ".sdf"}


def _env_int(name: str, default: int) -> int:
    try:
        return int(os.environ.get(name, default))
    except ValueError:
        return default


@dataclass(frozen=True)
class Limits:
    """What one job may contain. Environment variables TESSERA_MAX_* override the defaults."""

    unpacked_bytes: int = _env_int("TESSERA_MAX_UNPACKED_BYTES", 2 << 30)
    files: int = _env_int("TESSERA_MAX_FILES", 20_000)
    prims: int = _env_int("TESSERA_MAX_PRIMS", 2_000_000)
    # 16 M: what the service's pre-flight can translate in its default 8 GiB (about
    # 300 bytes a triangle; tessera_service.preflight.triangle_limit).
    triangles: int = _env_int("TESSERA_MAX_TRIANGLES", 16_000_000)
    texture_pixels: int = _env_int("TESSERA_MAX_TEXTURE_PIXELS", 16384 * 16384)
    # compressed -> uncompressed ratio above which one zip member is called a bomb
    compression_ratio: int = _env_int("TESSERA_MAX_COMPRESSION_RATIO", 200)


DEFAULT_LIMITS = Limits()


@dataclass
class Bundle:
    """An opened, pre-flighted bundle. `root` is the directory containment is checked
    against; `root_layer` the layer to open. Holds the unpack directory alive."""

    root: Path
    root_layer: Path
    limits: Limits = DEFAULT_LIMITS
    warnings: list[str] = field(default_factory=list)
    _tmp: str | None = None
    # Layers some asset path names but the bundle lacks, as (authored, anchored path,
    # where): whether that is fatal depends on whether the composed stage uses them
    # (an unselected variant's layer is not used); open_stage decides.
    unresolved_layers: list[tuple[str, str, str]] = field(default_factory=list)
    # Rooted at "/": the user's own files on their own machine (`tessera render` without
    # --sandbox). Every path is inside such a bundle, and absolute asset paths are
    # allowed too; URIs and search-path lookups still are not.
    trusted: bool = False

    def __post_init__(self) -> None:
        if self._tmp:
            # The unpacked files must outlive the Python object only as long as the Scene
            # that points at its textures; the finalizer removes them after that.
            self._finalizer = weakref.finalize(self, shutil.rmtree, self._tmp, True)

    def cleanup(self) -> None:
        if self._tmp:
            self._finalizer()
        if getattr(self, "_members", None) is not None:
            self._members_finalizer()

    def package_member(self, package_path: str, where: str) -> Path | None:
        """A file inside a (possibly nested) package, `pkg.usdz[dir/tex.png]` or
        `a.usdz[b.usdz[tex.png]]`, copied out into this bundle's private directory so
        image readers can open it; None when the member does not exist. The outermost
        package must lie inside the bundle and no member path may climb out of its
        package; member sizes obey the unpacking limits."""
        if getattr(self, "_members", None) is None:
            self._members = tempfile.mkdtemp(prefix="tessera-members-")
            self._members_finalizer = weakref.finalize(self, shutil.rmtree, self._members, True)
            self._member_files: dict[str, Path] = {}
        if package_path in self._member_files:
            return self._member_files[package_path]
        outer, _ = split_package_path(package_path)
        _contained(outer, str(self.root), self.root, f"texture of {where}")
        data = read_package_member(package_path, self.limits, where)
        if data is None:
            return None
        inner_name = package_path.rstrip("]").rsplit("[", 1)[-1]
        target = Path(self._members, str(len(self._member_files)), PurePosixPath(inner_name).name)
        target.parent.mkdir()
        fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
        with os.fdopen(fd, "wb") as out:
            out.write(data)
        self._member_files[package_path] = target
        return target

    # -- containment ---------------------------------------------------------------
    def check_asset(self, authored: str, anchor_dir: str, *, what: str) -> Path:
        """The absolute path inside the bundle that `authored` (as written in a layer whose
        directory is `anchor_dir`) names; SceneError if it would leave the bundle."""
        return _contained(authored, anchor_dir, self.root, what)

    def resolve_texture(self, asset, layer_dir: str | None, where: str) -> Path | None:
        """The texture file an Sdf.AssetPath names, checked for containment; None (the
        caller warns) when it does not exist."""
        authored = asset.path if hasattr(asset, "path") else str(asset)
        if not authored:
            return None
        resolved = getattr(asset, "resolvedPath", "") or ""
        if "[" in resolved:
            # Inside a package that is not the bundle itself (a .usdz referenced or
            # sublayered from another layer, possibly nested): read from the package.
            return self.package_member(resolved, where)
        if resolved:
            path = _contained(resolved, str(self.root), self.root, f"texture of {where}")
        else:
            path = _contained(authored, layer_dir or str(self.root), self.root, f"texture of {where}")
        probe = Path(str(path).replace("<UDIM>", "1001"))
        if "<UDIM>" in str(path):
            tiles = list(path.parent.glob(path.name.replace("<UDIM>", "1[0-9][0-9][0-9]")))
            for tile in tiles:  # every tile, not just the first, may be a symlink
                _contained(str(tile), str(self.root), self.root, f"texture of {where}")
            return path if tiles else None
        return path if probe.is_file() else None


def split_package_path(path: str) -> tuple[str, str]:
    """`a.usdz[b.usdz[c.png]]` -> ("a.usdz", "b.usdz[c.png]"); no brackets: (path, "")."""
    if "[" not in path:
        return path, ""
    outer, _, rest = path.partition("[")
    if not rest.endswith("]"):
        raise SceneError(f"asset path {path!r} is not a valid path inside a package")
    return outer, rest[:-1]


def _member_name(inner: str, what: str) -> str:
    name = os.path.normpath(inner.replace("\\", "/"))
    if name.startswith("..") or os.path.isabs(name) or "\x00" in name:
        raise SceneError(f"{what}: {inner!r} climbs out of its package")
    return name


def read_package_member(path: str, limits: Limits, what: str, exists_only: bool = False) -> bytes | None:
    """The bytes of `outer.usdz[member]`, following nested packages; None when a member
    is missing (with `exists_only`, b"" when it is there, without reading it). Only zip
    members are read (nothing is unpacked onto disk)."""
    import io

    outer, inner = split_package_path(path)
    source: object = outer
    while inner:
        head, rest = split_package_path(inner) if "[" in inner else (inner, "")
        name = _member_name(head, what)
        try:
            with zipfile.ZipFile(source) as zf:
                try:
                    info = zf.getinfo(name)
                except KeyError:
                    return None
                if info.file_size > limits.unpacked_bytes or (
                        info.compress_size and info.file_size > limits.compression_ratio * max(info.compress_size, 1024)):
                    raise SceneError(f"{what}: package member {name!r} is too large (zip bomb guard)")
                if info.flag_bits & 0x1:
                    raise SceneError(f"{what}: package member {name!r} is encrypted")
                if exists_only and not rest:
                    return b""
                data = zf.read(info)
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError, NotImplementedError) as exc:
            raise SceneError(f"{what}: cannot read package member {name!r} ({exc})") from None
        if not rest:
            return data
        source, inner = io.BytesIO(data), rest
    return None


def _contained(path: str, anchor_dir: str, root: Path, what: str) -> Path:
    """`path` anchored at `anchor_dir` (an absolute `path` is taken as it is: callers pass
    resolved paths here, authored absolute paths are refused before), if it lies inside
    `root` both as written and after following symlinks."""
    if "\x00" in path:
        raise SceneError(f"{what}: asset path {path!r} contains a NUL byte")
    if _URI.match(path):
        raise SceneError(f"{what}: asset path {path!r} is a URI; only files inside the bundle are allowed")
    if os.path.isabs(path):
        candidate = os.path.normpath(path)
    else:
        candidate = os.path.normpath(os.path.join(anchor_dir, path.replace("\\", "/")))
    root_s = os.path.normpath(str(root))
    if os.path.commonpath([candidate, root_s]) != root_s:
        raise SceneError(f"{what}: asset path {path!r} resolves outside the bundle")
    # A symlink on disk may point anywhere: compare real paths as well.
    real = os.path.realpath(candidate.replace("<UDIM>", "1001"))
    real_root = os.path.realpath(root_s)
    if os.path.exists(real) and os.path.commonpath([real, real_root]) != real_root:
        raise SceneError(f"{what}: asset path {path!r} is a symlink leading outside the bundle")
    return Path(candidate)


# -- unpacking ----------------------------------------------------------------------
def _check_member(info: zipfile.ZipInfo, archive: str) -> str | None:
    """The member's safe relative name, None for a directory; SceneError otherwise."""
    name = info.filename
    if "\x00" in name or "\\" in name:
        raise SceneError(f"{archive}: member {name!r} has an invalid name")
    if name.startswith("/") or _URI.match(name):
        raise SceneError(f"{archive}: member {name!r} has an absolute name")
    parts = PurePosixPath(name).parts
    if ".." in parts:
        raise SceneError(f"{archive}: member {name!r} escapes the archive with '..'")
    mode = info.external_attr >> 16
    if info.create_system == 3 and mode:  # made on Unix: the high bits are st_mode
        if stat.S_ISLNK(mode):
            raise SceneError(f"{archive}: member {name!r} is a symlink; symlinks are not allowed")
        if stat.S_IFMT(mode) not in (0, stat.S_IFREG, stat.S_IFDIR):  # 0: permissions only
            raise SceneError(f"{archive}: member {name!r} is not a regular file")
    if info.flag_bits & 0x1:
        raise SceneError(f"{archive}: member {name!r} is encrypted")
    if name.endswith("/"):
        return None
    return "/".join(p for p in parts if p not in ("", "."))


def unpack_archive(archive: Path, dest: Path, limits: Limits = DEFAULT_LIMITS) -> list[str]:
    """Unpacks a .zip or .usdz into `dest` (which must be empty), refusing absolute names,
    `..`, symlinks, duplicate names and anything over the limits. Returns the member names
    in archive order. Sizes are checked as declared and again as actually inflated."""
    label = archive.name
    try:
        zf = zipfile.ZipFile(archive)
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise SceneError(f"{label}: not a readable zip archive ({exc})") from None
    with zf:
        infos = zf.infolist()
        if len(infos) > limits.files:
            raise SceneError(f"{label}: {len(infos)} members, more than the limit of {limits.files} files")
        names: list[str] = []
        seen: set[str] = set()
        declared = 0
        for info in infos:
            rel = _check_member(info, label)
            if rel is None:
                continue
            if rel.lower() in seen:
                raise SceneError(f"{label}: member {rel!r} appears twice")
            seen.add(rel.lower())
            declared += info.file_size
            if declared > limits.unpacked_bytes:
                raise SceneError(f"{label}: unpacks to more than {limits.unpacked_bytes} bytes "
                                 f"(at member {rel!r})")
            if info.compress_size and info.file_size > limits.compression_ratio * max(info.compress_size, 1024):
                raise SceneError(f"{label}: member {rel!r} inflates {info.file_size // info.compress_size}x "
                                 f"(zip bomb guard)")
            names.append(rel)
        total = 0
        for info, rel in zip([i for i in infos if not i.filename.endswith("/")], names):
            target = dest.joinpath(*rel.split("/"))
            target.parent.mkdir(parents=True, exist_ok=True)
            written = 0
            try:
                fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
                with zf.open(info) as src, os.fdopen(fd, "wb") as out:
                    while chunk := src.read(1 << 20):
                        written += len(chunk)
                        total += len(chunk)
                        # The declared size can lie; the inflated bytes cannot.
                        if written > info.file_size or total > limits.unpacked_bytes:
                            raise SceneError(f"{label}: member {rel!r} inflates past its declared size "
                                             f"or the limit of {limits.unpacked_bytes} bytes (zip bomb guard)")
                        out.write(chunk)
            except (zipfile.BadZipFile, zlib.error, OSError, EOFError, NotImplementedError) as exc:
                raise SceneError(f"{label}: member {rel!r} cannot be unpacked ({exc})") from None
    return names


def _pick_root_layer(names: list[str], label: str, package: bool, entry: str | None = None) -> str:
    """The root layer: the first member for a .usdz (the package rule); for a .zip the
    member its comment names (`tessera-entry: PATH`, as a packed scene has), else the only
    USD file at the top level, else the first member when it is a USD file."""
    usd = [n for n in names if PurePosixPath(n).suffix.lower() in USD_SUFFIXES]
    if not usd:
        raise SceneError(f"{label}: no USD layer inside ({', '.join(names[:5]) or 'empty archive'})")
    if entry is not None and not package:
        if entry not in usd:
            raise SceneError(f"{label}: the entry layer {entry!r} its comment names is not a USD layer in it")
        return entry
    if package:
        if PurePosixPath(names[0]).suffix.lower() not in (".usda", ".usdc", ".usd"):
            raise SceneError(f"{label}: the first member {names[0]!r} of a usdz must be a USD layer")
        return names[0]
    top = [n for n in usd if "/" not in n]
    if len(top) == 1:
        return top[0]
    if names and names[0] in usd:
        return names[0]
    raise SceneError(f"{label}: cannot tell the root layer among {', '.join(top or usd)}; "
                     f"put it first in the archive or make it the only USD file at the top level")


_ENTRY_COMMENT = b"tessera-entry: "


def _zip_entry(path: Path) -> str | None:
    """The root layer a zip's comment names (`tessera-entry: PATH`, written by the
    service when it assembles a packed scene), or None."""
    try:
        with zipfile.ZipFile(path) as zf:
            comment = zf.comment
    except (zipfile.BadZipFile, OSError, ValueError):
        return None  # unpack_archive has refused it already
    if not comment.startswith(_ENTRY_COMMENT):
        return None
    return comment[len(_ENTRY_COMMENT):].decode("utf-8", "replace").strip()


def open_bundle(path: str | Path, *, root: str | Path | None = None,
                limits: Limits = DEFAULT_LIMITS) -> Bundle:
    """Unpacks (if needed) and pre-flights a bundle. Raises SceneError naming the offending
    file or asset path. For a loose layer, `root` (default: its directory) is the sandbox;
    `root="/"` trusts the whole local filesystem (Bundle.trusted)."""
    path = Path(path).absolute()
    if not path.is_file():
        raise SceneError(f"scene file not found: {path}")
    suffix = path.suffix.lower()
    if suffix not in BUNDLE_SUFFIXES:
        raise SceneError(f"{path.name}: unsupported file type {suffix or '(none)'}; "
                         f"use {', '.join(BUNDLE_SUFFIXES)}")
    if path.stat().st_size == 0:
        raise SceneError(f"{path.name}: the file is empty")
    if suffix in (".zip", ".usdz"):
        # The pid in the name lets the next API (or this one, once an inspection has
        # died) remove it when this process is killed (tessera_base.process).
        tmp = tempfile.mkdtemp(prefix=f"tessera-bundle-{os.getpid()}-")
        try:
            names = unpack_archive(path, Path(tmp), limits)
            rel = _pick_root_layer(names, path.name, suffix == ".usdz", _zip_entry(path))
            bundle = Bundle(Path(os.path.realpath(tmp)), Path(os.path.realpath(tmp), rel), limits, _tmp=tmp)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    else:
        base = Path(os.path.realpath(root if root is not None else path.parent))
        real = Path(os.path.realpath(path))
        if os.path.commonpath([str(real), str(base)]) != str(base):
            raise SceneError(f"{path.name}: the root layer is outside its bundle {base}")
        bundle = Bundle(base, real, limits, trusted=str(base) == os.path.realpath("/"))
    try:
        preflight(bundle)
    except BaseException:
        bundle.cleanup()
        raise
    return bundle


def preflight(bundle: Bundle) -> None:
    """Walks every layer and asset path the root layer depends on (all variants, payloads,
    clips, textures) and rejects anything that leaves the bundle.

    The walk is our own breadth-first search: a layer is opened (Sdf.Layer.FindOrOpen)
    only after its path passed the checks, and `UsdUtils.ModifyAssetPaths` with an
    identity function lists a layer's asset paths without opening anything.
    (UsdUtils.ComputeAllDependencies opens sublayers before its processing callback sees
    them, so it cannot be the gate.)"""
    from pxr import Sdf, Tf, UsdUtils

    _clear_search_paths()
    problems: list[str] = []
    missing: list[str] = []
    seen: set[str] = set()
    queue = [str(bundle.root_layer)]
    seen.add(queue[0])
    while queue:
        identifier = queue.pop(0)
        where = _rel(identifier, bundle.root)
        try:
            layer = Sdf.Layer.FindOrOpen(identifier)
        except Tf.ErrorException as exc:
            problems.append(f"cannot read USD file {where}: {_error_text(exc, bundle.root)}")
            continue
        if layer is None:
            problems.append(f"cannot read USD file {where}")
            continue
        authored_paths: list[str] = []
        UsdUtils.ModifyAssetPaths(layer, lambda p: (authored_paths.append(p), p)[1])
        for authored in dict.fromkeys(authored_paths):
            try:
                target = _check_dependency(bundle, layer, authored, where)
            except SceneError as exc:
                problems.append(str(exc))
                continue
            if target is None:
                continue
            outer = target.split("[", 1)[0]
            is_layer = os.path.splitext(target.rstrip("]"))[1].lower() in _LAYER_EXTENSIONS
            probe = outer.replace("<UDIM>", "1001")
            if "<UDIM>" in outer:
                continue  # texture tiles: checked for containment, read by the translator
            member_missing = "[" in target and os.path.exists(probe) and not is_layer and \
                read_package_member(target, bundle.limits, where, exists_only=True) is None
            if not os.path.exists(probe) or member_missing:
                if is_layer and authored.startswith(("./", "../")) and "[" not in target:
                    bundle.unresolved_layers.append((authored, target, where))
                elif is_layer and _names_itself(layer, authored):
                    continue  # assetInfo's identifier (`@Teapot.usd@`): nothing opens it
                elif is_layer:
                    # Refused even when unused: USD would look such a path up relative to
                    # the working directory (outside the bundle) when composing.
                    problems.append(f"{where}: layer {authored!r} is not in the bundle"
                                    + ("" if authored.startswith(("./", "../")) else
                                       " (search-path lookups are not allowed)"))
                else:
                    missing.append(f"{authored} (in {where})")
                continue
            if is_layer:
                if "[" not in target and os.path.getsize(outer) == 0:
                    problems.append(f"{where}: layer {authored!r} is an empty file")
                    continue
                if target not in seen:
                    seen.add(target)
                    if len(seen) > bundle.limits.files:
                        raise SceneError(f"the bundle references more than {bundle.limits.files} layers (limit)")
                    queue.append(target)
    if missing:
        unique_missing = list(dict.fromkeys(missing))
        bundle.warnings.append(f"{len(unique_missing)} asset(s) missing from the bundle, rendered without "
                               f"them: {', '.join(unique_missing[:4])}" + (" ..." if len(unique_missing) > 4 else ""))
    if problems:
        unique = list(dict.fromkeys(problems))
        raise SceneError("; ".join(unique[:5]) + (f" (and {len(unique) - 5} more)" if len(unique) > 5 else ""))


def _names_itself(layer, authored: str) -> bool:
    """Whether `authored` is only a prim's assetInfo identifier in `layer` (how an asset
    names itself, `identifier = @Teapot.usd@`) and no sublayer, reference or payload: an
    upload stored under another name would otherwise be refused for naming its own file.
    Value clips and the like, which USD does open, are not exempt."""
    from pxr import Sdf

    if authored in layer.GetCompositionAssetDependencies():
        return False
    identifiers: set[str] = set()

    def visit(path) -> None:
        if path.IsPrimPath():
            spec = layer.GetPrimAtPath(path)
            ident = (spec.assetInfo or {}).get("identifier") if spec else None
            if ident is not None:
                identifiers.add(getattr(ident, "path", str(ident)))

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return authored in identifiers and not _has_clips(layer, authored)


def _has_clips(layer, authored: str) -> bool:
    """Whether `authored` appears in the layer's text where it is more than an identifier
    (clip asset paths, attribute values): counted occurrences beyond the identifiers'."""
    text = layer.ExportToString()
    return text.count(f"@{authored}@") > text.count(f"identifier = @{authored}@")


def _check_dependency(bundle: Bundle, layer, authored: str, where: str) -> str | None:
    """The identifier an asset path of `layer` names, if it stays inside the bundle."""
    from pxr import Sdf

    if not authored:
        return None
    if "\x00" in authored:
        raise SceneError(f"{where}: asset path {authored!r} contains a NUL byte")
    if _URI.match(authored):
        raise SceneError(f"{where}: asset path {authored!r} is a URI; only files inside the bundle are allowed")
    if (authored.startswith(("/", "\\")) or os.path.isabs(authored)) and not bundle.trusted:
        raise SceneError(f"{where}: asset path {authored!r} is absolute; only relative paths inside "
                         f"the bundle are allowed")
    real = layer.realPath or layer.identifier
    if "[" in authored:
        # A package-relative path (pkg.usdz[inner]): the package must be inside the bundle
        # and the inner path must stay inside the package.
        outer, _, inner = authored.partition("[")
        inner_norm = os.path.normpath(inner.rstrip("]").replace("\\", "/"))
        if not authored.endswith("]") or inner_norm.startswith("..") or os.path.isabs(inner_norm) \
                or "[" in inner:
            raise SceneError(f"{where}: asset path {authored!r} is not a valid path inside a package")
        anchor = os.path.dirname(real.split("[", 1)[0])
        package = bundle.check_asset(outer, anchor, what=where)
        return f"{package}[{inner_norm}]"
    if "[" in real or real.lower().endswith(".usdz"):
        # Inside a package that is not the bundle itself (a referenced .usdz, or one
        # nested in it): anchored within it, and must not climb out of it.
        anchored = Sdf.ComputeAssetPathRelativeToLayer(layer, authored)
        outer, _, inner = anchored.partition("[")
        inner_norm = os.path.normpath(inner.rstrip("]").replace("\\", "/"))
        if inner_norm.startswith("..") or os.path.isabs(inner_norm) or not anchored.endswith("]"):
            raise SceneError(f"{where}: asset path {authored!r} resolves outside its package")
        bundle.check_asset(outer, str(bundle.root), what=where)
        return anchored
    return str(bundle.check_asset(authored, os.path.dirname(real), what=where))


def open_stage(bundle: Bundle, variants: Sequence[tuple[str, str, str]] = ()):
    """Opens the pre-flighted root layer with search paths cleared, then checks that every
    layer the composed stage used lies inside the bundle. `variants`, (prim path, variant
    set, variant) each, select variants in a session layer, so the stage composes -- and
    the checks see -- what they select."""
    from pxr import Ar, Sdf, Tf, Usd

    _clear_search_paths()
    session = Sdf.Layer.CreateAnonymous("variants.usda")
    selections = []
    for path, set_name, value in variants:
        text = f"{path}:{set_name}={value}"
        if not Sdf.Path.IsValidPathString(path) or not Sdf.Path(path).IsPrimPath():
            raise SceneError(f"variant {text!r}: {path!r} is not a prim path")
        Sdf.CreatePrimInLayer(session, path).variantSelections[set_name] = value
        selections.append((text, path, set_name, value))
    try:
        if selections:
            root_layer = Sdf.Layer.FindOrOpen(str(bundle.root_layer))
            stage = root_layer and Usd.Stage.Open(root_layer, session, Ar.DefaultResolverContext([]),
                                                  Usd.Stage.LoadAll)
        else:
            stage = Usd.Stage.Open(str(bundle.root_layer), Ar.DefaultResolverContext([]), Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise SceneError(f"cannot read USD file {bundle.root_layer.name}: {_error_text(exc, bundle.root)}") from None
    if stage is None:
        raise SceneError(f"cannot read USD file {bundle.root_layer.name}")
    for text, path, set_name, value in selections:
        _check_variant(stage, text, path, set_name, value)
    root = os.path.realpath(str(bundle.root))
    for layer in stage.GetUsedLayers():
        if layer.anonymous:
            continue
        real = os.path.realpath((layer.realPath or layer.identifier).split("[", 1)[0])
        if os.path.commonpath([real, root]) != root:
            raise SceneError(f"layer {layer.identifier} lies outside the bundle")
    errors = [str(err.GetMessage()) if hasattr(err, "GetMessage") else str(err)
              for err in stage.GetCompositionErrors()]
    # A missing layer is fatal only when the composed stage (with its variant selections)
    # asks for it; one only an unselected variant names is information.
    used, unused = [], []
    for authored, target, where in bundle.unresolved_layers:
        asked = any(f"@{target}@" in text or f"@{authored}@" in text for text in errors)
        (used if asked else unused).append(f"{where}: layer {authored!r} is not in the bundle")
    if used:
        unique = list(dict.fromkeys(used))
        raise SceneError("; ".join(unique[:5]) + (f" (and {len(unique) - 5} more)" if len(unique) > 5 else ""))
    if unused:
        unique = list(dict.fromkeys(unused))
        bundle.warnings.append(f"information: {len(unique)} layer(s) missing from the bundle are not used "
                               f"by the composed stage (e.g. only by unselected variants): "
                               + "; ".join(unique[:4]) + (" ..." if len(unique) > 4 else ""))
    missing_targets = {t for _, t, _ in bundle.unresolved_layers} | {a for a, _, _ in bundle.unresolved_layers}
    for text in errors:
        if "cycle" in text.lower():
            raise SceneError(f"composition cycle: {_first_line(text)}")
        if any(f"@{m}@" in text for m in missing_targets):
            continue  # reported above
        if ".mtlx@" in text:
            continue  # usd-core has no .mtlx format; the translator reads such looks itself
        bundle.warnings.append(f"composition: {_first_line(user_terms(text, bundle.root))}")
    return stage


def _check_variant(stage, text: str, path: str, set_name: str, value: str) -> None:
    """A selection must name a prim of the composed stage, one of its variant sets and one
    of that set's variants (or "" for none): else the render would silently be another."""
    prim = stage.GetPrimAtPath(path)
    if not prim or not prim.IsDefined():  # the selection's own "over" is no prim of the scene
        raise SceneError(f"variant {text!r}: the stage has no prim {path}")
    sets = prim.GetVariantSets()
    if not sets.HasVariantSet(set_name):
        names = sets.GetNames()
        raise SceneError(f"variant {text!r}: {path} has no variant set {set_name!r} "
                         f"({'its sets: ' + ', '.join(names) if names else 'it has none'})")
    choices = sets.GetVariantSet(set_name).GetVariantNames()
    if value and value not in choices:
        raise SceneError(f"variant {text!r}: {path}'s set {set_name!r} has no variant {value!r} "
                         f"(choices: {', '.join(choices)})")


_search_cleared = False


def _clear_search_paths() -> None:
    # The default resolver's search paths come from PXR_AR_DEFAULT_SEARCH_PATH; a bundle
    # must never be able to reach them.
    global _search_cleared
    if not _search_cleared:
        from pxr import Ar
        Ar.DefaultResolver.SetDefaultSearchPath([])
        _search_cleared = True


def _rel(path: str, root: Path) -> str:
    if Path(root) == Path("/"):
        return path  # a trusted local render: the full path says most
    try:
        return str(Path(path.split("[", 1)[0]).relative_to(root)) + (
            "[" + path.split("[", 1)[1] if "[" in path else "")
    except ValueError:
        return path


def _error_text(exc: Exception, root=None) -> str:
    """The first lines of a USD error, in the user's terms: paths inside the bundle (not
    the server's unpack directory), without USD's source locations, C++ namespaces or
    pointer addresses. str() of the error raises UnicodeDecodeError when the file holds
    bytes that are not UTF-8."""
    try:
        text = str(exc)
    except UnicodeDecodeError:
        return "the file is corrupt or not UTF-8 text (undecodable bytes in USD's error message)"
    return _first_line(user_terms(text, root))


_USD_SOURCE = re.compile(r"Error in '[^']*' at line \d+ in file [^ ]+ : ")
_USD_NAMESPACE = re.compile(r"\bpxrInternal_v[0-9_]+__pxrReserved__::")
_POINTER = re.compile(r"\b0x[0-9a-fA-F]{6,}\b")


def user_terms(text: str, root=None) -> str:
    """An error text for the person who uploaded the scene: the bundle's directory (and
    its real path) removed from paths, and USD's internals left out."""
    for base in {str(root), os.path.realpath(str(root))} if root is not None else ():
        if base.rstrip("/"):  # a bundle rooted at "/" (a trusted local render) keeps its paths
            text = text.replace(base.rstrip("/") + "/", "")
    text = _USD_SOURCE.sub("", text)
    text = _USD_NAMESPACE.sub("", text)
    return _POINTER.sub("<address>", text)


def _first_line(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return "; ".join(lines[:3])[:500] if lines else "unknown error"
