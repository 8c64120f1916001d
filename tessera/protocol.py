"""The one job/tile message schema shared by the service and the workers: the message
models (versioned), the tile grid and pass schedule, the encoding of tile results and how
passes combine. Where these live in Redis, and the scripts that move a job through its
states, are in tessera.redis_schema; how tile results become an image, in tessera.film.

Invariant: a pixel's value depends only on (scene, pixel, sample index, seed), so the
tile grid is a scheduling choice and never changes the image. Passes are combined by
`combine_passes`, which the local renderer uses too, so a farm render equals a local one
bit for bit whatever the pass schedule.
"""
from __future__ import annotations

import math
import re
import struct
import zlib
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, Field, field_serializer, field_validator, model_validator

from . import integrators
from .denoise import DENOISE_AOVS

SCHEMA_VERSION = 2

# Per-pixel outputs besides RGBA (docs/aovs.md), in canonical order, with their channel
# count in tile results. "variance" is the per-channel sample variance (FLAG_VARIANCE).
AOV_NAMES = ("albedo", "normal", "depth", "spp", "variance")
AOV_CHANNELS = {"albedo": 3, "normal": 3, "depth": 1, "spp": 1}  # the FLAG_AOVS section

MIN_PRIORITY, MAX_PRIORITY, DEFAULT_PRIORITY = 0, 9, 5

# Failure policy (per job, overridable in JobSpec).
DEFAULT_MAX_ATTEMPTS = 3      # failed deliveries of one tile pass before the job fails
BLOCKLIST_AFTER = 2           # failures of one job on one worker before it stops taking them


# A job id is what the service hands out: uuid4().hex. Anything else names no job (and a
# string such as "<id>:tiles" must never reach a key built from it).
JOB_ID_PATTERN = re.compile(r"[0-9a-f]{32}")


def is_job_id(value: str) -> bool:
    return JOB_ID_PATTERN.fullmatch(value) is not None


def scene_file_name(suffix: str) -> str:
    """The name an uploaded scene has on disk, alone in a private directory, wherever it is
    opened (the API's pre-flight, every worker): a loose layer sees the same bundle in both
    (one that references @./scene.usda@ passes or fails in both alike)."""
    return f"scene{suffix}"


JobState = Literal["queued", "running", "paused", "done", "failed", "cancelled"]
FINAL_STATES = ("done", "failed", "cancelled")


