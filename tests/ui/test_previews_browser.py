"""Issue 24, previews in the real browser: the camera keeps the whole body in frame (climbs,
jumps) on every page; the clip page shows and picks any span of a take of any length; its
keys. Screenshots go to ``test-artifacts/ui/``.

The takes are built from the real Bandai walk excerpt (tests/ui/takes.py), so these run
without ../shared; CMU's playground climb (01_02) runs too when ../shared is there.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

import httpx
import numpy as np
import pytest

from tests.conftest import shared_data_dir
from tests.ui.takes import bandai_take, climb, jump
from tests.ui.test_browser import browser, page, screenshot, serve  # noqa: F401 - fixtures

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def server(browser: Any, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:  # noqa: F811
    """This module's server (test_browser's `page` opens pages on it)."""
    with serve(tmp_path_factory.mktemp("previews")) as url:
        yield url


@pytest.fixture
def base(server: str) -> str:
    return server


def upload(base: str, name: str, data: bytes) -> dict[str, Any]:
    response = httpx.post(f"{base}/clips", files={"file": (name, data)}, timeout=120)
    assert response.status_code in (200, 201), response.text
    clip: dict[str, Any] = response.json()
    return clip


def head_heights(base: str, clip_id: int) -> np.ndarray:
    """The head's height (body heights) in every frame, from the API."""
    body = httpx.get(f"{base}/clips/{clip_id}/skeleton", params={"fps": 30}, timeout=60).json()
    frames = np.asarray(body["frames"])
    return np.asarray(frames[:, body["joints"].index("head"), 1])


def figure_index(page: Any, role: str, clip_id: int) -> int:  # noqa: F811
    figures = page.evaluate("() => window.__mocap.figures()")
    return next(i for i, f in enumerate(figures) if f["role"] == role and f["clipId"] == clip_id)


def wait_loaded(page: Any, role: str, clip_id: int) -> None:  # noqa: F811
    page.wait_for_function(
        "([role, id]) => window.__mocap.figures().some(f => f.role === role && f.clipId === id "
        "&& f.frameCount > 0 && f.points)",
        arg=[role, clip_id],
    )


def check_every_frame_inside(page: Any, role: str, clip_id: int) -> list[dict[str, Any]]:  # noqa: F811
    """Every frame the figure plays, drawn: the figure's box (joints, the head's disc, the
    lines) lies inside its canvas. Returns the frames."""
    index = figure_index(page, role, clip_id)
    frames: list[dict[str, Any]] = page.evaluate("(i) => window.__mocap.sweep(i)", index)
    state = page.evaluate("(i) => window.__mocap.figures()[i]", index)
    width, height = state["width"], state["height"]
    assert len(frames) > 10
    for frame in frames:
        box = frame["box"]
        assert box["top"] >= 0 and box["bottom"] <= height, (role, frame["time"], box, height)
        assert box["left"] >= 0 and box["right"] <= width, (role, frame["time"], box, width)
    return frames


def bottoms(frames: list[dict[str, Any]]) -> np.ndarray:
    return np.asarray([f["view"]["bottom"] for f in frames])


# -- 1: the camera follows height -----------------------------------------------------------


def test_a_climb_stays_in_frame_on_every_page(page: Any, base: str) -> None:  # noqa: F811
    clip = upload(base, "climb.bvh", climb())
    heads = head_heights(base, clip["id"])
    # A real climb: the head goes far above where a fixed camera showed it (1.26 body
    # heights above the floor was the top of the canvas).
    assert heads.max() > 2.5
    # The library card (the clip's first 20 s at 15 fps).
    page.goto("/")
    wait_loaded(page, "library", clip["id"])
    card = check_every_frame_inside(page, "library", clip["id"])
    # The search page's card, and the clip page's large figure (the whole take).
    page.goto(f"/#/search?clip={clip['id']}")
    wait_loaded(page, "query", clip["id"])
    check_every_frame_inside(page, "query", clip["id"])
    page.goto(f"/#/clips/{clip['id']}")
    wait_loaded(page, "clip", clip["id"])
    large = check_every_frame_inside(page, "clip", clip["id"])
    # The view rises with the body, smoothly: no jump between frames larger than the body's
    # own rise per frame, and no shaking (second differences stay tiny).
    for frames in (card, large):
        path = bottoms(frames)
        assert path[-1] - path[0] > 1.0
        step = np.abs(np.diff(path)).max()
        assert step < 0.05, step
        print("climb", step, np.abs(np.diff(path, 2)).max())
        assert np.abs(np.diff(path, 2)).max() < 0.01
    page.evaluate("() => window.__mocap.seek(7.5)")
    screenshot(page, "climb-clip-page")


