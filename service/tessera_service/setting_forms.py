"""POST /jobs's form fields for the render settings, generated from their one declaration
(tessera_base.protocol.RenderSettings with settings_spec.Takes): each field's type,
default, bounds and description become the form field and its OpenAPI doc."""
from __future__ import annotations

import inspect
from typing import Annotated, Any

from fastapi import Form, HTTPException

from tessera_base.protocol import SETTINGS
from tessera_base.settings_spec import Setting

FARM_SETTINGS = {name: s for name, s in SETTINGS.items() if s.takes.farm}


def form_parameter(setting: Setting) -> inspect.Parameter:
    """The keyword parameter FastAPI reads the setting's form field from."""
    description = setting.takes.form_help or setting.help
    if setting.takes.parse is not None:  # text the setting parses: empty is the default
        annotation = Annotated[str, Form(description=description)]
        return inspect.Parameter(setting.name, inspect.Parameter.KEYWORD_ONLY, default="",
                                 annotation=annotation)
    bounds = setting.bounds if setting.type is not str else {
        k: v for k, v in setting.bounds.items() if k == "max_length"}
    kind = setting.type if setting.default is not None else setting.type | None
    annotation = Annotated[kind, Form(description=description, **bounds)]
    return inspect.Parameter(setting.name, inspect.Parameter.KEYWORD_ONLY, default=setting.default,
                             annotation=annotation)


def with_setting_forms(endpoint):
    """Gives `endpoint` (whose signature ends in **settings) a form field per farm setting
    that it does not name itself; FastAPI reads the signature, so they are in the
    OpenAPI doc, and the endpoint receives them in **settings."""
    signature = inspect.signature(endpoint)
    own = [p for p in signature.parameters.values() if p.kind is not inspect.Parameter.VAR_KEYWORD]
    named = {p.name for p in own}
    generated = [form_parameter(s) for name, s in FARM_SETTINGS.items() if name not in named]
    endpoint.__signature__ = signature.replace(parameters=[
        *[p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in own], *generated])
    return endpoint


def settings_from_form(values: dict[str, Any]) -> dict[str, Any]:
    """The settings' form values as RenderSettings takes them: parsed text (a 422 naming
    the setting when it cannot be), unset ones left out so the model's defaults apply."""
    out = {}
    for name, value in values.items():
        setting = FARM_SETTINGS[name]
        if setting.takes.parse is not None:
            if not value.strip():
                continue
            try:
                value = setting.takes.parse(value)
            except ValueError as exc:
                raise HTTPException(422, f"{name} {exc}") from None
        if value is not None:
            out[name] = value
    return out
