"""Every limit setting is enforced end to end (real app, real motion core), and the upload size
limit also on a live server: from ``Content-Length`` before the body is sent, and while a
chunked body streams in."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.services.describe import MotionDescriber
from app.services.uploads import Upload
from tests.hardening.live import LiveServer, raw_request, unique_upload


def client_with(settings: Settings, **changes: Any) -> TestClient:
    return TestClient(create_app(Settings(data_dir=settings.data_dir, **changes)))


def assert_error(response: Any, status: int, code: str, *words: str) -> None:
    assert response.status_code == status, response.text
    body = response.json()
    assert set(body) == {"error", "detail"} and body["error"] == code, body
    for word in words:
        assert word in body["detail"], body["detail"]


# The real BVH fixture: 41 frames, 38 joints (end sites included), 11 levels deep, 34 kB.
@pytest.mark.parametrize(
    ("changes", "status", "code", "words"),
    [
        ({"max_frames": 40}, 422, "limit_exceeded", ("41 frames", "limit of 40")),
        ({"max_joints": 37}, 422, "limit_exceeded", ("joints", "limit of 37")),
        ({"max_depth": 10}, 422, "limit_exceeded", ("nested deeper", "limit of 10")),
        ({"max_frame_values": 10_000}, 422, "limit_exceeded", ("values", "limit of 10000")),
        ({"max_upload_bytes": 20_000}, 413, "payload_too_large", ("MOCAP_MAX_UPLOAD_BYTES",)),
        (
            {"describe_timeout_seconds": 1e-9},
            503,
            "describe_timeout",
            ("MOCAP_DESCRIBE_TIMEOUT_SECONDS", "try again"),
        ),
    ],
)
def test_clip_limits(
    settings: Settings, changes: dict[str, Any], status: int, code: str, words: tuple[str, ...]
) -> None:
    with client_with(settings, **changes) as client:
        for url in ("/clips", "/search"):
            assert_error(client.post(url, files=unique_upload(0)), status, code, *words)
        assert client.get("/health").json()["clips"] == 0
        assert not settings.files_dir.exists() or not any(settings.files_dir.rglob("*.*"))


def test_the_same_clip_passes_at_the_limits(settings: Settings) -> None:
    exact = {"max_frames": 41, "max_joints": 38, "max_depth": 11, "max_frame_values": 41 * 38 * 9}
    with client_with(settings, **exact) as client:
        assert client.post("/clips", files=unique_upload(0)).status_code == 201


def test_k_and_page_size_limits(settings: Settings) -> None:
    with client_with(settings, max_k=5, max_page_size=3) as client:
        clip = client.post("/clips", files=unique_upload(0)).json()
        assert client.get("/search", params={"clip": clip["id"], "k": 5}).status_code == 200
        assert_error(
            client.get("/search", params={"clip": clip["id"], "k": 6}),
            422,
            "invalid_input",
            "between 1 and 5",
        )
        assert_error(
            client.post("/search", params={"k": 6}, files=unique_upload(1)),
            422,
            "invalid_input",
            "between 1 and 5",
        )
        assert client.get("/clips", params={"limit": 3}).status_code == 200
        assert_error(client.get("/clips", params={"limit": 4}), 422, "invalid_input", "limit")


def test_describe_time_is_checked_between_stages(monkeypatch: pytest.MonkeyPatch) -> None:
    """A slow parse (simulated clock) is caught before the descriptors are computed (inside
    the read since the readers look at the deadline themselves, or right after it)."""
    from app.services import describe as describe_module

    clock = iter([0.0, 10.0, 10.0, 10.0])
    monkeypatch.setattr(describe_module.time, "monotonic", lambda: next(clock))
    computed: list[object] = []
    monkeypatch.setattr(describe_module, "analyse", lambda *a, **k: computed.append(a))
    describer = MotionDescriber(time_limit=5.0)
    upload = Upload.from_files(file=unique_upload(0)["file"])
    with pytest.raises(describe_module.DescribeTimeout, match="reading the file"):
        describer.describe(upload, Settings().parse_limits)
    assert computed == []


# -- on a live server ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    data_dir = tmp_path_factory.mktemp("limits") / "data"
    with LiveServer(data_dir, {"MOCAP_MAX_UPLOAD_BYTES": "100000"}) as server:
        yield server


def test_declared_length_over_the_limit_is_refused_before_the_body(
    small_server: LiveServer,
) -> None:
    head = (
        b"POST /clips HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        b"Content-Type: multipart/form-data; boundary=xx\r\n"
        b"Content-Length: 1000000000\r\n\r\n"
    )
    answer = raw_request(small_server, head, [])  # not a byte of the gigabyte is sent
    assert answer.startswith(b"HTTP/1.1 413"), answer[:200]
    assert b"payload_too_large" in answer


def test_chunked_body_over_the_limit_is_cut_off_while_streaming(small_server: LiveServer) -> None:
    head = (
        b"POST /clips HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        b"Content-Type: multipart/form-data; boundary=xx\r\n"
        b"Transfer-Encoding: chunked\r\n\r\n"
    )
    part = b'--xx\r\nContent-Disposition: form-data; name="file"; filename="a.bvh"\r\n\r\n'
    chunk = b"0 " * 5000
    chunks = [b"%x\r\n%s\r\n" % (len(part), part)]
    chunks += [b"%x\r\n%s\r\n" % (len(chunk), chunk)] * 100  # 1 MB in all, 10x the limit
    chunks.append(b"0\r\n\r\n")
    answer = raw_request(small_server, head, chunks)
    assert answer.startswith(b"HTTP/1.1 413"), answer[:200]
    health = httpx.get(f"{small_server.url}/health", timeout=10)
    assert health.status_code == 200 and health.json()["clips"] == 0
    assert not list(Path(small_server.data_dir / "files").glob("*/*"))


def test_a_stalled_upload_does_not_hold_back_every_other_upload(tmp_path: Path) -> None:
    """A client that sends the head of an upload declaring a large body, a few bytes of it,
    then nothing more, is cut off (408) once the grace is over; other uploads, answered 503
    ``busy`` while it held the gate's whole budget, go in again. Before: it held the budget
    for as long as its connection stayed open (90 s and more measured), and every upload of
    every client got 503."""
    from app.api.limits import BODY_GRACE_SECONDS

    env = {"MOCAP_MAX_CONCURRENT_DESCRIBES": "1", "MOCAP_MAX_UPLOAD_BYTES": "1000000"}
    with LiveServer(tmp_path / "data", env) as server:
        head = (
            b"POST /search HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            b"Content-Type: multipart/form-data; boundary=xx\r\n"
            b"Content-Length: 1000000\r\n\r\n"  # the whole budget of the one slot
            b'--xx\r\nContent-Disposition: form-data; name="file"; filename="a.bvh"\r\n\r\n'
        )
        started = time.monotonic()
        with socket.create_connection(("127.0.0.1", server.port), timeout=60) as stalled:
            stalled.sendall(head + b"HIERARCHY\n")
            time.sleep(0.5)  # let in by the gate
            with httpx.Client(base_url=server.url, timeout=30) as client:
                meanwhile = client.post("/search", files=unique_upload(1))
                assert_error(meanwhile, 503, "busy")
                answer = b""
                while b"\r\n\r\n" not in answer or not answer.rstrip().endswith(b"}"):
                    data = stalled.recv(65536)
                    if not data:
                        break
                    answer += data
                waited = time.monotonic() - started
                assert answer.startswith(b"HTTP/1.1 408"), answer[:300]
                assert b"request_timeout" in answer and b"came too slowly" in answer, answer
                assert BODY_GRACE_SECONDS - 1 < waited < BODY_GRACE_SECONDS + 10, waited
                after = client.post("/search", files=unique_upload(2))
                assert after.status_code == 200, after.text
                stored = client.post("/clips", files=unique_upload(3))
                assert stored.status_code == 201, stored.text