class RenderSettings(BaseModel):
    """What to render. Resolution is final here (scene defaults already applied).

    With `target_error` unset every tile gets `spp` samples in one pass. With it set the
    image is rendered to a noise target: tiles get passes of min_spp, then doubling up to
    max_spp samples, until their relative noise (see `tile_error`) is at most target_error,
    or until `time_limit` seconds after the job started."""

    width: int = Field(ge=1, le=16384)
    height: int = Field(ge=1, le=16384)
    spp: int = Field(default=64, ge=1, le=1 << 20, description="samples per pixel (fixed mode)")
    seed: int = Field(default=0, ge=0, le=2**32 - 1)
    max_depth: int = Field(default=64, ge=1, le=1024)
    tile_size: int = Field(default=64, ge=8, le=4096)
    target_error: float | None = Field(
        default=None, gt=0, le=1, allow_inf_nan=False,
        description="relative noise to stop at (0.01 = 1 %); unset: fixed spp")
    min_spp: int = Field(default=16, ge=1, le=1 << 20,
                         description="samples of the first pass (noise-target mode)")
    max_spp: int = Field(default=1024, ge=1, le=1 << 20,
                         description="most samples any pixel gets (noise-target mode)")
    time_limit: float | None = Field(
        default=None, gt=0, le=7 * 86400, allow_inf_nan=False,
        description="seconds after the job starts when no further passes begin "
                    "(noise-target mode; makes the image depend on timing)")
    integrator: str = Field(
        default_factory=integrators.default,
        description="light transport method: a name from the renderer's registry, or auto "
                    "(`tessera render --integrator help`, docs/integrators.md)")
    # Added within schema 2: optional with an empty default, so earlier messages stay valid.
    integrator_params: dict[str, float] = Field(
        default_factory=dict,
        description="the integrator's own settings, NAME -> number, as its registry entry declares "
                    "them (`tessera render --integrator help`; e.g. ao's max_distance); inf allowed")
    aovs: list[Literal["albedo", "normal", "depth", "spp", "variance"]] = Field(
        default_factory=list,
        description="extra per-pixel outputs written as EXR layers beside RGBA "
                    "(docs/aovs.md): albedo, normal, depth, spp, variance")

    default_light: bool = Field(
        default=True, description="light a stage that has no light (emissive geometry counts) with "
                                  "the default lighting: a white dome and a camera-relative key light "
                                  "(docs/scene-translation.md); false renders such a stage black")

    @field_validator("integrator")
    @classmethod
    def _integrator_name(cls, value: str) -> str:
        return integrators.validate(value)

    @field_validator("integrator_params", mode="before")
    @classmethod
    def _params_numbers(cls, value):
        """Accepts numbers or their text ("inf" included: JSON has no infinity, see below)."""
        if not isinstance(value, dict):
            raise ValueError("integrator_params must be a mapping of setting name to number")
        out = {}
        for key, v in value.items():
            number = None
            try:
                if isinstance(v, (int, float, str)) and not isinstance(v, bool):
                    number = float(v)
            except (ValueError, OverflowError):  # not a number; an integer beyond any float
                pass
            if number is None or math.isnan(number):
                raise ValueError(f"integrator setting {key!r} must be a number (or inf), not {v!r}")
            out[key] = number
        return out

    @field_serializer("integrator_params", when_used="json")
    def _params_json(self, value: dict[str, float]):
        # JSON has no infinity and pydantic would write null: write it as text instead.
        return {k: (v if math.isfinite(v) else repr(v)) for k, v in value.items()}

    @model_validator(mode="after")
    def _params_known(self) -> "RenderSettings":
        self.integrator_params = integrators.validate_params(self.integrator, self.integrator_params)
        return self

    @field_validator("aovs", mode="before")
    @classmethod
    def _aov_list(cls, value):
        """Accepts a list or a comma-separated string; "all" means every AOV. Stored
        without duplicates in the canonical order of AOV_NAMES."""
        if isinstance(value, str):
            value = [v.strip() for v in value.split(",") if v.strip()]
        if value is None:
            return []
        if "all" in value:
            return list(AOV_NAMES)
        unknown = [v for v in value if v not in AOV_NAMES]
        if unknown:
            raise ValueError(f"unknown AOV {unknown[0]!r} (known: {', '.join(AOV_NAMES)}, all)")
        return [name for name in AOV_NAMES if name in value]

    # Added within schema 2 like aovs. Denoising runs where the image is finished (the
    # local render, the service's merge), never in a worker; it needs the albedo and
    # normal AOVs, so they are asked for here (their own sample stream: the colour does not
    # change). docs/denoise.md.
    denoise: bool = Field(
        default=False,
        description="add an Open Image Denoise layer (denoised.R/G/B) and preview beside the "
                    "raw image; adds the albedo and normal AOVs (docs/denoise.md)")

    # Added within schema 2 like aovs: the region the EXR holds (x0, y0, x1, y1; x1, y1
    # exclusive) as its data window inside the full display window (docs/aovs.md). The
    # whole frame is still rendered: splats from anywhere land in the region.
    crop: tuple[int, int, int, int] | None = Field(
        default=None,
        description="write only this pixel region x0,y0,x1,y1 (x1, y1 exclusive) of the image "
                    "to the EXR, as its data window inside the full-frame display window")

    @field_validator("crop", mode="before")
    @classmethod
    def _crop_text(cls, value):
        """Accepts "x0,y0,x1,y1" (a form field) as well as four numbers; "" is no crop."""
        if isinstance(value, str):
            if not value.strip():
                return None
            parts = value.split(",")
            if len(parts) != 4:
                raise ValueError(f"crop must look like x0,y0,x1,y1, not {value!r}")
            return tuple(p.strip() for p in parts)
        return value

    @model_validator(mode="after")
    def _crop_inside(self) -> "RenderSettings":
        if self.crop is not None:
            x0, y0, x1, y1 = self.crop
            if not (0 <= x0 < x1 <= self.width and 0 <= y0 < y1 <= self.height):
                raise ValueError(f"crop {x0},{y0},{x1},{y1} is not a non-empty region of the "
                                 f"{self.width}x{self.height} frame (x1, y1 exclusive)")
        return self

    @model_validator(mode="after")
    def _spp_range(self) -> "RenderSettings":
        if self.target_error is not None and self.min_spp > self.max_spp:
            raise ValueError(f"min_spp ({self.min_spp}) is larger than max_spp ({self.max_spp})")
        return self

    @model_validator(mode="after")
    def _denoise_aovs(self) -> "RenderSettings":
        if self.denoise and not all(a in self.aovs for a in DENOISE_AOVS):
            self.aovs = [name for name in AOV_NAMES if name in self.aovs or name in DENOISE_AOVS]
        return self

    @property
    def adaptive(self) -> bool:
        return self.target_error is not None

    @property
    def lockstep(self) -> bool:
        """Noise-target mode in which the whole image advances pass by pass together and
        stops together (see `image_finished`). Integrators that cannot stop per tile (their
        stop_per_tile capability; today the splatting ones) need it: their light paths land
        on every tile's pixels, so a tile's noise is not its own to judge, and bdpt's MIS
        weights assume every pixel has as many camera samples as there are light paths per
        pixel, which per-tile stopping would break. `auto` may resolve to such an integrator,
        and a farm cannot know before it loads the scene, so it is scheduled the same way
        (local renders follow the same rule, so farm and local images stay identical)."""
        return self.adaptive and not integrators.stops_per_tile(self.integrator)


