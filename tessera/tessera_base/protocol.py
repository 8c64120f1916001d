"""The one job/tile message schema shared by the service and the workers: the message
models (versioned), the tile grid and pass schedule and the encoding of tile results. How
passes combine and when a render has converged: tessera_base.convergence; the queue's task
messages (TileTask), where these live in Redis, and the scripts that move a job through its
states: tessera_queue.tasks and tessera_queue.redis_schema; how tile results become an
image: tessera_base.film.

Invariant: a pixel's value depends only on (scene, pixel, sample index, seed), so the
tile grid is a scheduling choice and never changes the image. Passes are combined by
`convergence.combine_passes`, which the local renderer uses too, so a farm render equals a local one
bit for bit whatever the pass schedule.
"""
from __future__ import annotations

import math
import re
import struct
import zlib
from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, Field, field_serializer, field_validator, model_validator

from . import integrators
from .denoise import DENOISE_AOVS
from .settings_spec import RENDER, SUBMIT, Takes, parse_json_object, parse_list, parse_numbers, settings_of

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


MAX_FRAMES = 100_000


def parse_frames(spec: str) -> list[int]:
    """Frame numbers as render farms write them: comma-separated items, each a frame `7`, a
    range `1-24` (both ends included) or a stepped range `1-24x2` (1, 3, ..., 23); negative
    frames are written `-5--1`. In the order written, each frame once. ValueError names
    the item that is not of that form."""
    import re

    frames: dict[int, None] = {}
    for item in (part.strip() for part in spec.split(",")):
        m = re.fullmatch(r"(-?\d+)(?:-(-?\d+)(?:x(\d+))?)?", item)
        if not m:
            raise ValueError(f"frames: {item!r} is not a frame (7), a range (1-24) or a stepped range (1-24x2)")
        first = int(m.group(1))
        last = int(m.group(2)) if m.group(2) is not None else first
        step = int(m.group(3)) if m.group(3) is not None else 1
        if last < first or step < 1:
            raise ValueError(f"frames: {item!r} must run upwards with a step of at least 1")
        if (last - first) // step + 1 + len(frames) > MAX_FRAMES:
            raise ValueError(f"frames: more than {MAX_FRAMES} frames")
        frames.update(dict.fromkeys(range(first, last + 1, step)))
    return list(frames)


def numbered_path(path: str, frame: int) -> str:
    """The file of one frame: a run of `#` in the name is the zero-padded frame number
    (out.####.exr -> out.0007.exr); a name without one gets `.####` before its extension."""
    import os
    import re

    head, name = os.path.split(path)
    if "#" not in name:
        stem, ext = os.path.splitext(name)
        name = f"{stem}.####{ext}"
    run = re.search(r"#+", name)
    number = f"{frame:0{len(run.group())}d}" if frame >= 0 else f"-{-frame:0{len(run.group())}d}"
    return os.path.join(head, name[:run.start()] + number + name[run.end():])


def parse_variant(text: str) -> tuple[str, str, str]:
    """A variant selection as the CLI and the job setting write it, `/Prim/Path:set=value`,
    as (prim path, variant set, variant). ValueError names what is wrong."""
    import re

    m = re.fullmatch(r"(/[^\s:=]*):([^\s:=/]+)=([^\s:=/]*)", text.strip())
    if not m or m.group(1) != "/" and m.group(1).endswith("/"):
        raise ValueError(f"variant {text!r} must be /Prim/Path:set=value (e.g. /Car:color=red)")
    return m.group(1), m.group(2), m.group(3)


