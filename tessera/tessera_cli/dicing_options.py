"""`tessera render`'s screen-space dicing options (tessera_renderer.usd.dicing): kept apart
from cli.py so that the command table stays readable."""
from __future__ import annotations

import argparse


def add_dicing_options(parser: argparse.ArgumentParser) -> None:
    # Opt-in: the farm refines at the fixed level (its translated-scene keys do not hold the
    # resolution yet), and a default local render must equal the farm's bit for bit.
    parser.add_argument("--dicing-rate", type=float, default=None, metavar="PX",
                        help="dice subdivision surfaces: without --subdivision-level, each mesh is "
                             "refined until its edges are at most PX pixels long in the camera, e.g. 1 "
                             "(default: off, the fixed level 2 a farm job uses too)")
    parser.add_argument("--dicing-max-level", type=int, choices=range(1, 7), default=4, metavar="N",
                        help="no mesh is refined more than N times by dicing, 1-6 (default 4)")
    parser.add_argument("--dicing-memory", type=float, default=1024.0, metavar="MB",
                        help="levels are lowered, largest meshes first, until the refined triangles' "
                             "estimated memory fits MB (default 1024)")


def dicing_from_args(args: argparse.Namespace):
    """The Dicing for load_scene, measured at the image's resolution; None without
    --dicing-rate or with a fixed --subdivision-level."""
    from tessera_renderer.usd.dicing import Dicing

    if args.subdivision_level is not None or args.dicing_rate is None:
        return None
    return Dicing(rate=args.dicing_rate, max_level=args.dicing_max_level, memory_mb=args.dicing_memory,
                  resolution=tuple(args.res) if args.res else None)
