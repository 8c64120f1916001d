"""The test-render cache (tests/render_cache.py) returns a stored render only for the same
translated scene, settings and build; anything else renders anew."""
import numpy as np

import render_cache
from tessera_tools.many_lights import build


def test_a_render_is_reused_only_for_the_same_scene_settings_and_build(tmp_path, monkeypatch):
    monkeypatch.setenv("TESSERA_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("TESSERA_TEST_RENDER_CACHE", raising=False)
    calls = []

    def render(value):
        def go():
            calls.append(value)
            return {"img": np.full((2, 2), value, np.float32)}
        return go

    scene = build(20, res=8, light_selection="power")
    first = render_cache.cached("t", scene, {"seed": 1}, render(1.0))
    again = render_cache.cached("t", build(20, res=8, light_selection="power"), {"seed": 1}, render(9.0))
    assert calls == [1.0] and np.array_equal(first["img"], again["img"])  # the same key: stored bits
    render_cache.cached("t", scene, {"seed": 2}, render(2.0))               # another setting
    render_cache.cached("t", build(20, seed=2, res=8, light_selection="power"), {"seed": 1}, render(3.0))  # scene
    render_cache.cached("t", build(20, res=8, light_selection="bvh"), {"seed": 1}, render(4.0))  # light choice
    monkeypatch.setattr(render_cache, "tessera_build", lambda: "another core")
    render_cache.cached("t", scene, {"seed": 1}, render(5.0))               # another build
    assert calls == [1.0, 2.0, 3.0, 4.0, 5.0]
    monkeypatch.setenv("TESSERA_TEST_RENDER_CACHE", "0")
    render_cache.cached("t", scene, {"seed": 2}, render(6.0))               # off: always renders
    assert calls[-1] == 6.0