def test_a_walk_keeps_its_floor_and_a_jump_is_followed(page: Any, base: str) -> None:  # noqa: F811
    walk = upload(base, "walk-take.bvh", bandai_take(4.0))
    hop = upload(base, "jump.bvh", jump())
    assert head_heights(base, hop["id"]).max() > 1.6  # above the old fixed camera's top
    page.goto(f"/#/search?clip={walk['id']}")
    wait_loaded(page, "query", walk["id"])
    # Nothing needs the camera to move: the floor stays where it always is.
    still = bottoms(check_every_frame_inside(page, "query", walk["id"]))
    assert np.ptp(still) == pytest.approx(0, abs=1e-9)
    page.goto(f"/#/clips/{hop['id']}")
    wait_loaded(page, "clip", hop["id"])
    frames = check_every_frame_inside(page, "clip", hop["id"])
    # A jump fits the view (the figure is drawn a little smaller) rather than the view
    # lurching up and down with it: the view moves slowly if at all.
    path = bottoms(frames)
    assert np.abs(np.diff(path)).max() < 0.03
    assert np.abs(np.diff(path, 2)).max() < 0.005
    scale = frames[0]["view"]["scale"]
    height = page.evaluate("() => window.__mocap.figures().find(f => f.role === 'clip').height")
    assert scale < height / 1.4  # smaller than a walk's figure on the same canvas
    page.evaluate("() => window.__mocap.seek(2.3)")
    screenshot(page, "jump-clip-page")


@pytest.mark.parametrize("role", ["library", "clip"])
def test_cmu_playground_climb_in_frame(page: Any, base: str, role: str) -> None:  # noqa: F811
    path = shared_data_dir() / "cmu" / "bvh-mb" / "01" / "01_02.bvh"
    if not path.is_file():
        pytest.skip(f"{path} not found (../shared/data/cmu)")
    clip = upload(base, path.name, path.read_bytes())
    assert head_heights(base, clip["id"]).max() > 1.5  # it climbs
    page.goto("/" if role == "library" else f"/#/clips/{clip['id']}")
    wait_loaded(page, role, clip["id"])
    check_every_frame_inside(page, role, clip["id"])


# -- 2 and 3: a 60-s take, any span of it; the keys ----------------------------------------------


def rail_x(page: Any, seconds: float) -> float:  # noqa: F811
    """Where the page's timeline puts `seconds` (CSS px from the viewport's left)."""
    box = page.locator(".timeline-rail").bounding_box()
    view = page.evaluate(
        "() => [...document.querySelectorAll('.timeline-scale span')].map(s => s.textContent)"
    )
    start, end = (seconds_of(v) for v in view)
    return float(box["x"] + (seconds - start) / (end - start) * box["width"])


def seconds_of(text: str) -> float:
    """ "45.00 s" -> 45.0; "1:00.00" -> 60.0."""
    text = text.replace(" s", "")
    if ":" in text:
        minutes, rest = text.split(":")
        return int(minutes) * 60 + float(rest)
    return float(text)


