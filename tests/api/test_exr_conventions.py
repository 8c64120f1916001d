"""EXR files as compositing tools expect them (docs/aovs.md): layer names, standard
attributes (compression, screenWindow*, Rec.709 chromaticities), tessera: provenance,
crop regions as data window inside the full display window; and OpenEXR's own tools
(exrheader, exrinfo) and oiiotool read every kind of file Tessera writes."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tessera_base import images

ROOT = Path(__file__).resolve().parents[2]
CORNELL = ROOT / "examples" / "cornell" / "cornell.usda"
# The names OIIO, Nuke and Blender use (written out here, not taken from the code).
ALL_AOV_CHANNELS = {"R", "G", "B", "A", "albedo.R", "albedo.G", "albedo.B", "N.X", "N.Y", "N.Z", "Z",
                    "variance.R", "variance.G", "variance.B", "spp"}
TOOLS = ("exrheader", "exrinfo", "oiiotool")


def tessera(*args: str) -> subprocess.CompletedProcess:
    r = subprocess.run([sys.executable, "-m", "tessera", *args], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return r


def read_with_tools(path: Path) -> dict[str, str]:
    """Each tool's output; asserts each one read the file without complaint."""
    out = {}
    for tool, args in (("exrheader", []), ("exrinfo", ["-v"]), ("oiiotool", ["--info", "-v"])):
        r = subprocess.run([tool, *args, str(path)], capture_output=True, text=True)
        # Debian 12's exrinfo (OpenEXR 3.1.5) exits with an arbitrary status after a
        # successful read (0, 16, 79, 191 for the same file, run to run): for it, a read
        # is the parts listing on stdout and nothing on stderr.
        ok = r.returncode == 0 if tool != "exrinfo" else ("parts: 1" in r.stdout and not r.stderr.strip())
        assert ok and "error" not in r.stderr.lower(), (tool, r.returncode, r.stdout, r.stderr)
        out[tool] = r.stdout
    return out


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    if missing := [t for t in TOOLS if shutil.which(t) is None]:
        pytest.fail(f"{', '.join(missing)} not installed: run scripts/setup.sh (Debian packages "
                    f"openexr, openimageio-tools)")
    d = tmp_path_factory.mktemp("exr")
    common = ["--res", "48x32", "--spp", "8", "--seed", "3", "-q"]
    tessera("render", str(CORNELL), "-o", str(d / "full.exr"), "--aovs", "all", *common)
    tessera("render", str(CORNELL), "-o", str(d / "crop.exr"), "--aovs", "all", "--crop", "8,4,40,28", *common)
    tessera("render", str(CORNELL), "-o", str(d / "bdpt.exr"), "--integrator", "bdpt", *common[:-2], "16", "-q")
    tessera("denoise", str(d / "full.exr"), "-o", str(d / "denoised.exr"))
    return d


def test_layers_and_standard_attributes(renders):
    spec_channels = set(images.read_exr_channels(renders / "full.exr"))
    assert spec_channels == ALL_AOV_CHANNELS
    head = read_with_tools(renders / "full.exr")["exrheader"]
    assert "compression (type compression): zip" in head
    assert "screenWindowWidth (type float): 1" in head and "screenWindowCenter (type v2f): (0 0)" in head
    assert "chromaticities (type chromaticities)" in head
    info = read_with_tools(renders / "full.exr")["oiiotool"]
    assert "chromaticities: 0.64, 0.33, 0.3, 0.6, 0.15, 0.06, 0.3127, 0.329" in info


def test_tessera_provenance_in_the_header(renders):
    meta = images.read_render(renders / "full.exr").metadata
    import hashlib
    assert meta["tessera:scene_sha256"] == hashlib.sha256(CORNELL.read_bytes()).hexdigest()
    assert (meta["tessera:integrator"], meta["tessera:spp"], meta["tessera:seed"]) == ("path", "8", "3")
    assert meta["tessera:variance"] == "per-sample"
    # reached error: the luminance's relative standard error, RMS over pixels, at 8 spp
    # it lies between 5 % and 100 % (the closed-form check is tests of protocol.tile_error).
    assert 0.05 < float(meta["tessera:reached_error"]) < 1.0
    assert all(k.startswith("tessera:") for k in meta if k.split(":")[0] not in ("oiio", "openexr")
               and k not in ("compression", "DateTime", "PixelAspectRatio", "screenWindowCenter",
                             "screenWindowWidth", "chromaticities"))


def test_crop_writes_the_region_as_data_window_of_the_full_frame(renders):
    head = read_with_tools(renders / "crop.exr")["exrheader"]
    assert "dataWindow (type box2i): (8 4) - (39 27)" in head
    assert "displayWindow (type box2i): (0 0) - (47 31)" in head
    full, crop = (images.read_exr_channels(renders / f) for f in ("full.exr", "crop.exr"))
    assert set(crop) == ALL_AOV_CHANNELS
    for name in ALL_AOV_CHANNELS:  # the same seed: the region's pixels bit for bit
        np.testing.assert_array_equal(crop[name], full[name][4:28, 8:40], err_msg=name)
    # The PNG preview of a crop is the crop (the full frame's PNG is the full frame).
    import OpenImageIO as oiio

    for png, size in (("crop.png", (32, 24)), ("full.png", (48, 32))):
        spec = oiio.ImageInput.open(str(renders / png)).spec()
        assert (spec.width, spec.height) == size, png


def test_every_kind_of_file_reads_with_the_tools(renders, tmp_path):
    for name in ("full.exr", "crop.exr", "bdpt.exr", "denoised.exr"):
        read_with_tools(renders / name)
    for ref in sorted((ROOT / "examples" / "refs").glob("*.exr")):
        read_with_tools(ref)
    # The check can fail: a file cut short is refused by each tool.
    broken = tmp_path / "broken.exr"
    broken.write_bytes((renders / "full.exr").read_bytes()[:300])
    for tool, args in (("exrheader", []), ("exrinfo", ["-v"]), ("oiiotool", ["--info", "-v"])):
        r = subprocess.run([tool, *args, str(broken)], capture_output=True, text=True)
        refused = "error" in r.stderr.lower() if tool == "exrinfo" else (r.returncode != 0 or "error" in r.stderr.lower())
        assert refused, (tool, r.stdout, r.stderr)


def test_bad_crop_is_a_clear_error(tmp_path):
    r = subprocess.run([sys.executable, "-m", "tessera", "render", str(CORNELL), "--res", "16x16",
                        "--spp", "1", "--crop", "0,0,17,8", "-o", str(tmp_path / "x.exr"), "-q"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "not a non-empty region of the 16x16 frame" in r.stderr
    assert not (tmp_path / "x.exr").exists()


def test_crop_job_field_is_checked_against_the_frame():
    from pydantic import ValidationError

    from tessera_base.protocol import RenderSettings

    assert RenderSettings(width=32, height=16, crop="0,0,32,16").crop == (0, 0, 32, 16)
    assert RenderSettings(width=32, height=16, crop="").crop is None
    for bad in ("0,0,33,16", "4,4,4,8", "1,2,3", "a,b,c,d", "-1,0,4,4"):
        with pytest.raises(ValidationError):
            RenderSettings(width=32, height=16, crop=bad)
