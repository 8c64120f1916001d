"""An integrator's own settings (IntegratorInfo.params, e.g. ao's max_distance) in the job
schema, the CLI and the tile pass: checked against the registry's declared params, kept
through JSON (infinity included), and applied to the render (a changed reach changes the
image, and the image is the renderer's with the same params given directly)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from conftest import CORNELL
from tessera_cli import cli
from tessera_base import film, images, integrators
from tessera_base.protocol import RenderSettings, TileRect
from tessera_queue.tasks import TileTask


def settings(**kw) -> RenderSettings:
    return RenderSettings(**{"width": 16, "height": 16, "spp": 4, "tile_size": 16, **kw})


def test_params_are_checked_against_the_registry():
    s = settings(integrator="ao", integrator_params={"max_distance": 2})
    assert s.integrator_params == {"max_distance": 2.0}
    with pytest.raises(ValidationError, match="has no setting 'reach'.*known: max_distance"):
        settings(integrator="ao", integrator_params={"reach": 2})
    with pytest.raises(ValidationError, match="has no setting 'max_distance'.*it takes none"):
        settings(integrator="whitted", integrator_params={"max_distance": 2})
    with pytest.raises(ValidationError, match="has no setting 'max_distance'.*known: rr_depth"):
        settings(integrator="path", integrator_params={"max_distance": 2})
    assert settings(integrator="path", integrator_params={"rr_depth": 3}).integrator_params == {"rr_depth": 3.0}
    for bad in ("far", True, [1], "nan"):
        with pytest.raises(ValidationError, match="must be a number"):
            settings(integrator="ao", integrator_params={"max_distance": bad})
    # `auto` takes only what every integrator it may pick takes (no setting is common to them).
    assert integrators.params("auto") == {}
    assert set(integrators.params("ao")) == {"max_distance"}


def test_infinity_survives_json_as_the_farm_sends_it():
    s = settings(integrator="ao", integrator_params={"max_distance": "inf"})
    assert s.integrator_params["max_distance"] == math.inf
    task_json = TileTask(job_id="j" * 32, scene_hash="h", scene_name="s.usda", settings=s,
                         tile=TileRect(index=0, x0=0, y0=0, width=16, height=16)).model_dump_json()
    back = TileTask.model_validate_json(task_json)
    assert back.settings.integrator_params == {"max_distance": math.inf}
    assert settings(integrator="ao", integrator_params={"max_distance": 1.5}).model_dump_json() \
        .count('"max_distance":1.5') == 1


def _cli_render(tmp_path, name: str, *extra: str) -> np.ndarray:
    out = tmp_path / f"{name}.exr"
    code = cli.main(["render", str(CORNELL), "-o", str(out), "--res", "16x16", "--spp", "4",
                     "--tile", "8", "-q", "--no-variance", "--integrator", "ao", *extra])
    assert code == 0
    return images.read_exr(out)


def test_cli_passes_params_through_the_tile_pass(tmp_path):
    from tessera_renderer import load_scene

    scene = load_scene(str(CORNELL))
    near = _cli_render(tmp_path, "near", "--integrator-param", "max_distance=0.05")
    default = _cli_render(tmp_path, "default")
    # The renderer itself, given the reach directly, in one piece: the same pixels.
    direct = scene.render_tile(0, 0, 16, 16, width=16, height=16, spp=4, integrator="ao",
                               integrator_params={"max_distance": 0.05})
    assert np.array_equal(near[..., :3], direct[..., :3])
    # A short reach sees fewer occluders: the image is brighter than with the default reach.
    assert near[..., :3].mean() > default[..., :3].mean() + 0.05
    # The tile pass with the job's settings is the same again.
    s = RenderSettings(width=16, height=16, spp=4, tile_size=16, integrator="ao",
                       integrator_params={"max_distance": 0.05})
    result, _ = film.render_tile_pass(scene, s, TileRect(index=0, x0=0, y0=0, width=16, height=16),
                                      0, integrator="ao")
    assert np.array_equal(result.rgba, direct)


def test_cli_refuses_bad_params_in_the_users_terms(tmp_path, capsys):
    with pytest.raises(SystemExit):
        cli.main(["render", str(CORNELL), "--integrator-param", "max_distance"])
    assert "expected NAME=VALUE" in capsys.readouterr().err
    code = cli.main(["render", str(CORNELL), "-o", str(tmp_path / "x.exr"), "--res", "8x8", "-q",
                     "--integrator", "ao", "--integrator-param", "reach=1"])
    assert code == 2
    assert "has no setting 'reach'" in capsys.readouterr().err
    # A value only the integrator can judge is refused before rendering, in its words.
    out = tmp_path / "rr.exr"
    code = cli.main(["render", str(CORNELL), "-o", str(out), "--res", "8x8", "-q",
                     "--integrator", "path", "--integrator-param", "rr_depth=-1"])
    assert code == 2
    assert "invalid settings: path rr_depth must be a whole number >= 0" in capsys.readouterr().err
    assert not out.exists()
