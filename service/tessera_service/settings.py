"""Service configuration, from the environment (prefix TESSERA_)."""
from __future__ import annotations

from pydantic import AliasChoices, Field
from pydantic_settings import BaseSettings, SettingsConfigDict

MiB = 1 << 20


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="TESSERA_")

    redis_url: str = Field(
        default="redis://localhost:6379/0",
        validation_alias=AliasChoices("TESSERA_REDIS_URL", "REDIS_URL", "redis_url"),
        description="Redis holding the queue, scenes, jobs and results (also read from REDIS_URL)")
    max_upload_bytes: int = Field(default=256 * MiB, ge=1, description="largest accepted scene file")
    preflight_timeout: float = Field(default=60.0, gt=0,
                                     description="seconds the scene inspection may take")
    preflight_memory_bytes: int = Field(
        default=8192 * MiB, ge=0,
        description="address-space limit of the inspection process (0: no limit)")
    max_tiles: int = Field(default=1 << 16, ge=1, description="most tiles one job may have")
