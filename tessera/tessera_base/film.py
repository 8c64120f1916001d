"""Tile passes and the image they make: the one place where a tile pass is rendered
(`render_tile_pass`: local renders, the worker's render process, the bench), where an
image is assembled from tile results (`assemble_image`: local renders and the service's
merge), and where splats are normalised (`resolve_splats`). Farm and local images are
equal because both run this code, not because two copies agree.

Splats. A tile rendered by a splatting integrator (tessera_base.integrators) returns its own
pixels' camera part and adds its light paths' camera connections, wherever they land, to a
full-frame int64 fixed-point buffer. Integer sums are exact and order-free, so summing
layers over tiles in any order, on any number of machines, gives the same image:

    rgba + splats * 2^e * pixel_count / (SPLAT_SCALE * light_paths)

with light_paths the total over all tiles (one per pixel sample) and e the scene's
splat_exponent (the fixed point's unit, from its lights' power). Only this last step is
floating point, and it runs once per image on the exact sum.

`SplatSums` holds the summed layers of a job, one full-frame layer per pass (and per
variance batch): the farm folds every tile's layer into it as the tile is stored, so the
farm's storage does not grow with the number of tiles, and the local render does the same.
"""
from __future__ import annotations

import math
import struct
import time
import zlib
from dataclasses import dataclass, field, replace

import numpy as np

from . import integrators
from .protocol import AOV_CHANNELS, RenderSettings, SplatBatch, TileRect, TileResult, pass_range, job_tiles
from .convergence import BatchMeans, batch_ranges, combine_aovs, combine_passes, new_aov_frame

# The renderer's fixed-point splat scale (kSplatScale in C++); tests/base/test_protocol.py pins
# the two together (the service never imports the renderer).
SPLAT_SCALE = float(1 << 24)


# ------------------------------------------------------------------ splat arithmetic
def splat_layer(splats: np.ndarray) -> tuple[tuple[int, int, int, int], np.ndarray]:
    """The bounding rectangle (x0, y0, w, h) of a full-frame splat buffer's non-zero pixels
    and that part of it (an empty rectangle when nothing landed)."""
    nonzero = np.any(splats != 0, axis=2)
    rows, cols = np.flatnonzero(nonzero.any(axis=1)), np.flatnonzero(nonzero.any(axis=0))
    if len(rows) == 0:
        return (0, 0, 0, 0), np.zeros((0, 0, 3), np.int64)
    y0, y1, x0, x1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    return (x0, y0, x1 - x0, y1 - y0), np.ascontiguousarray(splats[y0:y1, x0:x1])


EMPTY_RECT = (0, 0, 0, 0)
EMPTY_LAYER = np.zeros((0, 0, 3), np.int64)


def add_splats(total: np.ndarray, rect: tuple[int, int, int, int], layer: np.ndarray) -> None:
    """Adds a splat layer into a full-frame int64 buffer (exact and order-free)."""
    x0, y0, w, h = rect
    if w and h:
        total[y0:y0 + h, x0:x0 + w] += layer


def resolve_splats(rgba: np.ndarray, splats: np.ndarray | None, light_paths: int,
                   exponent: int) -> np.ndarray:
    """Full-frame float32 RGBA = camera part + splats * 2^exponent * pixel_count /
    (SPLAT_SCALE * light paths of all tiles): the one splat normalisation."""
    out = np.array(rgba, dtype=np.float32, copy=True)
    if splats is not None and light_paths > 0:
        height, width = out.shape[:2]
        scale = math.ldexp(width * height / (SPLAT_SCALE * light_paths), exponent)
        out[..., :3] += (splats.astype(np.float64) * scale).astype(np.float32)
    return out


def splat_exponent_of(results) -> int:
    """The splat unit exponent shared by results carrying splats (0 if none does); results
    of one scene always share it, so a mismatch means they are not one job's."""
    exponents = {r.splat_exponent for r in results if r.splat is not None}
    if len(exponents) > 1:
        raise ValueError(f"tile results disagree on the splat unit (2^{sorted(exponents)})")
    return exponents.pop() if exponents else 0


