"""Reference sets: a folder of reference renders described by one manifest, `refs.json`.

Each entry names a scene (a path relative to the folder), how it was rendered (resolution,
integrator and its settings, spp or a noise target, seed), which Tessera rendered it, the
SHA-256 of the scene file at that time, and the reference EXR (with its variance and spp
layers and the tessera: metadata of every render). `tessera refs check` (tessera.refcheck)
renders each scene again with this working tree and compares it with its reference;
`tessera refs list` says which entries no longer match their scene or version.

The manifest is JSON so that a review diff shows exactly what a `refs update` changed.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, Field, ValidationError, field_validator

from tessera_base import integrators
from tessera_base.exr_header import scene_sha256

MANIFEST = "refs.json"
SCHEMA = 1
_NAME_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-.")


class RefsError(ValueError):
    """A reference set that cannot be used (no manifest, a bad entry, a missing scene): a
    usage error (exit code 2), never a verdict."""


class CheckBudget(BaseModel):
    """How much a check may render: looks at min_spp, then doubling totals up to max_spp."""
    min_spp: int = Field(default=64, ge=2, le=1 << 16)
    max_spp: int = Field(default=1024, ge=2, le=1 << 20)


class Reference(BaseModel):
    name: str = Field(description="unique within the set; names the EXR and the report's test case")
    scene: str = Field(description="the scene file, relative to the reference folder")
    width: int = Field(ge=1, le=16384)
    height: int = Field(ge=1, le=16384)
    integrator: str = Field(default_factory=integrators.default)  # the registry's first
    integrator_params: dict[str, float] = Field(default_factory=dict)
    max_depth: int = Field(default=64, ge=1, le=1024)
    seed: int = Field(default=0, ge=0, le=2**31)
    spp: int = Field(default=1024, ge=2, le=1 << 20, description="the reference's samples per pixel")
    target_error: float | None = Field(default=None, gt=0, le=1,
                                       description="render the reference to this noise target instead")
    check: CheckBudget = Field(default_factory=CheckBudget)
    exr: str = Field(description="the reference EXR, relative to the folder")
    # Filled in when the reference is rendered:
    tessera_version: str | None = None
    scene_sha256: str | None = None
    rendered_on: Literal["local", "farm"] = "local"

    @field_validator("name")
    @classmethod
    def _plain_name(cls, value: str) -> str:
        if not value or not set(value) <= _NAME_CHARS or value.startswith("."):
            raise ValueError(f"reference names may hold letters, digits, _ - . only, not {value!r}")
        return value


class RefSet(BaseModel):
    schema_version: int = Field(default=SCHEMA, alias="schema")
    alpha: float = Field(default=0.01, gt=0, lt=1,
                         description="false-alarm rate of one check when nothing changed")
    tolerance: float = Field(default=0.02, gt=0, lt=1,
                             description="relative difference of a region's mean within which it "
                                         "counts as the same when a check stops early")
    region: int = Field(default=32, ge=4, le=4096, description="region edge in pixels")
    references: list[Reference] = Field(default_factory=list)

    model_config = {"populate_by_name": True}

    def find(self, name: str) -> Reference:
        for ref in self.references:
            if ref.name == name:
                return ref
        known = ", ".join(r.name for r in self.references) or "none"
        raise RefsError(f"no reference named {name!r} (known: {known})")

    def select(self, names: list[str] | None) -> list[Reference]:
        return [self.find(n) for n in names] if names else list(self.references)


def manifest_path(folder: str | Path) -> Path:
    return Path(folder) / MANIFEST


def load(folder: str | Path) -> RefSet:
    path = manifest_path(folder)
    if not path.is_file():
        raise RefsError(f"{folder} is not a reference set: no {MANIFEST} (create one with "
                        f"`tessera refs create {folder} SCENE`)")
    try:
        data = json.loads(path.read_text())
        refs = RefSet.model_validate(data)
    except (OSError, ValueError, ValidationError) as exc:
        raise RefsError(f"{path}: {exc}") from None
    if refs.schema_version != SCHEMA:
        raise RefsError(f"{path}: schema {refs.schema_version}, this Tessera reads schema {SCHEMA}")
    names = [r.name for r in refs.references]
    if len(set(names)) != len(names):
        raise RefsError(f"{path}: reference names repeat")
    return refs


def save(folder: str | Path, refs: RefSet) -> None:
    path = manifest_path(folder)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(refs.model_dump(by_alias=True, mode="json"), indent=2) + "\n"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def scene_path(folder: str | Path, ref: Reference) -> Path:
    return (Path(folder) / ref.scene).resolve()




def status(folder: str | Path, ref: Reference) -> list[str]:
    """What no longer matches the entry: empty when scene, version and EXR are as recorded."""
    from . import __version__

    out = []
    scene = scene_path(folder, ref)
    if not scene.is_file():
        out.append(f"scene {ref.scene} is missing")
    elif ref.scene_sha256 and scene_sha256(scene) != ref.scene_sha256:
        out.append(f"scene {ref.scene} changed since the reference was rendered")
    exr = Path(folder) / ref.exr
    if not exr.is_file():
        out.append(f"reference {ref.exr} is missing (run `tessera refs update`)")
    if ref.tessera_version and ref.tessera_version != __version__:
        out.append(f"rendered by Tessera {ref.tessera_version}, this is {__version__}")
    return out