def pass_range(settings: RenderSettings, pass_index: int) -> tuple[int, int] | None:
    """(sample_start, spp) of pass `pass_index`, or None past the last pass."""
    if not settings.adaptive:
        return (0, settings.spp) if pass_index == 0 else None
    start, end = 0, settings.min_spp
    for _ in range(pass_index):
        if end >= settings.max_spp:
            return None
        start, end = end, min(2 * end, settings.max_spp)
    return start, end - start


class TileRect(BaseModel):
    index: int = Field(ge=0)
    x0: int = Field(ge=0)
    y0: int = Field(ge=0)
    width: int = Field(ge=1)
    height: int = Field(ge=1)


class JobSpec(BaseModel):
    schema_version: Literal[2] = SCHEMA_VERSION
    job_id: str
    scene_hash: str
    scene_name: str  # the uploaded file name; its suffix tells USD the format
    settings: RenderSettings
    priority: int = Field(default=DEFAULT_PRIORITY, ge=MIN_PRIORITY, le=MAX_PRIORITY)
    max_attempts: int = Field(default=DEFAULT_MAX_ATTEMPTS, ge=1, le=100)


class TileTask(BaseModel):
    """One stream message: everything a worker needs to render one pass of one tile."""

    schema_version: Literal[2] = SCHEMA_VERSION
    job_id: str
    scene_hash: str
    scene_name: str
    settings: RenderSettings
    tile: TileRect
    pass_index: int = Field(default=0, ge=0)
    priority: int = Field(default=DEFAULT_PRIORITY, ge=MIN_PRIORITY, le=MAX_PRIORITY)
    max_attempts: int = Field(default=DEFAULT_MAX_ATTEMPTS, ge=1, le=100)
    # A pass barrier of a lockstep job (RenderSettings.lockstep), queued once every tile's
    # pass `pass_index` is stored: whoever takes it decides whether the image needs pass
    # pass_index + 1 and queues it for every tile, or finishes the job. `tile` is unused.
    decide: bool = False
    # A scene-wide task (an integrator with scene_passes): iteration pass_index's scene
    # pass. Whoever takes it computes the product (tessera.film.run_scene_pass), stores it
    # once and queues that iteration's tile passes. `tile` is unused.
    scene_pass: bool = False

    @property
    def field(self) -> str:
        from .redis_schema import result_field, scene_task_field
        if self.scene_pass:
            return scene_task_field(self.pass_index)
        return result_field(self.tile.index, self.pass_index)

    def to_fields(self) -> dict[str, str]:
        return {"task": self.model_dump_json()}

    @classmethod
    def from_fields(cls, fields: dict) -> "TileTask":
        raw = fields.get(b"task", fields.get("task"))
        if raw is None:
            raise ValueError("stream entry has no 'task' field")
        return cls.model_validate_json(raw)

    def next_pass(self) -> "TileTask":
        return self.model_copy(update={"pass_index": self.pass_index + 1})


    def decide_task(self) -> "TileTask":
        """The barrier that follows this lockstep pass."""
        return self.model_copy(update={"decide": True})

    def pass_tasks(self, pass_index: int) -> list["TileTask"]:
        """Pass `pass_index` of every tile of this task's job."""
        s = self.settings
        return [self.model_copy(update={"tile": rect, "pass_index": pass_index, "decide": False,
                                        "scene_pass": False})
                for rect in tile_grid(s.width, s.height, s.tile_size)]

    def iteration_tasks(self, pass_index: int) -> list["TileTask"]:
        """What starts pass `pass_index`: its scene-wide task for an integrator with scene
        passes (which queues the tile passes once its product is stored), else the tiles."""
        if integrators.scene_passes(self.settings.integrator):
            return [self.model_copy(update={"pass_index": pass_index, "decide": False,
                                            "scene_pass": True})]
        return self.pass_tasks(pass_index)


def tile_grid(width: int, height: int, tile_size: int) -> list[TileRect]:
    """Row-major tiles covering the image; edge tiles are smaller."""
    tiles = []
    for y0 in range(0, height, tile_size):
        for x0 in range(0, width, tile_size):
            tiles.append(TileRect(index=len(tiles), x0=x0, y0=y0,
                                  width=min(tile_size, width - x0),
                                  height=min(tile_size, height - y0)))
    return tiles


def job_tasks(spec: JobSpec) -> list[TileTask]:
    """What a job starts with: the first pass of every tile, or, for an integrator with
    scene passes, the scene-wide task of the first iteration (which queues those tiles)."""
    s = spec.settings
    first = TileTask(job_id=spec.job_id, scene_hash=spec.scene_hash, scene_name=spec.scene_name,
                     settings=s, tile=tile_grid(s.width, s.height, s.tile_size)[0],
                     priority=spec.priority, max_attempts=spec.max_attempts)
    return first.iteration_tasks(0)


