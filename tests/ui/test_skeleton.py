"""GET /clips/{id}/skeleton and POST /skeleton: the joint positions the UI draws."""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.motion import display
from app.motion.body import build_body
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.skeleton_map import CANONICAL_BONES, CANONICAL_INDEX, CANONICAL_JOINTS
from app.services import previews
from app.services.lru import LRUCache
from app.services.preview_store import PREVIEWS_DIR
from tests.api.test_moments import long_take
from tests.calls import count_calls
from tests.conftest import SharedData
from tests.ui.conftest import ui_app, upload_asf_amc, upload_bvh

CMU_BVH = "cmu_mb_02_01_first41.bvh"  # 120 fps, 41 frames, the first an added T-pose
CMU_ASF, CMU_AMC = "cmu_02.asf", "cmu_02_01_first40.amc"
BANDAI = "bandai_walk_normal_001_first40.bvh"  # 30 fps, 40 frames


def frames_of(body: dict[str, object]) -> np.ndarray:
    return np.asarray(body["frames"], dtype=float)


def test_skeleton_is_the_motion_cores_joints_in_a_display_frame(
    ui_client: TestClient, fixtures_dir: Path
) -> None:
    path = fixtures_dir / CMU_BVH
    clip_id = upload_bvh(ui_client, path)
    response = ui_client.get(f"/clips/{clip_id}/skeleton", params={"fps": 120})
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "application/json"
    body = response.json()
    assert body["clip_id"] == clip_id and body["fps"] == 120
    assert body["joints"] == list(CANONICAL_JOINTS)
    assert body["bones"] == [list(b) for b in CANONICAL_BONES]
    assert body["units"] == "body heights"
    # The converter's T-pose frame is left out, as for the descriptors.
    assert body["lead_in_frames"] == 1 and body["frame_count"] == 40
    assert body["truncated"] is False and body["source_frame_count"] == 40
    frames = frames_of(body)
    assert frames.shape == (40, len(CANONICAL_JOINTS), 3)

    # Independently of how the endpoint builds its frame: the motion core's positions, in
    # body heights, moved rigidly (pairwise distances kept) with the world's up axis as y.
    core = build_body(read_bvh(path.read_bytes()))
    scaled = core.positions / core.height
    for f in (0, 17, 39):
        want = np.linalg.norm(scaled[f, :, None] - scaled[f, None, :], axis=-1)
        got = np.linalg.norm(frames[f, :, None] - frames[f, None, :], axis=-1)
        np.testing.assert_allclose(got, want, atol=2e-4)
    heights = scaled @ core.world_up
    floor = np.percentile(heights.min(axis=1), 5)  # robust to a frame gone wild
    np.testing.assert_allclose(frames[..., 1], heights - floor, atol=1e-4)

    pelvis, head = CANONICAL_INDEX["pelvis"], CANONICAL_INDEX["head"]
    # Origin: the floor under the first frame's pelvis; the floor is where the lowest joint
    # is in all but the 5 % of frames where it is lowest.
    np.testing.assert_allclose(frames[0, pelvis, [0, 2]], [0.0, 0.0], atol=1e-4)
    assert np.percentile(frames[..., 1].min(axis=1), 5) == pytest.approx(0.0, abs=1e-4)
    assert frames[0, head, 1] > frames[0, pelvis, 1] > frames[0, CANONICAL_INDEX["l_ankle"], 1]
    # Facing +z at the first frame: the subject's left hip is on +x, toes ahead of ankles.
    assert frames[0, CANONICAL_INDEX["l_hip"], 0] > frames[0, CANONICAL_INDEX["r_hip"], 0]
    for side in "lr":
        toe, ankle = CANONICAL_INDEX[f"{side}_toe"], CANONICAL_INDEX[f"{side}_ankle"]
        assert frames[0, toe, 2] > frames[0, ankle, 2]
    # ...and it walks forward.
    assert frames[-1, pelvis, 2] > frames[0, pelvis, 2]
    # Exactly the service's own transform, rounded to 4 decimals.
    np.testing.assert_array_equal(frames, np.round(display.display_positions(core), 4))


