"""The pytest plugin (entry point `tessera`, fixture `tessera_refs`): a project's test
checks a scene against its reference in one line. Run as another project would run it:
pytest in a child process on a folder of its own, the plugin found through the installed
entry point. Negative control: the same line on the scene with its light 10 % brighter
fails (a wiring test at 32x32 and 128 spp: docs/accuracy.md states the check's power)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tessera import refcheck, refs

pytestmark = pytest.mark.slow  # two renders and a child pytest: ~12 s of CPU

CORNELL = Path(__file__).resolve().parents[2] / "examples" / "cornell" / "cornell.usda"
EMISSION = "(17, 12, 4)"

PROJECT_TEST = '''
def test_look_unchanged(tessera_refs):
    tessera_refs.assert_same("refs", "cornell")


def test_look_with_a_brighter_light(tessera_refs):
    tessera_refs.assert_same("refs", "cornell", scene="brighter.usda")
'''


def test_one_line_check_passes_unchanged_and_fails_when_the_light_changes(tmp_path):
    scene = tmp_path / "cornell.usda"
    text = CORNELL.read_text()
    assert text.count(EMISSION) == 1
    scene.write_text(text)
    (tmp_path / "brighter.usda").write_text(text.replace(EMISSION, "(18.7, 13.2, 4.4)"))
    ref = refs.Reference(name="cornell", scene="../cornell.usda", width=32, height=32, spp=512,
                         check=refs.CheckBudget(min_spp=64, max_spp=128), exr="cornell.exr")
    folder = tmp_path / "refs"
    ref = refcheck.render_reference(folder, ref)
    refs.save(folder, refs.RefSet(references=[ref]))
    (tmp_path / "test_look.py").write_text(PROJECT_TEST)
    report = tmp_path / "reports"
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_look.py",
                        "--tessera-report", str(report), "--rootdir", str(tmp_path)],
                       cwd=tmp_path, capture_output=True, text=True)
    out = r.stdout + r.stderr
    assert r.returncode == 1, out
    assert "1 failed, 1 passed" in out, out
    assert "test_look_with_a_brighter_light" in out and "differs from the reference" in out, out
    for name in ("test_look_unchanged", "test_look_with_a_brighter_light"):
        assert (report / name / "index.html").is_file(), out
    assert "cornell: FAIL" in (report / "test_look_with_a_brighter_light" / "index.html").read_text()