# ------------------------------------------------------------------ tile results
# Version 2: a fixed header, then float32 sections, row-major:
#   rgba (h, w, 4): the mean of samples [sample_start, sample_start + spp)
#   variance (h, w, 3) if FLAG_VARIANCE: per-channel unbiased sample variance
#   splat if FLAG_SPLAT: a rect header (x0, y0, w, h) and int64 (h, w, 3) light-tracing
#       splats in the renderer's fixed point (tessera_renderer.film), covering that rect of
#       the full frame (the bounding box of where the pass's light paths landed). Summed
#       over all results (exact, order-free) and normalised by the job's total light_paths
#       (tessera.film.resolve_splats). The farm stores results with an empty splat rect and
#       sums their layers per pass instead (tessera.film.SplatSums). With FLAG_SPLAT_EXPONENT an int32 e follows the rect: the
#       fixed point's unit is 2^e (the scene's splat_exponent; 0 without the flag).
#   batches if FLAG_BATCHES (last): a u32 count, then per batch (in sample order) a u32
#       spp, a u64 light_paths, float32 (h, w, 3) camera part, a splat rect (x0, y0, w, h),
#       a u32 length and the zlib-compressed int64 (h, w, 3) splats of that rect (the
#       splat section's unit); see VARIANCE_BATCHES
#   aovs if FLAG_AOVS (version 3 only): a u32 mask (bit i: the i-th of AOV_CHANNELS'
#       names: albedo, normal, depth, spp), then each present AOV as float32 (h, w, c)
#       in that order (see docs/aovs.md for their meaning)
# Version 3 is version 2 plus FLAG_AOVS; it is written only for results that carry AOVs,
# so that results without them stay readable by version-2 readers, and a version-2 reader
# refuses a version-3 result ("unknown format") instead of misreading it.
# Version 1 (header without the pass fields, rgba only) is still read.
_HEADER_V1 = struct.Struct("<4sIiiii")          # magic, version, x0, y0, width, height
_HEADER = struct.Struct("<4sIiiiiIIIIQ")         # ... pass_index, sample_start, spp, flags, light_paths
_SPLAT_RECT = struct.Struct("<iiii")
_TILE_MAGIC = b"TSRT"
FLAG_VARIANCE = 1
FLAG_SPLAT = 2         # splat section stored raw
FLAG_SPLAT_ZLIB = 4    # splat section's int64 bytes zlib-compressed (u32 length first)
FLAG_AOVS = 8          # AOV section (version 3)
FLAG_SPLAT_EXPONENT = 16  # the splat section's unit exponent
FLAG_BATCHES = 32      # variance batches of a splatting integrator (see VARIANCE_BATCHES)
RESULT_VERSION_AOVS = 3

@dataclass
class TileResult:
    x0: int
    y0: int
    rgba: np.ndarray                    # float32 (h, w, 4)
    pass_index: int = 0
    sample_start: int = 0
    spp: int = 0                        # 0: unknown (a version-1 result)
    variance: np.ndarray | None = None  # float32 (h, w, 3)
    splat_rect: tuple[int, int, int, int] | None = None
    splat: np.ndarray | None = None     # int64 (h, w, 3), fixed point
    light_paths: int = 0
    aovs: dict[str, np.ndarray] | None = None  # name -> float32 (h, w, c) (AOV_CHANNELS)
    splat_exponent: int = 0             # the splats' fixed-point unit is 2^splat_exponent
    batches: list["SplatBatch"] | None = None  # variance batches (FLAG_BATCHES)


@dataclass
class SplatBatch:
    """One variance batch of a tile's pass: samples [start, start + spp) of the pass's
    range (batch_ranges), rendered on their own."""
    spp: int
    rgb: np.ndarray                     # float32 (h, w, 3): the camera part
    splat_rect: tuple[int, int, int, int]
    splat: np.ndarray                   # int64 (h, w, 3) of splat_rect, fixed point
    light_paths: int


