"""Moments you can trust, on real data (issue 24, items 6 and 7), over HTTP.

The library: 24 Bandai clips (labelled with their content and style, licence CC BY-NC 4.0),
the ten CMU ASF/AMC trials of subject 02 and four of their MotionBuilder BVH twins (labels
from CMU's index, another licence). Imported once for the module, searched through the
real app.

* **One list** (item 6): for random spans and labels, a filtered moments search returns
  exactly the unfiltered list restricted to the clips the label (or licence) keeps; a
  smaller ``k`` returns its beginning; a larger ``per_clip`` keeps every moment a smaller
  one chose, in order.
* **Exact copies** (item 7): random spans of 1.25-4 s cut from the stored files (``GET
  /clips/{id}/file?start=&end=``) and searched by upload, then stored as clips of their own
  and searched by clip, find their source first, placed within one of its frames. The full
  500-span figures are recorded by ``bench/bench_moments.py exact``; these check fewer.
"""

from __future__ import annotations

import io
import zipfile
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.importer import LabelRules, run_import
from app.main import create_app

BY_FILE = 30  # spans searched by upload here (500 in the bench)
BY_CLIP = 12  # spans stored and searched by clip here
PROPERTY_QUERIES = 12
BANDAI = "CC BY-NC 4.0"


@pytest.fixture(scope="module")
def library(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    from tests.conftest import shared_data_dir

    data = shared_data_dir()
    if not (data / "bandai-ds1").is_dir() or not (data / "cmu").is_dir():
        pytest.skip(f"needs ../shared/data/bandai-ds1 and cmu (not found under {data})")
    settings = Settings(data_dir=tmp_path_factory.mktemp("moments") / "data")
    rng = np.random.default_rng(24)
    bandai = sorted((data / "bandai-ds1" / "data").glob("*.bvh"))
    chosen = [bandai[i] for i in sorted(rng.choice(len(bandai), 24, replace=False))]
    styles = r"dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_\d+"
    report = run_import(
        settings, chosen, labels=LabelRules.build(regex=styles, licence=BANDAI), workers=2
    )
    assert not report.failed, report.failed
    cmu = [data / "cmu" / "asf-amc" / "02"]
    cmu += [data / "cmu" / "bvh-mb" / "02" / f"02_0{i}.bvh" for i in range(1, 5)]
    rules = LabelRules.build(tsv=data / "cmu" / "labels.tsv", licence="free for any use")
    report = run_import(settings, cmu, labels=rules, workers=2)
    assert not report.failed and len(report.imported) == 14, report
    with TestClient(create_app(settings)) as client:
        yield client


def clips(client: TestClient) -> list[dict[str, Any]]:
    page = client.get("/clips", params={"limit": 500}).json()
    items: list[dict[str, Any]] = page["items"]
    return items


def moments(client: TestClient, **params: Any) -> list[tuple[int, float, float, float]]:
    response = client.get("/search/moments", params=params)
    assert response.status_code == 200, response.text
    return [(m["id"], m["start"], m["end"], m["distance"]) for m in response.json()["results"]]


def random_span(rng: np.random.Generator, clip: dict[str, Any], low: float, high: float) -> Any:
    """Frames ``(first, stop)`` of a random span of ``low``-``high`` s of the clip (after its
    lead-in), or None when the clip is too short."""
    ft, frames, lead_in = clip["frame_time"], clip["frame_count"], clip["lead_in_frames"]
    usable = (frames - lead_in) * ft
    if usable < low:
        return None
    length = round(rng.uniform(low, min(high, usable)) / ft)
    first = lead_in + int(rng.integers(0, frames - lead_in - length + 1))
    return first, first + length


# -- item 6: one list, whatever k, per_clip and the filters ----------------------------------


def test_filtered_moments_are_the_unfiltered_list_restricted(library: TestClient) -> None:
    stored = clips(library)
    by_id = {c["id"]: c for c in stored}
    labels = sorted({label.lower() for c in stored for label in c["labels"]})
    rng = np.random.default_rng(6)
    checked = 0
    while checked < PROPERTY_QUERIES:
        clip = stored[int(rng.integers(len(stored)))]
        span = random_span(rng, clip, 1.0, 6.0)
        if span is None:
            continue
        ft = clip["frame_time"]
        query = {"clip": clip["id"], "start": span[0] * ft, "end": span[1] * ft}
        query["per_clip"] = int(rng.choice([1, 2, 3]))
        everything = moments(library, **query, k=1000)  # the whole list: fewer than 1000
        label = labels[int(rng.integers(len(labels)))]
        carriers = {c["id"] for c in stored if label in {x.lower() for x in c["labels"]}}
        filtered = moments(library, **query, k=10, label=label.upper())
        assert filtered == [m for m in everything if m[0] in carriers][:10], (query, label)
        for licence, keeps in (
            (BANDAI.lower(), lambda i: by_id[i]["licence"] == BANDAI),
            (f"!{BANDAI}", lambda i: by_id[i]["licence"] != BANDAI),
        ):
            kept = [m for m in everything if keeps(m[0])][:7]
            assert moments(library, **query, k=7, licence=licence) == kept, (query, licence)
        # A smaller k: the beginning of the list. A larger per_clip: every moment kept, in order.
        assert moments(library, **query, k=5) == everything[:5]
        distances = [m[3] for m in everything]
        assert distances == sorted(distances)
        wider = moments(library, **{**query, "per_clip": 3}, k=1000)
        assert [m for m in wider if m in set(everything)] == everything
        checked += 1


# -- item 7: exact copies are placed to a frame ----------------------------------------------


def cut_files(client: TestClient, clip: dict[str, Any], start: float, end: float) -> Any:
    response = client.get(f"/clips/{clip['id']}/file", params={"start": start, "end": end})
    assert response.status_code == 200, response.text
    if clip["format"] == "bvh":
        return {"file": ("cut.bvh", response.content)}
    with zipfile.ZipFile(io.BytesIO(response.content)) as archive:
        asf, amc = archive.namelist()
        return {"skeleton": (asf, archive.read(asf)), "motion": (amc, archive.read(amc))}


def found_first(results: list[dict[str, Any]], clip: dict[str, Any], truth: float) -> bool:
    """Whether the source clip comes first (or tied first: another clip holding the very same
    motion), placed within one of its frames."""
    best = results[0]["distance"]
    for moment in results:
        if moment["distance"] > best:
            break
        if moment["id"] == clip["id"]:
            return abs(moment["start"] - truth) <= clip["frame_time"] + 1e-6
    return False


def test_exact_copies_are_placed_to_a_frame(
    library: TestClient, capsys: pytest.CaptureFixture[str]
) -> None:
    stored = clips(library)
    rng = np.random.default_rng(7)
    misses: list[tuple[str, Any]] = []
    tried = {"file": 0, "clip": 0}
    while tried["file"] < BY_FILE or tried["clip"] < BY_CLIP:
        clip = stored[int(rng.integers(len(stored)))]
        span = random_span(rng, clip, 1.25, 4.0)
        if span is None:
            continue
        ft = clip["frame_time"]
        truth, end = span[0] * ft, span[1] * ft
        files = cut_files(library, clip, truth, end)
        if tried["file"] < BY_FILE:
            tried["file"] += 1
            response = library.post("/search/moments", params={"k": 3}, files=files)
            assert response.status_code == 200, response.text
            if not found_first(response.json()["results"], clip, truth):
                misses.append(("file", (clip["name"], truth, response.json()["results"][:2])))
        if tried["clip"] < BY_CLIP:
            tried["clip"] += 1
            added = library.post("/clips", files=files, data={"name": "probe"})
            assert added.status_code == 201, added.text
            probe = added.json()["id"]
            try:
                results = library.get("/search/moments", params={"clip": probe, "k": 3})
                assert results.status_code == 200, results.text
                if not found_first(results.json()["results"], clip, truth):
                    misses.append(("clip", (clip["name"], truth, results.json()["results"][:2])))
            finally:
                assert library.delete(f"/clips/{probe}").status_code == 204
    with capsys.disabled():
        print(f"\nexact copies: {tried} spans of 1.25-4 s, {len(misses)} not first to a frame")
    assert not misses, misses


def test_filtered_clip_search_is_the_unfiltered_ranking_restricted(library: TestClient) -> None:
    stored = clips(library)
    by_id = {c["id"]: c for c in stored}
    labels = sorted({label.lower() for c in stored for label in c["labels"]})
    rng = np.random.default_rng(61)
    for _ in range(PROPERTY_QUERIES):
        clip = stored[int(rng.integers(len(stored)))]
        descriptor = str(rng.choice(["motion", "posture", "kinetic"]))
        query = {"clip": clip["id"], "descriptor": descriptor}

        def hits(query: dict[str, Any] = query, **params: Any) -> list[tuple[int, float]]:
            response = library.get("/search", params={**query, **params})
            assert response.status_code == 200, response.text
            return [(h["id"], h["distance"]) for h in response.json()["results"]]

        everything = hits(k=1000)
        assert len(everything) == len(stored) - 1
        label = labels[int(rng.integers(len(labels)))]
        carriers = {c["id"] for c in stored if label in {x.lower() for x in c["labels"]}}
        assert hits(k=10, label=label) == [h for h in everything if h[0] in carriers][:10]
        other = [h for h in everything if by_id[h[0]]["licence"] != BANDAI]
        assert hits(k=10, licence=f"!{BANDAI}") == other[:10]
        k = int(rng.integers(1, 20))
        assert hits(k=k) == everything[:k]
