"""Worker configuration, from the environment (prefix TESSERA_WORKER_; the Redis URL also
from REDIS_URL). Command-line options override it."""
from __future__ import annotations

import argparse

from pydantic import AliasChoices, Field
from pydantic_settings import BaseSettings, SettingsConfigDict

GiB = 1 << 30


class WorkerSettings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="TESSERA_WORKER_")

    redis_url: str = Field(default="redis://localhost:6379/0",
                           validation_alias=AliasChoices("TESSERA_WORKER_REDIS_URL", "REDIS_URL",
                                                         "redis_url"))
    data_dir: str | None = Field(
        default=None, validation_alias=AliasChoices("TESSERA_DATA_DIR", "TESSERA_WORKER_DATA_DIR", "data_dir"),
        description="the farm's data directory, shared with the API (TESSERA_DATA_DIR; default "
                    "XDG_DATA_HOME/tessera/data): scenes and translated scenes")
    threads: int = Field(default=0, ge=0, description="renderer threads per tile (0: all cores)")
    heartbeat_ttl: float = Field(default=5.0, gt=0,
                                 description="seconds after its last heartbeat a worker is dead")
    memory_limit: int = Field(default=16 * GiB, ge=0,
                              description="address-space limit of the render process in bytes "
                                          "(0: none); exceeding it fails the job")
    tile_timeout: float = Field(default=1800.0, gt=0,
                                description="seconds one tile pass may render; exceeding it "
                                            "fails the job")
    stop_grace: float = Field(default=20.0, ge=0,
                              description="seconds a stopping worker (SIGTERM) keeps rendering "
                                          "its current tile; then it hands the tile back to "
                                          "the queue and exits. Keep it below the "
                                          "orchestrator's grace period (Kubernetes: "
                                          "terminationGracePeriodSeconds)")
    faults: str = Field(default="", description="fault injection for drills and tests: "
                                                "comma-separated KIND:GLOB[#TILE], KIND one of "
                                                "segv, abort, hang, oom, exit; GLOB matches "
                                                "the scene's file name")


def add_worker_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--redis-url", help="default: $REDIS_URL or redis://localhost:6379/0")
    parser.add_argument("--name", default=None, help="consumer name (default: host-pid-random)")
    parser.add_argument("--data-dir", help="the farm's data directory, shared with the API "
                                           "(default: $TESSERA_DATA_DIR or ~/.local/share/tessera/data)")
    parser.add_argument("--threads", type=int, help="renderer threads per tile (0: all cores)")
    parser.add_argument("--heartbeat-ttl", type=float,
                        help="seconds after its last heartbeat a worker counts as dead")
    parser.add_argument("--memory-limit", type=int,
                        help="address-space limit of the render process in bytes (0: none)")
    parser.add_argument("--tile-timeout", type=float, help="seconds one tile pass may render")
    parser.add_argument("--stop-grace", type=float,
                        help="seconds a stopping worker keeps rendering its tile before it "
                             "hands it back to the queue")


def settings_from_args(args: argparse.Namespace) -> WorkerSettings:
    settings = WorkerSettings()
    update = {k: getattr(args, k) for k in ("redis_url", "data_dir", "threads", "heartbeat_ttl",
                                           "memory_limit", "tile_timeout", "stop_grace")
              if getattr(args, k, None) is not None}
    return settings.model_copy(update=update)