def encode_tile(rect: TileRect, rgba: np.ndarray, *, pass_index: int = 0, sample_start: int = 0,
                spp: int = 0, variance: np.ndarray | None = None,
                splat_rect: tuple[int, int, int, int] | None = None,
                splat: np.ndarray | None = None, light_paths: int = 0,
                aovs: dict[str, np.ndarray] | None = None, splat_exponent: int = 0,
                batches: list[SplatBatch] | None = None) -> bytes:
    rgba = np.ascontiguousarray(rgba, dtype=np.float32)
    if rgba.shape != (rect.height, rect.width, 4):
        raise ValueError(f"tile {rect.index}: pixels have shape {rgba.shape}, "
                         f"expected {(rect.height, rect.width, 4)}")
    flags = 0
    parts = [rgba.tobytes()]
    if variance is not None:
        variance = np.ascontiguousarray(variance, dtype=np.float32)
        if variance.shape != (rect.height, rect.width, 3):
            raise ValueError(f"tile {rect.index}: variance has shape {variance.shape}, "
                             f"expected {(rect.height, rect.width, 3)}")
        flags |= FLAG_VARIANCE
        parts.append(variance.tobytes())
    version = SCHEMA_VERSION
    if aovs:
        unknown = set(aovs) - set(AOV_CHANNELS)
        if unknown:
            raise ValueError(f"tile {rect.index}: unknown AOV {sorted(unknown)[0]!r}")
        mask = 0
        sections = []
        for bit, (name, channels) in enumerate(AOV_CHANNELS.items()):
            if name not in aovs:
                continue
            layer = np.ascontiguousarray(aovs[name], dtype=np.float32)
            if layer.shape[:2] != (rect.height, rect.width) or layer.size != rect.height * rect.width * channels:
                raise ValueError(f"tile {rect.index}: AOV {name} has shape {layer.shape}, "
                                 f"expected {(rect.height, rect.width, channels)}")
            mask |= 1 << bit
            sections.append(layer.tobytes())
        flags |= FLAG_AOVS
        version = RESULT_VERSION_AOVS
        parts += [struct.pack("<I", mask)] + sections
    if splat is not None:
        if splat_rect is None:
            raise ValueError("a splat layer needs its rectangle")
        splat = np.ascontiguousarray(splat, dtype=np.int64)
        if splat.shape != (splat_rect[3], splat_rect[2], 3):
            raise ValueError(f"splat layer has shape {splat.shape}, rect {splat_rect}")
        # Splat layers are mostly small integers and zeros: zlib shrinks them several fold.
        packed = zlib.compress(splat.tobytes(), 1)
        flags |= FLAG_SPLAT | FLAG_SPLAT_ZLIB | FLAG_SPLAT_EXPONENT
        parts += [_SPLAT_RECT.pack(*splat_rect), struct.pack("<iI", splat_exponent, len(packed)), packed]
    if batches:
        flags |= FLAG_BATCHES
        parts.append(struct.pack("<I", len(batches)))
        for b in batches:
            rgb = np.ascontiguousarray(b.rgb, dtype=np.float32)
            layer = np.ascontiguousarray(b.splat, dtype=np.int64)
            if rgb.shape != (rect.height, rect.width, 3) or layer.shape != (b.splat_rect[3], b.splat_rect[2], 3):
                raise ValueError(f"tile {rect.index}: a variance batch has the wrong shape")
            packed = zlib.compress(layer.tobytes(), 1)
            parts += [struct.pack("<IQ", b.spp, b.light_paths), rgb.tobytes(),
                      _SPLAT_RECT.pack(*b.splat_rect), struct.pack("<I", len(packed)), packed]
    header = _HEADER.pack(_TILE_MAGIC, version, rect.x0, rect.y0, rect.width, rect.height,
                          pass_index, sample_start, spp, flags, light_paths)
    return header + b"".join(parts)