class RenderSettings(BaseModel):
    """What to render. Resolution is final here (scene defaults already applied).

    With `target_error` unset every tile gets `spp` samples in one pass (a progressive
    integrator, sppm or vcm: in passes of 1, 1, 2, 4, ... samples, see `pass_range`). With it
    set the image is rendered to a noise target: tiles get passes of min_spp, then doubling
    up to max_spp samples, until their relative noise (see `tile_error`) is at most
    target_error, or until `time_limit` seconds after the job started."""

    # Each field annotated with Takes is a render setting: the CLI options, the API's form
    # fields and the Python API's keywords are generated from it (settings_spec).
    width: Annotated[int, Takes(cli=(), form_help="default: the scene's render settings, else 512")] = Field(
        ge=1, le=16384, description="image width in pixels")
    height: Annotated[int, Takes(cli=(), form_help="default: the scene's render settings, else 512")] = Field(
        ge=1, le=16384, description="image height in pixels")
    spp: Annotated[int, Takes()] = Field(default=64, ge=1, le=1 << 20, description="samples per pixel (fixed mode)")
    seed: Annotated[int, Takes()] = Field(default=0, ge=0, le=2**32 - 1, description="random seed")
    # Added within schema 2 with a default that changes nothing, so earlier messages stay
    # valid and keep their images.
    seed_offset: Annotated[int, Takes()] = Field(
        default=0, ge=0, le=2**32 - 1,
        description="added to the seed (modulo 2^32): another independent render of the same job settings "
                    "(a second look at its noise, or each frame of a sequence its own) while "
                    "the seed stays the one the settings name")
    max_depth: Annotated[int, Takes()] = Field(default=64, ge=1, le=1024, description="maximum path length (bounces)")
    tile_size: Annotated[int, Takes(flag="--tile")] = Field(default=64, ge=8, le=4096, description="tile edge in pixels")
    target_error: Annotated[float | None, Takes(
        argparse=dict(nargs="?", const=0.01, metavar="REL"),
        cli_help="render to a relative noise target instead of a fixed --spp (default target 0.01 = 1 %)")] = Field(
        default=None, gt=0, le=1, allow_inf_nan=False,
        description="relative noise to stop at (0.01 = 1 %); unset: fixed spp")
    min_spp: Annotated[int, Takes()] = Field(default=16, ge=1, le=1 << 20,
                         description="samples of the first pass (noise-target mode)")
    max_spp: Annotated[int, Takes()] = Field(default=1024, ge=1, le=1 << 20,
                         description="most samples any pixel gets (noise-target mode)")
    time_limit: Annotated[float | None, Takes()] = Field(
        default=None, gt=0, le=7 * 86400, allow_inf_nan=False,
        description="seconds after the job starts when no further passes begin "
                    "(noise-target mode; makes the image depend on timing)")
    # The CLI's --integrator is hand-made: it checks the name before the renderer loads.
    integrator: Annotated[str, Takes(cli=())] = Field(
        default_factory=integrators.default,
        description="light transport method: a name from the renderer's registry, or auto "
                    "(`tessera render --integrator help`, docs/integrators.md)")
    # Added within schema 2: optional, so earlier messages stay valid.
    auto_pilot: Annotated[str | None, Takes(cli=())] = Field(
        default=None, max_length=4096,
        description="what `auto` measured before the job was sent (tessera.pilot's JSON: the choice "
                    "and each candidate's efficiency), when the client resolved it; logged with the "
                    "job and written to the image's tessera:auto")
    # Added within schema 2: optional with an empty default, so earlier messages stay valid.
    integrator_params: Annotated[dict[str, float], Takes(
        cli=(), parse=parse_json_object,
        form_help='the integrator\'s own settings as a JSON object of name -> number, e.g. {"max_distance": 2} '
                  'for ao ("inf" as a string for infinity; docs/integrators.md)')] = Field(
        default_factory=dict,
        description="the integrator's own settings, NAME -> number, as its registry entry declares "
                    "them (`tessera render --integrator help`; e.g. ao's max_distance); inf allowed")
    aovs: Annotated[list[Literal["albedo", "normal", "depth", "spp", "variance"]],
                    Takes(parse=str, argparse=dict(metavar="LIST"),
                          form_help="comma-separated extra EXR layers: albedo, normal, depth, spp, variance, "
                                    "or all (docs/aovs.md)")] = Field(
        default_factory=list,
        description="extra per-pixel outputs written as EXR layers beside RGBA "
                    "(docs/aovs.md): albedo, normal, depth, spp, variance")

    default_light: Annotated[bool, Takes(flag="--no-default-light", argparse=dict(action="store_false"),
                                         cli_help="a scene without any light renders black instead of "
                                                  "getting the default lighting (white dome + camera key light)")] = Field(
        default=True, description="light a stage that has no light (emissive geometry counts) with "
                                  "the default lighting: a white dome and a camera-relative key light "
                                  "(docs/scene-translation.md); false renders such a stage black")

    # Added within schema 2: optional, None meaning the renderer's default, so earlier
    # messages stay valid and keep their images.
    subdivision_level: Annotated[int | None, Takes(argparse=dict(metavar="N"))] = Field(
        default=None, ge=0, le=6,
        description="how many times subdivision surfaces are refined (0-6; default: the renderer's, "
                    "2; 0 renders their control cage; docs/scene-translation.md)")
    # Added within schema 2: optional, None keeping the fixed level, so earlier messages stay
    # valid and keep their images. The level each mesh gets is a function of the stage, the
    # camera, the image's width and height and these three: every worker of a job dices alike.
    dicing_rate: Annotated[float | None, Takes(argparse=dict(metavar="PX"))] = Field(
        default=None, gt=0, le=1024, allow_inf_nan=False,
        description="dice subdivision surfaces to the camera: without subdivision_level, each mesh is "
                    "refined until its edges are at most this many pixels long in the image, e.g. 1 "
                    "(default: off, the fixed level 2; docs/scene-translation.md, \"Subdivision dicing\")")
    dicing_max_level: Annotated[int | None, Takes(argparse=dict(metavar="N"))] = Field(
        default=None, ge=1, le=6,
        description="with dicing_rate: no mesh is refined more than this many times, 1-6 (default 4)")
    dicing_memory: Annotated[float | None, Takes(argparse=dict(metavar="MB"))] = Field(
        default=None, gt=0, le=1 << 20, allow_inf_nan=False,
        description="with dicing_rate: levels are lowered, largest meshes first, until the refined "
                    "triangles' estimated memory fits this many MB (default 1024)")
    camera: Annotated[str | None, Takes(argparse=dict(metavar="PRIM_PATH"))] = Field(
        default=None, min_length=1, max_length=1024, pattern=r"^/\S*$",
        description="the path of the Camera prim to render through (default: the RenderSettings' "
                    "camera, else the first camera, else a three-quarter view framing the scene)")
    # The CLI's --frame is hand-made: it excludes --frames, which is no setting of one image.
    frame: Annotated[float | None, Takes(cli=())] = Field(
        default=None, allow_inf_nan=False, ge=-1e9, le=1e9,
        description="the USD time code to render (default: the stage's startTimeCode, else the "
                    "default time; docs/motion.md)")
    shutter: Annotated[tuple[float, float] | None, Takes(
        parse=parse_numbers(2, float, "OPEN,CLOSE (two time codes)"), argparse=dict(metavar="OPEN,CLOSE"),
        cli_help="motion blur over [frame+OPEN, frame+CLOSE] in time codes, replacing the camera's "
                 "shutter:open/close; 0,0 renders without motion blur (docs/motion.md)",
        form_help="OPEN,CLOSE in time codes from the frame, replacing the camera's shutter:open/close "
                  "(0,0: no motion blur; docs/motion.md); empty: the camera's")] = Field(
        default=None,
        description="(open, close) in time codes from the frame, replacing the camera's "
                    "shutter:open/close; [0, 0] renders without motion blur (docs/motion.md)")

    variants: Annotated[list[str] | None, Takes(
        flag="--variant", parse=parse_list, cli_parse=lambda text: parse_variant(text) and text,
        argparse=dict(action="append", metavar="PRIM:SET=VALUE"),
        cli_help="render with this variant selected, e.g. /Car:color=red (repeatable)",
        form_help="comma-separated variant selections, each /Prim/Path:set=value (checked when a worker "
                  "composes the stage: an unknown prim, set or variant fails the job naming the choices)")] = Field(
        default=None, max_length=256,
        description="variant selections to render with, each /Prim/Path:set=value, in place of the "
                    "stage's own (docs/scene-translation.md, \"Variants\")")

    @field_validator("variants")
    @classmethod
    def _variant_selections(cls, value):
        if value is not None:
            for text in value:
                parse_variant(text)
        return value or None

    @field_validator("shutter")
    @classmethod
    def _shutter_interval(cls, value):
        if value is not None:
            open_, close = value
            if not (math.isfinite(open_) and math.isfinite(close)) or open_ > close or close - open_ > 1e6:
                raise ValueError(f"shutter must be two finite time codes with open <= close, not {list(value)}")
        return value

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
    denoise: Annotated[bool, Takes()] = Field(
        default=False,
        description="add an Open Image Denoise layer (denoised.R/G/B) and preview beside the "
                    "raw image; adds the albedo and normal AOVs (docs/denoise.md)")

    # Added within schema 2 like aovs: the region the EXR holds (x0, y0, x1, y1; x1, y1
    # exclusive) as its data window inside the full display window (docs/aovs.md). Only
    # the tiles meeting it are rendered, cut to it (job_tiles), unless the integrator splats;
    # every tile then passes it to the core as the camera window (film.render_tile_pass).
    crop: Annotated[tuple[int, int, int, int] | None, Takes(
        parse=parse_numbers(4, int, "X0,Y0,X1,Y1"), argparse=dict(metavar="X0,Y0,X1,Y1"),
        form_help="x0,y0,x1,y1 (x1, y1 exclusive): the EXR holds only this region, as its data window "
                  "inside the full frame (docs/aovs.md); empty: the whole image")] = Field(
        default=None,
        description="write only this pixel region x0,y0,x1,y1 (x1, y1 exclusive) of the image "
                    "to the EXR, as its data window inside the full-frame display window; only "
                    "the region is rendered (light, bdpt and vcm still trace every pixel's light "
                    "paths, which land in it; bdpt and vcm skip the camera work outside it)")

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
    def sample_seed(self) -> int:
        """The seed the samples are drawn with (what the image's tessera:seed records)."""
        return (self.seed + self.seed_offset) % 2**32

    @property
    def lockstep(self) -> bool:
        """Noise-target mode in which the whole image advances pass by pass together and
        stops together (see `image_finished`). Integrators that cannot stop per tile (their
        stop_per_tile capability; today the splatting ones) need it: their light paths land
        on every tile's pixels, so a tile's noise is not its own to judge, and bdpt's MIS
        weights assume every pixel has as many camera samples as there are light paths per
        pixel, which per-tile stopping would break. `auto` may resolve to such an integrator,
        and a farm cannot know before it loads the scene, so it is scheduled the same way
        (local renders follow the same rule, so farm and local images stay identical).
        A fixed-spp render of a progressive integrator (sppm, vcm, photon_direct) has several passes too,
        each with its scene pass, and advances the same way to its last."""
        if not self.adaptive:
            return integrators.progressive(self.integrator)
        return not integrators.stops_per_tile(self.integrator)


