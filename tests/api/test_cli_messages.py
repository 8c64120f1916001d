"""What `tessera` says when it is given something it cannot do (issue 44, "CLI messages"):
one line on stderr naming the option and what it takes, the right exit code, nothing
rendered or uploaded first, and no traceback. Each test runs the command as a user does,
in a child process, and checks stderr's exact line."""
from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
from pathlib import Path

from typing import Annotated

import pytest
from fastapi import Form

from conftest import CORNELL
from tessera_base.protocol import MAX_PRIORITY, MIN_PRIORITY

ROOT = Path(__file__).resolve().parents[2]
TINY = ["--res", "8x8", "--spp", "1", "--threads", "1", "-q"]


def tessera(*args: str, cwd: Path | None = None, stdout=subprocess.PIPE) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tessera", *map(str, args)], stdout=stdout,
                          stderr=subprocess.PIPE, text=True, timeout=300, cwd=cwd)


def err_lines(proc: subprocess.CompletedProcess) -> list[str]:
    return proc.stderr.splitlines()


@pytest.fixture
def silent_server():
    """A listening TCP socket nobody answers on: a client that connects leaves a
    connection in its backlog, so the test can tell whether anything was sent at all."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    server.setblocking(False)
    yield f"http://127.0.0.1:{server.getsockname()[1]}", server
    server.close()


def connected(server: socket.socket) -> bool:
    try:
        conn, _ = server.accept()
    except BlockingIOError:
        return False
    conn.close()
    return True


def closed_port() -> int:
    """A port on which nothing listens (bound, then released)."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


# -- output names -----------------------------------------------------------------------
def test_a_png_output_is_refused_in_one_line_before_anything_renders(tmp_path):
    out = tmp_path / "out" / "x.png"
    r = tessera("render", CORNELL, "-o", out, *TINY)
    assert r.returncode == 2
    assert err_lines(r) == [
        f"tessera render: -o {out}: the image is a float EXR with its layers, so its name must end in "
        f".exr (`-o {out.with_suffix('.exr')}` also writes the PNG preview {out})"]
    assert not (tmp_path / "out").exists()  # refused before the scene was even loaded
    # The control: the name the message suggests renders, and writes that very PNG.
    ok = tessera("render", CORNELL, "-o", out.with_suffix(".exr"), *TINY)
    assert ok.returncode == 0, ok.stderr
    assert out.is_file() and out.with_suffix(".exr").is_file()


# -- a closed pipe ----------------------------------------------------------------------
def test_help_into_a_closed_pipe_ends_without_a_traceback():
    """`tessera render --integrator help | head -1`: the reader is gone before the list is
    written. The pipe's read end is closed before the child starts, so every write fails."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        r = tessera("render", "--integrator", "help", stdout=write_end)
    finally:
        os.close(write_end)
    assert r.stderr == ""  # was: BrokenPipeError's traceback (or "Exception ignored ...")
    assert r.returncode == 1


# -- settings ---------------------------------------------------------------------------
def test_an_unknown_aov_is_one_line_naming_the_option_and_the_choices():
    r = tessera("render", CORNELL, "--aovs", "albedo,albedoo", *TINY)
    assert r.returncode == 2
    assert err_lines(r) == ["tessera render: --aovs: unknown AOV 'albedoo' "
                            "(known: albedo, normal, depth, spp, variance, all)"]


def test_an_unknown_integrator_setting_is_one_line_listing_the_known_ones():
    from tessera_base import integrators

    import tessera_renderer  # noqa: F401  (the registry is the renderer's)
    known = ", ".join(integrators.params("ao"))
    assert known  # the control below needs a setting that exists
    r = tessera("render", CORNELL, "--integrator", "ao", "--integrator-param", "max_dist=2", *TINY)
    assert r.returncode == 2
    assert err_lines(r) == [f"tessera render: --integrator-param: integrator 'ao' has no setting "
                            f"'max_dist' (known: {known})"]
    path = tessera("render", CORNELL, "--integrator-param", "max_dist=2", *TINY)
    assert err_lines(path)[-1].startswith(
        "tessera render: --integrator-param: integrator 'path' has no setting 'max_dist'")


def test_a_value_out_of_range_names_the_option_and_its_range():
    r = tessera("render", CORNELL, "--target-error", "2", *TINY)
    assert r.returncode == 2
    assert err_lines(r) == ["tessera render: --target-error: must be > 0 and <= 1, not 2.0"]


def test_submit_refuses_a_priority_out_of_range_before_sending_anything(silent_server, tmp_path):
    url, server = silent_server
    r = tessera("submit", CORNELL, "--server", url, "--priority", "12")
    assert r.returncode == 2
    assert err_lines(r) == ["tessera submit: argument --priority: must be a whole number from 0 to 9, "
                            "not '12' (`tessera submit --help` lists the options)"]
    assert not connected(server)


def test_submit_checks_the_render_settings_before_packing_and_uploading(silent_server):
    url, server = silent_server
    r = tessera("submit", CORNELL, "--server", url, "--aovs", "albedoo")
    assert r.returncode == 2
    assert err_lines(r) == ["tessera submit: --aovs: unknown AOV 'albedoo' "
                            "(known: albedo, normal, depth, spp, variance, all)"]
    r = tessera("submit", CORNELL, "--server", url, "--integrator-param", "max_dist=2")
    assert r.returncode == 2 and len(err_lines(r)) == 1
    assert err_lines(r)[0].startswith("tessera submit: --integrator-param: integrator 'path' has no setting 'max_dist'")
    r = tessera("submit", CORNELL, "--server", url, "--wait", "-o", "x.png")
    assert r.returncode == 2 and err_lines(r)[0].startswith("tessera submit: -o x.png: the image is a float EXR")
    assert not connected(server)


def test_submit_auto_says_the_farm_is_unreachable_before_running_the_pilot():
    url = f"http://127.0.0.1:{closed_port()}"
    r = tessera("submit", CORNELL, "--server", url, "--integrator", "auto", "--res", "16x16")
    assert r.returncode == 2
    lines = err_lines(r)
    assert len(lines) == 1 and lines[0].startswith(f"tessera submit: cannot talk to {url}: "), r.stderr
    assert "auto chose" not in r.stderr  # the pilot did not run


def test_the_api_s_field_errors_read_as_one_line():
    """FastAPI's 422 for a form field (a list of dicts) as `tessera.Client` reports it;
    the shape comes from a real FastAPI app with the API's own priority bounds."""
    from fastapi import FastAPI
    from fastapi.testclient import TestClient

    from tessera.client import _detail

    app = FastAPI()

    @app.post("/jobs")
    def create(priority: Annotated[int, Form(ge=MIN_PRIORITY, le=MAX_PRIORITY)] = 5):
        return {}

    with TestClient(app) as client:
        r = client.post("/jobs", data={"priority": "12"})
        assert r.status_code == 422
        assert _detail(r) == "priority: must be <= 9, not '12'"
        r = client.post("/jobs", data={"priority": "high"})
        assert _detail(r).startswith("priority: Input should be a valid integer") and "'high'" in _detail(r)


