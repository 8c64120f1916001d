"""`tessera refs create|update|check|list`: the command-line face of reference sets
(tessera.refs, tessera.refcheck, tessera.refreport). Exit codes as `tessera compare`:
0 every check passed, 1 a scene differs, 2 a usage error (no manifest, a bad entry)."""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path


def add_parser(sub, resolution, positive, add_integrator_option, integrator_params) -> None:
    """Adds `refs` to the CLI's subparsers (the CLI's own argument types passed in)."""
    p = sub.add_parser("refs", help="reference sets: render, check and report scenes against "
                                    "committed references (docs/accuracy.md)")
    rs = p.add_subparsers(dest="refs_command", required=True)

    c = rs.add_parser("create", help="add a scene to a reference set (creating it) and render its reference")
    c.add_argument("folder", help="the reference set's folder (holds refs.json and the EXRs)")
    c.add_argument("scene", help=".usda/.usdc/.usdz file")
    c.add_argument("--name", help="the reference's name (default: the scene file's stem)")
    c.add_argument("--res", type=resolution, help="WxH (default: the scene's)")
    c.add_argument("--spp", type=positive, default=1024, help="the reference's samples per pixel (default 1024)")
    c.add_argument("--target-error", type=float, default=None, metavar="REL",
                   help="render the reference to this relative noise target (at most --spp samples)")
    c.add_argument("--seed", type=int, default=0, help="the reference's seed (default 0)")
    c.add_argument("--max-depth", type=positive, default=64)
    c.add_argument("--check-min-spp", type=positive, default=64,
                   help="a check's first look (default 64 spp)")
    c.add_argument("--check-max-spp", type=positive, default=1024,
                   help="most samples per pixel a check renders (default 1024)")
    c.add_argument("--farm", metavar="URL", help="render the reference on this farm instead of locally")
    c.add_argument("--token", help="the farm's bearer token (default: $TESSERA_TOKEN)")
    c.add_argument("--threads", type=int, default=0)
    add_integrator_option(c, renders=True)
    c.set_defaults(func=cmd_create, integrator_params_fn=integrator_params)

    u = rs.add_parser("update", help="render references again (after an intended change)")
    u.add_argument("folder")
    u.add_argument("names", nargs="*", help="references to update (default: all)")
    u.add_argument("--farm", metavar="URL")
    u.add_argument("--token")
    u.add_argument("--threads", type=int, default=0)
    u.set_defaults(func=cmd_update)

    k = rs.add_parser("check", help="render each scene and compare it with its reference "
                                    "(exit 0 same, 1 differs, 2 usage error)")
    k.add_argument("folder")
    k.add_argument("names", nargs="*", help="references to check (default: all)")
    k.add_argument("--report", metavar="DIR", help="write the HTML report (index.html + PNGs) here")
    k.add_argument("--junit", metavar="FILE", help="write a JUnit XML file here (one test case per scene)")
    k.add_argument("--seed", type=int, default=None,
                   help="first seed of the check's looks (default: the reference's + 1000003)")
    k.add_argument("--strict", action="store_true",
                   help="fail a scene whose regions are not all decided within the budget")
    k.add_argument("--threads", type=int, default=0)
    k.set_defaults(func=cmd_check)

    ls = rs.add_parser("list", help="list the references and what changed since they were rendered")
    ls.add_argument("folder")
    ls.set_defaults(func=cmd_list)


