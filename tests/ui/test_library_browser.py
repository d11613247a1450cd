"""Issue 24, items 9-14, in the real browser: similarity in words, one result per capture
("+1 other file of this capture"), "this file is clip #N", source and licence on upload, the
licence filter, the one search box with sort and page jump, and managing clips in bulk
(select, shift-select, all matching; add/remove labels; delete with confirmation).

Built from tests/fixtures (CMU 02_01 as BVH and as ASF/AMC — one capture, two files — the
Bandai walk, and takes of several lengths made from it): runs without ../shared. Screenshots
go to ``test-artifacts/ui/``.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

import httpx
import pytest

from tests.conftest import FIXTURES_DIR
from tests.ui.takes import bandai_take
from tests.ui.test_browser import browser, screenshot, serve  # noqa: F401 - fixtures
from tests.ui.test_everyday_ui import browsing, upload

pytestmark = pytest.mark.slow

CMU_BVH = FIXTURES_DIR / "cmu_mb_02_01_first41.bvh"
CMU_ASF, CMU_AMC = FIXTURES_DIR / "cmu_02.asf", FIXTURES_DIR / "cmu_02_01_first40.amc"
BANDAI = FIXTURES_DIR / "bandai_walk_normal_001_first40.bvh"
TAKES = 25  # with the three above: two pages of 24
PHONE = {"width": 360, "height": 740}


@pytest.fixture(scope="module")
def library(browser: Any, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:  # noqa: F811
    cmu = {"labels": "walk, cmu", "source": "CMU Graphics Lab", "licence": "free for any use"}
    with serve(tmp_path_factory.mktemp("library")) as base:
        clips = {
            "bvh": upload(base, {"file": (CMU_BVH.name, CMU_BVH.read_bytes())}, **cmu),
            "amc": upload(
                base,
                {
                    "skeleton": (CMU_ASF.name, CMU_ASF.read_bytes()),
                    "motion": (CMU_AMC.name, CMU_AMC.read_bytes()),
                },
                **cmu,
            ),
            "bandai": upload(
                base,
                {"file": (BANDAI.name, BANDAI.read_bytes())},
                labels="walk, bandai",
                source="Bandai Namco Research",
                licence="CC BY-NC 4.0",
            ),
        }
        takes = [
            upload(
                base,
                {"file": (f"take_{i:02d}.bvh", bandai_take(1.5 + 0.1 * i))},
                labels="take",
                licence="CC0",
            )
            for i in range(TAKES)
        ]
        yield {"base": base, **clips, "takes": takes}


def card_ids(page: Any, selector: str = ".cards .card") -> list[int]:
    return [
        int(x) for x in page.locator(selector).evaluate_all("l => l.map(c => c.dataset.clipId)")
    ]


# -- 9, 10, 11: similarity, one result per capture, a stored file ------------------------------


def test_similarity_one_result_per_capture_and_the_stored_file(
    browser: Any,  # noqa: F811
    library: dict[str, Any],
) -> None:
    from playwright.sync_api import expect

    base, bvh, amc = library["base"], library["bvh"], library["amc"]
    with browsing(browser, base) as page:
        page.goto(f"/#/search?clip={bvh['id']}")
        query = page.locator(".card.query")
        results = page.locator(".card.result")
        expect(results.first).to_be_visible()
        # One result per capture (the default): the BVH's ASF/AMC twin is not a result, the
        # query says it was left out.
        expect(page.get_by_label("One result per capture")).to_be_checked()
        assert amc["id"] not in card_ids(page, ".card.result")
        others = query.locator("details.others")
        expect(others.locator("summary")).to_have_text(
            "+1 other file of this capture, left out of the results"
        )
        others.locator("summary").click()
        expect(others.locator(f'li[data-clip-id="{amc["id"]}"] a')).to_have_attribute(
            "href", f"#/clips/{amc['id']}"
        )
        # "NN % similar", the API's similarity, explained in one line (and on hover).
        api = httpx.get(
            f"{base}/search", params={"clip": bvh["id"], "k": 8, "collapse": "capture"}
        ).json()
        assert card_ids(page, ".card.result") == [h["id"] for h in api["results"]]
        for card, hit in zip(results.all(), api["results"], strict=True):
            expect(card.locator(".similarity-value")).to_have_text(
                f"{round(hit['similarity'])} % similar"
            )
            expect(card.locator(".distance-value")).to_have_text(f"{hit['distance']:.4f}")
        assert "typical neighbours" in (
            results.first.locator(".distance").get_attribute("title") or ""
        )
        expect(page.locator(".similarity-help")).to_contain_text(
            "“97 % similar”: nearer to the query than 97 %"
        )
        screenshot(page, "search-similarity-collapsed")

        # Switched off: every file is a result, the twin first.
        page.get_by_label("One result per capture").uncheck()
        page.get_by_role("button", name="Search", exact=True).click()
        expect(page).to_have_url(re.compile("collapse=off"))
        expect(results.first).to_have_attribute("data-clip-id", str(amc["id"]))
        expect(query.locator("details.others")).to_have_count(0)
        every = httpx.get(f"{base}/search", params={"clip": bvh["id"], "k": 8}).json()
        twin_hit = every["results"][0]
        assert twin_hit["id"] == amc["id"]
        expect(results.first.locator(".similarity-value")).to_have_text(
            f"{round(twin_hit['similarity'])} % similar"
        )

        # A file already stored: "this file is clip #N", linked; it comes first, its twin in
        # "+1 other file of this capture".
        page.get_by_label("One result per capture").check()
        page.locator("form.search-form input[type=file]").set_input_files(str(CMU_BVH))
        expect(page.locator("main .status")).to_contain_text(
            f"This file is clip #{bvh['id']} of the library."
        )
        stored = query.locator(".stored-clip")
        expect(stored).to_contain_text(f"This file is clip #{bvh['id']}")
        expect(results.first).to_have_attribute("data-clip-id", str(bvh["id"]))
        expect(results.first.locator(".distance-value")).to_have_text("0.0000")
        twin = results.first.locator("details.others")
        expect(twin.locator("summary")).to_have_text("+1 other file of this capture")
        twin.locator("summary").click()
        expect(twin.locator(f'li[data-clip-id="{amc["id"]}"]')).to_contain_text("ASF/AMC")
        expect(page).to_have_title("Search · mocap-index")  # opening it did not search from it
        screenshot(page, "search-stored-file")
        stored.get_by_role("link", name=f"clip #{bvh['id']}").click()
        expect(page).to_have_url(re.compile(rf"#/clips/{bvh['id']}$"))

        # Moments have a similarity too.
        take = library["takes"][-1]["id"]
        page.goto(f"/#/search?clip={take}&mode=moments&start=0&end=1.3")
        expect(page.locator(".card.moment .similarity-value").first).to_have_text(
            re.compile(r"^\d+ % similar$")
        )
        expect(page.locator(".similarity-help")).to_contain_text("typical nearest moments")


# -- 12: source and licence on upload, the licence filter (Library and Search) -----------------


def test_upload_with_source_and_licence(browser: Any, library: dict[str, Any]) -> None:  # noqa: F811
    from playwright.sync_api import expect

    base = library["base"]
    with browsing(browser, base) as page:
        page.goto("/#/upload")
        # The licences already in use are offered.
        page.wait_for_function("() => document.querySelectorAll('datalist option').length >= 3")
        page.get_by_label("Source of these clips").fill("Studio capture, day 3")
        page.get_by_label("Licence of these clips").fill("In-house only")
        page.set_input_files(
            "input[type=file]",
            files=[{"name": "day3.bvh", "mimeType": "text/plain", "buffer": bandai_take(2.42)}],
        )
        row = page.locator('.upload[data-name="day3.bvh"]')
        expect(row).to_have_attribute("data-state", "done")
        clip = httpx.get(f"{base}/clips/{row.get_attribute('data-clip-id')}").json()
        assert (clip["source"], clip["licence"]) == ("Studio capture, day 3", "In-house only")
        screenshot(page, "upload-source-licence")
        httpx.delete(f"{base}/clips/{clip['id']}")  # the other tests count the library


def test_library_search_box_licence_sort_and_page_jump(
    browser: Any,  # noqa: F811
    library: dict[str, Any],
) -> None:
    from playwright.sync_api import expect

    base = library["base"]
    total = 3 + TAKES
    with browsing(browser, base) as page:
        page.goto("/#/library")
        status = page.locator("main .status").first
        expect(status).to_have_text(f"Showing 1–24 of {total} clips.")
        find = page.get_by_label("Find", exact=True)
        # Every word, anywhere: a label and a source, a licence, a file name.
        find.fill("walk cmu")
        expect(status).to_have_text("Showing 1–2 of 2 matching clips.")
        assert sorted(card_ids(page)) == sorted([library["bvh"]["id"], library["amc"]["id"]])
        find.fill("FREE for any")
        expect(status).to_have_text("Showing 1–2 of 2 matching clips.")
        find.fill("first40.AMC")
        expect(page.locator(".cards .card")).to_have_count(1)
        expect(page).to_have_url(re.compile(r"q=first40\.AMC"))
        find.fill("")
        expect(status).to_have_text(f"Showing 1–24 of {total} clips.")

        # Licence: only one, then all but it.
        licence = page.get_by_label("Licence", exact=True)
        licence.select_option("CC BY-NC 4.0")
        expect(status).to_have_text("Showing 1–1 of 1 matching clip.")
        assert card_ids(page) == [library["bandai"]["id"]]
        page.get_by_label("all but this").check()
        expect(status).to_have_text(f"Showing 1–24 of {total - 1} matching clips.")
        expect(page).to_have_url(re.compile(r"licence=%21CC"))
        assert library["bandai"]["id"] not in card_ids(page)
        screenshot(page, "library-licence-excluded")
        licence.select_option("")
        expect(status).to_have_text(f"Showing 1–24 of {total} clips.")

        # Sort: longest first is the API's order.
        page.get_by_label("Order").select_option("-duration")
        longest = httpx.get(f"{base}/clips", params={"sort": "-duration", "limit": 24}).json()
        expect(page.locator(".cards .card").first).to_have_attribute(
            "data-clip-id", str(longest["items"][0]["id"])
        )
        assert card_ids(page) == [c["id"] for c in longest["items"]]

        # Jump to a page.
        page.get_by_label("Page", exact=True).fill("2")
        page.get_by_role("button", name="Go").click()
        expect(status).to_have_text(f"Showing 25–{total} of {total} clips.")
        expect(page).to_have_url(re.compile(r"page=2"))
        rest = httpx.get(
            f"{base}/clips", params={"sort": "-duration", "limit": 24, "offset": 24}
        ).json()
        assert card_ids(page) == [c["id"] for c in rest["items"]]
        screenshot(page, "library-sorted-page-2")

        # The Search page takes the licence filter too.
        page.goto(f"/#/search?clip={library['bandai']['id']}&k=30&licence=!CC0")
        expect(page.locator(".card.result").first).to_be_visible()
        expect(page.get_by_label("Licence", exact=True)).to_have_value("CC0")
        expect(page.get_by_label("all but this")).to_be_checked()
        shown = card_ids(page, ".card.result")
        api = httpx.get(
            f"{base}/search",
            params={
                "clip": library["bandai"]["id"],
                "k": 30,
                "licence": "!CC0",
                "collapse": "capture",
            },
        ).json()
        assert shown == [h["id"] for h in api["results"]]
        takes = {t["id"] for t in library["takes"]}
        assert shown and not takes & set(shown)


# -- 13: select cards, change their labels, delete them ---------------------------------------


def test_select_relabel_and_delete_in_bulk(browser: Any, library: dict[str, Any]) -> None:  # noqa: F811
    from playwright.sync_api import expect

    base = library["base"]

    def count(label: str) -> int:
        total: int = httpx.get(f"{base}/clips", params={"label": label, "limit": 1}).json()["total"]
        return total

    with browsing(browser, base) as page:
        page.goto("/#/library?label=take")
        cards = page.locator(".cards .card")
        expect(cards).to_have_count(24)
        selected = page.locator(".selected-count")
        expect(selected).to_contain_text("Tick clips")
        expect(page.get_by_label("Add labels")).to_be_hidden()
        # A click, then Shift+click: the range between.
        cards.nth(1).locator(".select-box").click()
        cards.nth(4).locator(".select-box").click(modifiers=["Shift"])
        expect(selected).to_have_text("4 clips selected.")
        expect(page.locator(".cards .card.selected")).to_have_count(4)
        picked = card_ids(page, ".cards .card.selected")
        assert picked == card_ids(page)[1:5]
        # Shift+click on a ticked one unticks the range back to it.
        cards.nth(3).locator(".select-box").click(modifiers=["Shift"])
        expect(selected).to_have_text("2 clips selected.")
        cards.nth(3).locator(".select-box").click()
        cards.nth(4).locator(".select-box").click()
        expect(selected).to_have_text("4 clips selected.")
        page.get_by_label("Add labels").fill("picked, Best")
        page.get_by_label("Remove labels").fill("nothing-here")
        page.get_by_role("button", name="Change labels").click()
        bulk_status = page.locator(".bulk-status")
        expect(bulk_status).to_have_text(
            "Added picked, Best and removed nothing-here: 4 clips changed of 4 selected."
        )
        assert count("picked") == 4 and count("best") == 4
        screenshot(page, "library-selected")

        # Every clip the filter matches (the next page's too).
        page.get_by_role("button", name=f"Select all {TAKES} matching").click()
        expect(selected).to_have_text(f"All {TAKES} matching clips selected.")
        expect(page.locator(".cards .card .select-box:checked")).to_have_count(24)
        page.get_by_label("Add labels").fill("batch-1")
        page.get_by_role("button", name="Change labels").click()
        expect(bulk_status).to_contain_text(f"{TAKES} clips changed of {TAKES} selected")
        assert count("batch-1") == TAKES
        page.get_by_role("button", name="Clear selection").click()
        expect(selected).to_contain_text("Tick clips")

        # Delete: the service says how many would go; Cancel keeps them.
        page.get_by_label("Label", exact=True).select_option("picked")
        expect(cards).to_have_count(4)
        cards.nth(0).locator(".select-box").click()
        cards.nth(1).locator(".select-box").click()
        doomed = card_ids(page, ".cards .card.selected")
        page.get_by_role("button", name="Delete…").click()
        confirm = page.locator("dialog.confirm")
        expect(confirm.get_by_role("heading")).to_have_text("Delete 2 clips?")
        expect(confirm.locator(".confirm-names li")).to_have_count(2)
        confirm.get_by_role("button", name="Cancel").click()
        assert count("picked") == 4
        page.get_by_role("button", name="Delete…").click()
        confirm.get_by_role("button", name="Delete", exact=True).click()
        expect(bulk_status).to_have_text("Deleted 2 clips.")
        expect(cards).to_have_count(2)
        assert count("picked") == 2
        for clip_id in doomed:
            assert httpx.get(f"{base}/clips/{clip_id}").status_code == 404
        # All matching, by the filter.
        page.get_by_role("button", name="Select all 2 matching").click()
        page.get_by_role("button", name="Delete…").click()
        expect(confirm.get_by_role("heading")).to_have_text("Delete 2 clips?")
        expect(confirm).to_contain_text("Every clip labelled picked.")
        confirm.get_by_role("button", name="Delete", exact=True).click()
        expect(page.locator("main .status").first).to_have_text("No clip matches these filters.")
        assert count("picked") == 0 and count("take") == TAKES - 4

        # On a phone: the bar with a selection fits.
        page.set_viewport_size(PHONE)
        page.get_by_label("Label", exact=True).select_option("take")
        cards.first.locator(".select-box").click()
        expect(page.get_by_label("Add labels")).to_be_visible()
        widths = page.evaluate("() => [document.documentElement.scrollWidth, innerWidth]")
        assert widths[0] <= widths[1], widths
        screenshot(page, "phone-library-selected")