def test_frames_are_resampled_to_the_requested_rate(
    ui_client: TestClient, fixtures_dir: Path
) -> None:
    clip_id = upload_bvh(ui_client, fixtures_dir / CMU_BVH)
    full = frames_of(ui_client.get(f"/clips/{clip_id}/skeleton", params={"fps": 120}).json())
    quarter = ui_client.get(f"/clips/{clip_id}/skeleton", params={"fps": 30}).json()
    assert quarter["fps"] == 30 and quarter["frame_count"] == 10  # 39 intervals / 4 + 1
    assert quarter["duration"] == pytest.approx(9 / 30)
    # Up to 30 fps the frames come from the stored preview (float32, 30 fps): the file's
    # frames to the last decimal.
    np.testing.assert_allclose(frames_of(quarter), full[::4][:10], atol=1.01e-4)
    # Above 30 fps, from the file itself.
    half = frames_of(ui_client.get(f"/clips/{clip_id}/skeleton", params={"fps": 60}).json())
    np.testing.assert_array_equal(half, full[::2])
    # A rate that does not divide the preview's: linear interpolation in time.
    odd = frames_of(ui_client.get(f"/clips/{clip_id}/skeleton", params={"fps": 7}).json())
    assert odd.shape[0] == 3  # t = 0, 1/7, 2/7 s within 39/120 s
    source = 30 / 7
    low = int(np.floor(source))
    stored = frames_of(quarter)
    want = stored[low] + (source - low) * (stored[low + 1] - stored[low])
    np.testing.assert_allclose(odd[1], want, atol=2e-4)
    # Not whole: an overview of a long take at a frame every 5 s.
    slow = ui_client.get(f"/clips/{clip_id}/skeleton", params={"fps": 0.2}).json()
    assert slow["fps"] == 0.2 and slow["frame_count"] == 1
    # Default 30 fps.
    assert ui_client.get(f"/clips/{clip_id}/skeleton").json()["fps"] == 30


def test_long_clips_are_truncated_and_say_so(ui_client: TestClient, fixtures_dir: Path) -> None:
    clip_id = upload_bvh(ui_client, fixtures_dir / BANDAI)  # 30 fps, 40 frames
    whole = ui_client.get(f"/clips/{clip_id}/skeleton").json()
    assert whole["frame_count"] == 40 and whole["truncated"] is False
    cut = ui_client.get(f"/clips/{clip_id}/skeleton", params={"max_frames": 25}).json()
    assert cut["frame_count"] == 25 and cut["truncated"] is True
    assert cut["source_frame_count"] == 40
    assert cut["source_duration"] == pytest.approx(39 / 30)
    np.testing.assert_array_equal(frames_of(cut), frames_of(whole)[:25])
    assert previews.MAX_SKELETON_FRAMES == 600


def test_asf_amc_clip_has_a_skeleton_like_its_bvh_twin(
    ui_client: TestClient, fixtures_dir: Path
) -> None:
    amc_id = upload_asf_amc(ui_client, fixtures_dir / CMU_ASF, fixtures_dir / CMU_AMC)
    bvh_id = upload_bvh(ui_client, fixtures_dir / CMU_BVH)
    amc = ui_client.get(f"/clips/{amc_id}/skeleton", params={"fps": 120}).json()
    bvh = ui_client.get(f"/clips/{bvh_id}/skeleton", params={"fps": 120}).json()
    assert amc["frame_count"] == bvh["frame_count"] == 40
    a, b = frames_of(amc), frames_of(bvh)
    # Same capture, two conversions with slightly different bone lengths: the figures agree
    # to a few hundredths of a body height.
    assert np.abs(a - b).max() < 0.1
    assert np.median(np.abs(a - b)) < 0.03
    asf = (fixtures_dir / CMU_ASF).read_bytes()
    core = build_body(read_asf_amc(asf, (fixtures_dir / CMU_AMC).read_bytes()))
    np.testing.assert_array_equal(a, np.round(display.display_positions(core), 4))


