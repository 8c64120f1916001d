"""The renderer's integrators, for every part of Tessera: names, descriptions and the
capabilities that decide how a job is scheduled and its image assembled.

The one list is the renderer core's registry (renderer/core/integrators/registry.cpp);
nothing in Python names an integrator. A process that has the renderer loaded reads it
directly; the service and the worker's main process never load the renderer (it parses
untrusted scenes), so they ask a child process once (`python -m tessera_renderer.registry`).

`auto` is not an integrator but a rule the renderer applies per scene (a delta light
shining through caustic-forming materials needs an integrator with `delta_caustics`);
before the scene is loaded, `auto` can be any of the integrators it may pick.
"""
from __future__ import annotations

import functools
import json
import subprocess
import sys

AUTO = "auto"


class RegistryError(RuntimeError):
    """The renderer's integrator list could not be read (the renderer is not installed)."""


@functools.cache
def _registry() -> dict:
    if "tessera_renderer._core" in sys.modules:
        from tessera_renderer.registry import describe
        return describe()
    try:
        out = subprocess.run([sys.executable, "-m", "tessera_renderer.registry"], capture_output=True,
                             text=True, timeout=120, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise RegistryError(f"cannot list the renderer's integrators: {exc}") from None
    if out.returncode != 0:
        last = (out.stderr.strip().splitlines() or ["no output"])[-1]
        raise RegistryError(f"cannot list the renderer's integrators: {last}")
    return json.loads(out.stdout)


def integrators() -> list[dict]:
    """Every integrator in registry order: name, description, capabilities, params."""
    return _registry()["integrators"]


def names() -> tuple[str, ...]:
    """What a user may ask for: every integrator's name, then `auto`."""
    return tuple(i["name"] for i in integrators()) + (AUTO,)


def default() -> str:
    """The integrator used when none is asked for: the registry's first."""
    return integrators()[0]["name"]


def validate(name: str) -> str:
    """`name` if an integrator (or `auto`) has it; else ValueError listing the known ones."""
    if name not in names():
        raise ValueError(f"unknown integrator {name!r} (known: {', '.join(names())})")
    return name


def _candidates(name: str) -> list[dict]:
    """The integrators `name` may turn out to be once the scene is known."""
    validate(name)
    picks = set(_registry()["auto"]) if name == AUTO else {name}
    return [i for i in integrators() if i["name"] in picks]


def splats(name: str) -> bool:
    """Whether images rendered with `name` carry light-path splats across tiles, to be
    normalised by the light paths traced (tessera/tessera_base/film.py). For `auto`: whether it may."""
    return any(i["splats"] for i in _candidates(name))


def scene_passes(name: str) -> bool:
    """Whether `name` needs a scene-wide pass before each iteration's tile passes (its
    product is what the tiles read: tessera_base.film.run_scene_pass). For `auto`: whether it may."""
    return any(i["scene_passes"] for i in _candidates(name))


def iteration_share_cap(name: str, values: dict[str, float]) -> int | None:
    """The most first-pass shares of samples one pass may hold for `name` with settings
    `values`, or None (no cap: the passes keep doubling). An integrator whose iterations
    trace batches of paths (its `iteration_cap`) holds at most `max_per_iteration` paths an
    iteration (or its setting `max_param`); the cap is the largest power of two of batches
    within that, at least 1 (the core's IterationShareCap, integrators/integrator.h: both
    must agree, tests/renderer/test_vcm.py checks). For `auto`: none (the integrators it
    picks have no cap)."""
    if name == AUTO:
        return None
    entry = next((i for i in integrators() if i["name"] == name), None)
    cap = entry.get("iteration_cap") if entry else None
    if not cap:
        return None
    per_batch = float(values.get(cap["param"], cap["per_batch"]))
    most = float(values.get(cap["max_param"], cap["max_per_iteration"])) if cap["max_param"] else cap["max_per_iteration"]
    share = 1
    while per_batch > 0 and share * 2 * per_batch <= most and share < 1 << 40:
        share *= 2
    return share


def progressive(name: str) -> bool:
    """Whether `name`'s iterations trace batches of paths (its `iteration_cap`: sppm, vcm,
    photon_direct):
    its estimate converges only as iterations add batches and shrink the radius, so even a
    fixed-spp render runs in passes (protocol.pass_range). For `auto`: no (the integrators
    it may pick in a fixed-spp render have no such cap)."""
    return iteration_share_cap(name, {}) is not None


def stops_per_tile(name: str) -> bool:
    """Whether a tile may stop on a noise target on its own (else the whole image advances
    in lockstep). For `auto`: only if every integrator it may pick can."""
    return all(i["stop_per_tile"] for i in _candidates(name))


def scene_warnings(name: str, *, curve_segments: int = 0, linked_lights: int = 0, media: bool = False) -> list[str]:
    """What `name` cannot render of a scene with these features, one line each (the CLI,
    local renders and the service add them to the scene's warnings). For `auto`: what any
    integrator it may pick cannot. `linked_lights`: lights with UsdLux light or shadow
    links; `media`: the scene has participating media (path's media kernel ignores links)."""
    out = []
    if curve_segments and not all(i.get("shades_curves", True) for i in _candidates(name)):
        out.append(f"the {name} integrator does not shade curves ({curve_segments} curve segments): "
                   f"they render black; any other integrator shades them")
    if linked_lights:
        honouring = [i["name"] for i in integrators() if i.get("honours_light_links")]
        if media:
            out.append(f"{linked_lights} light(s) have UsdLux light or shadow links, which no integrator honours "
                       f"in a scene with participating media yet: rendered as if every light lit everything")
        elif not all(i.get("honours_light_links") for i in _candidates(name)):
            out.append(f"the {name} integrator does not honour UsdLux light and shadow links ({linked_lights} "
                       f"light(s) have them) in every light path; {' and '.join(honouring)} do")
    return out


def params(name: str) -> dict[str, str]:
    """The extra settings `name` takes (setting -> description). For `auto`: those every
    integrator it may pick takes, since the pick waits for the scene."""
    cands = _candidates(name)
    common = set(cands[0]["params"]) if cands else set()
    for i in cands[1:]:
        common &= set(i["params"])
    return {k: v for k, v in cands[0]["params"].items() if k in common} if cands else {}


def validate_params(name: str, values: dict[str, float]) -> dict[str, float]:
    """`values` (setting -> number) sorted by name if `name` takes every setting; else
    ValueError listing the ones it takes."""
    known = params(name)
    for key in values:
        if key not in known:
            took = f"known: {', '.join(known)}" if known else "it takes none"
            raise ValueError(f"integrator {name!r} has no setting {key!r} ({took})")
    return dict(sorted(values.items()))


def pilot_candidates(*, mirrors_or_glass: bool, noise_target: bool, delta_caustics: bool,
                     light_paths: bool = True) -> tuple[str, ...]:
    """The integrators `auto`'s measuring pilot (tessera/tessera/pilot.py) tries, in registry
    order, for a scene with (or without) mirrors or glass and delta-light caustics, rendered
    to a noise target or not: each integrator's `pilot_candidate` says when it is one,
    delta-light caustics leave out those that cannot find them (`delta_caustics`), and a
    scene whose lights cannot start light paths (`light_paths` False: portals) those that
    start paths at the lights (`traces_light_paths`)."""
    when = {"always": True, "mirrors_or_glass_with_noise_target": mirrors_or_glass and noise_target}
    return tuple(i["name"] for i in integrators()
                 if when.get(i["pilot_candidate"], False) and (i["delta_caustics"] or not delta_caustics)
                 and (light_paths or not i.get("traces_light_paths", False)))


def merging_alpha(name: str) -> float:
    """A merging integrator's default radius exponent alpha (its variance falls as J^-alpha
    over J iterations); 0 for any other integrator."""
    return next((float(i["merging_alpha"]) for i in integrators() if i["name"] == name), 0.0)


def preview_integrator() -> str:
    """The integrator whose scene-wide product is a camera-independent solution, which
    `tessera preview` solves once and re-renders from any view (`view_independent_product`)."""
    found = [i["name"] for i in integrators() if i["view_independent_product"]]
    if len(found) != 1:
        raise RegistryError(f"the preview needs one integrator with a view-independent product, "
                            f"the registry has {found or 'none'}")
    return found[0]


def help_text() -> str:
    """One line per integrator, for `tessera render --integrator help`."""
    width = max(len(n) for n in names())
    lines = []
    for i in integrators():
        lines.append(f"{i['name']:<{width}}  {i['description']}")
        lines += [f"{'':<{width}}    --integrator-param {k}=VALUE: {v}" for k, v in i["params"].items()]
    picks = " or ".join(dict.fromkeys(_registry()["auto"]))
    lines.append(f"{AUTO:<{width}}  per scene: {picks} (see docs/integrators.md)")
    return "\n".join(lines)