# magic, x0, y0, w, h of the non-zero rectangle; then the rectangle's int64 values as
# byte planes (all lowest bytes, then all second bytes, ...), zlib'd: splat values are
# small against int64, so the high planes are nearly all zero and shrink to nothing.
_SUM_HEADER = struct.Struct("<4siiii")
_SUM_MAGIC = b"TSP2"


class SplatSums:
    """A job's splats summed over tiles: one full-frame int64 layer per field, the field
    being "<pass>" (the pass's splats) or "<pass>:<batch>" (a variance batch's).

    `fold` moves a tile result's layers in here and leaves the result with empty layers
    (its light paths and splat unit stay with it): a result then weighs its tile's pixels
    only. Layers encode to bytes (`encode`/`decode`) for the farm's splats hash."""

    def __init__(self, width: int, height: int, layers: dict[str, np.ndarray] | None = None):
        self.width, self.height = width, height
        self.layers: dict[str, np.ndarray] = dict(layers or {})

    @staticmethod
    def pass_field(pass_index: int) -> str:
        return str(pass_index)

    @staticmethod
    def batch_field(pass_index: int, batch: int) -> str:
        return f"{pass_index}:{batch}"

    def layer(self, name: str) -> np.ndarray:
        if name not in self.layers:
            self.layers[name] = np.zeros((self.height, self.width, 3), np.int64)
        return self.layers[name]

    def batch_stack(self, pass_index: int, batches: int) -> np.ndarray:
        """The layers of pass `pass_index`'s batches 0 .. batches-1 as one (batches, height,
        width, 3) array, for a render call to add them in place (render_tile_pass `into`);
        its [j] is the field "<pass>:<j>" itself, with what the field already held."""
        names = [self.batch_field(pass_index, j) for j in range(batches)]
        first = self.layers.get(names[0])
        if first is not None and first.base is not None and first.base.shape[0] == batches and all(
                self.layers.get(n) is not None and self.layers[n].base is first.base for n in names):
            return first.base
        stack = np.zeros((batches, self.height, self.width, 3), np.int64)
        for j, name in enumerate(names):
            if name in self.layers:
                stack[j] = self.layers[name]
            self.layers[name] = stack[j]
        return stack

    def fold(self, result: TileResult) -> TileResult:
        """Adds the result's splat layers (its pass's and its batches') into these sums;
        returns the result with empty layers."""
        if result.splat is None:
            return result
        add_splats(self.layer(self.pass_field(result.pass_index)), result.splat_rect, result.splat)
        batches = None
        if result.batches:
            batches = []
            for j, b in enumerate(result.batches):
                add_splats(self.layer(self.batch_field(result.pass_index, j)), b.splat_rect, b.splat)
                batches.append(replace(b, splat_rect=EMPTY_RECT, splat=EMPTY_LAYER))
        return replace(result, splat_rect=EMPTY_RECT, splat=EMPTY_LAYER, batches=batches)

    @staticmethod
    def fields_of(result: TileResult) -> list[str]:
        """The fields a result's splats fold into."""
        if result.splat is None:
            return []
        p = result.pass_index
        return [SplatSums.pass_field(p)] + [SplatSums.batch_field(p, j)
                                            for j in range(len(result.batches or ()))]

    def get(self, name: str) -> np.ndarray | None:
        return self.layers.get(name)

    def encode(self, name: str) -> bytes:
        rect, layer = splat_layer(self.layer(name))
        planes = np.ascontiguousarray(layer.reshape(-1).view(np.uint8).reshape(-1, 8).T)
        return _SUM_HEADER.pack(_SUM_MAGIC, *rect) + zlib.compress(planes.tobytes(), 1)

    def decode_into(self, name: str, data: bytes) -> None:
        """Sets field `name` from encode()'s bytes."""
        if len(data) < _SUM_HEADER.size:
            raise ValueError(f"splat sum {name!r} is truncated")
        magic, x0, y0, w, h = _SUM_HEADER.unpack_from(data)
        if magic != _SUM_MAGIC or w < 0 or h < 0 or x0 < 0 or y0 < 0 \
                or x0 + w > self.width or y0 + h > self.height:
            raise ValueError(f"splat sum {name!r} does not fit the {self.width}x{self.height} image")
        try:
            raw = zlib.decompress(data[_SUM_HEADER.size:], bufsize=max(w * h * 24, 1))
        except zlib.error as e:
            raise ValueError(f"splat sum {name!r} is corrupt: {e}") from None
        if len(raw) != w * h * 24:
            raise ValueError(f"splat sum {name!r} has the wrong size")
        planes = np.frombuffer(raw, np.uint8).reshape(8, -1)
        values = np.ascontiguousarray(planes.T).view(np.int64).reshape(h, w, 3)
        full = np.zeros((self.height, self.width, 3), np.int64)
        add_splats(full, (x0, y0, w, h), values)
        self.layers[name] = full

    @classmethod
    def from_fields(cls, width: int, height: int, fields: dict) -> "SplatSums":
        sums = cls(width, height)
        for key, data in fields.items():
            sums.decode_into(key.decode() if isinstance(key, bytes) else str(key), data)
        return sums

    def passes_total(self) -> np.ndarray | None:
        """The sum of every pass's layer (batches excluded), or None without any."""
        names = [n for n in self.layers if ":" not in n]
        if not names:
            return None
        total = np.zeros((self.height, self.width, 3), np.int64)
        for n in names:
            total += self.layers[n]
        return total