def pass_range(settings: RenderSettings, pass_index: int) -> tuple[int, int] | None:
    """(sample_start, spp) of pass `pass_index`, or None past the last pass. Passes double
    (min_spp, min_spp, 2 min_spp, 4 min_spp, ...) up to max_spp; for an integrator whose
    iterations trace batches of paths they stop doubling at its cap (iteration_share_cap
    times min_spp) and stay there, so that every iteration's paths keep up with its samples.

    A fixed spp is one pass, except for a progressive integrator (sppm, vcm, photon_direct): its iterations
    (fresh photons or light paths, a smaller radius) must grow with the samples asked for,
    or its error stops falling where one iteration's paths leave it. Its passes are then
    those of a noise target with min_spp = 1 and max_spp = spp, all of them: 1, 1, 2, 4, ...
    samples, at most the cap's, up to spp (SmallVCM's loop of one sample a pixel per
    iteration, with doubling iterations)."""
    if settings.adaptive:
        first, last = settings.min_spp, settings.max_spp
    elif integrators.progressive(settings.integrator):
        first, last = 1, settings.spp
    else:
        return (0, settings.spp) if pass_index == 0 else None
    cap = integrators.iteration_share_cap(settings.integrator, settings.integrator_params)
    largest = last if cap is None else cap * first
    start, end = 0, min(first, last)
    for _ in range(pass_index):
        if end >= last:
            return None
        start, end = end, min(end + min(end, largest), last)
    return start, end - start