# -- noise targets ----------------------------------------------------------------------
def test_a_noise_target_not_reached_is_said_with_the_measured_noise(tmp_path):
    """4 spp at most cannot bring the box to 0.1 % noise: the console says so with the
    header's own numbers. The control, a 90 % target, is reached and says nothing of it."""
    from tessera_base.images import read_render

    out = tmp_path / "missed.exr"
    r = tessera("render", CORNELL, "-o", out, "--res", "16x16", "--tile", "8", "--threads", "1", "-q",
                "--target-error", "0.001", "--min-spp", "2", "--max-spp", "4")
    assert r.returncode == 0, r.stderr
    header = read_render(out).metadata
    reached = float(header["tessera:reached_error"])
    assert reached > 0.001
    missed = [line for line in err_lines(r) if "not reached" in line]
    assert missed == [f"warning: noise target 0.10% not reached: the image's noise is {reached:.2%}, "
                      f"{reached / 0.001:.1f}x the target (tessera:reached_error); stopped by --max-spp 4"]
    out = tmp_path / "reached.exr"
    r = tessera("render", CORNELL, "-o", out, "--res", "16x16", "--tile", "8", "--threads", "1", "-q",
                "--target-error", "0.9", "--min-spp", "2", "--max-spp", "4")
    assert r.returncode == 0, r.stderr
    assert float(read_render(out).metadata["tessera:reached_error"]) <= 0.9
    assert "not reached" not in r.stderr


def test_the_no_variance_help_no_longer_promises_half_the_time():
    r = tessera("render", "--help")
    assert r.returncode == 0
    text = " ".join(r.stdout.split())
    assert "instead of twice" not in text
    assert "--no-variance write no variance and spp layers" in text


# -- frames -----------------------------------------------------------------------------
def _animated_box(path: Path) -> Path:
    """The box with one time-sampled prim: frames differ."""
    from pxr import Sdf, Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    stage.GetRootLayer().subLayerPaths.append(str(CORNELL))
    xform = UsdGeom.Xform.Define(stage, "/Mover")
    op = xform.AddTranslateOp()
    op.Set((0.0, 0.0, 0.0), Usd.TimeCode(1))
    op.Set((0.1, 0.0, 0.0), Usd.TimeCode(3))
    stage.GetRootLayer().Save()
    assert list(Sdf.Layer.FindOrOpen(str(path)).ListAllTimeSamples()) == [1.0, 3.0]
    return path


def test_frames_of_a_still_scene_get_one_hint(tmp_path):
    r = tessera("render", CORNELL, "-o", tmp_path / "still.#.exr", "--frames", "1-5x2", *TINY)
    assert r.returncode == 0, r.stderr
    hints = [line for line in err_lines(r) if "no animation" in line]
    assert hints == ["warning: cornell.usda has no animation (no time samples): every frame of "
                     "--frames 1-5x2 renders the same image"]
    assert sorted(p.name for p in tmp_path.glob("still.*.exr")) == ["still.1.exr", "still.3.exr", "still.5.exr"]
    # The control: a stage with time samples gets no such hint.
    moving = _animated_box(tmp_path / "moving.usda")
    r = tessera("render", moving, "-o", tmp_path / "moving.#.exr", "--frames", "1-3x2", *TINY)
    assert r.returncode == 0, r.stderr
    assert "no animation" not in r.stderr


# -- the README -------------------------------------------------------------------------
def test_the_readme_s_first_render_example_renders_a_file_that_exists(tmp_path):
    """The first `tessera render` command of the README names a scene of this repository,
    and runs as written (here at a tiny size, into tmp_path)."""
    text = (ROOT / "README.md").read_text()
    first = next(line for line in text.splitlines() if line.startswith("tessera render "))
    words = first.split()
    scene = words[2]
    assert (ROOT / scene).is_file(), first
    r = tessera("render", scene, "-o", tmp_path / "readme.exr", *TINY, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert re.search(r"^wrote .*readme\.exr", r.stderr, re.M)