def decode_tile(data: bytes) -> TileResult:
    if len(data) < _HEADER_V1.size:
        raise ValueError("tile result is truncated")
    magic, version, x0, y0, w, h = _HEADER_V1.unpack_from(data)
    if magic != _TILE_MAGIC or version not in (1, 2, RESULT_VERSION_AOVS):
        raise ValueError(f"tile result has unknown format {magic!r} v{version}")
    if w < 1 or h < 1 or w > 1 << 16 or h > 1 << 16:
        raise ValueError(f"tile result has impossible size {w}x{h}")
    if version == 1:
        expected = _HEADER_V1.size + w * h * 16
        if len(data) != expected:
            raise ValueError(f"tile result has {len(data)} bytes, expected {expected}")
        return TileResult(x0, y0, _floats(data, _HEADER_V1.size, (h, w, 4)))
    if len(data) < _HEADER.size:
        raise ValueError("tile result is truncated")
    *_, pass_index, sample_start, spp, flags, light_paths = _HEADER.unpack_from(data)
    known = FLAG_VARIANCE | FLAG_SPLAT | FLAG_SPLAT_ZLIB | FLAG_SPLAT_EXPONENT | FLAG_BATCHES | (
        FLAG_AOVS if version >= RESULT_VERSION_AOVS else 0)
    if flags & ~known:
        raise ValueError(f"tile result v{version} has unknown flags {flags & ~known:#x}")
    expected = _HEADER.size + w * h * 16 + (w * h * 12 if flags & FLAG_VARIANCE else 0)
    offset = _HEADER.size
    result = TileResult(x0, y0, None, pass_index, sample_start, spp, light_paths=light_paths)
    aov_layout: list[tuple[str, int, int]] = []  # (name, channels, offset)
    if flags & FLAG_AOVS:
        if len(data) < expected + 4:
            raise ValueError("tile result is truncated")
        (mask,) = struct.unpack_from("<I", data, expected)
        if mask >> len(AOV_CHANNELS):
            raise ValueError(f"tile result has unknown AOVs (mask {mask:#x})")
        expected += 4
        for bit, (name, channels) in enumerate(AOV_CHANNELS.items()):
            if mask & (1 << bit):
                aov_layout.append((name, channels, expected))
                expected += w * h * channels * 4
    if flags & FLAG_SPLAT:
        if len(data) < expected + _SPLAT_RECT.size:
            raise ValueError("tile result is truncated")
        sx, sy, sw, sh = _SPLAT_RECT.unpack_from(data, expected)
        if sw < 0 or sh < 0:
            raise ValueError("tile result has a negative splat size")
        result.splat_rect = (sx, sy, sw, sh)
        head = _SPLAT_RECT.size
        if flags & FLAG_SPLAT_EXPONENT:
            if len(data) < expected + head + 4:
                raise ValueError("tile result is truncated")
            (result.splat_exponent,) = struct.unpack_from("<i", data, expected + head)
            if not -1000 < result.splat_exponent < 1000:
                raise ValueError(f"tile result has an impossible splat exponent {result.splat_exponent}")
            head += 4
        if flags & FLAG_SPLAT_ZLIB:
            if len(data) < expected + head + 4:
                raise ValueError("tile result is truncated")
            (packed_len,) = struct.unpack_from("<I", data, expected + head)
            splat_offset = expected + head + 4
            expected += head + 4 + packed_len
        else:
            splat_offset = expected + head
            expected += head + sw * sh * 24
    if flags & FLAG_BATCHES:
        expected = _decode_batches(data, expected, w, h, result)
    if len(data) != expected:
        raise ValueError(f"tile result has {len(data)} bytes, expected {expected}")
    result.rgba = _floats(data, offset, (h, w, 4))
    offset += w * h * 16
    if flags & FLAG_VARIANCE:
        result.variance = _floats(data, offset, (h, w, 3))
        offset += w * h * 12
    if aov_layout:
        result.aovs = {name: _floats(data, at, (h, w, c)) for name, c, at in aov_layout}
        offset = aov_layout[-1][2] + w * h * aov_layout[-1][1] * 4
    if flags & FLAG_SPLAT:
        sx, sy, sw, sh = result.splat_rect
        if flags & FLAG_SPLAT_ZLIB:
            try:
                raw = zlib.decompress(data[splat_offset:splat_offset + packed_len], bufsize=sw * sh * 24)
            except zlib.error as e:
                raise ValueError(f"tile result has a corrupt splat layer: {e}") from None
            if len(raw) != sw * sh * 24:
                raise ValueError("tile result's splat layer has the wrong size")
            result.splat = np.frombuffer(raw, dtype=np.int64).reshape(sh, sw, 3)
        else:
            result.splat = np.frombuffer(data, dtype=np.int64, count=sw * sh * 3,
                                         offset=splat_offset).reshape(sh, sw, 3)
    return result


def _decode_batches(data: bytes, offset: int, w: int, h: int, result: TileResult) -> int:
    """Reads the FLAG_BATCHES section at `offset` into result.batches; returns its end."""
    def need(n: int) -> None:
        if len(data) < offset + n:
            raise ValueError("tile result is truncated")
    need(4)
    (count,) = struct.unpack_from("<I", data, offset)
    offset += 4
    if count > 1 << 16:
        raise ValueError(f"tile result has an impossible batch count {count}")
    result.batches = []
    for _ in range(count):
        need(12 + w * h * 12 + _SPLAT_RECT.size + 4)
        spp, light_paths = struct.unpack_from("<IQ", data, offset)
        rgb = _floats(data, offset + 12, (h, w, 3))
        offset += 12 + w * h * 12
        sx, sy, sw, sh = _SPLAT_RECT.unpack_from(data, offset)
        (packed_len,) = struct.unpack_from("<I", data, offset + _SPLAT_RECT.size)
        offset += _SPLAT_RECT.size + 4
        if sw < 0 or sh < 0:
            raise ValueError("tile result has a negative splat size")
        need(packed_len)
        try:
            raw = zlib.decompress(data[offset:offset + packed_len], bufsize=max(sw * sh * 24, 1))
        except zlib.error as e:
            raise ValueError(f"tile result has a corrupt batch splat layer: {e}") from None
        if len(raw) != sw * sh * 24:
            raise ValueError("tile result's batch splat layer has the wrong size")
        offset += packed_len
        result.batches.append(SplatBatch(spp, rgb, (sx, sy, sw, sh),
                                         np.frombuffer(raw, dtype=np.int64).reshape(sh, sw, 3), light_paths))
    return offset


def _floats(data: bytes, offset: int, shape: tuple[int, ...]) -> np.ndarray:
    count = int(np.prod(shape))
    return np.frombuffer(data, dtype=np.float32, count=count, offset=offset).reshape(shape)


