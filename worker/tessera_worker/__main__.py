"""python -m tessera_worker [--redis-url URL] [--name NAME] [--threads N] ...

The same worker as `tessera worker`, without the rest of the CLI. Every option also has an
environment variable (see settings.py); options override them."""
from __future__ import annotations

import argparse
import logging

from .settings import add_worker_options, settings_from_args
from .worker import run_worker


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m tessera_worker", description=__doc__)
    add_worker_options(parser)
    parser.add_argument("--log-level", default="INFO")
    args = parser.parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    run_worker(settings=settings_from_args(args), name=args.name)


if __name__ == "__main__":
    main()
