"""The monitor page (routers/monitor.py) in a real browser: Debian's chromium, headless,
driven by selenium, against a real farm (redis-server, the API with a token, a worker).

Every wait is on a page condition (WebDriverWait), never on time. Screenshots of each step
go to $TESSERA_MONITOR_SCREENSHOTS when set (scripts/monitor-screenshots.py sets it to
docs/monitor), else to the test's tmp_path."""
from __future__ import annotations

import base64
import io
import os
import time
from datetime import datetime, timezone
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image

from conftest import CORNELL, start_api, start_worker

pytestmark = pytest.mark.slow

webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is in the test extras")
from selenium.common.exceptions import (NoSuchElementException,  # noqa: E402
                                        StaleElementReferenceException, WebDriverException)
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support import expected_conditions as EC  # noqa: E402
from selenium.webdriver.support.ui import Select, WebDriverWait  # noqa: E402

TOKEN = "monitor-test-token-8c1f"
ROOT_TOKEN = "monitor-root-token-41d7"  # an admin's (worker actions)
WORKER = "monitor-worker-1"
FAULTY = "monitor-faulty"  # its render process segfaults on tile 1 of poison*.usda
WAIT = 120  # seconds any page condition may take on a loaded 2-core machine
# A pixel's displayed value may differ from the PNG's by rounding at most; a real
# difference (another image, a flipped one) moves many pixels by tens of levels.
MAX_LEVEL_DIFFERENCE = 2


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    logs = tmp_path_factory.mktemp("monitor-farm")
    api, base = start_api(redis_server, logs, api_tokens=f"alice:{TOKEN},root:{ROOT_TOKEN}",
                          api_admins="root")
    worker = start_worker(redis_server, WORKER, logs, heartbeat_ttl=5.0, tile_timeout=600.0)
    yield base, [api, worker]
    worker.stop()
    api.stop()


@pytest.fixture(scope="module")
def shots(tmp_path_factory) -> Path:
    target = os.environ.get("TESSERA_MONITOR_SCREENSHOTS")
    path = Path(target) if target else tmp_path_factory.mktemp("monitor-screenshots")
    path.mkdir(parents=True, exist_ok=True)
    return path


def wait(driver, condition, message: str, farm_processes=()):
    try:
        # The page rebuilds its tables on every poll: an element found a moment ago may
        # be gone; the condition is then tried again.
        return WebDriverWait(driver, WAIT, poll_frequency=0.1, ignored_exceptions=(
            NoSuchElementException, StaleElementReferenceException)).until(condition)
    except WebDriverException as e:
        logs = "\n".join(p.log() for p in farm_processes)
        raise AssertionError(f"{message}\n{e}\n{logs}") from None


def attribute_is(by_id: str, name: str, value: str):
    def check(driver):
        element = driver.find_element(By.ID, by_id)
        return element if element.get_attribute(name) == value else False
    return check


def job_row(job_id: str, css: str = "") -> tuple[str, str]:
    return By.CSS_SELECTOR, f'#jobs tr[data-job="{job_id}"] {css}'.strip()


def listed_as(job_id: str, state: str):
    """The job list shows the job in `state`."""
    return lambda driver: driver.find_element(*job_row(job_id)).get_attribute("data-state") == state


WORKER_CURRENT = (By.CSS_SELECTOR, f'#workers tr[data-worker="{WORKER}"] td.current')


def shown_pixels(driver, img_id: str) -> np.ndarray:
    """The <img>'s pixels as the browser decoded them (drawn to a canvas), 8-bit RGB."""
    data_url = driver.execute_script("""
        const img = document.getElementById(arguments[0]);
        const canvas = document.createElement('canvas');
        canvas.width = img.naturalWidth; canvas.height = img.naturalHeight;
        canvas.getContext('2d').drawImage(img, 0, 0);
        return canvas.toDataURL('image/png');""", img_id)
    raw = base64.b64decode(data_url.split(",", 1)[1])
    return np.asarray(Image.open(io.BytesIO(raw)).convert("RGB")).astype(int)


