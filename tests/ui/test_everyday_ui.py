"""Issue #14 in the real browser: the clip page, dropping a file anywhere, the skip link,
same-named clips told apart, the empty search page, synthetic clips.

Real CMU 02_04 in its three formats (ASF/AMC, MotionBuilder BVH, DAZ BVH) from
``../shared/data/cmu`` when present, else the small fixtures (02_01 as ASF/AMC and BVH).
Screenshots go to ``test-artifacts/ui/``.
"""

from __future__ import annotations

import re
import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.conftest import FIXTURES_DIR, shared_data_dir
from tests.ui.test_browser import (  # noqa: F401
    TIMEOUT_MS,
    browser,
    screenshot,
    serve,
    watch_problems,
)

pytestmark = pytest.mark.slow


def same_named_clips(tmp_path: Path) -> list[dict[str, tuple[str, bytes]]]:
    """One capture in several formats, as upload fields: [{field: (file name, bytes)}]."""
    cmu = shared_data_dir() / "cmu"
    files = [
        cmu / "asf-amc/02/02.asf",
        cmu / "asf-amc/02/02_04.amc",
        cmu / "bvh-mb/02/02_04.bvh",
        cmu / "bvh-daz/02/02_04.bvh",
    ]
    if all(p.is_file() for p in files):
        asf, amc, mb, daz = (p.read_bytes() for p in files)
        return [
            {"skeleton": ("02.asf", asf), "motion": ("02_04.amc", amc)},
            {"file": ("02_04.bvh", mb)},
            {"file": ("02_04.bvh", daz)},
        ]
    read = lambda name: (FIXTURES_DIR / name).read_bytes()  # noqa: E731
    return [
        {
            "skeleton": ("02.asf", read("cmu_02.asf")),
            "motion": ("02_01.amc", read("cmu_02_01_first40.amc")),
        },
        {"file": ("02_01.bvh", read("cmu_mb_02_01_first41.bvh"))},
    ]


def upload(base: str, files: dict[str, tuple[str, bytes]], **data: Any) -> dict[str, Any]:
    response = httpx.post(f"{base}/clips", files=files, data=data, timeout=120)
    assert response.status_code in (200, 201), response.text
    clip: dict[str, Any] = response.json()
    return clip


@contextmanager
def browsing(
    browser: Any,  # noqa: F811
    base: str,
    viewport: dict[str, int] | None = None,
) -> Iterator[Any]:
    """A page on ``base`` (1280 × 900 unless ``viewport``); fails on any script error."""
    context = browser.new_context(
        viewport=viewport or {"width": 1280, "height": 900}, base_url=base, accept_downloads=True
    )
    context.set_default_timeout(TIMEOUT_MS)
    page = context.new_page()
    problems = watch_problems(page)
    try:
        yield page
    finally:
        context.close()
    assert not problems, problems


def drop_files(page: Any, selector: str, files: list[tuple[str, bytes]]) -> None:
    """Drop files on an element as a user's drag and drop does (a DataTransfer with Files)."""
    payload = [[name, list(data)] for name, data in files]
    transfer = page.evaluate_handle(
        """(files) => {
          const transfer = new DataTransfer();
          for (const [name, bytes] of files) {
            transfer.items.add(new File([new Uint8Array(bytes)], name));
          }
          return transfer;
        }""",
        payload,
    )
    for event in ("dragenter", "dragover", "drop"):
        page.dispatch_event(selector, event, {"dataTransfer": transfer})


# -- 1, 5, 14: the clip page ----------------------------------------------------------------


