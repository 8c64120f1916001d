"""Where each render setting may be set, declared once beside the setting itself.

A render setting is one field of protocol.RenderSettings: its name, type, default, bounds
and help text are that field's (pydantic validates them in every route, and the job's
spec in Redis is that model's JSON). Annotating the field with `Takes(...)` says which
routes take it; from that one declaration the CLI's options (tessera_cli), the API's form
fields and their OpenAPI doc (tessera_service) and the Python API's keywords are
generated (`settings_of`). A field without `Takes` is set by no user (none today).

Adding a setting is its field in RenderSettings and its use (docs/extending.md, "A new
render setting").
"""
from __future__ import annotations

import types
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from annotated_types import Ge, Gt, Le, Lt, MaxLen

RENDER, SUBMIT = "render", "submit"  # the CLI commands that take render settings


@dataclass(frozen=True)
class Takes:
    """The routes a RenderSettings field is set through.

    cli:   the `tessera` commands with an option for it (render: a local render, submit: a
           farm job); () when no command has one (or a hand-written one does, see flag).
    farm:  whether POST /jobs has a form field for it (a farm job's spec carries every
           field either way).
    flag:  the CLI option's name (default `--name-with-dashes`).
    parse: text -> value for a form field (and a CLI option) that is not a plain number,
           word or switch (a pair, a list, JSON); raises ValueError naming what is wrong.
           The form field is then text, empty meaning the default.
    cli_parse: the same for one CLI option's text when it differs from `parse` (an
           option given once per item, `action: append`).
    argparse: keywords of the CLI option that differ from the generated ones (action,
           nargs, const, metavar).
    cli_help / form_help: when the route needs other words than the field's description.
    """
    cli: tuple[str, ...] = (RENDER, SUBMIT)
    farm: bool = True
    flag: str | None = None
    parse: Callable[[str], Any] | None = None
    cli_parse: Callable[[str], Any] | None = None
    argparse: dict = field(default_factory=dict)
    cli_help: str | None = None
    form_help: str | None = None


@dataclass(frozen=True)
class Setting:
    """One render setting as the routes see it (derived from its RenderSettings field)."""
    name: str
    type: type                  # the scalar type a plain option or form field has
    default: Any                # None: unset, the model's default (or factory) applies
    bounds: dict[str, Any]      # ge, gt, le, lt, max_length, allow_inf_nan as the field declares them
    help: str
    takes: Takes

    @property
    def flag(self) -> str:
        return self.takes.flag or "--" + self.name.replace("_", "-")

    def bounds_text(self) -> str:
        """`0-9`, `> 0 and <= 1`: the range in a message's words."""
        b = self.bounds
        low = f">= {b['ge']}" if "ge" in b else f"> {b['gt']}" if "gt" in b else None
        high = f"<= {b['le']}" if "le" in b else f"< {b['lt']}" if "lt" in b else None
        if "ge" in b and "le" in b:
            return f"{b['ge']}-{b['le']}"
        return " and ".join(x for x in (low, high) if x) or "valid"


def settings_of(model) -> dict[str, Setting]:
    """The settings a pydantic model declares with `Takes`, by name, in field order."""
    out = {}
    for name, info in model.model_fields.items():
        takes = next((m for m in info.metadata if isinstance(m, Takes)), None)
        if takes is None:
            continue
        bounds = {}
        for m in info.metadata:
            for kind, attr in ((Ge, "ge"), (Gt, "gt"), (Le, "le"), (Lt, "lt"), (MaxLen, "max_length")):
                if isinstance(m, kind):
                    bounds[attr] = getattr(m, attr)
            if getattr(m, "allow_inf_nan", None) is False:  # pydantic's own metadata
                bounds["allow_inf_nan"] = False
        default = None if info.is_required() or info.default_factory is not None else info.default
        out[name] = Setting(name, _scalar(info.annotation), default, bounds,
                            info.description or "", takes)
    return out


def _scalar(annotation) -> type:
    """int for `int | None`; str for what is not one scalar (those declare a parse)."""
    if isinstance(annotation, types.UnionType) or typing.get_origin(annotation) is typing.Union:
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        annotation = args[0] if len(args) == 1 else str
    return annotation if annotation in (int, float, bool, str) else str


# ---------------------------------------------------------------- parsers of text forms
def parse_numbers(count: int, kind: type, what: str) -> Callable[[str], tuple]:
    """`A,B,...`: `count` comma-separated numbers of `kind`."""
    def parse(text: str) -> tuple:
        parts = [p.strip() for p in text.split(",")]
        try:
            if len(parts) != count:
                raise ValueError
            return tuple(kind(p) for p in parts)
        except ValueError:
            raise ValueError(f"must look like {what}, not {text!r}") from None
    return parse


def parse_list(text: str) -> list[str] | None:
    """Comma-separated items; None when there are none."""
    return [v.strip() for v in text.split(",") if v.strip()] or None


def parse_json_object(text: str) -> dict:
    import json

    try:
        value = json.loads(text)
    except (ValueError, RecursionError) as exc:  # ValueError: bad JSON, or an over-long integer
        raise ValueError(f"is not JSON: {exc}") from None
    if not isinstance(value, dict):
        raise ValueError('must be a JSON object such as {"max_distance": 2}')
    return value