def png_pixels(data: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB")).astype(int)


def same_image(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and int(np.abs(a - b).max()) <= MAX_LEVEL_DIFFERENCE


def colourful(rgb: np.ndarray) -> bool:
    """The Cornell box as rendered, not a black or grey frame: red wall on the left, green
    on the right. (R - G) averaged over the left quarter exceeds that of the right quarter
    by more than 30 levels (about 70 at 16 spp); grey, black or mirrored frames give 0 or
    less."""
    quarter = rgb.shape[1] // 4
    red_minus_green = rgb[..., 0].astype(float) - rgb[..., 1]
    return float(red_minus_green[:, :quarter].mean() - red_minus_green[:, -quarter:].mean()) > 30


def check_shown_image(driver, img_id: str, expected_png: bytes) -> None:
    shown, expected = shown_pixels(driver, img_id), png_pixels(expected_png)
    assert same_image(shown, expected), (
        f"#{img_id} shows another image than the API's PNG: shapes {shown.shape} / "
        f"{expected.shape}, largest difference {np.abs(shown - expected).max()} levels")
    assert colourful(shown), f"#{img_id} is black or grey, not the Cornell box"
    # Negative controls: the same checks refuse a mirrored image (red and green walls
    # swapped), a grey one and one a few levels off.
    assert not same_image(shown, expected[:, ::-1]) and not colourful(shown[:, ::-1])
    assert not colourful(np.repeat(shown.mean(axis=2, keepdims=True), 3, axis=2).astype(int))
    assert not same_image(shown, np.clip(expected + MAX_LEVEL_DIFFERENCE + 1, 0, 255))


def drop_file(driver, scene: Path) -> None:
    """Drops the scene on the form's drop zone as a file dragged from the desktop would
    arrive: a drop event whose DataTransfer holds the file."""
    driver.execute_script("""
        const bytes = Uint8Array.from(atob(arguments[1]), (c) => c.charCodeAt(0));
        const transfer = new DataTransfer();
        transfer.items.add(new File([bytes], arguments[0]));
        const zone = document.getElementById('drop');
        for (const type of ['dragover', 'drop']) {
          zone.dispatchEvent(new DragEvent(type, {dataTransfer: transfer, bubbles: true,
                                                  cancelable: true}));
        }""", scene.name, base64.b64encode(scene.read_bytes()).decode())


def submit_through_form(driver, scene: Path, dropped: bool = False, **fields: str) -> str:
    if dropped:
        drop_file(driver, scene)
        assert driver.find_element(By.ID, "file-name").text == (
            f"{scene.name} ({scene.stat().st_size} bytes)")
    else:
        driver.find_element(By.ID, "file").send_keys(str(scene))
    for name, value in fields.items():
        if name == "denoise":
            box = driver.find_element(By.ID, "denoise")
            if box.is_selected() != (value == "true"):
                box.click()
        elif name == "integrator":
            Select(driver.find_element(By.ID, "integrator")).select_by_value(value)
        else:
            element = driver.find_element(By.ID, name)
            element.clear()
            element.send_keys(value)
    previous = driver.find_element(By.ID, "upload-result").get_attribute("data-job")
    driver.find_element(By.ID, "submit").click()
    wait(driver, lambda d: d.find_element(By.ID, "upload-result").get_attribute("data-job")
         not in (None, previous),
         "the upload form did not report a new job: " + driver.find_element(By.ID, "upload-result").text)
    return driver.find_element(By.ID, "upload-result").get_attribute("data-job")


def test_monitor_page(farm, browser, shots):
    base, processes = farm
    api = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60)
    anonymous = httpx.Client(base_url=base, timeout=60)
    driver = browser

    # --- the page is public; it holds no data, and its token is asked for
    page = anonymous.get("/")
    assert page.status_code == 200 and "<title>Tessera monitor</title>" in page.text
    assert anonymous.get("/monitor/monitor.js").status_code == 200
    assert anonymous.get("/jobs").status_code == 401
    assert anonymous.get("/workers").status_code == 401
    driver.get(base + "/")
    wait(driver, EC.visibility_of_element_located((By.ID, "login")), "no token prompt")
    driver.find_element(By.ID, "token").send_keys("not-the-token")
    driver.find_element(By.ID, "token").submit()
    wait(driver, EC.text_to_be_present_in_element((By.ID, "login-error"), "not valid"),
         "a wrong token was not refused on the page")
    driver.save_screenshot(str(shots / "1-token.png"))
    driver.find_element(By.ID, "token").send_keys(TOKEN)
    driver.find_element(By.ID, "token").submit()
    wait(driver, EC.visibility_of_element_located((By.ID, "monitor")),
         "the token was not accepted")
    assert driver.execute_script("return sessionStorage.getItem('tessera.token')") == TOKEN

    # --- the worker is listed, with its heartbeat
    row = wait(driver, EC.presence_of_element_located(
        (By.CSS_SELECTOR, f'#workers tr[data-worker="{WORKER}"]')), "the worker is not listed", processes)
    assert "s ago" in row.text and "idle" in row.text
    driver.save_screenshot(str(shots / "2-signed-in.png"))

    # --- a job submitted through the form runs to 100 %, with its previews and events
    job = submit_through_form(driver, CORNELL, width="128", height="128", spp="16",
                              denoise="true", target_error="")
    wait(driver, EC.presence_of_element_located(job_row(job, 'td.progress[data-percent="100"]')),
         "the job's progress did not reach 100 %", processes)
    wait(driver, attribute_is("job-state", "data-state", "done"), "the job panel is not done",
         processes)
    wait(driver, attribute_is("preview", "data-state", "done"), "no final preview", processes)
    wait(driver, attribute_is("denoised", "data-state", "done"), "no final denoised preview",
         processes)
    status = api.get(f"/jobs/{job}").json()
    assert status["state"] == "done" and status["tiles_done"] == status["tiles_total"] == 4
    assert status["settings"]["denoise"] is True and status["owner"] == "alice"
    driver.save_screenshot(str(shots / "3-job-done.png"))
    check_shown_image(driver, "preview", api.get(f"/jobs/{job}/preview.png").content)
    check_shown_image(driver, "denoised", api.get(f"/jobs/{job}/denoised.png").content)
    # The event log replays the job's stream: one tile event per tile (2x2 tiles of 64 at
    # 128x128) and the final state.
    events = driver.find_elements(By.CSS_SELECTOR, "#events li")
    assert sum(e.get_attribute("data-type") == "tile" for e in events) == 4
    assert events[-1].get_attribute("data-type") == "state" and "done" in events[-1].text
    # The page never carries the data itself, and every data path refuses the anonymous.
    assert job not in anonymous.get("/").text
    for path in (f"/jobs/{job}", f"/jobs/{job}/events", f"/jobs/{job}/preview.png",
                 f"/jobs/{job}/denoised.png", f"/jobs/{job}/priority"):
        assert anonymous.get(path).status_code == 401, path

    # --- a second job, dropped on the form, to a noise target it will not reach soon: its
    # previews update as passes land, the worker shows its tile; then pause, resume,
    # priority, cancel
    long_job = submit_through_form(driver, CORNELL, dropped=True, width="128", height="128",
                                   spp="16", target_error="0.0001", max_spp="1048576",
                                   denoise="true")
    wait(driver, attribute_is("job-state", "data-state", "running"),
         "the long job is not running", processes)
    # Passes go out in queue order, so after 8 progress events every tile (2x2) has its
    # first pass, and previews fetched after them show the whole box.
    for img in ("preview", "denoised"):
        wait(driver, lambda d: int(d.find_element(By.ID, img).get_attribute("data-events") or 0)
             >= 8, f"the {img} did not update as passes landed", processes)
        assert driver.find_element(By.ID, img).get_attribute("data-state") == "running"
        assert colourful(shown_pixels(driver, img)), f"the running job's {img} is black or grey"
    assert int(driver.find_element(By.ID, "preview").get_attribute("data-loads")) >= 2
    wait(driver, EC.text_to_be_present_in_element(WORKER_CURRENT, long_job),
         "the worker does not show the long job's tile", processes)
    driver.save_screenshot(str(shots / "4-second-job-running.png"))
    driver.find_element(By.ID, "pause").click()
    wait(driver, listed_as(long_job, "paused"), "pausing did not show", processes)
    assert api.get(f"/jobs/{long_job}").json()["state"] == "paused"
    driver.find_element(By.ID, "resume").click()
    wait(driver, listed_as(long_job, "running"), "resuming did not show", processes)
    priority = driver.find_element(By.ID, "priority")
    priority.clear()
    priority.send_keys("8")
    driver.find_element(By.ID, "set-priority").click()
    wait(driver, EC.text_to_be_present_in_element(job_row(long_job, "td.priority"), "8"),
         "the priority change did not show", processes)
    assert api.get(f"/jobs/{long_job}").json()["priority"] == 8
    driver.find_element(By.ID, "cancel").click()
    wait(driver, listed_as(long_job, "cancelled"), "cancelling did not show in the list", processes)
    wait(driver, attribute_is("job-state", "data-state", "cancelled"),
         "the job panel is not cancelled", processes)
    assert api.get(f"/jobs/{long_job}").json()["state"] == "cancelled"
    wait(driver, EC.text_to_be_present_in_element(WORKER_CURRENT, "idle"),
         "the worker did not go idle after the cancel", processes)
    driver.save_screenshot(str(shots / "5-second-job-cancelled.png"))
    states = [e.text.rsplit(" ", 1)[-1]
              for e in driver.find_elements(By.CSS_SELECTOR, '#events li[data-type="state"]')]
    assert states == ["queued", "running", "paused", "running", "cancelled"], states


def test_page_without_tokens_asks_for_none(redis_server, browser, tmp_path):
    """A `tessera serve` farm without tokens (anonymous loopback): the page shows the farm
    at once, and offers no token to forget."""
    api, base = start_api(redis_server, tmp_path)  # allow_anonymous_loopback
    try:
        browser.get(base + "/")
        wait(browser, EC.visibility_of_element_located((By.ID, "monitor")),
             "the page did not open without a token", [api])
        assert not browser.find_element(By.ID, "login").is_displayed()
        assert not browser.find_element(By.ID, "forget-token").is_displayed()
        wait(browser, EC.text_to_be_present_in_element((By.ID, "status"), "updated"),
             "the job list was not loaded", [api])
    finally:
        api.stop()


SMALL = dict(width=64, height=64, spp=2, max_depth=4, tile_size=32)  # four tiles of 32


def sign_in(driver, base: str, token: str) -> None:
    driver.get(base + "/")
    driver.execute_script("sessionStorage.setItem('tessera.token', arguments[0])", token)
    driver.get(base + "/")
    wait(driver, EC.visibility_of_element_located((By.ID, "monitor")), "the token was not accepted")


def sequence_row(seq: str, css: str = "") -> tuple[str, str]:
    return By.CSS_SELECTOR, f'#jobs tr.sequence-row[data-sequence="{seq}"] {css}'.strip()


def task_rows(driver) -> list[dict]:
    return driver.execute_script("""
        return [...document.querySelectorAll('#tasks tbody tr')].map((r) => ({
          index: Number(r.dataset.index), state: r.dataset.state, slow: r.dataset.slow,
          cls: r.className, cells: [...r.cells].map((c) => c.textContent)}));""")


def stream_ids(api: httpx.Client, job: str) -> list[str]:
    """The ids of the job's SSE events (the job is final: the stream ends)."""
    with api.stream("GET", f"/jobs/{job}/events") as r:
        return [line[4:] for line in r.iter_lines() if line.startswith("id: ")]


def test_sequence_tasks_log_event_times_and_download(farm, browser, shots):
    """A frame range is one row with a cell per frame (frame 3 cancelled before it ran);
    filtered to done jobs, the strip still shows frame 3 (from the range's status);
    expanded, a row per frame; a frame's panel shows its task table, its events at the times
    they happened (not when the page read them) and its log as the API has it, and
    downloads its EXR."""
    base, processes = farm
    api = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60)
    root = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {ROOT_TOKEN}"}, timeout=60)
    assert root.post(f"/workers/{WORKER}/disable").status_code == 200  # no frame starts yet
    try:
        with open(CORNELL, "rb") as f:
            r = api.post("/jobs", files={"file": ("cornell.usda", f)},
                         data={**{k: str(v) for k, v in SMALL.items()}, "frames": "1-3"})
        assert r.status_code == 201, r.text
        seq, frame_jobs = r.json()["id"], {f["frame"]: f["job"] for f in r.json()["frames"]}
        assert api.delete(f"/jobs/{frame_jobs[3]}").json()["state"] == "cancelled"
    finally:
        root.post(f"/workers/{WORKER}/enable")
    deadline = time.monotonic() + WAIT
    while [f["state"] for f in api.get(f"/jobs/{seq}").json()["frames"]] != ["done", "done", "cancelled"]:
        assert time.monotonic() < deadline, api.get(f"/jobs/{seq}").json()
        time.sleep(0.05)
    opened = datetime.now(timezone.utc)
    driver = browser
    sign_in(driver, base, TOKEN)
    wait(driver, lambda d: [c.get_attribute("data-state") for c in
                            d.find_elements(*sequence_row(seq, ".frame-cell"))] == ["done", "done", "cancelled"],
         "the sequence row does not show frames done, done, cancelled", processes)
    cells = driver.find_elements(*sequence_row(seq, ".frame-cell"))
    assert [c.get_attribute("data-frame") for c in cells] == ["1", "2", "3"]
    assert [c.get_attribute("data-job") for c in cells] == [frame_jobs[1], frame_jobs[2], frame_jobs[3]]
    # One row for the range, none per frame until it is expanded.
    assert not driver.find_elements(By.CSS_SELECTOR, f'#jobs tr[data-job="{frame_jobs[1]}"]')
    driver.save_screenshot(str(shots / "6-sequence.png"))
    # Only done jobs listed: frame 3 is not on the page, yet its cell is, from the range.
    Select(driver.find_element(By.ID, "filter-state")).select_by_value("done")
    wait(driver, lambda d: d.find_element(By.ID, "page-info").text == "jobs 1–" + str(len(
        api.get("/jobs", params={"state": "done", "limit": 1000}).json()["jobs"])), "the state filter did not apply")
    assert [c.get_attribute("data-state") for c in driver.find_elements(*sequence_row(seq, ".frame-cell"))] == [
        "done", "done", "cancelled"]
    driver.find_element(*sequence_row(seq, "td.scene")).click()
    wait(driver, lambda d: [r.find_element(By.CSS_SELECTOR, "td.scene").text for r in d.find_elements(
        By.CSS_SELECTOR, f'#jobs tr.frame-row[data-sequence="{seq}"]')] == ["frame 1", "frame 2", "frame 3"],
         "expanding the sequence did not list its frames")
    driver.find_element(*job_row(frame_jobs[2])).click()
    wait(driver, attribute_is("job-state", "data-state", "done"), "frame 2's panel is not done", processes)

    # Tasks: four tiles, done, on the worker.
    wait(driver, lambda d: len(task_rows(d)) == 4, "no task table", processes)
    rows = task_rows(driver)
    assert [(r["index"], r["state"], r["cells"][3]) for r in rows] == [(i, "done", WORKER) for i in range(4)]
    tasks = api.get(f"/jobs/{frame_jobs[2]}/tasks").json()["tiles"]
    assert [r["cells"][4] for r in rows] == [str(t["passes_done"]) for t in tasks]

    # Events at their own times: the stream ids' milliseconds, each event exactly once.
    wait(driver, lambda d: d.find_elements(By.CSS_SELECTOR, '#events li[data-type="state"]')
         and "done" in d.find_elements(By.CSS_SELECTOR, '#events li[data-type="state"]')[-1].text,
         "the events did not replay to done", processes)
    shown = [e.get_attribute("data-time") for e in driver.find_elements(By.CSS_SELECTOR, "#events li")]
    expected = [datetime.fromtimestamp(int(i.split("-")[0]) / 1000, timezone.utc)
                .isoformat(timespec="milliseconds").replace("+00:00", "Z") for i in stream_ids(api, frame_jobs[2])]
    assert shown == expected
    # ... and not the page's: every frame was done before the page was opened, so a replay
    # stamped with the time the page read it would be later than that.
    assert max(datetime.fromisoformat(t.replace("Z", "+00:00")) for t in shown) < opened

    # The log view is the API's log, line for line.
    log = api.get(f"/jobs/{frame_jobs[2]}/log").json()["lines"]
    wait(driver, attribute_is("log", "data-lines", str(len(log))), "the log view is not the job's log")
    assert driver.find_element(By.ID, "log").get_attribute("textContent").split("\n") == log
    driver.execute_script("document.getElementById('tasks-summary').scrollIntoView()")
    driver.save_screenshot(str(shots / "7-frame-tasks-events-log.png"))

    # The EXR download: the page fetches it with the token and saves it.
    driver.find_element(By.ID, "download-exr").click()
    exr = api.get(f"/jobs/{frame_jobs[2]}/image.exr").content
    wait(driver, attribute_is("download-exr", "data-bytes", str(len(exr))), "the EXR was not downloaded")


