"""Reference sets (tessera.refs, tessera.refcheck, tessera.refreport): the committed set in
examples/refs is checked unchanged (passes) and with the red wall's albedo 2 % higher
(fails: the smallest change the check claims to find at its budget, the negative
control); the JUnit file is parsed, the HTML report read; pooling looks is exact."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from tessera_base import images
from tessera import refcheck, refs

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE_REFS = ROOT / "examples" / "refs"
CORNELL = ROOT / "examples" / "cornell" / "cornell.usda"
RED = "(0.63, 0.065, 0.05)"


def tessera(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tessera", *args], capture_output=True, text=True)


def red_wall_scaled(tmp_path: Path, factor: float) -> Path:
    """The Cornell box with the red wall's diffuse albedo times `factor` (its own file)."""
    text = CORNELL.read_text()
    assert text.count(RED) == 1
    r, g, b = (float(v) * factor for v in RED.strip("()").split(","))
    out = tmp_path / f"cornell_red_{factor:g}.usda"
    out.write_text(text.replace(RED, f"({r:.6g}, {g:.6g}, {b:.6g})"))
    return out


def copy_set(tmp_path: Path, names: list[str], scene: Path | None = None) -> Path:
    """The committed reference set reduced to `names`, optionally pointing at another scene."""
    folder = tmp_path / "refs"
    folder.mkdir()
    manifest = json.loads((EXAMPLE_REFS / refs.MANIFEST).read_text())
    manifest["references"] = [r for r in manifest["references"] if r["name"] in names]
    for r in manifest["references"]:
        shutil.copy(EXAMPLE_REFS / r["exr"], folder / r["exr"])
        r["scene"] = str(scene or CORNELL)
    (folder / refs.MANIFEST).write_text(json.dumps(manifest))
    return folder


def test_pooling_two_looks_equals_the_statistics_of_all_their_samples():
    """accumulate's per-sample pooling against numpy's mean and variance of the samples
    themselves (independent of the code): exact to float32 rounding."""
    rng = np.random.default_rng(3)
    samples = rng.gamma(0.5, 2.0, size=(4, 5, 3, 48))       # skewed, like path contributions

    def image(s):
        rgba = np.concatenate([s.mean(axis=3), np.ones((4, 5, 1))], axis=2)
        return images.RenderImage(rgba.astype(np.float32), s.var(axis=3, ddof=1).astype(np.float32),
                                  np.full((4, 5), s.shape[3], np.float32), {}, images.VARIANCE_PER_SAMPLE)

    pooled = refcheck.accumulate(image(samples[..., :16]), image(samples[..., 16:]))
    np.testing.assert_allclose(pooled.rgba[..., :3], samples.mean(axis=3), rtol=1e-5)
    np.testing.assert_allclose(pooled.variance, samples.var(axis=3, ddof=1), rtol=1e-4)
    assert np.all(pooled.spp == 48)
    # The check can fail: the naive average of the two variances misses the between term.
    naive = 0.5 * (samples[..., :16].var(axis=3, ddof=1) + samples[..., 16:].var(axis=3, ddof=1))
    assert not np.allclose(naive, samples.var(axis=3, ddof=1), rtol=1e-2)


def test_look_schedule_doubles_up_to_the_budget():
    assert refcheck.look_schedule(refs.CheckBudget(min_spp=64, max_spp=512)) == [64, 128, 256, 512]
    assert refcheck.look_schedule(refs.CheckBudget(min_spp=64, max_spp=300)) == [64, 128, 256, 300]


def test_bad_sets_are_usage_errors(tmp_path):
    r = tessera("refs", "check", str(tmp_path))
    assert r.returncode == 2 and "no refs.json" in r.stderr
    (tmp_path / refs.MANIFEST).write_text('{"schema": 1, "references": [{"name": "a/b"}]}')
    r = tessera("refs", "list", str(tmp_path))
    assert r.returncode == 2 and "refs.json" in r.stderr
    (tmp_path / "x").mkdir()
    folder = copy_set(tmp_path / "x", ["cornell"])
    r = tessera("refs", "check", str(folder), "nosuch")
    assert r.returncode == 2 and "no reference named 'nosuch'" in r.stderr


