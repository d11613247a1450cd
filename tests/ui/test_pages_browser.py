"""Issue 24 in the real browser, page by page: every page fits a 360-px phone; search
previews come compressed and compact and fill progressively; moments say they use `motion`;
choosing the animation of a multi-animation file (Upload and Search); the Upload summary
tells new clips from those already stored; errors look like errors; the map's axes and
colours. Screenshots of every page at desktop and phone widths go to ``test-artifacts/ui/``.

Everything here is built from tests/fixtures: it runs without ../shared.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from app.motion.formats import read_bvh
from tests.conftest import FIXTURES_DIR
from tests.motion.gltf_builder import two_animation_glb
from tests.ui.takes import bandai_take, climb
from tests.ui.test_browser import browser, screenshot, serve  # noqa: F401 - fixtures
from tests.ui.test_everyday_ui import browsing, drop_files

pytestmark = pytest.mark.slow

PHONE = {"width": 360, "height": 740}
DESKTOP = {"width": 1280, "height": 900}
CMU_BVH = FIXTURES_DIR / "cmu_mb_02_01_first41.bvh"
CMU_ASF, CMU_AMC = FIXTURES_DIR / "cmu_02.asf", FIXTURES_DIR / "cmu_02_01_first40.amc"
BANDAI = FIXTURES_DIR / "bandai_walk_normal_001_first40.bvh"
# Okabe and Ito's colours and two of Paul Tol's (app/static/util.js).
COLOUR_BLIND_SAFE = {
    "#0072B2", "#E69F00", "#009E73", "#CC79A7", "#56B4E9",
    "#D55E00", "#000000", "#F0E442", "#882255", "#999933",
}  # fmt: skip


def glb() -> tuple[str, bytes]:
    return ("walk.glb", two_animation_glb(read_bvh(CMU_BVH.read_bytes())))


def upload(base: str, files: dict[str, tuple[str, bytes]], **data: Any) -> dict[str, Any]:
    response = httpx.post(f"{base}/clips", files=files, data=data, timeout=120)
    assert response.status_code in (200, 201), response.text
    clip: dict[str, Any] = response.json()
    return clip


@pytest.fixture(scope="module")
def library(browser: Any, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:  # noqa: F811
    """A server with a small library: CMU 02_01 as BVH and ASF/AMC, the Bandai walk, a 30-s
    take, a climb, each labelled."""
    with serve(tmp_path_factory.mktemp("pages")) as base:
        clips = {
            "bvh": upload(base, {"file": (CMU_BVH.name, CMU_BVH.read_bytes())}, labels="walk"),
            "amc": upload(
                base,
                {
                    "skeleton": (CMU_ASF.name, CMU_ASF.read_bytes()),
                    "motion": (CMU_AMC.name, CMU_AMC.read_bytes()),
                },
                labels="walk",
            ),
            "bandai": upload(base, {"file": (BANDAI.name, BANDAI.read_bytes())}, labels="walk"),
            "take": upload(base, {"file": ("take.bvh", bandai_take(30.0))}, labels="take"),
            "climb": upload(base, {"file": ("climb.bvh", climb())}, labels="climb"),
        }
        # A rig for the Rigs page: the BVH clip's skeleton.
        rig = httpx.post(f"{base}/rigs", params={"from_clip": clips["bvh"]["id"]}, timeout=60)
        assert rig.status_code == 201, rig.text
        yield {"base": base, **clips}


def no_sideways_scroll(page: Any, what: str) -> None:
    widths = page.evaluate(
        "() => [document.documentElement.scrollWidth, document.body.scrollWidth, innerWidth]"
    )
    assert widths[0] <= widths[2] and widths[1] <= widths[2], (what, widths)


def figures_drawn(page: Any) -> None:
    page.wait_for_function(
        "() => window.__mocap.figures().length > 0 && "
        "window.__mocap.figures().every(f => f.frameCount > 0 || f.error)"
    )


# -- 4: every page on a phone (and on a desktop, for the screenshots) --------------------------


@pytest.mark.parametrize("width", ["phone", "desktop"])
def test_every_page_fits_the_screen(browser: Any, library: dict[str, Any], width: str) -> None:  # noqa: F811
    from playwright.sync_api import expect

    base = library["base"]
    viewport = PHONE if width == "phone" else DESKTOP
    take = library["take"]["id"]
    pages = {
        "library": ("/#/library", ".cards .card"),
        "search": (f"/#/search?clip={library['bvh']['id']}", ".card.result"),
        "moments": (f"/#/search?clip={take}&mode=moments&start=1&end=3", ".card.moment"),
        "map": ("/#/map", "canvas.map-canvas[data-points]"),
        "clip": (f"/#/clips/{take}", ".span-band"),
        "upload": ("/#/upload", ".dropzone"),
        "rigs": ("/#/rigs", ".rig-card canvas"),
    }
    with browsing(browser, base, viewport) as page:
        for name, (url, ready) in pages.items():
            page.goto(url)
            expect(page.locator(ready).first).to_be_visible()
            if name in ("library", "search", "moments", "clip"):
                figures_drawn(page)
            if name == "upload":  # with rows: a stored file, an error, a choice of animations
                files = [("broken.bvh", b"HIERARCHY"), (BANDAI.name, BANDAI.read_bytes()), glb()]
                page.set_input_files(
                    "input[type=file]",
                    files=[
                        {"name": n, "mimeType": "application/octet-stream", "buffer": b}
                        for n, b in files
                    ],
                )
                expect(page.locator(".animation-choice")).to_be_visible()
                expect(page.locator('.upload[data-state="error"]')).to_have_count(1)
            if name == "rigs":  # drawn, its mapping unfolded
                page.wait_for_function("() => window.__mocap.rigs().length === 1")
                page.locator(".rig-card summary").first.click()
                # A BVH's unit the service gives as a scale in metres reads in centimetres.
                units = httpx.get(f"{base}/rigs").json()["items"][0]["units"]
                if units.endswith(" m") and units != "1 m":
                    cm = f"{float(units[:-2]) * 100:.3g}"
                    expect(page.locator(".rig-card .format-line")).to_contain_text(
                        f"1 unit = {cm} cm"
                    )
            if name == "clip":  # a span picked, the rail zoomed
                page.get_by_label("From (s)").fill("12")
                page.get_by_label("To (s)").fill("14.5")
                page.get_by_role("button", name="Zoom in").click()
            no_sideways_scroll(page, name)
            screenshot(page, f"{width}-{name}")


# -- 5: compressed, compact previews, shown as they come ------------------------------------


def test_search_previews_are_compact_and_compressed(browser: Any, library: dict[str, Any]) -> None:  # noqa: F811
    from playwright.sync_api import expect

    base = library["base"]
    with browsing(browser, base, DESKTOP) as page:
        seen: list[tuple[str, str | None, int]] = []
        page.on(
            "response",
            lambda r: (
                seen.append((r.url, r.headers.get("content-encoding"), r.status))
                if "/skeleton" in r.url
                else None
            ),
        )
        # Every file a result (collapse=off): the library holds twins of one capture.
        page.goto(f"/#/search?clip={library['bvh']['id']}&k=4&collapse=off")
        expect(page.locator(".card.result")).to_have_count(4)
        figures_drawn(page)
        expect(page.locator(".progress-note")).to_have_text("")  # all came
        assert len(seen) == 5
        for url, encoding, status in seen:
            assert status == 200 and "encoding=compact" in url
            assert encoding == "gzip"


# -- 8, 17: moments use motion; errors look like errors; the drop hint ------------------------


def test_moments_say_they_use_motion(browser: Any, library: dict[str, Any]) -> None:  # noqa: F811
    from playwright.sync_api import expect

    with browsing(browser, library["base"], DESKTOP) as page:
        page.goto(f"/#/search?clip={library['bvh']['id']}&descriptor=kinetic")
        select = page.get_by_label("Descriptor")
        expect(select).to_have_value("kinetic")
        expect(select).to_be_enabled()
        page.get_by_label("moments").check()
        expect(select).to_be_disabled()
        expect(select).to_have_value("motion")
        expect(page.locator(".search-form ~ .hint").first).to_contain_text(
            "Moments are always found with the motion descriptor"
        )
        page.get_by_label("whole clips").check()
        expect(select).to_be_enabled()
        expect(select).to_have_value("kinetic")


def test_a_failed_search_looks_like_an_error(browser: Any, library: dict[str, Any]) -> None:  # noqa: F811
    from playwright.sync_api import expect

    with browsing(browser, library["base"], DESKTOP) as page:
        page.goto("/#/search")
        hint = page.locator(".drop-hint")
        for kind in ("BVH", "FBX", "glTF/GLB", "VRMA", "ASF", "AMC"):
            expect(hint).to_contain_text(kind)
        status = page.locator("main .status")
        expect(status).not_to_have_class("status error")
        # The page is ready (its first status said) before the file is dropped: a drop while it
        # still loads had its answer written over by that first status (a run at load 8).
        expect(status).to_contain_text("Pick a clip")
        drop_files(page, "main h1", [("broken.bvh", b"HIERARCHY\nROOT Hips\n{\n")])
        expect(status).to_contain_text("Search with broken.bvh failed")
        expect(status).to_have_class("status error")
        expect(status).to_have_attribute("role", "alert")
        colour = status.evaluate("e => getComputedStyle(e).color")
        assert colour == "rgb(180, 35, 24)", colour  # --error, not the muted grey
        screenshot(page, "search-error")
        # Back to a plain status once a search works.
        page.goto(f"/#/search?clip={library['bvh']['id']}")
        expect(status).to_contain_text("nearest first")
        expect(status).to_have_class("status")


# -- 15, 16: a file of several animations; the Upload summary ----------------------------------


def test_choose_animations_to_upload_and_to_search_with(browser: Any, tmp_path: Path) -> None:  # noqa: F811
    from playwright.sync_api import expect

    name, data = glb()
    with serve(tmp_path) as base, browsing(browser, base, DESKTOP) as page:
        page.goto("/#/upload")
        drop_files(page, "main h1", [(name, data)])
        row = page.locator(".upload", has=page.locator(".animation-choice"))
        choice = row.locator(".animation-choice")
        expect(choice).to_contain_text("2 animations in this file")
        expect(choice.get_by_label("walk")).to_be_checked()  # the longest, ticked
        expect(choice.get_by_label("start")).not_to_be_checked()
        expect(choice.locator("li").first).to_contain_text("0.3 s")  # with its length
        summary = page.locator("main .status")
        expect(summary).to_contain_text("1 file waiting for a choice of animations")
        screenshot(page, "upload-choose-animations")
        choice.get_by_label("start").check()
        choice.get_by_role("button", name="Upload the animations ticked").click()
        rows = page.locator('.upload[data-state="done"]')
        expect(rows).to_have_count(2)
        for animation in ("walk", "start"):
            row = page.locator(f'.upload[data-name="walk.glb · {animation}"]')
            expect(row).to_contain_text("stored as clip")
        expect(summary).to_have_text("2 clips stored, 0 failed.")
        stored = httpx.get(f"{base}/clips").json()["items"]
        assert sorted(c["name"] for c in stored) == ["walk · start", "walk · walk"]
        # The same file again: nothing new is stored, and the summary says so.
        drop_files(page, "main h1", [(name, data)])
        page.locator(".animation-choice").get_by_role("button").click()
        expect(summary).to_have_text("2 clips stored, 1 already in the library, 0 failed.")
        expect(page.locator(".upload").last).to_contain_text("already in the library as clip #")

        # Search with the file: the animations are offered; another one searches again.
        page.goto("/#/search")
        drop_files(page, "main h1", [(name, data)])
        status = page.locator("main .status")
        expect(status).to_contain_text("nearest to the file walk.glb · walk")
        chooser = page.get_by_label("Animation of the file")
        expect(chooser).to_be_visible()
        options = chooser.locator("option").all_inner_texts()
        assert [o.split(" (")[0] for o in options] == ["walk", "start"]
        assert all(o.endswith(" s)") for o in options)
        chooser.select_option("start")
        expect(status).to_contain_text("nearest to the file walk.glb · start")
        first = page.locator(".card.result").first
        stored_start = next(c for c in stored if c["name"] == "walk · start")
        expect(first).to_have_attribute("data-clip-id", str(stored_start["id"]))
        expect(first.locator(".distance-value")).to_have_text("0.0000")
        screenshot(page, "search-choose-animation")


def test_upload_summary_counts_duplicates_apart(browser: Any, tmp_path: Path) -> None:  # noqa: F811
    from playwright.sync_api import expect

    with serve(tmp_path) as base, browsing(browser, base, DESKTOP) as page:
        upload(base, {"file": (BANDAI.name, BANDAI.read_bytes())})
        upload(base, {"file": (CMU_BVH.name, CMU_BVH.read_bytes())})
        page.goto("/#/upload")
        page.set_input_files("input[type=file]", [str(BANDAI), str(CMU_BVH)])
        expect(page.locator('.upload[data-state="done"]')).to_have_count(2)
        expect(page.locator("main .status")).to_have_text(
            "0 clips stored, 2 already in the library, 0 failed."
        )


# -- 21: the map's axes and colours ------------------------------------------------------------


def test_map_axes_in_plain_words_and_twenty_safe_colours(browser: Any, tmp_path: Path) -> None:  # noqa: F811
    from playwright.sync_api import expect

    with serve(tmp_path) as base:
        # 22 clips (takes of different lengths: different contents), 22 labels: 20 get a
        # style of their own, the last two are "other labels".
        for i in range(22):
            take = bandai_take(1.0 + i / 10)
            upload(base, {"file": (f"t{i}.bvh", take)}, labels=f"label-{i:02d}")
        for viewport, name in ((DESKTOP, "desktop"), (PHONE, "phone")):
            with browsing(browser, base, viewport) as page:
                page.goto("/#/map")
                expect(page.locator("canvas.map-canvas")).to_have_attribute("data-points", "22")
                x_axis, y_axis = page.locator(".axis-x"), page.locator(".axis-y")
                expect(x_axis).to_have_text("How much the body moves")
                assert "e_all" in (x_axis.get_attribute("title") or "")
                assert "Onuma" in (x_axis.get_attribute("title") or "")
                expect(y_axis).to_have_text("Upper body against legs")
                assert "r_u/l" in (y_axis.get_attribute("title") or "")
                entries = page.locator(".legend li[data-colour]")
                expect(entries).to_have_count(20)
                styles = [
                    (e.get_attribute("data-colour"), e.get_attribute("data-marker"))
                    for e in entries.all()
                ]
                assert len(set(styles)) == 20  # every label its own colour and marker
                assert {colour for colour, _ in styles} <= COLOUR_BLIND_SAFE
                assert {marker for _, marker in styles} == {"circle", "square"}
                expect(page.locator(".legend")).to_contain_text("other labels")
                no_sideways_scroll(page, "map")
                screenshot(page, f"{name}-map-20-labels")
                page.get_by_label("Axes").select_option("pca")
                expect(x_axis).to_have_text("Main way clips differ")
                assert "principal component" in (x_axis.get_attribute("title") or "")
