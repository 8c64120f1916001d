"""`auto` by measurement (tessera/tessera/pilot.py): the pilot's variance estimates against
what the integrators are known to do, its choice rule, and what a render records.

Timing is never asserted: the choice depends on measured seconds. What is deterministic
(the pilot images' seeds are fixed) is checked: the relative variances, the choice as the
argmax of the recorded efficiencies, and the metadata. The benchmark of the choices is in
docs/benchmarks/auto.md.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tessera.pilot import PilotRow, choose, pilot_size, run_pilot

REPO = Path(__file__).resolve().parents[2]
CAUSTIC = REPO / "examples" / "caustic" / "caustic.usda"
# What the registry declares (renderer/core/integrators: each integrator's pilot_candidate
# and merging_alpha), written out here so a change there fails these tests.
ALWAYS = ("path", "bdpt")
MERGING = ("sppm", "vcm")  # registry order
MERGING_ALPHA = {"sppm": 2.0 / 3.0, "vcm": 0.75}


def test_choose_takes_the_most_efficient_and_the_first_on_a_tie():
    rows = [PilotRow("path", 0.01, 0.2, 500.0), PilotRow("bdpt", 0.02, 0.05, 1000.0)]
    assert choose(rows) == "bdpt"
    assert choose(list(reversed(rows))) == "bdpt"
    assert choose([PilotRow("path", 1, 1, 1.0), PilotRow("bdpt", 1, 1, 1.0)]) == "path"
    rows[1].efficiency = 400.0  # control: the other way round
    assert choose(rows) == "path"
    with pytest.raises(ValueError):
        choose([])


def test_a_merging_integrator_wins_by_its_typical_efficiency_too():
    """The rule for rare hits: the highest efficiency wins unless a merging integrator has
    the highest typical efficiency (the median of pixel groups' means, which one lucky
    pixel does not move). The numbers are one pilot's on the caustic seen in a mirror, where
    a pixel seeing the light through the mirror made sppm's mean variance 12.5."""
    rows = [PilotRow("path", 0.0126, 42.1, 1.89, typical_efficiency=0.5),
            PilotRow("bdpt", 0.0232, 36.4, 1.18, typical_efficiency=0.2),
            PilotRow("sppm", 0.0507, 12.5, 0.1, typical_efficiency=12.8)]
    assert choose(rows) == "sppm"
    rows[2].typical_efficiency = 0.4  # control: sppm typical below path's
    assert choose(rows) == "path"
    # Typical efficiency never promotes an unbiased integrator over the mean's choice.
    rows = [PilotRow("path", 1, 1, 2.0, typical_efficiency=1.0), PilotRow("bdpt", 1, 1, 1.0, typical_efficiency=9.0)]
    assert choose(rows) == "path"


def test_pilot_keeps_the_render_aspect_on_a_coarse_grid():
    assert pilot_size(1920, 1080) == (64, 36)
    assert pilot_size(100, 400) == (16, 64)
    assert pilot_size(4000, 10) == (64, 8)


def test_pilot_variance_sees_bdpt_win_the_caustic_per_sample(cornell_path):
    """Per sample, BDPT's relative variance on the glass ball's caustic is several times
    path's (the bench: relMSE 16.9 for path at 4 spp vs 1.97 for bdpt at 1 spp); on the
    diffuse Cornell box they are within a factor 2. A pilot whose scale were each
    candidate's own mean (fireflies divided by themselves) saw them equal on the caustic
    (0.203 vs 0.205): the 3 x margin fails it."""
    from tessera_base.protocol import RenderSettings
    from tessera_renderer import load_scene

    caustic = load_scene(CAUSTIC)
    p = run_pilot(caustic, RenderSettings(width=caustic.width, height=caustic.height), threads=2)
    rel = {r.integrator: r.rel_variance for r in p.rows}
    assert [r.integrator for r in p.rows] == list(ALWAYS)
    assert rel["path"] > 3 * rel["bdpt"], rel
    assert p.choice == choose(p.rows)
    cornell = load_scene(cornell_path)
    p = run_pilot(cornell, RenderSettings(width=64, height=64), threads=2)
    rel = {r.integrator: r.rel_variance for r in p.rows}
    assert 0.5 < rel["path"] / rel["bdpt"] < 2.0, rel