def test_a_span_after_40_s_of_a_60_s_take(page: Any, base: str) -> None:  # noqa: F811
    from playwright.sync_api import expect

    take = upload(base, "minute.bvh", bandai_take(60.0))
    assert take["duration"] == pytest.approx(60.0, abs=0.05)
    page.goto(f"/#/clips/{take['id']}")
    wait_loaded(page, "clip", take["id"])
    controls = page.get_by_role("group", name=f"Playback of {take['name']}")
    readout = controls.locator("output")
    expect(readout).to_contain_text("/ 1:00.00")  # the whole take, not its first 20 s
    # The overview holds the whole take at a rate that fits 600 frames.
    state = page.evaluate("() => window.__mocap.figures().find(f => f.role === 'clip')")
    assert state["frameCount"] <= 600 and state["fps"] * 60 == pytest.approx(599, abs=1)

    # Keys: pause, go to 42 s a second at a time, zoom in twice around the playhead.
    rail = controls.get_by_role("slider", name="Time")
    rail.focus()
    page.keyboard.press("Space")
    expect(controls.get_by_role("button", name="Play")).to_be_visible()
    page.keyboard.press("Home")
    for _ in range(42):
        page.keyboard.press("Shift+ArrowRight")
    expect(readout).to_contain_text("frame 1261 / 1800 · 42.00 s")
    page.keyboard.press("+")
    page.keyboard.press("+")
    scale = page.locator(".timeline-scale span")
    expect(scale.first).not_to_have_text("0.00 s")
    start, end = (seconds_of(t) for t in scale.all_inner_texts())
    assert end - start == pytest.approx(15, abs=0.1) and start < 42 < end

    # The span band has the rail's box, to the pixel; the thumb sits at the playhead's x.
    band = page.locator(".span-band").bounding_box()
    rail_box = rail.bounding_box()
    assert band["x"] == pytest.approx(rail_box["x"], abs=0.5)
    assert band["width"] == pytest.approx(rail_box["width"], abs=0.5)
    thumb = page.locator(".timeline-thumb").bounding_box()
    assert thumb["x"] + thumb["width"] / 2 == pytest.approx(rail_x(page, 42), abs=1)

    # Drag 43 s to 46 s on the band.
    y = band["y"] + band["height"] / 2
    page.mouse.move(rail_x(page, 43), y)
    page.mouse.down()
    page.mouse.move(rail_x(page, 44.5), y, steps=3)
    page.mouse.move(rail_x(page, 46), y, steps=3)
    page.mouse.up()
    span_from = float(page.get_by_label("From (s)").input_value())
    span_to = float(page.get_by_label("To (s)").input_value())
    per_pixel = 15 / rail_box["width"]
    assert span_from == pytest.approx(43, abs=2 * per_pixel)
    assert span_to == pytest.approx(46, abs=2 * per_pixel)
    box = page.locator(".span-box").bounding_box()
    assert box["x"] == pytest.approx(rail_x(page, span_from), abs=1)
    assert box["x"] + box["width"] == pytest.approx(rail_x(page, span_to), abs=1)

    # Previewed: the figure plays the span, looping, from frames fetched at the file's rate.
    expect(page.get_by_label("Play only the span")).to_be_checked()
    page.wait_for_function(
        "() => window.__mocap.figures().some(f => f.role === 'clip' && f.source === 'detail')"
    )
    seen = set()
    for _ in range(20):
        state = page.evaluate("() => window.__mocap.figures().find(f => f.role === 'clip')")
        seen.add((state["frame"], state["source"]))
        page.wait_for_timeout(100)
    frames = sorted(f for f, _ in seen)
    assert len(frames) > 5
    assert span_from * 30 - 1 <= frames[0] and frames[-1] <= span_to * 30 + 1
    assert any(source == "detail" for _, source in seen)
    screenshot(page, "long-take-span")

    # And the span is what moments are searched for.
    page.get_by_role("button", name="Find moments like this span").click()
    expect(page).to_have_url(re.compile(rf"clip={take['id']}.*start=4[23]"))
    expect(page.locator("main .status")).to_contain_text("Moments like")


def test_clip_page_keys(page: Any, base: str) -> None:  # noqa: F811
    from playwright.sync_api import expect

    take = upload(base, "keys.bvh", bandai_take(6.0))
    page.goto(f"/#/clips/{take['id']}")
    wait_loaded(page, "clip", take["id"])
    controls = page.get_by_role("group", name=f"Playback of {take['name']}")
    readout = controls.locator("output")
    page.locator("h1").click()  # the keys work wherever the focus is (but text boxes)
    page.keyboard.press("Space")
    expect(controls.get_by_role("button", name="Play")).to_have_attribute("aria-pressed", "false")
    page.keyboard.press("Space")
    expect(controls.get_by_role("button", name="Pause")).to_have_attribute("aria-pressed", "true")
    page.keyboard.press("Space")
    page.keyboard.press("Home")
    expect(readout).to_contain_text("frame 1 / 180 · 0.00 s")
    page.keyboard.press("ArrowRight")
    expect(readout).to_contain_text("frame 2 / 180")
    page.keyboard.press("Shift+ArrowRight")
    expect(readout).to_contain_text("frame 32 / 180")
    page.keyboard.press("ArrowLeft")
    expect(readout).to_contain_text("frame 31 / 180 · 1.00 s")
    page.keyboard.press("[")
    expect(page.get_by_label("From (s)")).to_have_value("1")
    page.keyboard.press("Shift+ArrowRight")
    page.keyboard.press("Shift+ArrowRight")
    page.keyboard.press("]")
    expect(page.get_by_label("To (s)")).to_have_value("3")
    expect(page.locator(".span-box")).to_be_visible()
    page.keyboard.press("End")
    expect(readout).to_contain_text("frame 180 / 180")
    page.keyboard.press("Shift+ArrowLeft")
    expect(readout).to_contain_text("frame 150 / 180")
    # Typing in a text box types: "[" goes into the name, the span stays.
    name = page.get_by_label("Name", exact=True)
    name.fill("")
    name.press("[")
    name.press("Space")
    expect(name).to_have_value("[ ")
    expect(page.get_by_label("From (s)")).to_have_value("1")
    expect(readout).to_contain_text("frame 150 / 180")
