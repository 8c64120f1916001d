"""The `tessera` command's options: the render settings' options generated from their one
declaration (tessera_base.protocol.RenderSettings with settings_spec.Takes), the few
hand-made ones (resolution, integrator, frames) and the one-line messages that name an
option when its value is refused."""
from __future__ import annotations

import argparse
import sys

from tessera_base.protocol import SETTINGS
from tessera_base.settings_spec import RENDER, Setting


def resolution(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must look like 640x480, not {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError("resolution must be positive")
    return w, h


def int_range(low: int, high: int):
    """An argparse type: a whole number from low to high, refused in one line naming both."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be a whole number from {low} to {high}, not {text!r}")
        return value
    return parse


def positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {value}")
    return value


# ------------------------------------------------------------- the generated settings
def add_setting_options(parser: argparse.ArgumentParser, command: str) -> None:
    """An option for every render setting that `command` takes (settings_spec.Takes.cli).
    Every option defaults to None (unset): RenderSettings (or, for submit, the farm)
    applies the setting's default, and checks its bounds in one place."""
    for setting in SETTINGS.values():
        if command not in setting.takes.cli:
            continue
        kwargs: dict = dict(dest=setting.name, default=None, help=_help(setting, command))
        if setting.type is bool:
            kwargs["action"] = "store_true"
        else:
            kwargs["type"] = _argument_type(setting)
        kwargs.update(setting.takes.argparse)
        parser.add_argument(setting.flag, **kwargs)


def _argument_type(setting: Setting):
    parse = setting.takes.cli_parse or setting.takes.parse
    if parse is None:
        return setting.type

    def argument(text: str):
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    argument.__name__ = setting.name  # argparse names the type in its messages
    return argument


def _help(setting: Setting, command: str) -> str:
    text = setting.takes.cli_help or setting.help
    if setting.default is not None and setting.type is not bool:
        text += (f" (default {setting.default})" if command == RENDER
                 else f" (default: the farm's, {setting.default})")
    return text.replace("%", "%%")  # argparse formats help with %


def settings_from_args(args: argparse.Namespace, command: str) -> dict:
    """The render settings given on the command line (unset ones left out), with the
    hand-made options' (--integrator, --integrator-param, --frame)."""
    values = {name: getattr(args, name) for name, s in SETTINGS.items()
              if command in s.takes.cli and getattr(args, name, None) is not None}
    if args.integrator is not None:
        values["integrator"] = args.integrator
    if getattr(args, "frame", None) is not None:
        values["frame"] = args.frame
    if args.integrator_params:
        values["integrator_params"] = integrator_params(args)
    return values


def settings_problem(args: argparse.Namespace, command: str) -> str | None:
    """What RenderSettings refuses in the command line's settings, in the options' words,
    before a scene is loaded or sent (the resolution may be the scene's, not known yet:
    then only what does not depend on it); None when there is nothing."""
    from pydantic import ValidationError

    from tessera_base.protocol import RenderSettings

    if (problem := params_problem(args)) is not None:
        return problem
    values = settings_from_args(args, command)
    width, height = args.res or (16384, 16384)
    if not args.res:
        values.pop("crop", None)
    try:
        RenderSettings(width=width, height=height, **values)
    except ValidationError as exc:
        return settings_error(exc)
    return None


def option(field: str) -> str:
    """The option that sets a RenderSettings field, for messages in the user's terms."""
    if field in ("width", "height"):
        return "--res"
    if field == "integrator_params":
        return "--integrator-param"
    return SETTINGS[field].flag if field in SETTINGS else "--" + field.replace("_", "-")


def settings_error(exc) -> str:
    """A pydantic ValidationError of RenderSettings in one line: each problem as
    `--option: what is wrong (allowed values)`, without pydantic's own framing."""
    parts = []
    for error in exc.errors(include_url=False):
        field = str(error["loc"][0]) if error.get("loc") else None
        message = error["msg"].removeprefix("Value error, ")
        ctx = error.get("ctx") or {}
        if field in SETTINGS and ({"ge", "gt", "le", "lt"} & set(ctx)):
            message = f"must be {SETTINGS[field].bounds_text()}, not {error['input']!r}"
        if field is None:  # a check across fields: its message names them
            parts.append(message)
        else:
            parts.append(f"{option(field)}: {message}")
    return "; ".join(dict.fromkeys(parts))


# ------------------------------------------------------------- the hand-made options
class _IntegratorOption(argparse.Action):
    """--integrator NAME, checked against the renderer's registry before anything is
    loaded; `--integrator help` lists the integrators and exits. With `renders` (the
    command loads the renderer anyway) the registry is read in process, not from a child."""

    def __init__(self, *args, renders: bool = False, **kwargs):
        super().__init__(*args, **kwargs)
        self.renders = renders

    def __call__(self, parser, namespace, value, option_string=None):
        if self.renders:
            import tessera_renderer  # noqa: F401
        from tessera_base import integrators
        if value == "help":
            print(integrators.help_text())
            sys.stdout.flush()  # a closed pipe raises here, inside main's handler
            parser.exit(0)
        try:
            setattr(namespace, self.dest, integrators.validate(value))
        except ValueError as exc:
            parser.error(str(exc))


def add_integrator_option(parser: argparse.ArgumentParser, renders: bool = False) -> None:
    parser.add_argument("--integrator", default=None, action=_IntegratorOption, renders=renders, metavar="NAME",
                        help="light transport method (default: the registry's first; `help` lists "
                             "them; see docs/integrators.md)")
    parser.add_argument("--integrator-param", dest="integrator_params", action="append", default=None,
                        type=integrator_param, metavar="NAME=VALUE",
                        help="one of the integrator's own settings (repeatable; `--integrator help` "
                             "lists them), e.g. --integrator ao --integrator-param max_distance=2")


def integrator_param(text: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    return name.strip(), value.strip()


def integrator_params(args: argparse.Namespace) -> dict[str, str]:
    """--integrator-param pairs as a dict (checked by RenderSettings against the registry)."""
    return dict(args.integrator_params or [])


def params_problem(args: argparse.Namespace) -> str | None:
    """--integrator-param names the integrator does not take, in the option's terms."""
    from tessera_base import integrators

    try:
        integrators.validate_params(args.integrator or integrators.default(), integrator_params(args))
    except ValueError as exc:
        return f"--integrator-param: {exc}"
    return None


def add_frame_options(parser: argparse.ArgumentParser) -> None:
    """--frame, or --frames: a range of images (no setting of one image, hence hand-made)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--frame", type=float, default=None, metavar="TIME",
                       help="the USD time code to render (default: the stage's startTimeCode, else "
                            "its default time; docs/motion.md)")
    group.add_argument("--frames", default=None, metavar="LIST",
                       help="render these frames, one EXR each: 1-24, 1-24x2 (every second), "
                            "1,5,9 or a mix; the output's run of # is the frame number "
                            "(default: OUTPUT with .#### before .exr: out.0001.exr); on a farm, "
                            "one job per frame")

