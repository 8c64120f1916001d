"""Service configuration, from the environment (prefix TESSERA_)."""
from __future__ import annotations

from pydantic import AliasChoices, Field, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict
from typing_extensions import Annotated

MiB = 1 << 20
DAY = 86400


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="TESSERA_")

    redis_url: str = Field(
        default="redis://localhost:6379/0",
        validation_alias=AliasChoices("TESSERA_REDIS_URL", "REDIS_URL", "redis_url"),
        description="Redis holding the queue, scenes, jobs and results (also read from REDIS_URL)")
    api_tokens: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="the API's users and their bearer tokens, comma-separated `user:token` "
                    "entries (a user may have several; a bare `token` belongs to the user "
                    "`default`); empty: no authentication (allowed only on a loopback address)")
    api_admins: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="comma-separated user names that see and control every user's jobs")
    allow_anonymous_loopback: bool = Field(
        default=False,
        description="without api_tokens, serve requests whose both ends are loopback "
                    "addresses (and that no proxy forwarded from elsewhere) without a token; "
                    "off: a server without tokens answers every request 401")
    trusted_proxies: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="comma-separated addresses or CIDR networks of reverse proxies whose "
                    "Forwarded / X-Forwarded-For headers are believed; from any other peer "
                    "those headers make a request's origin unknown")
    allowed_hosts: Annotated[list[str], NoDecode] = Field(
        default_factory=lambda: ["localhost", "127.0.0.1", "::1"],
        description="comma-separated host names by which anonymous loopback requests may "
                    "address this server (their Host header, and the Origin of a request that "
                    "changes something); loopback IP addresses always count. Guards a "
                    "token-less farm against web pages (DNS rebinding, cross-site forms); "
                    "requests with a token are not checked")
    blob_store_concurrency: int = Field(
        default=2, ge=1,
        description="PUT /blobs uploads whose verified bytes are copied into the data "
                    "directory at once (each up to max_upload_bytes); the others wait")
    user_upload_concurrency: int = Field(
        default=4, ge=1,
        description="PUT /blobs uploads one user may have in flight at once; one more gets 429 "
                    "with Retry-After (each streams to a temporary file of up to "
                    "max_upload_bytes, so this bounds what one user puts on the API's disk)")
    upload_concurrency: int = Field(
        default=16, ge=1,
        description="PUT /blobs uploads in flight at once for all users together; beyond: 429")
    user_blob_quota_bytes: int = Field(
        default=1024 * MiB, ge=1,
        description="bytes of packed-scene files (PUT /blobs) one user may keep stored; an "
                    "upload past it gets 413 (six 250 MiB uploads of one user filled the "
                    "deploy Redis)")
    max_upload_bytes: int = Field(default=256 * MiB, ge=1, description="largest accepted scene file")
    preflight_timeout: float = Field(default=60.0, gt=0,
                                     description="seconds the scene inspection may take")
    preflight_memory_bytes: int = Field(
        default=8192 * MiB, ge=0,
        description="address-space limit of the inspection process (0: no limit); it also "
                    "caps the triangle limit (preflight.triangle_limit)")
    max_triangles: int = Field(
        default=16_000_000, ge=1,
        description="most triangles a scene may have (the renderer's TESSERA_MAX_TRIANGLES, "
                    "lowered to what preflight_memory_bytes can translate)")
    user_max_triangles: int = Field(
        default=4_000_000, ge=1,
        description="most triangles one user's scene may declare (counted from its face counts "
                    "before it is built; a per-user limit under max_triangles). 10^7 declared "
                    "triangles in an 82 KB file cost the farm 9 GB")
    user_max_translated_bytes: int = Field(
        default=256 * MiB, ge=1,
        description="largest translated scene (the blob workers share through Redis, textures "
                    "included) one user's scene may make, measured by the pre-flight")
    user_limits: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="per-user overrides of user_max_triangles and user_max_translated_bytes, "
                    "comma-separated `user:triangles=N:translated=BYTES` entries (either part "
                    "may be left out)")
    preflight_concurrency: int = Field(
        default=2, ge=1, description="scene inspections that may run at once (across scenes)")
    preflight_queue: int = Field(
        default=4, ge=0,
        description="uploads that may wait for an inspection slot; beyond: 429 at once")
    compare_max_pixels: int = Field(
        default=1 << 23, ge=1,
        description="largest image POST /compare accepts, in pixels (checked from the EXR "
                    "headers before decoding; larger: 413). A comparison takes about 800 "
                    "bytes a pixel (2048x2048: 3.2 GB resident, under 4 GiB of address "
                    "space); 8 Mpx (3840x2160 fits) stays within compare_memory_bytes")
    compare_memory_bytes: int = Field(
        default=8192 * MiB, ge=0,
        description="address-space limit of the child process that runs a comparison (0: no "
                    "limit); the API process itself reads no pixel of a compared image")
    compare_timeout: float = Field(default=120.0, gt=0,
                                   description="seconds a comparison may take")
    compare_concurrency: int = Field(
        default=1, ge=1,
        description="comparisons that may run at once; others wait up to compare_timeout, "
                    "and beyond preflight_queue waiting ones: 429")
    http_header_timeout: float = Field(
        default=10.0, gt=0,
        description="seconds a connection may take to send a request's headers, from its "
                    "first byte (or its opening); then it is closed (tessera serve)")
    http_body_idle_timeout: float = Field(
        default=30.0, gt=0,
        description="seconds a request body may go without a byte before the connection is "
                    "closed (tessera serve)")
    http_max_connections: int = Field(
        default=2048, ge=1,
        description="open connections the API keeps at most (lowered to its descriptor limit "
                    "less 256); beyond, a new one gets 503 and is closed (tessera serve)")
    max_tiles: int = Field(default=1 << 16, ge=1, description="most tiles one job may have")
    max_frames: int = Field(default=10_000, ge=1, description="most frames one frame range may have")
    job_retention: float = Field(
        default=7 * DAY, ge=0,
        description="seconds a finished job (status, tiles, image, events, log) is kept (0: forever)")
    scene_retention: float = Field(
        default=7 * DAY, ge=0,
        description="seconds an uploaded scene and its pre-flight result are kept after the "
                    "last job that used it was submitted (0: forever)")

    data_dir: str | None = Field(
        default=None,
        description="the data directory: uploaded files, scenes and translated scenes, as files "
                    "named by their SHA-256 (Redis keeps their index only). The API and every "
                    "worker must share it (TESSERA_DATA_DIR for both; several machines: a shared "
                    "volume). Default: XDG_DATA_HOME/tessera/data (~/.local/share/tessera/data)")
    data_sweep_seconds: float = Field(
        default=600.0, gt=0,
        description="seconds between sweeps of the data directory, which delete the files "
                    "nothing holds any more (an upload past its retention, a scene no job "
                    "holds past its retention); also at start")

    job_redis_budget: int = Field(
        default=1024 * MiB, ge=1,
        description="most bytes one job may keep in Redis (its tile results, splat sums and "
                    "images; estimated before it is queued: docs/farm.md, Memory per job)")

    stall_seconds: float = Field(
        default=600.0, gt=0,
        description="/healthz reports degraded when queued or running jobs have shown no "
                    "progress for this long")

    @field_validator("api_tokens", "api_admins", "trusted_proxies", "allowed_hosts", "user_limits",
                     mode="before")
    @classmethod
    def _split_tokens(cls, value):
        if isinstance(value, str):
            return [t.strip() for t in value.split(",") if t.strip()]
        return value

    @field_validator("user_limits")
    @classmethod
    def _check_user_limits(cls, value: list[str]) -> list[str]:
        for entry in value:
            _parse_user_limit(entry)
        return value

    def scene_limits(self, user: str) -> tuple[int, int]:
        """(triangles, translated bytes) that `user`'s scenes may have."""
        triangles, translated = self.user_max_triangles, self.user_max_translated_bytes
        for entry in self.user_limits:
            name, limits = _parse_user_limit(entry)
            if name == user:
                triangles = limits.get("triangles", triangles)
                translated = limits.get("translated", translated)
        return triangles, translated


def _parse_user_limit(entry: str) -> tuple[str, dict[str, int]]:
    name, *parts = entry.split(":")
    limits = {}
    for part in parts:
        key, _, number = part.partition("=")
        if key not in ("triangles", "translated") or not number.isdigit() or int(number) < 1:
            raise ValueError(f"user_limits entry {entry!r}: expected "
                             f"user:triangles=N:translated=BYTES (positive integers)")
        limits[key] = int(number)
    if not name:
        raise ValueError(f"user_limits entry {entry!r} names no user")
    return name, limits