@pytest.mark.parametrize(
    ("params", "word"),
    [
        ({"fps": 0}, "fps"),
        ({"fps": 1001}, "fps"),
        ({"max_frames": 0}, "max_frames"),
        ({"max_frames": 601}, "max_frames"),
        ({"encoding": "msgpack"}, "encoding"),
        ({"start": 1, "end": 0.5}, "start (1 s) must be before end"),
        ({"start": 2, "end": 3}, "the span [2 s, 3 s) lies outside the clip"),
        ({"start": -1}, "the span [-1 s, 1.33333 s) lies outside the clip"),
    ],
)
def test_bad_parameters_are_422(
    ui_client: TestClient, fixtures_dir: Path, params: dict[str, object], word: str
) -> None:
    clip_id = upload_bvh(ui_client, fixtures_dir / BANDAI)  # 40 frames at 30 fps
    response = ui_client.get(f"/clips/{clip_id}/skeleton", params=params)
    assert response.status_code == 422
    body = response.json()
    assert body["error"] == "invalid_input" and body["detail"].startswith(word), body


def test_unknown_clip_is_404_and_non_number_is_422(
    ui_client: TestClient, fixtures_dir: Path
) -> None:
    response = ui_client.get("/clips/999/skeleton")
    assert response.status_code == 404
    assert response.json() == {"error": "not_found", "detail": "no clip with id 999"}
    clip_id = upload_bvh(ui_client, fixtures_dir / BANDAI)
    response = ui_client.get(f"/clips/{clip_id}/skeleton", params={"fps": "fast"})
    assert response.status_code == 422 and response.json()["error"] == "invalid_input"