def test_clip_page(browser: Any, tmp_path: Path) -> None:  # noqa: F811
    from playwright.sync_api import expect

    clips = same_named_clips(tmp_path)
    with serve(tmp_path) as base, browsing(browser, base) as page:
        stored = [
            upload(
                base,
                files,
                labels="walk, cmu",
                source="CMU Graphics Lab Motion Capture Database",
                licence="free for any use",
            )
            for files in clips
        ]
        clip = stored[0]  # the ASF/AMC one
        page.goto("/")
        card = page.locator(f'.cards .card[data-clip-id="{clip["id"]}"]')
        card.locator("canvas").click()  # the stick figure opens the clip's page
        expect(page).to_have_url(re.compile(rf"#/clips/{clip['id']}$"))
        expect(page.locator("h1.clip-title")).to_contain_text(clip["name"])
        expect(page.locator("h1.clip-title .badge")).to_have_text("ASF/AMC")
        facts = page.locator("dl.facts")
        expect(facts.locator('[data-fact="files"]')).to_have_text(
            re.compile(r"02\.asf\s*02_0\d\.amc")
        )
        expect(facts.locator('[data-fact="frames"]')).to_have_text(f"{clip['frame_count']:,}")
        duration = facts.locator('[data-fact="duration"]')
        expect(duration).to_have_text(re.compile(r"^\d+\.\d\d s$"))  # no float noise
        assert float(duration.inner_text().split()[0]) == pytest.approx(clip["duration"], abs=0.006)
        expect(facts.locator('[data-fact="skeleton-family"]')).to_have_text(clip["skeleton_family"])
        expect(facts.locator('[data-fact="lead-in-frames"]')).to_contain_text(
            str(clip["lead_in_frames"])
        )
        expect(facts.locator('[data-fact="labels"]')).to_have_text(re.compile(r"walk\s*cmu"))
        expect(facts.locator('[data-fact="source"]')).to_have_text(
            "CMU Graphics Lab Motion Capture Database"
        )
        expect(facts.locator('[data-fact="licence"]')).to_have_text("free for any use")
        expect(page.locator(".clip-warnings")).to_have_count(0)  # none given: no section
        # How the joints were mapped (issue #10): one row per canonical joint, with how.
        rows = page.locator(".clip-mapping tbody tr")
        expect(rows).to_have_count(21)
        expect(rows.first).to_have_text(re.compile(r"^pelvis\s*\S+\s*structure"))

        # The large preview plays; pause, scrub, and the readout follows the file's frames.
        page.wait_for_function(
            "() => window.__mocap.figures().some(f => f.role === 'clip' && f.frameCount > 0)"
        )
        controls = page.get_by_role("group", name=f"Playback of {clip['name']}")
        controls.get_by_role("button", name="Pause").click()
        expect(controls.get_by_role("button", name="Play")).to_have_attribute(
            "aria-pressed", "false"
        )
        scrub = controls.get_by_role("slider", name="Time")
        scrub.focus()  # the keys step the file's own frames: 0.2 s on
        page.keyboard.press("Home")
        steps = round(0.2 / clip["frame_time"])
        for _ in range(steps):
            page.keyboard.press("ArrowRight")
        readout = controls.locator("output")
        first = clip["lead_in_frames"] + steps + 1
        expect(readout).to_contain_text(f"frame {first} / {clip['frame_count']} · 0.20 s")
        screenshot(page, "clip-page")

        # Download the original files, as the service names them.
        with page.expect_download() as got:
            page.get_by_role("button", name=re.compile(r"^Download 02_0\d\.amc$")).click()
        assert got.value.suggested_filename.endswith(".amc")
        assert Path(got.value.path()).read_bytes() == clips[0]["motion"][1]
        # ... or as a BVH of its own skeleton (issue #12), which any animation tool opens.
        with page.expect_download() as got:
            page.get_by_role("button", name="Download as BVH").click()
        assert got.value.suggested_filename.endswith(".bvh")
        exported = Path(got.value.path()).read_text()
        assert exported.startswith("HIERARCHY") and f"Frames: {clip['frame_count']}" in exported

        # Rename and relabel (case-duplicates dropped), set the licence.
        page.get_by_label("Name", exact=True).fill("walk, turning (CMU 02)")
        page.get_by_label("Labels (comma-separated)").fill("Walk, turn, walk")
        page.get_by_label("Licence").fill("CC0")
        page.get_by_role("button", name="Save changes").click()
        expect(page.get_by_role("alert")).to_have_text(f"Saved the changes to clip #{clip['id']}.")
        expect(page.locator("h1.clip-title")).to_contain_text("walk, turning (CMU 02)")
        expect(facts.locator('[data-fact="labels"]')).to_have_text(re.compile(r"^Walk\s*turn$"))
        expect(facts.locator('[data-fact="licence"]')).to_have_text("CC0")
        saved = httpx.get(f"{base}/clips/{clip['id']}").json()
        assert (saved["name"], saved["labels"], saved["licence"]) == (
            "walk, turning (CMU 02)",
            ["Walk", "turn"],
            "CC0",
        )

        # Find similar: the search page with this clip as the query.
        page.get_by_role("link", name=re.compile("Find clips similar to")).click()
        expect(page.locator(".card.query")).to_have_attribute("data-clip-id", str(clip["id"]))
        page.go_back()

        # Delete, with confirmation: Cancel keeps it, Delete removes it.
        page.get_by_role("button", name="Delete clip…").click()
        dialog = page.get_by_role("dialog")
        expect(dialog).to_contain_text("This cannot be undone")
        dialog.get_by_role("button", name="Cancel").click()
        expect(dialog).to_be_hidden()
        assert httpx.get(f"{base}/clips/{clip['id']}").status_code == 200
        page.get_by_role("button", name="Delete clip…").click()
        dialog.get_by_role("button", name="Delete", exact=True).click()
        expect(page).to_have_title("Library · mocap-index")
        expect(page.get_by_role("alert")).to_contain_text(f"Deleted clip #{clip['id']}")
        expect(page.locator(".cards .card")).to_have_count(len(stored) - 1)
        assert httpx.get(f"{base}/clips/{clip['id']}").status_code == 404