def test_failed_tile_blocklist_worker_actions_and_retry(farm, browser, shots, redis_server, tmp_path):
    """A worker that crashes on tile 1: after two failures the job blocklists it and the
    tile waits (the healthy worker is disabled); the admin's 'clear blocklist' lets it fail a
    third time, which fails the job, shown on the tile's row; then the admin disables the
    faulty worker, enables the healthy one and retries: the new job is done."""
    base, processes = farm
    root = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {ROOT_TOKEN}"}, timeout=60)
    alice = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60)
    # Only an admin changes workers.
    assert alice.post(f"/workers/{WORKER}/disable").status_code == 403
    assert alice.delete(f"/workers/{WORKER}/blocklist").status_code == 403
    assert root.post("/workers/nobody/disable").status_code == 404
    assert root.post(f"/workers/{WORKER}/disable").json()["disabled"] is True
    faulty = start_worker(redis_server, FAULTY, tmp_path, heartbeat_ttl=5.0, faults="segv:poison*.usda#1")
    every = [*processes, faulty]
    try:
        scene = tmp_path / "poison.usda"
        scene.write_bytes(CORNELL.read_bytes())
        with open(scene, "rb") as f:
            r = alice.post("/jobs", files={"file": (scene.name, f)},
                           data={**{k: str(v) for k, v in SMALL.items()}, "max_attempts": "3"})
        assert r.status_code == 201, r.text
        job = r.json()["id"]
        driver = browser
        sign_in(driver, base, ROOT_TOKEN)
        # The name filter finds it; the tile waits, queued, with two failed attempts.
        driver.find_element(By.ID, "filter-name").send_keys("poison")
        driver.find_element(By.ID, "filter-apply").click()
        wait(driver, lambda d: [r.get_attribute("data-job") for r in d.find_elements(
            By.CSS_SELECTOR, "#jobs tbody tr[data-job]")] == [job], "the name filter did not show only the job")
        driver.find_element(*job_row(job)).click()

        def tile1(d):
            rows = [r for r in task_rows(d) if r["index"] == 1]
            return rows[0] if rows else None
        wait(driver, lambda d: (t := tile1(d)) and t["state"] == "queued" and t["cells"][6] == "2",
             "tile 1 does not wait with two failed attempts", every)
        assert "SIGSEGV" in tile1(driver)["cells"][9]
        assert all(r["state"] == "done" for r in task_rows(driver) if r["index"] != 1)
        driver.find_element(By.CSS_SELECTOR, f'#workers tr[data-worker="{FAULTY}"] '
                                             f'button[data-action="clear blocklist"]').click()
        wait(driver, EC.text_to_be_present_in_element((By.ID, "worker-result"),
                                                      f"{FAULTY}: taken off the blocklist of 1 job"),
             "clearing the blocklist did not show", every)
        wait(driver, attribute_is("job-state", "data-state", "failed"), "the job did not fail", every)
        wait(driver, lambda d: (t := tile1(d)) and t["state"] == "failed" and t["cells"][6] == "3",
             "tile 1 is not shown failed after three attempts", every)
        assert "failed" in tile1(driver)["cls"]
        driver.execute_script("document.getElementById('tasks-summary').scrollIntoView()")
        driver.save_screenshot(str(shots / "8-failed-tile.png"))

        # Worker actions from the page, then retry.
        driver.find_element(By.CSS_SELECTOR, f'#workers tr[data-worker="{FAULTY}"] button[data-action="disable"]').click()
        wait(driver, lambda d: d.find_element(By.CSS_SELECTOR, f'#workers tr[data-worker="{FAULTY}"]')
             .get_attribute("data-disabled") == "true", "disabling did not show", every)
        driver.find_element(By.CSS_SELECTOR, f'#workers tr[data-worker="{WORKER}"] button[data-action="enable"]').click()
        wait(driver, lambda d: d.find_element(By.CSS_SELECTOR, f'#workers tr[data-worker="{WORKER}"]')
             .get_attribute("data-disabled") == "false", "enabling did not show", every)
        driver.find_element(By.ID, "retry").click()
        wait(driver, lambda d: d.find_element(By.ID, "control-result").get_attribute("data-retried"),
             "retry did not report a new job", every)
        retried = driver.find_element(By.ID, "control-result").get_attribute("data-retried")
        assert retried != job
        wait(driver, attribute_is("job-state", "data-state", "done"), "the retried job is not done", every)
        wait(driver, lambda d: [r["state"] for r in task_rows(d)] == ["done"] * 4, "its tiles are not done", every)
        assert {r["cells"][3] for r in task_rows(driver)} == {WORKER}
        wait(driver, attribute_is("preview", "data-state", "done"), "no final preview of the retried job", every)
        assert colourful(shown_pixels(driver, "preview")), "the retried job's preview is black or grey"
        assert alice.get(f"/jobs/{retried}").json()["owner"] == "alice"  # the job's owner, not root
        assert f"retried as job {retried}" in alice.get(f"/jobs/{job}/log").json()["lines"][-1]
        driver.save_screenshot(str(shots / "9-retried.png"))

        # Delete: the old job goes, with everything it kept.
        driver.find_element(*job_row(job)).click()
        wait(driver, attribute_is("job-state", "data-state", "failed"), "the old job is not selected")
        driver.find_element(By.ID, "delete").click()
        wait(driver, attribute_is("status", "data-deleted", job), "the delete did not report", every)
        assert alice.get(f"/jobs/{job}").status_code == 404
        wait(driver, lambda d: not d.find_elements(*job_row(job)), "the deleted job is still listed")
    finally:
        root.post(f"/workers/{WORKER}/enable")
        faulty.stop()
