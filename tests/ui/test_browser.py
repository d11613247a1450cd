"""End-to-end: the web UI in a real headless chromium against a real uvicorn server.

Debian's chromium is driven by Playwright's Python package used only as a driver
(``executable_path``; ``playwright install`` is never run): ``scripts/install_browser.sh``
installs both. The tests skip, saying why, when the browser, the driver or ``../shared/data``
is missing — unless ``MOCAP_REQUIRE_BROWSER=1`` (CI), where a missing browser fails them.
Screenshots of every page go to ``test-artifacts/ui/``.
"""

from __future__ import annotations

import base64
import math
import os
import re
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from app.motion.body import build_body
from app.motion.display import display_positions
from app.motion.formats import read_bvh
from tests.conftest import FIXTURES_DIR, REPO_ROOT, shared_data_dir

pytestmark = pytest.mark.slow

ARTIFACTS = REPO_ROOT / "test-artifacts" / "ui"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
# One capture in two formats: the BVH conversion and the original ASF/AMC are each other's
# nearest neighbours.
BVH = Path("cmu/bvh-mb/02/02_01.bvh")
ASF, AMC = Path("cmu/asf-amc/02/02.asf"), Path("cmu/asf-amc/02/02_01.amc")
TIMEOUT_MS = 20_000
START_SECONDS = 90  # for a UI server to answer /health


def _missing(reason: str) -> None:
    if os.environ.get("MOCAP_REQUIRE_BROWSER") == "1":
        pytest.fail(f"{reason} (MOCAP_REQUIRE_BROWSER=1: the browser tests must run)")
    pytest.skip(reason)


def chromium_path() -> str | None:
    for candidate in (os.environ.get("MOCAP_CHROMIUM"), "/usr/bin/chromium"):
        if candidate and Path(candidate).is_file():
            return candidate
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def data_files() -> dict[str, Path]:
    root = shared_data_dir()
    files = {"bvh": root / BVH, "asf": root / ASF, "amc": root / AMC}
    missing = [str(p) for p in files.values() if not p.is_file()]
    if missing:
        pytest.skip(f"real motion data not found: {', '.join(missing)} (set MOCAP_SHARED_DATA)")
    return files


@contextmanager
def serve(data_dir: Path, **env_vars: str) -> Iterator[str]:
    """A real uvicorn on 127.0.0.1 with a free port on ``data_dir``; yields its base URL."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
    env.update(MOCAP_DATA_DIR=str(data_dir), PYTHONPATH=str(REPO_ROOT), **env_vars)
    log_path = data_dir / "server.log"
    log = log_path.open("wb")
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "uvicorn",
            "--factory",
            "tests.ui.serve:create_ui_app",
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--log-level",
            "warning",
        ],
        cwd=REPO_ROOT,
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    base = f"http://127.0.0.1:{port}"
    try:
        # Starting is importing the app and opening the library: ~5 s on a quiet machine,
        # over 30 s with the machine's two cores shared by a dozen processes. Not a verdict
        # on the service (its start-up is measured under bench/).
        deadline = time.monotonic() + START_SECONDS
        while True:
            if process.poll() is not None:
                log.flush()
                pytest.fail(f"the server exited: {log_path.read_text()[-2000:]}")
            try:
                if httpx.get(f"{base}/health", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                pytest.fail(f"the server did not answer /health within {START_SECONDS} s")
            time.sleep(0.2)
        yield base
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        log.close()


@pytest.fixture(scope="module")
def server(browser: Any, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The server of the tests below, on a fresh data dir, open to everyone."""
    with serve(tmp_path_factory.mktemp("ui-data")) as base:
        yield base


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        _missing("the Playwright Python driver is not installed (run scripts/install_browser.sh)")
    executable = chromium_path()
    if executable is None:
        _missing("chromium is not installed (run scripts/install_browser.sh)")
    with sync_playwright() as playwright:
        instance = playwright.chromium.launch(
            executable_path=executable, headless=True, args=CHROMIUM_ARGS
        )
        try:
            yield instance
        finally:
            instance.close()


@pytest.fixture
def page(browser: Any, server: str) -> Iterator[Any]:
    context = browser.new_context(viewport={"width": 1280, "height": 900}, base_url=server)
    context.set_default_timeout(TIMEOUT_MS)
    page = context.new_page()
    problems = watch_problems(page)
    yield page
    context.close()
    assert not problems, problems


def watch_problems(page: Any) -> list[str]:
    """The page's script errors and console errors (4xx answers are expected), as they come."""
    problems: list[str] = []
    page.on("pageerror", lambda error: problems.append(f"page error: {error}"))
    page.on(
        "console",
        lambda message: (
            problems.append(f"console {message.type}: {message.text}")
            if message.type == "error" and "status of 4" not in message.text
            else None
        ),
    )
    return problems