def test_clip_page_asks_for_the_key_to_delete(browser: Any, tmp_path: Path) -> None:  # noqa: F811
    from playwright.sync_api import expect

    key = "open sesame"
    files = same_named_clips(tmp_path)[1]
    with serve(tmp_path, MOCAP_API_KEY=key) as base, browsing(browser, base) as page:
        response = httpx.post(f"{base}/clips", files=files, headers={"X-API-Key": key}, timeout=120)
        clip = response.json()
        page.goto(f"/#/clips/{clip['id']}")
        page.get_by_role("button", name="Delete clip…").click()
        page.get_by_role("dialog").get_by_role("button", name="Delete", exact=True).click()
        actions = page.locator(".clip-actions")
        expect(actions.get_by_role("alert")).to_contain_text("needs an API key to delete the clip")
        actions.get_by_label("API key", exact=True).fill("wrong")
        actions.get_by_role("button", name="Use this key").click()
        expect(actions.get_by_role("alert")).to_contain_text("The API key was refused")
        assert httpx.get(f"{base}/clips/{clip['id']}").status_code == 200
        actions.get_by_label("API key", exact=True).fill(key)
        actions.get_by_role("button", name="Use this key").click()
        expect(page).to_have_title("Library · mocap-index")
        assert httpx.get(f"{base}/clips/{clip['id']}").status_code == 404


def test_clip_page_shows_warnings_and_mapping_when_the_api_gives_them(
    browser: Any,  # noqa: F811
    tmp_path: Path,
) -> None:
    """Issue #10's `warnings` and joint mapping, as the service gives them for a real file
    that needed a repair: a BVH with two frame lines more than its `Frames:` declares."""
    from playwright.sync_api import expect

    name, data = same_named_clips(tmp_path)[1]["file"]
    last = data.rstrip(b"\r\n").splitlines()[-1]
    padded = data.rstrip(b"\r\n") + b"\n" + last + b"\n" + last + b"\n"
    with serve(tmp_path) as base, browsing(browser, base) as page:
        clip = upload(base, {"file": (name, padded)})
        assert clip["warnings"] and "ignored" in clip["warnings"][0]
        page.goto(f"/#/clips/{clip['id']}")
        expect(page.locator(".clip-warnings")).to_contain_text(clip["warnings"][0])
        mapping = page.locator(".clip-mapping")
        expect(mapping.locator("tbody tr")).to_have_count(21)
        expect(mapping.locator("tbody tr", has_text="head")).to_contain_text("end effector")


# -- 2, 4: a file dropped anywhere; same-named clips told apart --------------------------------


