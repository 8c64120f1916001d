"""`tessera preview` in a real browser: the CLI serves a solved radiosity scene, Debian's
chromium (headless, selenium) shows it on a canvas, a drag orbits and the wheel zooms.

Every wait is on an event: the CLI's "preview at" line, or a page condition (the canvas's
data-view, set once a frame for that view is drawn); never on time."""
from __future__ import annotations

import subprocess
import sys
from urllib.parse import parse_qs

import httpx
import numpy as np
import pytest

from conftest import CORNELL, clean_env
from tessera_base.images import tonemap_srgb8
from tessera_renderer import load_scene

pytestmark = pytest.mark.slow

webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is in the test extras")
from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402

RES = 64
PARAMS = {"element_size": 150.0}
WAIT = 120  # seconds a page condition may take on a loaded 2-core machine


@pytest.fixture(scope="module")
def preview_url():
    cmd = [sys.executable, "-m", "tessera", "preview", str(CORNELL), "--port", "0", "--res", f"{RES}x{RES}",
           "--integrator-param", f"element_size={PARAMS['element_size']}"]
    proc = subprocess.Popen(cmd, env=clean_env(), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    seen = []
    for line in proc.stdout:  # blocks until the server says where it listens, or exits
        seen.append(line)
        if line.startswith("preview at "):
            break
    else:
        raise AssertionError("tessera preview exited before serving:\n" + "".join(seen))
    url = line.split()[2]
    yield url
    proc.terminate()
    proc.wait(timeout=30)


def canvas_pixels(driver) -> np.ndarray:
    data = driver.execute_script("""
        const c = document.getElementById('c');
        return Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data);""")
    return np.asarray(data, np.uint8).reshape(RES, RES, 4)


def served_frame(url: str, view: str) -> np.ndarray:
    r = httpx.get(f"{url}frame?{view}", timeout=60)
    assert r.status_code == 200, r.text
    return np.frombuffer(r.content, np.uint8).reshape(RES, RES, 4)


def drawn_view(driver, condition) -> str:
    """Waits until the canvas shows a view satisfying condition(yaw, pitch, zoom) and the page
    wants no newer one; returns that view's query string."""
    def check(d):
        view, pending = d.execute_script(
            "const c = document.getElementById('c'); return [c.dataset.view || '', dirty || busy];")
        if not view or pending:
            return False
        q = {k: float(v[0]) for k, v in parse_qs(view).items()}
        return view if condition(q["yaw"], q["pitch"], q["zoom"]) else False
    return WebDriverWait(driver, WAIT, poll_frequency=0.05).until(check)


def red_left_green_right(rgb: np.ndarray) -> bool:
    """The Cornell box seen from the front: (R - G) over the left quarter exceeds that over the
    right quarter by 30 levels (a black, grey or mirrored frame gives 0 or less)."""
    q = rgb.shape[1] // 4
    d = rgb[..., 0].astype(float) - rgb[..., 1]
    return float(d[:, :q].mean() - d[:, -q:].mean()) > 30


def test_the_page_shows_the_solution_and_follows_drag_and_wheel(preview_url, browser):
    driver = browser
    driver.get(preview_url)
    first = drawn_view(driver, lambda yaw, pitch, zoom: (yaw, pitch, zoom) == (0, 0, 1))
    shown = canvas_pixels(driver)
    # The canvas holds exactly the bytes the server sent for that view, and those are the
    # radiosity image rendered here, in this process, by the renderer's own tile pass.
    assert np.array_equal(shown, served_frame(preview_url, first))
    scene = load_scene(str(CORNELL))
    product = scene.scene_pass("radiosity", 0, threads=2, integrator_params=PARAMS)
    direct = scene.render_tile(0, 0, RES, RES, width=RES, height=RES, spp=1, threads=2,
                               integrator="radiosity", integrator_params=PARAMS, scene_product=product)
    assert np.array_equal(shown[..., :3], tonemap_srgb8(direct))
    assert red_left_green_right(shown[..., :3])
    assert not red_left_green_right(shown[:, ::-1, :3])  # control: mirrored, it fails
    assert "frames/s" in driver.find_element(By.ID, "fps").text

    # A drag of 40 pixels to the right orbits by yaw -= 40 * 0.01 (the page's rule).
    canvas = driver.find_element(By.ID, "c")
    ActionChains(driver).move_to_element(canvas).click_and_hold().move_by_offset(40, 0).release().perform()
    turned_view = drawn_view(driver, lambda yaw, pitch, zoom: yaw < 0)
    turned = canvas_pixels(driver)
    assert np.array_equal(turned, served_frame(preview_url, turned_view))
    assert float(parse_qs(turned_view)["yaw"][0]) == pytest.approx(-0.4, abs=0.021)
    assert np.abs(turned.astype(int) - shown).max() > 50  # the view moved

    # Scrolling down zooms out: the box (lit) covers less of the frame, the black outside more.
    ActionChains(driver).scroll_to_element(canvas).scroll_from_origin(
        webdriver.common.actions.wheel_input.ScrollOrigin.from_element(canvas), 0, 400).perform()
    zoomed_view = drawn_view(driver, lambda yaw, pitch, zoom: zoom > 1.2)
    zoomed = canvas_pixels(driver)
    assert np.array_equal(zoomed, served_frame(preview_url, zoomed_view))
    lit = lambda img: float((img[..., :3].max(axis=2) > 8).mean())  # noqa: E731
    assert lit(zoomed) < lit(turned) - 0.05, (lit(zoomed), lit(turned))


def test_bad_views_and_paths_are_refused(preview_url):
    for query in ("zoom=0", "zoom=-1", "yaw=nan", "pitch=inf", "yaw=left"):
        r = httpx.get(f"{preview_url}frame?{query}", timeout=60)
        assert r.status_code == 400, (query, r.status_code)
        assert "finite numbers" in r.text
    assert httpx.get(f"{preview_url}nothing-here", timeout=60).status_code == 404
    assert httpx.get(f"{preview_url}info", timeout=60).json()["solve_seconds"] > 0