def screenshot(page: Any, name: str) -> None:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / f"{name}.png"), full_page=True)


def screenshot_of(locator: Any, name: str) -> None:
    """One element (a dialog, say) as it is shown."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    locator.screenshot(path=str(ARTIFACTS / f"{name}.png"))


def upload_row(page: Any, name: str) -> Any:
    return page.locator(f'.upload[data-name="{name}"]')


def test_upload_search_and_map(
    page: Any, server: str, data_files: dict[str, Path], tmp_path: Path
) -> None:
    from playwright.sync_api import expect

    page.goto("/")
    expect(page.locator("nav a[aria-current=page]")).to_have_text("Library")
    expect(page.locator("main .status")).not_to_have_text("Loading…")

    # Upload: two real files (a BVH, and an ASF+AMC pair) and a broken one, in one go.
    page.get_by_role("link", name="Upload", exact=True).click()
    expect(page).to_have_title("Upload · mocap-index")
    broken = tmp_path / "broken.bvh"
    broken.write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 x\n")
    page.get_by_label("Labels for these clips (comma-separated)").fill("walk, cmu")
    page.set_input_files(
        "input[type=file]",
        [str(data_files["bvh"]), str(data_files["asf"]), str(data_files["amc"]), str(broken)],
    )
    bvh_row = upload_row(page, "02_01.bvh")
    amc_row = upload_row(page, "02_01.amc + 02.asf")
    expect(bvh_row).to_have_attribute("data-state", "done")
    expect(amc_row).to_have_attribute("data-state", "done")
    expect(bvh_row).to_contain_text("stored as clip #")
    # The service's own message, next to the file that caused it.
    broken_row = upload_row(page, "broken.bvh")
    expect(broken_row).to_have_attribute("data-state", "error")
    expect(broken_row.locator(".upload-message")).to_contain_text("parse error:")
    expect(broken_row.locator(".upload-message")).to_contain_text("'broken.bvh'")
    expect(page.locator("main .status")).to_have_text("2 clips stored, 1 failed.")
    bvh_id = int(bvh_row.get_attribute("data-clip-id"))
    amc_id = int(amc_row.get_attribute("data-clip-id"))
    screenshot(page, "upload")

    # Search from the BVH clip: its ASF/AMC twin is among (first in) the results.
    bvh_row.get_by_role("link", name="find similar").click()
    expect(page).to_have_title("Search · mocap-index")
    query = page.locator(".card.query")
    expect(query).to_have_attribute("data-clip-id", str(bvh_id))
    results = page.locator(".card.result")
    # One result per capture (the UI's default): the twin stands beside the query, not as a
    # result; switched off, it is the one result.
    others = query.locator("details.others")
    expect(others.locator("summary")).to_have_text(
        "+1 other file of this capture, left out of the results"
    )
    expect(results).to_have_count(0)
    expect(page.locator("main .status")).to_contain_text("only other files of this capture")
    page.get_by_label("One result per capture").uncheck()
    page.get_by_role("button", name="Search", exact=True).click()
    expect(page).to_have_url(re.compile("collapse=off"))
    expect(results).to_have_count(1)
    expect(results.first).to_have_attribute("data-clip-id", str(amc_id))
    expect(results.first.locator(".distance-value")).to_have_text(re.compile(r"^\d+\.\d{4}$"))
    page.wait_for_function(
        "() => window.__mocap.figures().filter(f => f.frameCount > 0).length === 2"
    )
    screenshot(page, "search")

    # Click the result: search from it (the BVH clip is now the result).
    results.first.locator("canvas").click()
    expect(query).to_have_attribute("data-clip-id", str(amc_id))
    expect(results.first).to_have_attribute("data-clip-id", str(bvh_id))
    # Another descriptor through the form.
    page.get_by_label("Descriptor").select_option("kinetic")
    page.get_by_role("button", name="Search", exact=True).click()
    expect(page).to_have_url(re.compile("descriptor=kinetic"))
    expect(results.first).to_have_attribute("data-clip-id", str(bvh_id))
    # A file as the query: the same BVH bytes are found at distance 0, then the twin.
    page.locator("form.search-form input[type=file]").set_input_files(str(data_files["bvh"]))
    expect(query).to_have_attribute("data-clip-id", "")
    expect(page.locator("main .status")).to_contain_text("nearest to the file 02_01.bvh")
    expect(results).to_have_count(2)
    expect(results.first).to_have_attribute("data-clip-id", str(bvh_id))
    expect(results.first.locator(".distance-value")).to_have_text("0.0000")
    expect(results.nth(1)).to_have_attribute("data-clip-id", str(amc_id))
    page.wait_for_function(
        "() => window.__mocap.figures().some(f => f.role === 'query' && f.frameCount > 0)"
    )

    # Map: both clips, coloured by label; focusing it previews a clip, Enter searches.
    page.get_by_role("link", name="Map", exact=True).click()
    canvas = page.locator("canvas.map-canvas")
    expect(canvas).to_have_attribute("data-points", "2")
    expect(page.locator(".legend")).to_contain_text("walk (2)")
    canvas.focus()
    tooltip = page.locator(".map-tooltip")
    expect(tooltip).to_be_visible()
    expect(tooltip).to_contain_text("02_01")
    page.wait_for_function(
        "() => window.__mocap.figures().some(f => f.role === 'map' && f.frameCount > 0)"
    )
    screenshot(page, "map")
    page.keyboard.press("Enter")
    expect(page).to_have_title("Search · mocap-index")
    # One result per capture again (a new search from the map): the twin beside the query.
    expect(query.locator("details.others")).to_have_count(1)
    expect(results).to_have_count(0)

    # Library: both clips with moving previews; the name filter.
    page.get_by_role("link", name="Library", exact=True).click()
    cards = page.locator(".cards .card")
    expect(cards).to_have_count(2)
    page.wait_for_function(
        "() => [...document.querySelectorAll('.cards canvas')].every(c => c.dataset.frame)"
    )
    expect(page.locator("main .status")).to_have_text("Showing 1–2 of 2 clips.")
    screenshot(page, "library")
    page.get_by_label("Find", exact=True).fill("nothing like it")
    expect(cards).to_have_count(0)
    expect(page.locator("main .status")).to_have_text("No clip matches these filters.")


def test_a_gltf_dropped_with_its_bin_and_texture_is_one_clip(page: Any, tmp_path: Path) -> None:
    from playwright.sync_api import expect

    from tests.api.test_scene_uploads import separate_gltf

    vrma = (FIXTURES_DIR / "three_vrm_test.vrma").read_bytes()
    document, binary = separate_gltf(vrma, "anim.bin")
    files = {"anim.gltf": document, "anim.bin": binary, "skin.png": b"not read"}
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    (tmp_path / "alone").mkdir()
    (tmp_path / "alone" / "stray.bin").write_bytes(binary)
    page.goto("/#/upload")
    expect(page).to_have_title("Upload · mocap-index")
    page.set_input_files("input[type=file]", [str(tmp_path / name) for name in files])
    row = upload_row(page, "anim.gltf")
    # Read first in a parser worker (listing its animations), which may have to start.
    expect(row).to_have_attribute("data-state", "done", timeout=3 * TIMEOUT_MS)
    expect(row).to_contain_text("stored as clip #")
    # The buffer and the texture went with it: no rows of their own.
    expect(page.locator(".upload")).to_have_count(1)
    # A buffer dropped without its document is said to belong with one.
    page.set_input_files("input[type=file]", [str(tmp_path / "alone" / "stray.bin")])
    stray = upload_row(page, "stray.bin")
    expect(stray).to_have_attribute("data-state", "error")
    expect(stray).to_contain_text("drop it together with its .gltf file")


def test_stick_figure_matches_the_api_joint_positions(
    page: Any, server: str, data_files: dict[str, Path]
) -> None:
    """The query figure of a known CMU clip, paused on a frame, is drawn where the API's
    joint positions for that frame project to — and those are the motion core's."""
    path = data_files["bvh"]
    response = httpx.post(
        f"{server}/clips", files={"file": (path.name, path.read_bytes())}, timeout=60
    )
    assert response.status_code in (200, 201), response.text
    clip_id = response.json()["id"]
    api = httpx.get(f"{server}/clips/{clip_id}/skeleton", params={"fps": 30}, timeout=60).json()
    compact = httpx.get(
        f"{server}/clips/{clip_id}/skeleton", params={"fps": 30, "encoding": "compact"}, timeout=60
    ).json()

    page.goto(f"/#/search?clip={clip_id}")
    page.wait_for_function(
        "() => window.__mocap.figures().some(f => f.role === 'query' && f.frameCount > 0)"
    )
    frame = 40
    page.evaluate(f"() => window.__mocap.seek({(frame + 0.5) / 30})")
    state = next(f for f in page.evaluate("() => window.__mocap.figures()") if f["role"] == "query")
    assert state["clipId"] == clip_id and state["frame"] == frame
    assert state["frameCount"] == api["frame_count"] and state["fps"] == 30

    # The page draws the compact encoding's numbers (float32 pelvis + int16 offsets), which
    # are the JSON's to 1e-4 body heights.
    joints = decode_compact(compact)[frame]
    np.testing.assert_allclose(joints, api["frames"][frame], atol=1.5e-4)
    centre = api["joints"].index(state["centreJoint"])
    want = project(joints, state["width"], state["height"], state["camera"], state["view"], centre)
    np.testing.assert_allclose(np.asarray(state["points"]), want, atol=1e-3)
    joints = api["frames"][frame]

    # The API's positions are the motion core's (in body heights, display frame).
    core = build_body(read_bvh(path.read_bytes()))
    np.testing.assert_allclose(joints, display_positions(core)[frame * 4], atol=2e-3)

    # A person, upright: head above the feet on screen, the followed pelvis centred.
    index = {name: i for i, name in enumerate(api["joints"])}
    points = np.asarray(state["points"])
    assert points[index["head"], 1] < points[index["l_ankle"], 1]
    assert points[index["head"], 1] < points[index["r_ankle"], 1]
    assert points[index["pelvis"], 0] == pytest.approx(state["width"] / 2)

    # And the pixels: the left thigh and upper arm (drawn last, blue) are on the canvas.
    for a, b in (("l_hip", "l_knee"), ("l_shoulder", "l_elbow")):
        u, v = (points[index[a]] + points[index[b]]) / 2
        rgb = page.evaluate(
            """([u, v]) => {
              const c = document.querySelector('.card.query canvas');
              const r = window.devicePixelRatio || 1;
              const x = Math.round(u * r) - 1, y = Math.round(v * r) - 1;
              const d = c.getContext('2d').getImageData(x, y, 3, 3).data;
              let best = [0, 0, 0], score = -1;
              for (let i = 0; i < d.length; i += 4) {
                const s = d[i+3] * (d[i+2] - d[i]);
                if (s > score) { score = s; best = [d[i], d[i+1], d[i+2], d[i+3]]; }
              }
              return best;
            }""",
            [float(u), float(v)],
        )
        assert rgb[3] > 200 and math.dist(rgb[:3], (31, 111, 235)) < 60, (a, b, rgb)
    screenshot(page, "stick-figure")


