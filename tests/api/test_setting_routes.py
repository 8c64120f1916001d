"""Every render setting is declared once (RenderSettings' field with settings_spec.Takes)
and reaches each route it declares: a CLI option of `tessera render` and `submit`, a form
field of POST /jobs with its bounds in the OpenAPI doc, a keyword of `tessera.render`.
The controls: a setting that declares no CLI route gets no option, and the checks below
fail for a name that is not a setting."""
from __future__ import annotations

import argparse

import pytest
from fastapi import FastAPI

from tessera_base.protocol import SETTINGS, RenderSettings
from tessera_base.settings_spec import RENDER, SUBMIT
from tessera_cli.cli import build_parser
from tessera_service.routers import submit


def command_options(command: str) -> dict[str, str]:
    """dest -> option string of one `tessera` command."""
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return {a.dest: a.option_strings[-1] for a in sub.choices[command]._actions if a.option_strings}


def form_schema() -> dict:
    app = FastAPI()
    app.include_router(submit.router)
    schema = app.openapi()
    body = schema["paths"]["/jobs"]["post"]["requestBody"]["content"]["multipart/form-data"]["schema"]
    return schema["components"]["schemas"][body["$ref"].rsplit("/", 1)[-1]]["properties"]


@pytest.mark.parametrize("command", [RENDER, SUBMIT])
def test_each_command_has_an_option_for_every_setting_it_takes(command):
    options = command_options(command)
    for name, setting in SETTINGS.items():
        if command in setting.takes.cli:
            assert options.get(name) == setting.flag, name
    # The controls: settings whose options are hand-made or absent.
    assert options["integrator"] == "--integrator" and "width" not in options and "auto_pilot" not in options
    assert "not_a_setting" not in options


def test_the_api_has_a_form_field_for_every_farm_setting_with_its_bounds():
    fields = form_schema()
    for name, setting in SETTINGS.items():
        if not setting.takes.farm:
            continue
        assert name in fields, name
        text = str(fields[name])
        for bound, key in (("ge", "'minimum'"), ("le", "'maximum'"), ("gt", "'exclusiveMinimum'")):
            if bound in setting.bounds and setting.takes.parse is None:
                assert f"{key}: {float(setting.bounds[bound])}" in text, (name, bound, text)
    assert fields["seed_offset"]["description"] == RenderSettings.model_fields["seed_offset"].description
    assert "not_a_setting" not in fields


def test_an_option_out_of_bounds_is_one_line_naming_it_and_its_range(capsys):
    from tessera_cli.cli import main

    assert main(["render", "missing.usda", "--seed-offset", str(2**32)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"tessera render: --seed-offset: must be 0-{2**32 - 1}, not {2**32}"]
    # The control: in bounds, the same command gets as far as loading the scene.
    assert main(["render", "missing.usda", "--seed-offset", str(2**32 - 1)]) == 2
    assert "--seed-offset" not in capsys.readouterr().err


def test_the_python_api_takes_every_setting_by_name_and_refuses_others():
    import tessera

    with pytest.raises(TypeError, match="unknown setting 'seed_ofset'"):
        tessera.render("missing.usda", seed_ofset=1)
