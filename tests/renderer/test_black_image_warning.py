"""Issue 43: a finished image that is black for its exposure (99 % of its pixels below 1 %
of display white) gets one warning line naming the scene's brightest light and its
intensity: in a local render (tessera render) and on the farm (the job's warnings once
its image is merged, tests/farm/test_farm_black_image.py)."""
from __future__ import annotations

import numpy as np
import pytest

from tessera_base.film import BLACK_PIXEL, BLACK_SHARE, black_image_warning
from usd_fixtures import DIM_SPHERE_LIGHT_USDA


def test_the_rule_at_its_edges():
    """99 % of the pixels below 1 % of white warns, 98.99 % does not; a pixel at exactly
    1 % is not dark, one just below is (authored pixel values, 100 x 100)."""
    img = np.zeros((100, 100, 4), np.float32)
    img.reshape(-1, 4)[:100, 0] = BLACK_PIXEL  # 100 bright pixels: 99.00 % dark
    assert BLACK_SHARE == 0.99 and BLACK_PIXEL == 0.01
    line = black_image_warning(img, "/Light (SphereLight, intensity 10)")
    assert line is not None and "99.0 %" in line and "/Light (SphereLight, intensity 10)" in line
    img.reshape(-1, 4)[100, 1] = BLACK_PIXEL  # 101 bright: 98.99 % dark
    assert black_image_warning(img, None) is None
    img.reshape(-1, 4)[100, 1] = np.nextafter(np.float32(BLACK_PIXEL), np.float32(0))
    assert black_image_warning(img, None) is not None
    assert "no light" in black_image_warning(np.zeros((4, 4, 4), np.float32), None)


def _render(tmp_path, intensity, capsys):
    from tessera_cli.cli import main

    scene = tmp_path / f"dim{intensity}.usda"
    scene.write_text(DIM_SPHERE_LIGHT_USDA.replace("INTENSITY", str(intensity)))
    out = tmp_path / f"dim{intensity}.exr"
    assert main(["render", str(scene), "--res", "24x24", "--spp", "4", "-q", "-o", str(out)]) == 0
    return [ln for ln in capsys.readouterr().err.splitlines() if "black for its exposure" in ln]


@pytest.mark.parametrize("intensity,black", [(10, True), (1000000, False)])
def test_a_local_render_says_when_its_image_is_black(tmp_path, capsys, intensity, black):
    """The dim file warns once and names /Light, the brighter of its two lights, with the
    authored intensity; the same file with the light turned up (negative control) does not."""
    import OpenImageIO as oiio

    lines = _render(tmp_path, intensity, capsys)
    px = oiio.ImageBuf(str(tmp_path / f"dim{intensity}.exr")).get_pixels(oiio.FLOAT)[..., :3]
    dark = float((px.max(axis=-1) < BLACK_PIXEL).mean())
    assert (dark >= BLACK_SHARE) is black  # the image itself, measured here
    if black:
        assert len(lines) == 1 and f"/Light (SphereLight, intensity {intensity})" in lines[0], lines
    else:
        assert lines == []