# ------------------------------------------------------------------ combining passes
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def combine_passes(passes: list[TileResult]) -> tuple[np.ndarray, np.ndarray | None, int]:
    """Combines passes of one tile (in pass order) into (rgba float32, variance or None,
    total samples): the sample-count-weighted mean, computed in float64. One pass is
    returned as it is, so a fixed-spp image is exactly the renderer's output."""
    passes = sorted(passes, key=lambda p: p.pass_index)
    if len(passes) == 1:
        p = passes[0]
        return p.rgba, p.variance, p.spp
    counts = [p.spp for p in passes]
    if min(counts) < 1:
        raise ValueError("cannot combine passes without sample counts")
    total = sum(counts)
    mean = sum(n * p.rgba.astype(np.float64) for n, p in zip(counts, passes)) / total
    variance = None
    if all(p.variance is not None for p in passes) and total > 1:
        # Chan et al.: pooled sum of squared deviations of the combined sample set.
        m2 = sum((n - 1) * p.variance.astype(np.float64)
                 + n * (p.rgba[..., :3].astype(np.float64) - mean[..., :3]) ** 2
                 for n, p in zip(counts, passes))
        variance = (m2 / (total - 1)).astype(np.float32)
    return mean.astype(np.float32), variance, total


def combine_aovs(passes: list[TileResult]) -> dict[str, np.ndarray]:
    """Combines the AOVs of one tile's passes (docs/aovs.md): albedo and normal as the
    sample-count-weighted mean; spp as the sum; depth as the mean over the samples that hit
    something, each pass weighted by its hit count spp * alpha (+inf where none hit). One
    pass is returned as it is. Every pass must carry the same AOVs."""
    passes = sorted(passes, key=lambda p: p.pass_index)
    names = set(passes[0].aovs or {})
    if any(set(p.aovs or {}) != names for p in passes):
        raise ValueError("passes of one tile carry different AOVs")
    if len(passes) == 1 or not names:
        return dict(passes[0].aovs or {})
    counts = [p.spp for p in passes]
    if min(counts) < 1:
        raise ValueError("cannot combine passes without sample counts")
    total = sum(counts)
    out = {}
    for name in names:
        layers = [p.aovs[name].astype(np.float64).reshape(*p.rgba.shape[:2], -1) for p in passes]
        if name == "spp":
            out[name] = sum(layers).astype(np.float32)
        elif name == "depth":
            hits = [n * p.rgba[..., 3:4].astype(np.float64) for n, p in zip(counts, passes)]
            weight = sum(hits)
            num = sum(k * np.where(k > 0, d, 0.0) for k, d in zip(hits, layers))  # no 0 * inf
            with np.errstate(invalid="ignore", divide="ignore"):
                out[name] = np.where(weight > 0, num / np.where(weight > 0, weight, 1.0),
                                     np.inf).astype(np.float32)
        else:
            out[name] = (sum(n * a for n, a in zip(counts, layers)) / total).astype(np.float32)
    return out


def new_aov_frame(settings: RenderSettings) -> dict[str, np.ndarray]:
    """Full-frame float32 buffers for the job's AOVs (AOV layers are (h, w, c))."""
    channels = dict(AOV_CHANNELS, variance=3)
    return {name: np.zeros((settings.height, settings.width, channels[name]), np.float32)
            for name in settings.aovs}


def tile_error(rgba: np.ndarray, variance: np.ndarray, samples: int) -> float:
    """The tile's relative noise: the RMS over its pixels of (standard error of the pixel's
    luminance) / (its luminance), with luminances floored at 1 % of the tile's mean (and
    1e-4) so that black pixels do not dominate. A tile without variance (background) is 0."""
    lum = rgba[..., :3].astype(np.float64) @ _LUMINANCE
    var_mean = (variance.astype(np.float64) @ (_LUMINANCE ** 2)) / max(samples, 1)
    floor = max(1e-4, 0.01 * float(np.mean(np.abs(lum))))
    rel = var_mean / np.maximum(np.abs(lum), floor) ** 2
    return float(np.sqrt(np.mean(rel)))


def tile_finished(settings: RenderSettings, pass_index: int, rgba: np.ndarray,
                  variance: np.ndarray | None, samples: int) -> bool:
    """Whether a tile needs no further pass after `pass_index` (timing aside)."""
    if pass_range(settings, pass_index + 1) is None:
        return True
    if variance is None:
        return False
    return tile_error(rgba, variance, samples) <= settings.target_error


# ------------------------------------------------------------------ lockstep passes
# A lockstep job's error is judged on whole-image pass estimates (batch means): pass p's
# image I_p (camera part of every tile + that pass's splats over its own light paths) is an
# independent estimate with variance sigma^2 / n_p. With N = sum n_p and the weighted mean
# M = sum n_p I_p / N, E[sum n_p (I_p - M)^2] = (K - 1) sigma^2, so
#   Var(M) ~= (S2 - S1^2 / N) / ((K - 1) N),  S1 = sum n_p I_p,  S2 = sum n_p I_p^2,
# per pixel on luminance. Owen-scrambled passes are not quite independent (their union is
# better stratified than each), which makes this estimate conservative.