# Every render setting and the routes that take it (settings_spec), in field order.
SETTINGS = settings_of(RenderSettings)


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


def dicing_of(settings: RenderSettings) -> dict | None:
    """The screen-space dicing a job asks for, as JSON values
    (tessera_renderer.usd.dicing.Dicing.from_json reads them): None with a fixed
    subdivision_level or without dicing_rate. Measured at the job's full frame, never a
    tile's or the crop's, so that every worker of the job refines alike."""
    if settings.subdivision_level is not None or settings.dicing_rate is None:
        return None
    return {"rate": settings.dicing_rate, "max_level": settings.dicing_max_level,
            "memory_mb": settings.dicing_memory, "resolution": [settings.width, settings.height]}


def tile_grid(width: int, height: int, tile_size: int) -> list[TileRect]:
    """Row-major tiles covering the image; edge tiles are smaller."""
    tiles = []
    for y0 in range(0, height, tile_size):
        for x0 in range(0, width, tile_size):
            tiles.append(TileRect(index=len(tiles), x0=x0, y0=y0,
                                  width=min(tile_size, width - x0),
                                  height=min(tile_size, height - y0)))
    return tiles


def job_tiles(settings: "RenderSettings", integrator: str | None = None) -> list[TileRect]:
    """The tiles a job renders: the whole grid, or with a crop only the grid's tiles that
    meet it, cut to it (each keeps its grid index). A pixel depends only on (scene, pixel,
    sample, seed), so the crop's pixels equal the full render's bit for bit. Not for an
    integrator that splats (`integrator`, default settings.integrator; `auto` may): a
    crop pixel also gathers the light paths started from every other pixel, so those
    render the whole grid, the crop as the renderer's camera window (film.render_tile_pass:
    outside it only the light paths are traced, bdpt and vcm skip their camera work)."""
    s = settings
    grid = tile_grid(s.width, s.height, s.tile_size)
    if s.crop is None:
        return grid
    if integrators.splats(integrator or s.integrator):
        return grid
    cx0, cy0, cx1, cy1 = s.crop
    out = []
    for t in grid:
        x0, y0 = max(t.x0, cx0), max(t.y0, cy0)
        x1, y1 = min(t.x0 + t.width, cx1), min(t.y0 + t.height, cy1)
        if x0 < x1 and y0 < y1:
            out.append(TileRect(index=t.index, x0=x0, y0=y0, width=x1 - x0, height=y1 - y0))
    return out


