"""python -m tessera_worker [--redis-url URL] [--name NAME] [--threads N]

The same worker as `tessera worker`, without the rest of the CLI."""
from __future__ import annotations

import argparse
import logging
import os

from .worker import HEARTBEAT_TTL, run_worker


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m tessera_worker", description=__doc__)
    parser.add_argument("--redis-url", default=os.environ.get("REDIS_URL", "redis://localhost:6379/0"),
                        help="default: $REDIS_URL or redis://localhost:6379/0")
    parser.add_argument("--name", default=None, help="consumer name (default: host-pid-random)")
    parser.add_argument("--threads", type=int, default=1, help="renderer threads per tile")
    parser.add_argument("--heartbeat-ttl", type=float, default=HEARTBEAT_TTL,
                        help="seconds after its last heartbeat a worker counts as dead")
    parser.add_argument("--log-level", default="INFO")
    args = parser.parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    run_worker(args.redis_url, name=args.name, threads=args.threads,
               heartbeat_ttl=args.heartbeat_ttl)


if __name__ == "__main__":
    main()
