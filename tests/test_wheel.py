"""The pip-installable wheel and the CI templates that install it (README, "Using it
elsewhere"; docs/accuracy.md, "In CI").

The wheel: `pip wheel .` builds the C++ core into a wheel; installed into a fresh virtual
environment (no editable install, the repository nowhere on sys.path, run from outside it)
it imports every module, ships every data file of its packages, and `tessera render`
renders the Cornell box with the same pixels, bit for bit, as the development install.

The CI templates, run as scripts with that wheel as their package: the GitHub Action
(action.yml, a composite action: its `run:` steps with bash, its `uses:` upload steps
checked for the paths they upload) and the GitLab CI template
(ci/tessera-refs.gitlab-ci.yml: before_script and script, then its artifact paths),
each checking examples/refs in a temporary project, and failing (exit 1, report and JUnit
still written) on a reference 5 % too bright.

Slow: it compiles the core (once per run; ccache, when installed, makes a rebuild of
unchanged sources a cache hit, and build/wheel keeps the CMake tree between runs) and
installs the dependencies into three new environments (the wheel's, the action's, the
template's)."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import CORNELL
from tessera_base import images

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {  # import name -> source folder (pyproject's wheel.packages)
    "tessera": "tessera/tessera", "tessera_base": "tessera/tessera_base",
    "tessera_queue": "tessera/tessera_queue", "tessera_tools": "tessera/tessera_tools",
    "tessera_renderer": "renderer/tessera_renderer", "tessera_worker": "worker/tessera_worker",
    "tessera_service": "service/tessera_service",
}


def clean_env() -> dict[str, str]:
    """The environment without anything that would put the repository on sys.path."""
    return {k: v for k, v in os.environ.items()
            if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "PYTHONSTARTUP")}


def run(cmd, **kw) -> subprocess.CompletedProcess:
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    assert r.returncode == 0, f"{cmd}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    env = {**os.environ, "CMAKE_BUILD_PARALLEL_LEVEL": "2"}
    launcher = ["-C", "cmake.define.CMAKE_CXX_COMPILER_LAUNCHER=ccache"] if shutil.which("ccache") else []
    # No build isolation: the build requirements of this environment, so the compiler
    # sees the same nanobind paths each run and ccache hits.
    run([sys.executable, "-m", "pip", "wheel", ROOT, "--no-deps", "--no-build-isolation", "-w", out,
         "-C", f"build-dir={ROOT / 'build' / 'wheel'}", *launcher], env=env, timeout=3600)
    wheels = list(out.glob("tessera-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


@pytest.fixture(scope="module")
def venv(wheel, tmp_path_factory) -> Path:
    where = tmp_path_factory.mktemp("venv")
    run([sys.executable, "-m", "venv", where / "venv"], env=clean_env())
    python = where / "venv" / "bin" / "python"
    # pytest: the reference-set plugin (an entry point) is imported by pytest only.
    run([python, "-m", "pip", "install", "-q", wheel, "pytest"], env=clean_env(), cwd=where, timeout=1800)
    return where / "venv"


def test_the_wheel_holds_the_core_and_every_package_file(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    assert any(n.startswith("tessera_renderer/_core.") and n.endswith(".so") for n in names), names
    assert any(n.startswith("tessera_renderer/_subdivision.") for n in names)
    expected = set()
    for name, folder in PACKAGES.items():
        for f in (ROOT / folder).rglob("*"):
            if f.is_file() and "__pycache__" not in f.parts and not f.name.endswith("_test.cpp"):
                expected.add(f"{name}/{f.relative_to(ROOT / folder).as_posix()}")
    assert expected - names == set()  # the Lua scripts, the monitor page, the registry, ...
    # No C++ unit tests, build trees or the repository's own folders in it.
    assert not [n for n in names if "test" in Path(n).name and n.endswith((".cpp", "_test"))]
    assert not [n for n in names if n.split("/")[0] in ("build", "tests", "examples", "docs", "deploy")]


def test_a_fresh_venv_imports_every_module_from_site_packages(venv, tmp_path):
    code = """
import importlib, pkgutil, sys
names = sys.argv[1:]
seen, bad = 0, []
for top in names:
    pkg = importlib.import_module(top)
    assert "site-packages" in pkg.__file__, pkg.__file__
    for m in pkgutil.walk_packages(pkg.__path__, top + "."):
        if m.name.endswith("__main__"):
            continue  # runs the CLI
        if m.name.rsplit(".", 1)[-1].startswith("lib"):
            continue  # a shared library loaded with ctypes (libtessera_vdb), not a Python module
        seen += 1
        try:
            importlib.import_module(m.name)
        except Exception as e:
            bad.append(f"{m.name}: {e!r}")