def test_drop_a_file_anywhere_and_same_named_results(browser: Any, tmp_path: Path) -> None:  # noqa: F811
    from playwright.sync_api import expect

    clips = same_named_clips(tmp_path)
    with serve(tmp_path) as base, browsing(browser, base) as page:
        stored = [upload(base, files) for files in clips]
        page.goto("/#/search")
        # A drop on the header (not a drop zone) neither leaves the app nor navigates.
        bvh_name, bvh_bytes = clips[1]["file"]
        drop_files(page, "header.top", [(bvh_name, bvh_bytes)])
        expect(page).to_have_url(re.compile(r"#/search$"))
        query = page.locator(".card.query")
        expect(page.locator("main .status")).to_contain_text(f"nearest to the file {bvh_name}")
        expect(query).to_have_attribute("data-clip-id", "")
        results = page.locator(".card.result")
        expect(results).to_have_count(len(stored))
        expect(results.first).to_have_attribute("data-clip-id", str(stored[1]["id"]))
        expect(results.first.locator(".distance-value")).to_have_text("0.0000")
        page.wait_for_function("() => window.__mocap.figures().every(f => f.frameCount > 0)")
        screenshot(page, "search-drop")

        # Same-named clips: each card says its format and file names; the name is not cut.
        page.goto(f"/#/search?clip={stored[1]['id']}")
        expect(results).to_have_count(len(stored) - 1)
        badges = sorted(results.locator(".badge").all_inner_texts())
        want = sorted(s["format"].upper() for i, s in enumerate(stored) if i != 1)
        assert badges == want
        for card in results.all():
            clip_id = int(card.get_attribute("data-clip-id"))
            clip = next(s for s in stored if s["id"] == clip_id)
            expect(card.locator(".filenames")).to_have_text(", ".join(clip["filenames"]))
            name = card.locator(".clip-name")
            expect(name).to_have_attribute(
                "title",
                f"{clip['name']} — {', '.join(clip['filenames'])} — skeleton "
                f"{clip['skeleton_family']} — clip #{clip_id}",
            )
            expect(card.locator(".family")).to_have_text(f"· {clip['skeleton_family']}")
            assert name.evaluate("e => e.scrollWidth <= e.clientWidth")  # wrapped, not cut
        page.wait_for_function("() => window.__mocap.figures().every(f => f.frameCount > 0)")
        screenshot(page, "same-named-results")
        # The name opens the clip's page.
        results.first.locator(".clip-name a").click()
        expect(page).to_have_url(re.compile(r"#/clips/\d+$"))

        # The Upload page takes a drop anywhere too.
        page.goto("/#/upload")
        page.get_by_label("Labels from file names").fill(r"(?P<subject>\d+)_(?P<take>\d+)")
        drop_files(page, "main h1", [("renamed_02_07.bvh", bvh_bytes)])
        row = page.locator('.upload[data-name="renamed_02_07.bvh"]')
        expect(row).to_have_attribute("data-state", "done")
        expect(row).to_contain_text(f"already in the library as clip #{stored[1]['id']}")
        labels = httpx.get(f"{base}/clips/{stored[1]['id']}").json()["labels"]
        assert labels == ["02", "07"]  # Python's group spelling works in the page too


# -- 3, 5: skip link; the empty search page; k; the map's descriptor ---------------------------


def test_skip_link_empty_search_k_and_map_default(browser: Any, tmp_path: Path) -> None:  # noqa: F811
    from playwright.sync_api import expect

    clips = same_named_clips(tmp_path)
    with serve(tmp_path) as base, browsing(browser, base) as page:
        stored = [upload(base, files) for files in clips]
        page.goto("/#/search")
        expect(page.locator("main .status")).to_contain_text("Pick a clip")
        expect(page.locator(".player-controls")).to_be_hidden()  # nothing runs when empty
        assert page.evaluate("() => window.__mocap.figures().length") == 0

        url = f"/#/search?clip={stored[0]['id']}&descriptor=motion"
        page.goto(url)
        expect(page.locator(".card.query")).to_have_attribute("data-clip-id", str(stored[0]["id"]))
        skip = page.get_by_role("link", name="Skip to content")
        skip.focus()
        page.keyboard.press("Enter")
        expect(page.locator("main#view")).to_be_focused()
        expect(page).to_have_url(re.compile(re.escape(url.lstrip("/")) + "$"))
        expect(page.locator(".card.query")).to_have_attribute("data-clip-id", str(stored[0]["id"]))
        expect(page.locator(".player-controls")).to_be_visible()

        page.get_by_label("Results").fill("80")
        page.get_by_role("button", name="Search", exact=True).click()
        expect(page.locator("main .status")).to_contain_text("At most 50 here")

        search_default = page.evaluate("() => fetch('/descriptors').then(r => r.json())")["default"]
        page.goto("/#/map")
        expect(page.get_by_label("Descriptor (PCA and outliers)")).to_have_value(search_default)


# -- 12: a synthetic clip ---------------------------------------------------------------------


def test_synthetic_clip_says_no_preview(browser: Any, tmp_path: Path) -> None:  # noqa: F811
    from playwright.sync_api import expect

    data = tmp_path
    with serve(data) as base, browsing(browser, base) as page:
        db = sqlite3.connect(data / "mocap-index.sqlite3")
        with db:
            db.execute(
                "INSERT INTO clips (name, format, content_hash, frame_count, frame_time, duration, "
                "joint_count, skeleton_family, lead_in_frames, created_at) VALUES "
                "('synthetic-000001', 'synthetic', ?, 90, 0.0333, 3.0, 0, 'synthetic', 0, "
                "'2026-11-22 10:00:00')",
                ("e" * 64,),
            )
        clip_id = db.execute("SELECT max(id) FROM clips").fetchone()[0]
        db.close()
        page.goto("/")
        page.wait_for_function(
            "() => window.__mocap.figures().some(f => (f.error || '').includes('synthetic clip'))"
        )
        page.goto(f"/#/clips/{clip_id}")
        expect(page.locator(".preview-note")).to_have_text(
            "Synthetic clip: no preview (it has no stored file)."
        )
        expect(page.locator(".downloads")).to_contain_text("no stored file to download")