def project(
    joints: Any,
    width: float,
    height: float,
    camera: dict[str, float],
    view: dict[str, float],
    centre: int,
) -> np.ndarray:
    """The page's projection (figure.js projectFrame), written again from its definition:
    an orthographic camera turned by yaw about the vertical, looking down by pitch,
    following the centre joint over the floor; `view` gives its scale (px per body height)
    and the height (body heights, on the screen) at the canvas's bottom edge."""
    p = np.asarray(joints, dtype=float)
    dx = p[:, 0] - p[centre, 0]
    dz = p[:, 2] - p[centre, 2]
    across = dx * math.cos(camera["yaw"]) + dz * math.sin(camera["yaw"])
    depth = -dx * math.sin(camera["yaw"]) + dz * math.cos(camera["yaw"])
    up = p[:, 1] * math.cos(camera["pitch"]) - depth * math.sin(camera["pitch"])
    scale = view["scale"]
    return np.stack([width / 2 + across * scale, height - (up - view["bottom"]) * scale], 1)


def decode_compact(body: dict[str, Any]) -> np.ndarray:
    """``(F, C, 3)`` float32 positions of a ``compact`` skeleton response, as the page has
    them."""
    count, joints = body["frame_count"], len(body["joints"])
    root = np.frombuffer(base64.b64decode(body["root"]), "<f4").reshape(count, 1, 3)
    offsets = np.frombuffer(base64.b64decode(body["offsets"]), "<i2").reshape(count, joints, 3)
    return np.asarray(root.astype(np.float64) + offsets * body["offset_unit"], dtype=np.float32)


def test_the_page_asks_for_the_api_key(browser: Any, tmp_path: Path) -> None:
    """With MOCAP_REQUIRE_KEY_FOR_READS the page still loads, asks for the key, and works
    once it has the right one."""
    from playwright.sync_api import expect

    key = "correct horse battery staple"
    with serve(tmp_path, MOCAP_API_KEY=key, MOCAP_REQUIRE_KEY_FOR_READS="true") as base:
        context = browser.new_context(viewport={"width": 1280, "height": 700}, base_url=base)
        context.set_default_timeout(TIMEOUT_MS)
        try:
            page = context.new_page()
            page.goto("/")
            alert = page.get_by_role("alert")
            expect(alert).to_contain_text("The service needs an API key")
            page.get_by_label("API key").fill("wrong")
            page.get_by_role("button", name="Use this key").click()
            expect(alert).to_contain_text("The API key was refused")
            page.get_by_label("API key").fill(key)
            page.get_by_role("button", name="Use this key").click()
            expect(alert).to_be_hidden()
            expect(page.locator("main .status")).to_have_text(
                "The library is empty: upload some clips."
            )
            screenshot(page, "api-key")
        finally:
            context.close()