def test_list_says_what_changed(tmp_path):
    folder = copy_set(tmp_path, ["cornell"])
    r = tessera("refs", "list", str(folder))
    assert r.returncode == 0 and "up to date" in r.stdout, r.stdout + r.stderr
    variant = red_wall_scaled(tmp_path, 1.02)
    manifest = json.loads((folder / refs.MANIFEST).read_text())
    manifest["references"][0]["scene"] = str(variant)
    (folder / refs.MANIFEST).write_text(json.dumps(manifest))
    r = tessera("refs", "list", str(folder))
    assert "changed since the reference was rendered" in r.stdout, r.stdout


def test_red_wall_two_percent_brighter_fails_with_reports(tmp_path):
    """The negative control: the red wall's albedo 2 % higher fails the check (exit 1), in
    the JUnit file (a <failure> in the one test case) and in the HTML report."""
    folder = copy_set(tmp_path, ["cornell"], scene=red_wall_scaled(tmp_path, 1.02))
    junit, report = tmp_path / "junit.xml", tmp_path / "report"
    r = tessera("refs", "check", str(folder), "--junit", str(junit), "--report", str(report))
    assert r.returncode == 1, r.stdout + r.stderr
    assert "cornell: FAIL (differs)" in r.stdout
    suite = ET.parse(junit).getroot().find("testsuite")
    assert suite.get("tests") == "1" and suite.get("failures") == "1"
    (case,) = suite.findall("testcase")
    assert case.get("name") == "cornell"
    failure = case.find("failure")
    assert failure is not None and failure.get("type") == "differs"
    assert "differ beyond noise" in failure.get("message")
    props = {p.get("name"): p.get("value") for p in case.find("properties")}
    assert props["verdict"] == "differs" and int(props["spp"]) <= 512
    page = (report / "index.html").read_text()
    assert "cornell: FAIL" in page and "FLIP" in page
    for kind in ("reference", "test", "heatmap", "regions"):
        assert f"cornell.{kind}.png" in page
        assert images.read_exr(report / f"cornell.{kind}.png").shape == (64, 64, 3)
    heat = images.read_exr(report / "cornell.heatmap.png")
    assert (heat[..., 0] - heat[..., 2] > 0.3).any()  # orange/red: inside a rejected block
    # The region map points at the red wall (the left of the frame): brighter there.
    regions = images.read_exr(report / "cornell.regions.png")
    redness = regions[..., 0] - regions[..., 2]
    assert redness[:, :32].mean() > redness[:, 32:].mean() + 0.1


@pytest.mark.slow
def test_unchanged_cornell_passes_and_stops_early(tmp_path):
    """The same check on the unchanged scene passes, and decides before its budget ends."""
    folder = copy_set(tmp_path, ["cornell"])
    junit = tmp_path / "junit.xml"
    r = tessera("refs", "check", str(folder), "--junit", str(junit))
    assert r.returncode == 0, r.stdout + r.stderr
    (case,) = ET.parse(junit).getroot().iter("testcase")
    assert case.find("failure") is None
    props = {p.get("name"): p.get("value") for p in case.find("properties")}
    assert props["verdict"] == "same", r.stdout
    assert int(props["spp"]) < int(props["max_spp"]), r.stdout


@pytest.mark.slow
def test_bdpt_reference_passes_unchanged_and_fails_on_brighter_red_wall(tmp_path):
    """A splatting integrator's reference (batch-means variance): unchanged passes; the red
    wall's albedo 5 % higher fails (32x32, at most 256 spp: 2 % is below its power)."""
    refset = refs.load(EXAMPLE_REFS)
    ref = refset.find("cornell-bdpt")
    same = refcheck.check(EXAMPLE_REFS, refset, ref)
    assert same.passed and same.verdict in ("same", "inconclusive"), same.why
    changed = refcheck.check(EXAMPLE_REFS, refset, ref, scene_file=red_wall_scaled(tmp_path, 1.05))
    assert not changed.passed and changed.verdict == "differs", changed.why