def variance_of_mean(s1: np.ndarray, s2: np.ndarray, samples: int, batches: int) -> np.ndarray:
    """The batch-means estimate above: Var(M) ~= (S2 - S1^2 / N) / ((K - 1) N), float64,
    from S1 = sum n_k I_k, S2 = sum n_k I_k^2 over K >= 2 batches of N samples in all."""
    n = float(samples)
    return np.maximum(s2 - s1 * (s1 / n), 0.0) / (batches - 1) / n


# Every image's noise estimate for the splatting integrators (light, bdpt; auto when it
# resolves to one): a light path splats onto other pixels than its camera sample's, so a
# pixel's per-sample variance describes only its camera half. Instead every pass's sample
# range is also rendered as VARIANCE_BATCHES independent sub-ranges (batches), each a whole
# image of its own (camera part + its own splats normalised by its own light paths); the
# spread of the batch images per pixel estimates the variance of the pixel's mean with
# K - 1 degrees of freedom (K batches in all). The image itself is rendered as before.
VARIANCE_BATCHES = 8


def batch_ranges(sample_start: int, spp: int, batches: int = VARIANCE_BATCHES) -> list[tuple[int, int]]:
    """A pass's samples [sample_start, sample_start + spp) as min(batches, spp) contiguous
    (start, count) ranges of near-equal size."""
    k = max(1, min(batches, spp))
    base, extra = divmod(spp, k)
    out, start = [], sample_start
    for j in range(k):
        n = base + (1 if j < extra else 0)
        out.append((start, n))
        start += n
    return out


@dataclass
class BatchMeans:
    """Per-pixel, per-channel running sums over independent batch images (S1, S2 above)."""

    batches: int = 0
    samples: int = 0
    s1: np.ndarray | None = None  # float64: sum n_k I_k
    s2: np.ndarray | None = None  # float64: sum n_k I_k^2

    def add(self, image: np.ndarray, n: int) -> None:
        x = np.asarray(image, dtype=np.float64)
        if self.s1 is None:
            self.s1, self.s2 = np.zeros_like(x), np.zeros_like(x)
        self.s1 += n * x
        self.s2 += n * x * x
        self.batches += 1
        self.samples += n

    def variance_of_mean(self) -> np.ndarray | None:
        """float32 estimated variance of the mean of all batches; None below 2 batches."""
        if self.batches < 2 or self.s1 is None:
            return None
        return variance_of_mean(self.s1, self.s2, self.samples, self.batches).astype(np.float32)


@dataclass
class PassAccumulator:
    """Running sums over the passes of a lockstep job (see above); bytes round-trip so a
    farm keeps it in Redis between barriers."""

    passes: int = 0
    samples: int = 0
    s1: np.ndarray | None = None  # float64 (h, w): sum n_p lum(I_p)
    s2: np.ndarray | None = None  # float64 (h, w): sum n_p lum(I_p)^2

    def add(self, image: np.ndarray, spp: int) -> "PassAccumulator":
        lum = image[..., :3].astype(np.float64) @ _LUMINANCE
        s1 = spp * lum if self.s1 is None else self.s1 + spp * lum
        s2 = spp * lum * lum if self.s2 is None else self.s2 + spp * lum * lum
        return PassAccumulator(self.passes + 1, self.samples + spp, s1, s2)

    def error(self) -> float | None:
        """Relative noise of the image so far, as `tile_error` measures a tile; None before
        two passes (one pass cannot estimate its own variance)."""
        if self.passes < 2 or self.s1 is None:
            return None
        var_mean = variance_of_mean(self.s1, self.s2, self.samples, self.passes)
        mean = self.s1 / float(self.samples)
        floor = max(1e-4, 0.01 * float(np.mean(np.abs(mean))))
        return float(np.sqrt(np.mean(var_mean / np.maximum(np.abs(mean), floor) ** 2)))

    def to_bytes(self) -> bytes:
        if self.s1 is None:
            return struct.pack("<IQII", self.passes, self.samples, 0, 0)
        h, w = self.s1.shape
        return (struct.pack("<IQII", self.passes, self.samples, h, w)
                + zlib.compress(np.stack([self.s1, self.s2]).tobytes(), 1))

    @classmethod
    def from_bytes(cls, data: bytes | None) -> "PassAccumulator":
        if not data:
            return cls()
        passes, samples, h, w = struct.unpack_from("<IQII", data)
        if h == 0:
            return cls(passes, samples)
        arrays = np.frombuffer(zlib.decompress(data[struct.calcsize("<IQII"):]),
                               dtype=np.float64).reshape(2, h, w)
        return cls(passes, samples, arrays[0].copy(), arrays[1].copy())


def image_finished(settings: RenderSettings, pass_index: int, acc: PassAccumulator) -> bool:
    """Whether a lockstep job needs no pass after `pass_index` (timing aside); `acc` holds
    passes 0..pass_index."""
    if pass_range(settings, pass_index + 1) is None:
        return True
    error = acc.error()
    return error is not None and error <= settings.target_error