def cmd_create(args: argparse.Namespace) -> int:
    from tessera_base import integrators
    from tessera_renderer import SceneError, load_scene

    from . import refcheck, refs

    folder, scene = Path(args.folder), Path(args.scene)
    try:
        refset = refs.load(folder) if refs.manifest_path(folder).is_file() else refs.RefSet()
        if not scene.is_file():
            raise refs.RefsError(f"scene {scene} does not exist")
        name = args.name or scene.stem
        if any(r.name == name for r in refset.references):
            raise refs.RefsError(f"{folder} already has a reference named {name!r} "
                                 f"(`tessera refs update {folder} {name}` renders it again)")
        if args.res:
            width, height = args.res
        else:
            try:
                loaded = load_scene(scene)
            except SceneError as exc:
                raise refs.RefsError(str(exc)) from None
            width, height = loaded.width, loaded.height
        ref = refs.Reference(
            name=name, scene=os.path.relpath(scene.resolve(), folder.resolve()), width=width,
            height=height, integrator=args.integrator or integrators.default(),
            integrator_params=args.integrator_params_fn(args), max_depth=args.max_depth,
            seed=args.seed, spp=args.spp, target_error=args.target_error,
            check=refs.CheckBudget(min_spp=args.check_min_spp, max_spp=args.check_max_spp),
            exr=f"{name}.exr")
        ref = refcheck.render_reference(folder, ref, threads=args.threads, progress=True, farm=args.farm,
                                    token=args.token or os.environ.get("TESSERA_TOKEN"))
    except (refs.RefsError, ValueError) as exc:
        print(f"tessera refs create: {exc}", file=sys.stderr)
        return 2
    refset.references.append(ref)
    refs.save(folder, refset)
    print(f"{ref.name}: wrote {folder / ref.exr} ({ref.width}x{ref.height}, {ref.integrator}, "
          f"{ref.spp} spp) and {refs.manifest_path(folder)}", file=sys.stderr)
    return 0


def cmd_update(args: argparse.Namespace) -> int:
    from . import refcheck, refs

    folder = Path(args.folder)
    try:
        refset = refs.load(folder)
        chosen = {r.name for r in refset.select(args.names)}
        for i, ref in enumerate(refset.references):
            if ref.name in chosen:
                refset.references[i] = refcheck.render_reference(
                    folder, ref, threads=args.threads, progress=True, farm=args.farm,
                    token=args.token or os.environ.get("TESSERA_TOKEN"))
                print(f"{ref.name}: rendered again", file=sys.stderr)
                refs.save(folder, refset)
    except refs.RefsError as exc:
        print(f"tessera refs update: {exc}", file=sys.stderr)
        return 2
    return 0


def cmd_list(args: argparse.Namespace) -> int:
    from . import refs

    try:
        refset = refs.load(args.folder)
    except refs.RefsError as exc:
        print(f"tessera refs list: {exc}", file=sys.stderr)
        return 2
    for ref in refset.references:
        changes = refs.status(args.folder, ref)
        target = f"noise target {ref.target_error:.2%}" if ref.target_error else f"{ref.spp} spp"
        print(f"{ref.name}: {ref.scene} {ref.width}x{ref.height} {ref.integrator} {target} seed {ref.seed} "
              f"(Tessera {ref.tessera_version or '?'}, {ref.rendered_on}): "
              + ("; ".join(changes) if changes else "up to date"))
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    from . import refcheck, refreport, refs

    folder = Path(args.folder)
    try:
        refset = refs.load(folder)
        chosen = refset.select(args.names)
    except refs.RefsError as exc:
        print(f"tessera refs check: {exc}", file=sys.stderr)
        return 2
    results, errors = [], {}
    for ref in chosen:
        try:
            result = refcheck.check(folder, refset, ref, seed=args.seed, threads=args.threads,
                                    strict=args.strict)
        except refs.RefsError as exc:
            errors[ref.name] = str(exc)
            print(f"{ref.name}: ERROR: {exc}", file=sys.stderr)
            continue
        results.append(result)
        print(f"{ref.name}: {'PASS' if result.passed else 'FAIL'} ({result.verdict}): {result.why}")
        for note in result.notes:
            print(f"  note: {note}")
    try:
        if args.report:
            index = refreport.write_html(results, args.report, errors=errors)
            print(f"report: {index}", file=sys.stderr)
        if args.junit:
            refreport.write_junit(results, args.junit, errors=errors)
            print(f"junit: {args.junit}", file=sys.stderr)
    except OSError as exc:
        print(f"tessera refs check: {exc}", file=sys.stderr)
        return 2
    if errors:
        return 2
    return 0 if all(r.passed for r in results) else 1