def test_delta_caustics_choose_bdpt_without_a_pilot(tmp_path):
    from pxr import Gf, Sdf, UsdLux, UsdShade

    from tessera_base.protocol import RenderSettings
    from tessera_renderer import load_scene
    from usd_fixtures import add_material, add_mesh, new_stage

    path = tmp_path / "glass_bulb.usda"
    stage = new_stage(path)
    mat = add_material(stage, "/M", (0.5, 0.5, 0.5))
    UsdShade.Shader(stage.GetPrimAtPath("/M/Surface")).CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(0.0)
    add_mesh(stage, "/Q", [(0, 0, 0), (1, 0, 0), (1, 1, 0)], [3], [0, 1, 2], mat)
    bulb = UsdLux.SphereLight.Define(stage, "/Bulb")
    bulb.CreateTreatAsPointAttr(True)
    bulb.AddTranslateOp().Set(Gf.Vec3d(0, 3, 0))
    stage.GetRootLayer().Save()
    p = run_pilot(load_scene(path), RenderSettings(width=32, height=32), threads=2)
    assert p.choice == "bdpt" and not p.rows and "delta light" in p.reason


def test_cli_auto_reports_the_pilot_and_records_it_in_the_exr(tmp_path, cornell_path):
    import OpenImageIO as oiio

    out = tmp_path / "auto.exr"
    r = subprocess.run([sys.executable, "-m", "tessera", "render", str(cornell_path), "--res", "32x32", "--spp", "4",
                        "--integrator", "auto", "-o", str(out), "-q"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "auto chose " in r.stderr and "efficiency path" in r.stderr, r.stderr
    spec = oiio.ImageInput.open(str(out)).spec()
    pilot = json.loads(spec.getattribute("tessera:auto"))
    rows = [PilotRow(**row) for row in pilot["rows"]]
    assert {r.integrator for r in rows} == set(ALWAYS)
    assert pilot["choice"] == choose(rows)  # the recorded numbers give the recorded choice
    assert spec.getattribute("tessera:integrator") == pilot["choice"]
    assert f"auto chose {pilot['choice']}" in r.stderr
    # Its seconds are extrapolated from the coarse pilot, and the line says so.
    for row in rows:
        assert (f"~{row.seconds * 1e3:.0f} ms a {pilot['spp']}-spp pass, extrapolated to full size"
                in r.stderr), r.stderr


def test_merging_candidates_join_for_mirrors_or_glass_in_a_progressive_render(cornell_path):
    """vcm and sppm are candidates only where they can win: a scene with delta surfaces
    (the caustic's glass ball; the Cornell box has none) rendered in passes (a noise target;
    a fixed-spp render is one iteration, where a merging integrator has not converged)."""
    from tessera.pilot import candidates
    from tessera_base.protocol import RenderSettings
    from tessera_renderer import load_scene

    progressive = RenderSettings(width=64, height=64, target_error=0.01)
    fixed = RenderSettings(width=64, height=64, spp=64)
    caustic, cornell = load_scene(CAUSTIC), load_scene(cornell_path)
    assert caustic.has_delta_surfaces() and not cornell.has_delta_surfaces()
    assert candidates(caustic, progressive) == ALWAYS + MERGING
    assert candidates(caustic, fixed) == ALWAYS
    assert candidates(cornell, progressive) == ALWAYS


def test_merging_handicap_is_the_slower_variance_decay_to_the_noise_target():
    """A merging integrator needs (v / eps)^(1/alpha) passes to the target eps =
    target_error^2 where an unbiased one needs v / eps: the handicap is (v / eps)^(1 -
    1/alpha), the passes clamped to [1, the render's batches: max_spp / min_spp]."""
    from tessera.pilot import merging_batches, merging_handicap
    from tessera_base.protocol import RenderSettings

    st = RenderSettings(width=8, height=8, target_error=0.1, min_spp=16, max_spp=1024)
    assert merging_batches(st) == 64
    assert merging_batches(st.model_copy(update={"max_spp": 2048})) == 128  # control: one pass more
    assert merging_handicap("sppm", 0.16, st) == pytest.approx(16 ** -0.5)
    assert merging_handicap("vcm", 0.16, st) == pytest.approx(16 ** (1 - 4 / 3))
    assert merging_handicap("sppm", 0.001, st) == 1.0          # reached in one pass
    assert merging_handicap("sppm", 100.0, st) == pytest.approx(64 ** -0.5)  # the render stops at max_spp
    assert merging_handicap("path", 100.0, st) == 1.0
    assert merging_handicap("sppm", 0.16, st.model_copy(update={"target_error": None})) == 1.0


def test_pilot_on_the_caustic_measures_merging_and_records_its_numbers():
    """On the glass ball's caustic (progressive render), the pilot measures all four; sppm's
    photon estimate has a far lower relative variance per pass than path's fireflies (measured
    0.135 against 11: asserted 10x), and the recorded numbers give the recorded choice:
    efficiency = handicap / (rel_variance x seconds), seconds extrapolated to the render's
    size and holding the scene pass's."""
    from tessera.pilot import merging_handicap
    from tessera_base.protocol import RenderSettings
    from tessera_renderer import load_scene

    caustic = load_scene(CAUSTIC)
    st = RenderSettings(width=caustic.width, height=caustic.height, target_error=0.01)
    p = run_pilot(caustic, st, threads=2)
    rows = {r.integrator: r for r in p.rows}
    assert list(rows) == [*ALWAYS, *MERGING]
    assert rows["path"].rel_variance > 10 * rows["sppm"].rel_variance, rows
    for name, r in rows.items():
        assert r.handicap == pytest.approx(merging_handicap(name, r.rel_variance, st))
        assert (r.handicap < 1) == (name in MERGING_ALPHA)
        assert r.efficiency == pytest.approx(r.handicap / (r.rel_variance * r.seconds))
        assert (r.scene_seconds > 0) == (name in MERGING_ALPHA) and r.seconds > r.scene_seconds
    # target 1e-2: eps = 1e-4, so v / eps = 1350 passes, clamped to the render's 1024 / 16 = 64.
    assert rows["sppm"].handicap == pytest.approx(min(rows["sppm"].rel_variance / 1e-4, 64) ** -0.5)
    assert p.choice == choose(p.rows)


def test_typical_mean_is_not_moved_by_one_pixel_but_is_by_a_region():
    """One pixel of 4096 at 1e4 over 0.1 elsewhere moves the mean to 2.54 and the typical
    mean not at all; a region of 64 such pixels, spread over every group, moves both."""
    import numpy as np

    from tessera.pilot import typical_mean

    v = np.full(4096, 0.1)
    v[5] = 1e4
    assert v.mean() == pytest.approx(2.5414, rel=1e-3)
    assert typical_mean(v) == pytest.approx(0.1)
    v[:64] = 1e4  # control: a region (the pixels of a caustic) is no rare hit
    assert typical_mean(v) > 100


def test_the_registry_declares_the_candidates_and_the_merging_exponents():
    """The pilot's rule is data in the core's registry: which integrators are candidates for
    which scene features, and the radius exponent each merging integrator defaults to (the
    constant its `alpha` setting defaults to, so a render with that alpha given explicitly is
    bit-identical to one without; a slightly different alpha is not, the control)."""
    import numpy as np

    from tessera_base import integrators
    from tessera_renderer import load_scene
    from tessera_renderer.film import new_splat_buffer

    cases = {(False, False, False): ALWAYS, (True, False, False): ALWAYS, (False, True, False): ALWAYS,
             (True, True, False): ALWAYS + MERGING, (True, True, True): ("bdpt",) + MERGING,
             (False, False, True): ("bdpt",)}
    for (mirrors, target, caustics), expected in cases.items():
        assert integrators.pilot_candidates(mirrors_or_glass=mirrors, noise_target=target,
                                            delta_caustics=caustics) == expected
    for name in ("path", "bdpt", "light", "radiosity"):
        assert integrators.merging_alpha(name) == 0.0
    scene = load_scene(CAUSTIC)
    for name, alpha in MERGING_ALPHA.items():
        assert integrators.merging_alpha(name) == pytest.approx(alpha, rel=1e-6)

        def render(params):  # iteration 1: the radius has shrunk by alpha's schedule once
            product = scene.scene_pass(name, 1, seed=3, threads=2, integrator_params=params)
            splats = new_splat_buffer(16, 16)
            image = scene.render_tile(0, 0, 16, 16, width=16, height=16, spp=2, sample_start=2, threads=2,
                                      integrator=name, integrator_params=params, scene_product=product,
                                      splats=splats)
            return np.concatenate([np.asarray(image).ravel(), splats.ravel().astype(np.float64)])

        default = render({})
        assert np.array_equal(default, render({"alpha": integrators.merging_alpha(name)})), name
        assert not np.array_equal(default, render({"alpha": alpha * 0.95})), name