def _splats_of(width: int, height: int, results, sums: SplatSums | None,
               field_name: str | None, layer_of) -> np.ndarray | None:
    """Full-frame sum of the results' own layers (layer_of(r) -> (rect, layer) or None) and
    of `sums`' field (every pass's when field_name is None); None if nothing splats."""
    total = None
    for r in results:
        got = layer_of(r)
        if got is not None:
            if total is None:
                total = np.zeros((height, width, 3), np.int64)
            add_splats(total, *got)
    extra = None
    if sums is not None:
        extra = sums.passes_total() if field_name is None else sums.get(field_name)
    if extra is not None:
        total = extra.copy() if total is None else total + extra
    return total


# ------------------------------------------------------------------ one tile pass
def run_scene_pass(scene, settings: RenderSettings, iteration: int, *, integrator: str,
                   threads: int = 0) -> bytes:
    """The scene-wide pass of iteration `iteration` (= the pass index) of an integrator with
    scene_passes: its product, opaque bytes that every tile pass of that iteration reads
    (render_tile_pass's scene_product). What local renders and the worker's scene tasks
    both run. A pure function of (scene, integrator, its params, seed, iteration), so the
    farm's product, and with it its image, equals the local one bit for bit."""
    return scene.scene_pass(integrator, iteration, seed=settings.sample_seed, max_depth=settings.max_depth,
                            threads=threads, integrator_params=dict(settings.integrator_params))


