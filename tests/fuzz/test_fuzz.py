"""Property-based fuzzing (Hypothesis) of the scene builder and of the USD translation:
random and malformed input either works or raises a clear exception (the core's
ValueError, the binding's TypeError, SceneError), never another exception type, never a
crash. Each campaign runs in a child process (fuzz_child.py), so a segfault or abort
fails the test and shows the input that caused it."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

CHILD = Path(__file__).with_name("fuzz_child.py")
# Examples per campaign: enough to reach every kind of breakage the strategies draw,
# few enough to keep the suite fast (each campaign takes a few seconds).
EXAMPLES = {"scene": 300, "wrapper": 200, "usd": 150}


@pytest.mark.parametrize("campaign", list(EXAMPLES))
def test_fuzz_campaign(campaign, tmp_path):
    r = subprocess.run([sys.executable, str(CHILD), campaign, str(tmp_path), str(EXAMPLES[campaign])],
                       capture_output=True, text=True, timeout=600, cwd=tmp_path)
    current = tmp_path / "current"
    last = current.read_text()[:3000] if current.exists() else "(none)"
    if r.returncode < 0:
        pytest.fail(f"the {campaign} fuzz process died of {signal.Signals(-r.returncode).name} on:\n{last}\n"
                    f"{r.stderr[-3000:]}")
    assert r.returncode == 0, f"{campaign}: a falsifying example\n{r.stdout[-4000:]}\n{r.stderr[-4000:]}"
    outcomes = json.loads((tmp_path / "summary.json").read_text())
    print(campaign, outcomes)
    # Not vacuous: the campaign both built/loaded scenes and had some refused.
    assert sum(n for k, n in outcomes.items() if k.startswith("refused")) > 0, outcomes
    assert sum(n for k, n in outcomes.items() if not k.startswith("refused")) > 0, outcomes


def test_a_crash_in_the_child_is_reported(tmp_path):
    """The harness itself: a child that segfaults is seen as a signal, not as a pass."""
    r = subprocess.run([sys.executable, "-c", "import ctypes; ctypes.string_at(0)"], capture_output=True)
    assert r.returncode == -signal.SIGSEGV


# ------------------------------------------------------------------ what the fuzzing found
def test_non_utf8_usda_is_a_scene_error(tmp_path):
    """USD's parse error quotes the file; str() of it raised UnicodeDecodeError (found by
    the usd campaign)."""
    from tessera_renderer import SceneError, load_scene

    path = tmp_path / "bad.usda"
    path.write_bytes(b"#usda\x80 1.0\n")
    with pytest.raises(SceneError, match="cannot read USD file bad.usda"):
        load_scene(path)


def test_denormal_focal_length_is_a_scene_error(tmp_path):
    """focalLength 1e-45 passed the positivity check, and the core refused the infinite
    field of view only at render time with a bare ValueError (found by the usd campaign)."""
    from tessera_renderer import SceneError, load_scene

    sys.path.insert(0, str(CHILD.parent))
    from fuzz_child import BASE_USDA, VALID

    path = tmp_path / "cam.usda"
    path.write_text(BASE_USDA.format(**{**VALID, "focal": "1e-45"}))
    with pytest.raises(SceneError, match="field of view is degenerate"):
        load_scene(path)
    path.write_text(BASE_USDA.format(**VALID))
    assert load_scene(path).render_tile(0, 0, 4, 4, width=4, height=4, spp=1).shape == (4, 4, 4)