def count_reads(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """A list that grows by one each time a stored clip's file is parsed for a preview."""
    return count_calls(monkeypatch, previews, "read_stored_motion")


def test_skeletons_are_cached_and_carry_an_etag(
    ui_client: TestClient, fixtures_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    clip_id = upload_bvh(ui_client, fixtures_dir / BANDAI)
    reads = count_reads(monkeypatch)
    first = ui_client.get(f"/clips/{clip_id}/skeleton")
    again = ui_client.get(f"/clips/{clip_id}/skeleton")
    other_rate = ui_client.get(f"/clips/{clip_id}/skeleton", params={"fps": 15})
    assert first.content == again.content and other_rate.status_code == 200
    assert reads == []  # the preview stored with the clip answers every rate up to 30 fps
    etag = first.headers["etag"]
    assert etag != other_rate.headers["etag"]
    unchanged = ui_client.get(f"/clips/{clip_id}/skeleton", headers={"If-None-Match": etag})
    assert unchanged.status_code == 304 and unchanged.content == b""


def test_stored_previews_outlive_the_process(
    ui_client: TestClient, fixtures_dir: Path, settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A clip's file is parsed once: its preview is kept under the data directory, and a new
    server process (a new cache) answers from it; a damaged preview file is made again."""
    clip_id = upload_bvh(ui_client, fixtures_dir / CMU_BVH)
    first = ui_client.get(f"/clips/{clip_id}/skeleton", params={"fps": 15}).content
    stored = list((settings.data_dir / "previews").rglob("*.npz"))
    assert len(stored) == 1
    reads = count_reads(monkeypatch)
    with TestClient(ui_app(settings)) as fresh:
        assert fresh.get(f"/clips/{clip_id}/skeleton", params={"fps": 15}).content == first
        assert reads == []
    stored[0].write_bytes(b"not a preview")
    with TestClient(ui_app(settings)) as fresh:
        assert fresh.get(f"/clips/{clip_id}/skeleton", params={"fps": 15}).content == first
        assert reads == [1]
    assert np.load(stored[0])["positions"].dtype == np.float32  # stored anew


def test_lru_cache_keeps_the_most_recent() -> None:
    cache: LRUCache[int, str] = LRUCache(2)
    cache.put(1, "a")
    cache.put(2, "b")
    assert cache.get(1) == "a"  # 1 is now the most recent
    cache.put(3, "c")
    assert cache.get(2) is None and cache.get(1) == "a" and cache.get(3) == "c"
    assert len(cache) == 2


def test_lru_cache_bounded_by_weight() -> None:
    cache: LRUCache[int, bytes] = LRUCache(10, max_weight=10, weigh=len)
    cache.put(1, b"aaaa")
    cache.put(2, b"bbbb")
    cache.put(3, b"cccc")  # 12 > 10: the oldest goes
    assert cache.get(1) is None and cache.weight == 8
    cache.put(4, b"d" * 20)  # heavier than the bound alone: kept, everything else goes
    assert len(cache) == 1 and cache.get(4) == b"d" * 20
    cache.put(4, b"e")
    assert cache.weight == 1


def test_a_span_of_a_take(ui_client: TestClient, fixtures_dir: Path) -> None:
    """start/end pick any part of a take, in seconds of the file (lead-in included)."""
    take = ui_client.post("/clips", files={"file": ("take.bvh", long_take())}).json()
    whole = ui_client.get(f"/clips/{take['id']}/skeleton").json()  # 120 frames at 30 fps
    assert whole["start"] == 0 and whole["frame_count"] == 120
    part = ui_client.get(
        f"/clips/{take['id']}/skeleton", params={"start": 2, "end": 3, "max_frames": 600}
    ).json()
    assert part["start"] == pytest.approx(2, abs=1e-4)  # frames [60, 90) of the file
    assert part["frame_count"] == 30
    assert part["truncated"] is False
    np.testing.assert_array_equal(frames_of(part), frames_of(whole)[60:90])
    cut = ui_client.get(
        f"/clips/{take['id']}/skeleton", params={"start": 2, "max_frames": 10}
    ).json()
    assert cut["frame_count"] == 10 and cut["truncated"] is True
    np.testing.assert_array_equal(frames_of(cut), frames_of(whole)[60:70])
    # A file with a lead-in frame: file time 0.1 s is its frame 12, the preview's frame 11.
    clip_id = upload_bvh(ui_client, fixtures_dir / CMU_BVH)
    full = frames_of(ui_client.get(f"/clips/{clip_id}/skeleton", params={"fps": 120}).json())
    late = ui_client.get(
        f"/clips/{clip_id}/skeleton", params={"fps": 120, "start": 0.1, "end": 0.2}
    ).json()
    assert late["start"] == pytest.approx(12 / 120, abs=1e-4) and late["lead_in_frames"] == 1
    np.testing.assert_array_equal(frames_of(late), full[11 : 11 + late["frame_count"]])


def test_compact_encoding_is_the_same_frames(ui_client: TestClient, fixtures_dir: Path) -> None:
    clip_id = upload_bvh(ui_client, fixtures_dir / BANDAI)
    plain = ui_client.get(f"/clips/{clip_id}/skeleton").json()
    response = ui_client.get(f"/clips/{clip_id}/skeleton", params={"encoding": "compact"})
    compact = response.json()
    assert compact["encoding"] == "compact" and "frames" not in compact
    count, joints = compact["frame_count"], len(compact["joints"])
    root = np.frombuffer(base64.b64decode(compact["root"]), "<f4").reshape(count, 3)
    offsets = np.frombuffer(base64.b64decode(compact["offsets"]), "<i2").reshape(count, joints, 3)
    decoded = root[:, None] + offsets * compact["offset_unit"]
    np.testing.assert_allclose(decoded, frames_of(plain), atol=1.5e-4)
    assert len(response.content) < len(json.dumps(plain)) / 2
    # The extent: a standing walker, measured on every stored frame (also for an overview).
    extent = compact["extent"]
    assert 0.8 < extent["height"] < 1.1 and 0.1 < extent["reach"] < 0.6
    overview = ui_client.get(f"/clips/{clip_id}/skeleton", params={"fps": 1}).json()
    assert overview["frame_count"] == 2 and overview["extent"] == extent


def test_responses_are_compressed_when_large(ui_client: TestClient, fixtures_dir: Path) -> None:
    """JSON is gzipped for clients that accept it; small answers and downloads are not."""
    clip_id = upload_bvh(ui_client, fixtures_dir / BANDAI)
    big = ui_client.get(f"/clips/{clip_id}/skeleton", headers={"Accept-Encoding": "gzip"})
    assert big.headers["content-encoding"] == "gzip"
    assert int(big.headers["content-length"]) < len(big.content) / 3
    small = ui_client.get("/health", headers={"Accept-Encoding": "gzip"})
    assert "content-encoding" not in small.headers
    download = ui_client.get(f"/clips/{clip_id}/file", headers={"Accept-Encoding": "gzip"})
    assert download.status_code == 200 and "content-encoding" not in download.headers
    plain = ui_client.get(f"/clips/{clip_id}/skeleton", headers={"Accept-Encoding": "identity"})
    assert "content-encoding" not in plain.headers and plain.json() == big.json()


def test_skeleton_of_an_uploaded_file(ui_client: TestClient, fixtures_dir: Path) -> None:
    path = fixtures_dir / BANDAI
    clip_id = upload_bvh(ui_client, path)
    stored = ui_client.get(f"/clips/{clip_id}/skeleton").json()
    response = ui_client.post("/skeleton", files={"file": (path.name, path.read_bytes())})
    assert response.status_code == 200, response.text
    uploaded = response.json()
    assert uploaded["clip_id"] is None
    # The stored clip's frames come from its stored preview (float32): to the last decimal.
    np.testing.assert_allclose(frames_of(uploaded), frames_of(stored), atol=1.01e-4)
    asf, amc = fixtures_dir / CMU_ASF, fixtures_dir / CMU_AMC
    pair = ui_client.post(
        "/skeleton",
        params={"fps": 120},
        files={"skeleton": (asf.name, asf.read_bytes()), "motion": (amc.name, amc.read_bytes())},
    )
    assert pair.status_code == 200 and pair.json()["frame_count"] == 40


def test_skeleton_of_a_broken_upload_names_the_file(ui_client: TestClient) -> None:
    response = ui_client.post(
        "/skeleton", files={"file": ("broken.bvh", b"HIERARCHY\nROOT Hips\n{\n")}
    )
    assert response.status_code == 422
    body = response.json()
    assert body["error"] == "parse_error" and "'broken.bvh'" in body["detail"]
    response = ui_client.post("/skeleton", files={"file": ("walk.obj", b"x")})
    assert response.status_code == 415


def test_skeleton_of_an_upload_with_an_overflowed_number_is_refused_as_its_upload_is(
    ui_client: TestClient, fixtures_dir: Path
) -> None:
    """Found by the upload fuzz: a frame value of 1e308 puts a hand 1e305 body heights out,
    finite, until the preview's reach overflowed to inf, which no JSON holds: a 500. The
    preview now takes the body an upload is described from, and its verdict."""
    text = (fixtures_dir / BANDAI).read_text()
    head, frames = text.split("Frame Time:")
    lines = frames.split("\n")
    values = lines[20].split()
    values[56] = "1e308"  # frame 20: a joint's Zposition (every Bandai joint has six channels)
    lines[20] = " ".join(values)
    damaged = (head + "Frame Time:" + "\n".join(lines)).encode()
    response = ui_client.post("/skeleton", files={"file": ("b.bvh", damaged)})
    assert response.status_code == 422, response.text
    detail = response.json()["detail"]
    assert "frame 20" in detail and "'b.bvh'" in detail, detail


@pytest.mark.slow
def test_skeleton_of_a_whole_cmu_clip(ui_client: TestClient, shared_data: SharedData) -> None:
    path = shared_data("cmu", "bvh-mb", "02", "02_01.bvh")
    clip_id = upload_bvh(ui_client, path)
    body = ui_client.get(f"/clips/{clip_id}/skeleton").json()
    core = build_body(read_bvh(path.read_bytes()))
    assert body["source_frame_count"] == core.frame_count
    assert body["frame_count"] == int(np.floor((core.frame_count - 1) / 4)) + 1
    # The file's frame time is 0.008333 s, not 1/120: output frames drift off the source's
    # over the clip (by 1% of a frame at frame 250) and are interpolated between two.
    np.testing.assert_allclose(frames_of(body), display.display_positions(core)[::4], atol=1e-3)


def test_display_up_is_the_nearest_axis() -> None:
    np.testing.assert_array_equal(display.display_up(np.array([0.45, 0.78, 0.43])), [0, 1, 0])
    np.testing.assert_array_equal(display.display_up(np.array([0.1, -0.2, -0.9])), [0, 0, -1])


@pytest.mark.slow
@pytest.mark.parametrize(
    "name", ["dataset-1_walk-left_sad_001.bvh", "dataset-1_dash_normal_001.bvh"]
)
def test_leaning_clips_stay_on_the_floor(
    ui_client: TestClient, shared_data: SharedData, name: str
) -> None:
    # The body leans over 30 degrees on average in these clips: the motion core's world_up
    # is tilted there, and a figure drawn on it would rise as it travels.
    path = shared_data("bandai-ds1", "data", name)
    clip_id = upload_bvh(ui_client, path)
    frames = frames_of(ui_client.get(f"/clips/{clip_id}/skeleton").json())
    pelvis = frames[:, CANONICAL_INDEX["pelvis"]]
    travel = np.linalg.norm(pelvis[-1, [0, 2]] - pelvis[0, [0, 2]])
    assert travel > 1.0  # it goes somewhere, over the floor
    assert np.ptp(pelvis[:, 1]) < 0.15  # ...without rising or sinking
    feet = frames[:, [CANONICAL_INDEX["l_toe"], CANONICAL_INDEX["r_toe"]], 1].min(axis=1)
    assert feet.max() < 0.2  # a foot is near the floor in every frame


def test_an_uploaded_clip_is_previewed_without_parsing_it_again(
    ui_client: TestClient, fixtures_dir: Path, settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``POST /clips`` stores the clip's preview (made from the body the describer built):
    the first view reads it, and it is what parsing the clip again gives."""
    clip_id = upload_bvh(ui_client, fixtures_dir / CMU_BVH)
    stored = list((settings.data_dir / PREVIEWS_DIR).rglob("*.npz"))
    assert len(stored) == 1
    written = stored[0].stat().st_mtime_ns
    reads = count_reads(monkeypatch)
    shown = {
        encoding: ui_client.get(
            f"/clips/{clip_id}/skeleton", params={"fps": 15, "encoding": encoding}
        ).content
        for encoding in previews.ENCODINGS
    }
    cache: previews.SkeletonCache = ui_client.app.state.skeleton_cache  # type: ignore[attr-defined]
    assert reads == [] and len(cache.motions) == 0  # no clip was parsed
    assert stored[0].stat().st_mtime_ns == written  # read, not made again
    stored[0].unlink()
    with TestClient(ui_app(settings)) as fresh:  # nothing stored: the clip is parsed
        for encoding, content in shown.items():
            again = fresh.get(
                f"/clips/{clip_id}/skeleton", params={"fps": 15, "encoding": encoding}
            )
            assert again.content == content
    assert reads == [1]


def test_an_upload_is_stored_when_its_preview_cannot_be(
    ui_client: TestClient, fixtures_dir: Path, settings: Settings
) -> None:
    # A file where the previews folder should be: nothing can be written there, even by root.
    (settings.data_dir / PREVIEWS_DIR).write_bytes(b"not a folder")
    clip_id = upload_asf_amc(ui_client, fixtures_dir / CMU_ASF, fixtures_dir / CMU_AMC)
    assert ui_client.get(f"/clips/{clip_id}").status_code == 200
    response = ui_client.get(f"/clips/{clip_id}/skeleton")
    assert response.status_code == 200 and response.json()["frame_count"] > 0