def in_crop(settings: "RenderSettings", array: np.ndarray | None) -> np.ndarray | None:
    """The crop's region of a full-frame array (h, w, ...), or the array without a crop.
    What the user sees of a cropped render: its noise, its PNG, its black-image check
    (the pixels outside it were never rendered)."""
    if array is None or settings.crop is None:
        return array
    x0, y0, x1, y1 = settings.crop
    return array[y0:y1, x0:x1]


# ------------------------------------------------------------------ tile results
# Version 2: a fixed header, then float32 sections, row-major:
#   rgba (h, w, 4): the mean of samples [sample_start, sample_start + spp)
#   variance (h, w, 3) if FLAG_VARIANCE: per-channel unbiased sample variance
#   splat if FLAG_SPLAT: a rect header (x0, y0, w, h) and int64 (h, w, 3) light-tracing
#       splats in the renderer's fixed point (tessera_renderer.film), covering that rect of
#       the full frame (the bounding box of where the pass's light paths landed). Summed
#       over all results (exact, order-free) and normalised by the job's total light_paths
#       (tessera_base.film.resolve_splats). The farm stores results with an empty splat rect and
#       sums their layers per pass instead (tessera_base.film.SplatSums). With FLAG_SPLAT_EXPONENT an int32 e follows the rect: the
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
    range (batch_ranges), as a render of them alone gives them (made in the pass's own
    render call: render.h VarianceBatches)."""
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