def render_tile_pass(scene, settings: RenderSettings, rect: TileRect, pass_index: int, *,
                     integrator: str, threads: int = 0, variance: bool = False,
                     batches: bool = False, scene_product: bytes | None = None,
                     into: SplatSums | None = None) -> tuple[TileResult, float]:
    """Pass `pass_index` of one tile: what every renderer of Tessera runs. `integrator` is
    resolved (scene.resolve_integrator); one with scene_passes needs `scene_product`, the
    product of run_scene_pass for iteration pass_index. Returns the TileResult (RGBA; the per-sample
    variance if `variance` or the variance AOV is asked for; settings.aovs; for a
    splatting integrator its splat layer and light paths, and with `batches` its variance
    batches, convergence.VARIANCE_BATCHES) and the seconds it took.

    `into`: the job's SplatSums, for a renderer that sums the whole job itself (the local
    render). The splats are then added to it directly, and the result comes back as
    SplatSums.fold would leave it (empty layers): the same sums, without a full-frame
    buffer per tile to scan and add."""
    sample_start, spp = pass_range(settings, pass_index)
    core_aovs = [a for a in settings.aovs if a in AOV_CHANNELS]
    want_variance = variance or "variance" in settings.aovs
    splatting = integrators.splats(integrator)
    # A splatting integrator's variance batches come from the same render call as the
    # image: each sample's splats go to its batch's layer as well as the pass's, and each
    # batch's camera mean is kept beside the image's.
    ranges = batch_ranges(sample_start, spp) if splatting and batches else []
    splats = batch_splats = None
    if splatting and into is not None:
        splats = into.layer(SplatSums.pass_field(pass_index))
        batch_splats = into.batch_stack(pass_index, len(ranges)) if ranges else None
    elif splatting:
        splats = np.zeros((settings.height, settings.width, 3), np.int64)
        batch_splats = np.zeros((len(ranges), settings.height, settings.width, 3), np.int64) if ranges else None
    batch_rgb = np.empty((len(ranges), rect.height, rect.width, 3), np.float32) if ranges else None
    common = dict(width=settings.width, height=settings.height, seed=settings.sample_seed,
                  max_depth=settings.max_depth, threads=threads, integrator=integrator,
                  integrator_params=dict(settings.integrator_params), scene_product=scene_product,
                  # A splatting integrator's tiles cover the frame (their light paths splat into
                  # the crop): the window keeps their camera work and splats to the crop.
                  camera_window=settings.crop)
    started = time.perf_counter()
    out = scene.render_tile(rect.x0, rect.y0, rect.width, rect.height, spp=spp,
                            sample_start=sample_start, return_variance=want_variance,
                            splats=splats, aovs=core_aovs, batch_splats=batch_splats,
                            batch_rgb=batch_rgb, **common)
    layers, var = None, None
    if core_aovs:
        rgba, layers = out
        var = layers.pop("variance", None)
    elif want_variance:
        rgba, var = out
    else:
        rgba = out
    result = TileResult(rect.x0, rect.y0, rgba, pass_index, sample_start, spp, var, aovs=layers)
    if splatting:
        layer_of = (lambda _: (EMPTY_RECT, EMPTY_LAYER)) if into is not None else splat_layer
        result.splat_rect, result.splat = layer_of(splats)
        # One light path per sample; the scene's fixed-point unit goes with the layer.
        result.light_paths = rect.width * rect.height * spp
        result.splat_exponent = scene.splat_exponent
        if ranges:
            result.batches = [SplatBatch(n, b_rgb, *layer_of(b_splats), rect.width * rect.height * n)
                              for (_, n), b_splats, b_rgb in zip(ranges, batch_splats, batch_rgb)]
    return result, time.perf_counter() - started


# ------------------------------------------------------------------ whole images
@dataclass
class Assembled:
    """An image from tile results. `variance`: the per-sample variance (None unless every
    tile has it); `spp`: samples per pixel; `aovs`: settings.aovs (with_aovs) as
    full-frame float32 layers; `batch_variance`: for a splatting integrator, the variance of
    the pixel's mean from the variance batches and the batch count (None without batches);
    `variance_kind`: what aovs["variance"] means (images.VARIANCE_PER_SAMPLE or
    images.batch_means_kind(K); None when it is not a valid estimate: splats without
    batches)."""
    rgba: np.ndarray
    variance: np.ndarray | None
    spp: np.ndarray
    aovs: dict[str, np.ndarray] = field(default_factory=dict)
    batch_variance: tuple[np.ndarray, int] | None = None
    variance_kind: str | None = None
    splatting: bool = False


