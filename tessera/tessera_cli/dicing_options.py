"""`tessera render`'s screen-space dicing options (tessera_renderer.usd.dicing): kept apart
from cli.py so that the command table stays readable."""
from __future__ import annotations

import argparse


def add_dicing_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dicing-rate", type=float, default=1.0, metavar="PX",
                        help="without --subdivision-level, each subdivision mesh is refined until its "
                             "edges are at most PX pixels long in the camera (default 1)")
    parser.add_argument("--dicing-max-level", type=int, choices=range(1, 7), default=4, metavar="N",
                        help="no mesh is refined more than N times by dicing, 1-6 (default 4)")
    parser.add_argument("--dicing-memory", type=float, default=1024.0, metavar="MB",
                        help="levels are lowered, largest meshes first, until the refined triangles' "
                             "estimated memory fits MB (default 1024)")


def dicing_from_args(args: argparse.Namespace):
    """The Dicing for load_scene, measured at the image's resolution; None when a fixed
    --subdivision-level was asked for."""
    from tessera_renderer.usd.dicing import Dicing

    if args.subdivision_level is not None:
        return None
    return Dicing(rate=args.dicing_rate, max_level=args.dicing_max_level, memory_mb=args.dicing_memory,
                  resolution=tuple(args.res) if args.res else None)