assert not any(p.startswith(%r) for p in sys.path if p), sys.path
print(seen)
print("\\n".join(bad))
""" % str(ROOT)
    r = run([venv / "bin" / "python", "-c", code, *PACKAGES], env=clean_env(), cwd=tmp_path)
    lines = r.stdout.strip().splitlines()
    assert lines[1:] == [], lines[1:]
    sources = sum(1 for folder in PACKAGES.values() for f in (ROOT / folder).rglob("*.py")
                  if "__pycache__" not in f.parts and f.name not in ("__init__.py", "__main__.py"))
    assert int(lines[0]) >= sources  # every module file of the source tree was imported


def test_tessera_render_from_the_wheel_equals_the_development_install(venv, tmp_path):
    scene = tmp_path / "cornell.usda"
    shutil.copy(CORNELL, scene)  # nothing read from the repository
    args = [scene, "--spp", "4", "--res", "32x32", "-q"]
    run([venv / "bin" / "tessera", "render", *args, "-o", tmp_path / "wheel.exr"], env=clean_env(), cwd=tmp_path)
    run([sys.executable, "-m", "tessera", "render", *args, "-o", tmp_path / "dev.exr"], cwd=tmp_path)
    wheel_px, dev_px = (images.read_exr(tmp_path / f) for f in ("wheel.exr", "dev.exr"))
    assert wheel_px.shape == (32, 32, 4) and 0.05 < float(wheel_px[..., :3].mean()) < 1.0
    assert np.array_equal(wheel_px.view(np.uint32), dev_px.view(np.uint32))
    assert (tmp_path / "wheel.png").stat().st_size > 0


# ------------------------------------------------------------------ the CI templates
def project(where: Path, brighter: float | None = None) -> Path:
    """A project with examples/refs as tests/refs (the scenes beside, where refs.json
    points); with `brighter`, only the cornell reference, its pixels scaled by it."""
    shutil.copytree(ROOT / "examples" / "cornell", where / "tests" / "cornell")
    refs = where / "tests" / "refs"
    shutil.copytree(ROOT / "examples" / "refs", refs)
    if brighter is not None:
        manifest = json.loads((refs / "refs.json").read_text())
        manifest["references"] = [r for r in manifest["references"] if r["name"] == "cornell"]
        (refs / "refs.json").write_text(json.dumps(manifest, indent=2))
        exr = refs / "cornell.exr"
        channels = images.read_exr_channels(exr)
        rgba = np.stack([channels[c] for c in "RGBA"], axis=-1)
        rgba[..., :3] *= brighter
        aovs = {}
        if "variance.R" in channels:
            aovs["variance"] = np.stack([channels[f"variance.{c}"] for c in "RGB"], axis=-1) * brighter ** 2
        if "spp" in channels:
            aovs["spp"] = channels["spp"]
        header = images.read_render(exr).metadata
        images.write_exr(exr, rgba, {k: v for k, v in header.items() if k.startswith("tessera:")}, aovs=aovs)
    return where


def junit_cases(path: Path) -> tuple[int, int]:
    """(test cases, failed ones) of a JUnit file."""
    import xml.etree.ElementTree as ET

    cases = ET.parse(path).getroot().iter("testcase")
    n = failed = 0
    for case in cases:
        n += 1
        failed += case.find("failure") is not None or case.find("error") is not None
    return n, failed


def github_steps(inputs: dict[str, str], action_path: Path, temp: Path):
    """action.yml's steps with ${{ inputs.* }}, github.action_path and runner.temp resolved
    as the runner would: (step, env, resolved `with`)."""
    action = yaml.safe_load((ROOT / "action.yml").read_text())
    assert action["runs"]["using"] == "composite"
    values = {f"inputs.{k}": str(v.get("default", "")) for k, v in action["inputs"].items()}
    values.update({f"inputs.{k}": v for k, v in inputs.items()})
    values.update({"github.action_path": str(action_path), "runner.temp": str(temp)})

    def resolve(text: str) -> str:
        return re.sub(r"\$\{\{\s*([\w.-]+)\s*\}\}", lambda m: values[m.group(1)], str(text))

    for step in action["runs"]["steps"]:
        if "run" in step:
            assert "${{" not in step["run"], f"{step['name']}: expressions belong in env"
            assert step.get("shell") == "bash"
        yield step, {k: resolve(v) for k, v in step.get("env", {}).items()}, \
            {k: resolve(v) for k, v in step.get("with", {}).items()}


def run_github_action(wheel: Path, workspace: Path, temp: Path) -> tuple[int, list[Path]]:
    """Runs action.yml as a runner would, `if: always()` included: (the exit code of the
    first failing run step or 0, the paths its upload steps upload)."""
    failed, uploads = 0, []
    github_path = temp / "github_path"  # one per job, as the runner makes it
    github_path.unlink(missing_ok=True)
    for step, env, with_ in github_steps({"package": str(wheel), "refs": "tests/refs"}, ROOT, temp):
        if failed and step.get("if") != "always()":
            continue
        if "uses" in step:
            assert step["uses"].startswith("actions/upload-artifact@")
            uploads.append(workspace / with_["path"])
            continue
        r = subprocess.run(["bash", "-c", step["run"]], cwd=workspace, capture_output=True, text=True,
                           env={**clean_env(), **env, "GITHUB_PATH": str(github_path)}, timeout=1800)
        if r.returncode != 0:
            failed = r.returncode
            print(step["name"], r.stdout[-2000:], r.stderr[-2000:])
    assert (temp / "tessera-venv" / "bin") == Path(github_path.read_text().strip())
    return failed, uploads


def test_github_action_checks_references_and_uploads_report_and_junit(wheel, tmp_path):
    good = project(tmp_path / "good")
    temp = tmp_path / "runner-temp"
    temp.mkdir()
    code, uploads = run_github_action(wheel, good, temp)
    assert code == 0
    assert [p.relative_to(good).as_posix() for p in uploads] == ["out/tessera-refs", "out/tessera-refs/junit.xml"]
    assert all(p.exists() for p in uploads) and (uploads[0] / "index.html").exists()
    assert junit_cases(uploads[1]) == (2, 0)  # cornell and cornell-bdpt, both the same
    # The negative control: a reference 5 % too bright fails the step, and both uploads
    # (if: always()) still find what they upload.
    bad = project(tmp_path / "bad", brighter=1.05)
    code, uploads = run_github_action(wheel, bad, temp)
    assert code == 1
    assert all(p.exists() for p in uploads) and junit_cases(uploads[1]) == (1, 1)


def run_gitlab_job(wheel: Path, workspace: Path, venv: Path) -> tuple[int, list[Path], Path]:
    """The template's job as a GitLab runner runs it: its variables, before_script and script
    in one shell (exit code, artifact paths, JUnit report)."""
    template = yaml.safe_load((ROOT / "ci" / "tessera-refs.gitlab-ci.yml").read_text())
    job = template[".tessera-refs"]
    variables = {**{k: str(v) for k, v in job["variables"].items()},
                 "TESSERA_PACKAGE": str(wheel), "TESSERA_VENV": str(venv)}
    script = "\n".join([*job["before_script"], *job["script"]])
    r = subprocess.run(["bash", "-c", script], cwd=workspace, capture_output=True, text=True,
                       env={**clean_env(), **variables}, timeout=1800)
    print(r.stdout[-2000:], r.stderr[-2000:])

    def expand(path: str) -> Path:
        return workspace / re.sub(r"\$(\w+)", lambda m: variables[m.group(1)], path)

    assert job["artifacts"]["when"] == "always"
    return r.returncode, [expand(p) for p in job["artifacts"]["paths"]], expand(job["artifacts"]["reports"]["junit"])


def test_gitlab_template_checks_references_and_keeps_report_and_junit(wheel, tmp_path):
    good = project(tmp_path / "good")
    code, paths, junit = run_gitlab_job(wheel, good, tmp_path / "venv")
    assert code == 0
    assert [p.relative_to(good).as_posix() for p in paths] == ["out/tessera-refs"]
    assert (paths[0] / "index.html").exists() and junit_cases(junit) == (2, 0)
    bad = project(tmp_path / "bad", brighter=1.05)
    code, paths, junit = run_gitlab_job(wheel, bad, tmp_path / "venv")
    assert code == 1 and (paths[0] / "index.html").exists() and junit_cases(junit) == (1, 1)
    # Without a package the job says what to set, before installing anything.
    template = yaml.safe_load((ROOT / "ci" / "tessera-refs.gitlab-ci.yml").read_text())[".tessera-refs"]
    r = subprocess.run(["bash", "-c", "\n".join(template["before_script"])], cwd=good, capture_output=True,
                       text=True, env={**clean_env(), **{k: str(v) for k, v in template["variables"].items()}})
    assert r.returncode == 2 and "set TESSERA_PACKAGE" in r.stderr