def assemble_image(settings: RenderSettings, passes_by_tile: dict[int, list[TileResult]],
                   sums: SplatSums | None = None, *, partial: bool = False,
                   with_aovs: bool = False, tiles: list[TileRect] | None = None) -> Assembled:
    """Combines each tile's passes (convergence.combine_passes) and pastes the tiles into the
    full image; adds every splat (the results' own layers and `sums`), exactly, and
    normalises them once by all results' light paths. With `partial`, missing tiles and
    passes are left out (a preview of a running job). `tiles`: the job's tiles
    (protocol.job_tiles of the settings by default; a local render passes those it chose
    with the integrator `auto` resolved to). Raises ValueError when the results do not
    form the image."""
    s = settings
    grid = {t.index: t for t in (job_tiles(s) if tiles is None else tiles)}
    if not partial and set(passes_by_tile) != set(grid):
        missing = sorted(set(grid) - set(passes_by_tile))
        raise ValueError(f"{len(missing)} of {len(grid)} tiles are missing (first: {missing[:5]})")
    full = np.zeros((s.height, s.width, 4), np.float32)
    variance: np.ndarray | None = np.zeros((s.height, s.width, 3), np.float32)
    spp = np.zeros((s.height, s.width), np.float32)
    aovs = new_aov_frame(s) if with_aovs else {}
    used: list[TileResult] = []
    for index in sorted(passes_by_tile):
        if index not in grid:
            raise ValueError(f"tile {index} is not one of this job's {len(grid)} tiles")
        rect = grid[index]
        results = sorted(passes_by_tile[index], key=lambda r: r.pass_index)
        if [r.pass_index for r in results] != list(range(len(results))):
            if not partial:
                raise ValueError(f"tile {index} is missing a pass")
            results = [r for i, r in enumerate(results) if r.pass_index == i]
            if not results:
                continue
        used += results
        try:
            rgba, var, n = combine_passes(results)
            layers = combine_aovs(results) if any(a in AOV_CHANNELS for a in aovs) else {}
        except ValueError as e:
            raise ValueError(f"tile {index}: {e}") from e
        window = (slice(rect.y0, rect.y0 + rect.height), slice(rect.x0, rect.x0 + rect.width))
        full[window] = rgba
        spp[window] = n
        if var is None:
            variance = None
        elif variance is not None:
            variance[window] = var
        if var is not None:
            layers["variance"] = var
        for name, buf in aovs.items():
            if layers.get(name) is None:
                raise ValueError(f"tile {index} has no {name} AOV (rendered by a worker without AOVs?)")
            buf[window] = np.asarray(layers[name], np.float32).reshape(rect.height, rect.width, -1)
    if s.crop is not None:
        # A splatting integrator's tiles cover the frame (for their light paths), but only
        # the crop's pixels were sampled for themselves: outside it every layer is 0.
        x0, y0, x1, y1 = s.crop
        outside = np.ones(spp.shape, bool)
        outside[y0:y1, x0:x1] = False
        spp[outside] = 0
    splats = _splats_of(s.width, s.height, used, sums, None,
                        lambda r: (r.splat_rect, r.splat) if r.splat is not None else None)
    out = Assembled(full, variance, spp, aovs, splatting=splats is not None)
    if splats is not None:
        light_paths = sum(r.light_paths for r in used if r.splat is not None)
        out.rgba = resolve_splats(full, splats, light_paths, splat_exponent_of(used))
        if not partial:
            out.batch_variance = batch_variance(s.width, s.height, used, sums)
    if "variance" in aovs:
        from . import images  # EXR metadata names; OpenImageIO only when asked

        if not out.splatting:
            out.variance_kind = images.VARIANCE_PER_SAMPLE
        elif out.batch_variance is not None:
            # light and bdpt: the per-sample layer misses the splats; the batches replace it.
            aovs["variance"] = out.batch_variance[0]
            out.variance_kind = images.batch_means_kind(out.batch_variance[1])
    return out


def pass_image(width: int, height: int, results: list[TileResult],
               sums: SplatSums | None = None) -> np.ndarray:
    """The full-frame RGBA estimate of one pass from all tiles' results of that pass (and
    the pass's splat sum, if its layers were folded)."""
    full = np.zeros((height, width, 4), dtype=np.float32)
    for r in results:
        h, w = r.rgba.shape[:2]
        full[r.y0:r.y0 + h, r.x0:r.x0 + w] = r.rgba
    field_name = SplatSums.pass_field(results[0].pass_index) if results else None
    splats = _splats_of(width, height, results, sums, field_name,
                        lambda r: (r.splat_rect, r.splat) if r.splat is not None else None)
    if splats is None:
        return full
    light_paths = sum(r.light_paths for r in results if r.splat is not None)
    return resolve_splats(full, splats, light_paths, splat_exponent_of(results))


