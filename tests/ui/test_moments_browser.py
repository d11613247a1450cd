"""Moments in the browser: the search page's "moments" switch shows spans with timelines,
plays only those spans, offers the cut file, and a click searches from a moment."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import httpx

from tests.api.test_moments import long_take
from tests.motion.conftest import BANDAI_FIXTURE, fixture_bytes
from tests.ui.test_browser import TIMEOUT_MS, browser, page, serve, server  # noqa: F401 - fixtures


def test_moment_search_shows_timelines_and_plays_spans(page: Any, server: str) -> None:  # noqa: F811
    from playwright.sync_api import expect

    with httpx.Client(base_url=server, timeout=60) as client:
        take = client.post("/clips", files={"file": ("take.bvh", long_take())}).json()["id"]
        walk = client.post("/clips", files={"file": ("walk.bvh", fixture_bytes(BANDAI_FIXTURE))})
        assert walk.status_code in (200, 201)

    page.goto(f"/#/search?clip={take}&mode=moments&start=0&end=1.3")
    expect(page.locator("main .status")).to_contain_text("Moments like")
    expect(page.get_by_label("moments")).to_be_checked()
    moments = page.locator(".card.moment")
    expect(moments.first).to_be_visible()
    assert moments.count() >= 2  # the walk excerpt and the take's own third part
    first = moments.first
    expect(first.locator(".timeline-span")).to_be_visible()
    expect(first.locator(".span-text")).to_contain_text(" of ")
    href = first.locator("a.download").get_attribute("href")
    assert href is not None and "start=" in href and "end=" in href
    cut = httpx.get(server + href, timeout=30)
    assert cut.status_code == 200 and b"MOTION" in cut.content
    # The figure plays only its span: every frame drawn lies within the moment's frames
    # (the preview is at 30 fps here, these clips have no lead-in).
    moment = httpx.get(f"{server}/search/moments", params={"clip": take, "start": 0, "end": 1.3})
    top = moment.json()["results"][0]
    canvas = first.locator("canvas")
    seen = set()
    for _ in range(15):
        frame = canvas.get_attribute("data-frame")
        if frame is not None:
            seen.add(int(frame))
        page.wait_for_timeout(100)
    assert len(seen) > 2, seen
    assert int(top["start"] * 30) - 1 <= min(seen) and max(seen) <= int(top["end"] * 30) + 1
    # Clicking a moment searches from it.
    canvas.click()
    expect(page).to_have_url(re.compile(r"mode=moments"))
    expect(page).to_have_url(re.compile(rf"clip={top['id']}.*start="))
    expect(page.locator("main .status")).to_contain_text("Moments like")


def test_dragging_a_span_on_the_clip_page_searches_moments_like_it(
    page: Any,  # noqa: F811
    server: str,  # noqa: F811
) -> None:
    from playwright.sync_api import expect

    with httpx.Client(base_url=server, timeout=60) as client:
        take = client.post("/clips", files={"file": ("take.bvh", long_take())}).json()
        walk = client.post("/clips", files={"file": ("walk.bvh", fixture_bytes(BANDAI_FIXTURE))})
        assert walk.status_code in (200, 201)

    page.goto(f"/#/clips/{take['id']}")
    band = page.locator(".span-band")
    expect(band).to_be_visible()
    expect(page.locator(".clip-preview .clock")).to_contain_text(" / ")  # preview loaded
    # Drag from the first third of the band back to its start: 0 s to about 1.3 s of the
    # 4-s take (its first pass over the walk, which is found again in its third part).
    box = band.bounding_box()
    assert box is not None
    y = box["y"] + box["height"] / 2
    page.mouse.move(box["x"] + box["width"] / 3, y)
    page.mouse.down()
    page.mouse.move(box["x"] + box["width"] / 6, y, steps=4)
    page.mouse.move(box["x"] - 5, y, steps=4)
    page.mouse.up()
    expect(page.locator(".span-box")).to_be_visible()
    start = float(page.get_by_label("From (s)").input_value())
    end = float(page.get_by_label("To (s)").input_value())
    duration = take["duration"]
    assert start == 0 and abs(end - duration / 3) < 0.15, (start, end)
    page.get_by_role("button", name="Find moments like this span").click()
    expect(page).to_have_url(re.compile(rf"clip={take['id']}.*mode=moments|mode=moments.*clip="))
    expect(page.get_by_label("moments")).to_be_checked()
    expect(page.locator("main .status")).to_contain_text("Moments like")
    assert page.locator(".card.moment").count() >= 1
    # Typed times work too; an empty span is refused on the page.
    page.goto(f"/#/clips/{take['id']}")
    page.get_by_label("From (s)").fill("2")
    page.get_by_label("To (s)").fill("1")
    page.get_by_role("button", name="Find moments like this span").click()
    expect(page.locator(".clip-actions .status")).to_contain_text("end must come after")


def test_the_moment_download_sends_the_api_key(browser: Any, tmp_path: Path) -> None:  # noqa: F811
    """With MOCAP_REQUIRE_KEY_FOR_HEAVY a cut needs the key: the Download link fetches the
    file with the key the page holds (a plain link would get 401)."""
    from playwright.sync_api import expect

    key = "moments-key-3b9"
    env = {"MOCAP_API_KEY": key, "MOCAP_REQUIRE_KEY_FOR_HEAVY": "true"}
    with serve(tmp_path, **env) as base:
        with httpx.Client(base_url=base, headers={"X-API-Key": key}, timeout=60) as client:
            take = client.post("/clips", files={"file": ("take.bvh", long_take())}).json()["id"]
            walk = client.post(
                "/clips", files={"file": ("walk.bvh", fixture_bytes(BANDAI_FIXTURE))}
            )
            assert walk.status_code in (200, 201)
        context = browser.new_context(base_url=base, accept_downloads=True)
        context.set_default_timeout(TIMEOUT_MS)
        try:
            page = context.new_page()
            page.goto("/")
            page.evaluate("key => sessionStorage.setItem('mocap-index.api-key', key)", key)
            page.goto(f"/#/search?clip={take}&mode=moments&start=0&end=1.3")
            expect(page.locator("main .status")).to_contain_text("Moments like")
            link = page.locator(".card.moment").first.locator("a.download")
            with page.expect_download() as got:
                link.click()
            saved = got.value.path()
            assert Path(saved).read_bytes().startswith(b"HIERARCHY"), Path(saved).read_bytes()[:200]
            expect(page.locator("main .status")).to_contain_text("Downloaded")
        finally:
            context.close()