def batch_variance(width: int, height: int, results: list[TileResult],
                   sums: SplatSums | None = None) -> tuple[np.ndarray, int] | None:
    """The variance of every pixel's mean from the results' variance batches (see
    convergence.VARIANCE_BATCHES): batch j of pass p of every tile makes one whole image, in
    (pass, batch) order. None unless every result has batches and there are at least two."""
    if not results or any(not r.batches for r in results):
        return None
    exponent = splat_exponent_of(results)
    acc = BatchMeans()
    for p in sorted({r.pass_index for r in results}):
        of_pass = [r for r in results if r.pass_index == p]
        for j in range(len(of_pass[0].batches)):
            rgb = np.zeros((height, width, 4), np.float32)
            n = of_pass[0].batches[j].spp
            for r in of_pass:
                if len(r.batches) != len(of_pass[0].batches) or r.batches[j].spp != n:
                    raise ValueError(f"tiles of pass {p} disagree on their variance batches")
                b = r.batches[j]
                th, tw = b.rgb.shape[:2]
                rgb[r.y0:r.y0 + th, r.x0:r.x0 + tw, :3] = b.rgb
            splats = _splats_of(width, height, of_pass, sums, SplatSums.batch_field(p, j),
                                lambda r, j=j: (r.batches[j].splat_rect, r.batches[j].splat))
            light_paths = sum(r.batches[j].light_paths for r in of_pass)
            acc.add(resolve_splats(rgb, splats, light_paths, exponent)[..., :3], n)
    var = acc.variance_of_mean()
    return None if var is None else (var, acc.batches)


# ------------------------------------------------------------------ the denoised layer
def add_denoised(settings: RenderSettings, rgba: np.ndarray, aovs: dict[str, np.ndarray]) -> str | None:
    """With settings.denoise, puts the denoised image (tessera_base.denoise) into `aovs` as its
    "denoised" layer, from the finished (or partial) image's colour, albedo and normal:
    the local render and the service's merge both finish images here. `rgba` is never
    changed. Returns None, or, when denoising is impossible (library missing, unusable
    AOVs), the reason as a warning: the raw image is still good, so no caller fails."""
    if not settings.denoise:
        return None
    from .denoise import DENOISED_LAYER, DenoiseError, denoise

    try:
        aovs[DENOISED_LAYER] = denoise(rgba, aovs)
    except DenoiseError as e:
        return f"no denoised layer: {e}"
    return None


# ------------------------------------------------------------------ black images
# An image is black for its exposure when this share of its pixels stays below this
# fraction of display white (1.0: Tessera applies no exposure, the PNG preview maps 1.0 to
# white). A dim file (a Blender export's one SphereLight of intensity 10 far away) renders
# so; the user deserves one line saying it is the file, with the light to turn up.
BLACK_PIXEL = 0.01
BLACK_SHARE = 0.99


def black_image_warning(rgba: np.ndarray, brightest_light: str | None) -> str | None:
    """One warning line when `rgba` (h, w, >= 3) is black for its exposure, naming the
    scene's brightest light (SceneData.brightest_light); None otherwise. Local renders and
    the service's merge both finish images through it."""
    rgb = np.asarray(rgba)[..., :3]
    if rgb.size == 0:
        return None
    # A pixel is dark when its brightest channel is; NaN (never written) counts as dark.
    dark = ~(np.nanmax(np.where(np.isfinite(rgb), rgb, 0.0), axis=-1) >= BLACK_PIXEL)
    share = float(dark.mean())
    if share < BLACK_SHARE:
        return None
    light = brightest_light or "none: the scene has no light and no emission"
    return (f"the image is black for its exposure: {100 * share:.1f} % of its pixels are below "
            f"{100 * BLACK_PIXEL:g} % of display white (mean {float(np.nanmean(rgb)):.3g}); its brightest light "
            f"is {light}; raise its intensity or exposure")
