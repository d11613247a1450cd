"""The upload fuzz suite: real files of every format, damaged at random, sent to the real
service over HTTP (``mocap-index serve`` in a subprocess).

Sources: the real fixtures of ``tests/fixtures`` — two BVH files, an ASF skeleton with its AMC
motion, a binary FBX, a VRM animation (a GLB container), and a real BVH clip written as a
skinned GLB and as a ``.gltf`` with its buffer embedded. Damage (hypothesis draws 1-3 of
them): bit flips, truncation, duplicated and removed lines (or byte ranges), numbers replaced
by huge or non-finite values (in the text, in a glTF's JSON, as float32 in its binary chunk),
long tokens, and a wrong file extension. Each damaged upload goes to ``POST /clips`` (with the
API key) and to one of ``POST /search``, ``POST /search/moments`` or ``POST /skeleton``
(without), and every answer must:

* never be a 5xx, and a 4xx must be the one error shape;
* come within :data:`ANSWER_LIMIT` (the server runs with a 10-s describe and parser limit);
* never hold ``/health`` up: it is asked every 50 ms during each request and must answer
  within :data:`HEALTH_LIMIT` (1 s) every time;
* store nothing when refused: the clip count, every index and the stored files unchanged (an
  accepted upload is deleted again).

Budget: ``MOCAP_FUZZ_SECONDS`` (default 40 s of fuzzing, the whole module about 1.5 minutes
in CI), at most ``MOCAP_UPLOAD_FUZZ_EXAMPLES`` examples; CI draws the same examples every run
(hypothesis ``derandomize``), ``MOCAP_FUZZ_RANDOM=1`` draws new ones (docs/hardening.md
records long runs). A failing input is written to ``tests/hostile/found/`` with an entry in
``found.json`` (:func:`tests.hostile.make_corpus.record_found`) before the test fails: commit
it, and :func:`test_every_failure_ever_found_stays_fixed` replays it from then on.
"""

from __future__ import annotations

import base64
import contextlib
import hashlib
import json
import os
import re
import struct
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from app.motion.formats import read_bvh
from tests.hardening.live import FIXTURES, LiveServer
from tests.hostile import make_corpus
from tests.hostile.make_corpus import Case
from tests.motion.gltf_builder import gltf_parts, pack_glb

KEY = "upload-fuzz-key-81c"
SECONDS = float(os.environ.get("MOCAP_FUZZ_SECONDS", "40"))
EXAMPLES = int(os.environ.get("MOCAP_UPLOAD_FUZZ_EXAMPLES", "2000"))
RANDOM = os.environ.get("MOCAP_FUZZ_RANDOM") == "1"
LIMIT_SECONDS = 10  # the server's describe and parser time limits here
ANSWER_LIMIT = 3 * LIMIT_SECONDS  # a stage may overrun the describe limit once: be generous
HEALTH_LIMIT = 1.0
HEALTH_EVERY = 0.05
READ_ROUTES = ("/search", "/search/moments", "/skeleton")
# A word of digits then a letter once took the BVH and AMC readers time growing with the
# square of its length (issue 21, item 1; regression fixtures in tests/hostile/found.json).
LONG_NUMBER_WORD = 100_000
LONG_TOKEN = 100_000  # letters only, or digits only (a huge but well-formed number)


# -- sources ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Source:
    """A real upload: its parts (role -> file name, bytes) and how each part is built."""

    name: str
    parts: dict[str, tuple[str, bytes]] = field(repr=False)
    container: bool = False  # a GLB: its JSON and binary chunks are damaged apart too


def glb_chunks(data: bytes) -> tuple[bytes, bytes] | None:
    """The JSON and binary chunks of a GLB; None once earlier damage broke its frame."""
    try:
        json_length = struct.unpack_from("<I", data, 12)[0]
        rest = data[20 + json_length :]
        binary_length = struct.unpack_from("<I", rest, 0)[0] if rest else 0
    except struct.error:
        return None
    if data[:4] != b"glTF" or 20 + json_length > len(data) or 8 + binary_length > max(len(rest), 8):
        return None
    return data[20 : 20 + json_length], rest[8 : 8 + binary_length]


def repack_glb(text: bytes, binary: bytes) -> bytes:
    """A GLB of these chunks, lengths and padding right (so the damage is inside them)."""
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text
    if binary:
        chunks += struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def fixture(name: str) -> bytes:
    return (FIXTURES / name).read_bytes()


def sources() -> list[Source]:
    bvh = fixture("cmu_mb_02_01_first41.bvh")
    document, binary = gltf_parts(read_bvh(bvh.decode()).slice_frames(0, 20), name="walk")
    embedded = json.loads(json.dumps(document))
    data_uri = "data:application/octet-stream;base64," + base64.b64encode(binary).decode()
    embedded["buffers"][0]["uri"] = data_uri
    asf_amc = {
        "skeleton": ("02.asf", fixture("cmu_02.asf")),
        "motion": ("02_01.amc", fixture("cmu_02_01_first40.amc")),
    }
    return [
        Source("bvh_cmu", {"file": ("walk.bvh", bvh)}),
        Source("bvh_bandai", {"file": ("b.bvh", fixture("bandai_walk_normal_001_first40.bvh"))}),
        Source("asf_amc", asf_amc),
        Source("fbx", {"file": ("human.fbx", fixture("ufbx_maya_human_ik_7400_binary.fbx"))}),
        Source("vrma", {"file": ("test.vrma", fixture("three_vrm_test.vrma"))}, container=True),
        Source("glb", {"file": ("walk.glb", pack_glb(document, binary))}, container=True),
        Source("gltf", {"file": ("walk.gltf", json.dumps(embedded).encode())}),
    ]


SOURCES = sources()


# -- damage ------------------------------------------------------------------------------------

NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
SPECIAL_NUMBERS = [
    b"1e308",
    b"-1e308",
    b"1e309",
    b"-1e400",
    b"nan",
    b"NaN",
    b"inf",
    b"-inf",
    b"Infinity",
    b"1e-400",
    b"1" + b"0" * 400,
    b"0x1p3",
    b"1_000",
]
SPECIAL_FLOATS = [np.inf, -np.inf, np.nan, 3.4e38, -3.4e38, 1e-45, 0.0]
WRONG_EXTENSIONS = [".bvh", ".fbx", ".glb", ".gltf", ".vrma", ".amc", ".txt"]


@st.composite
def byte_damage(draw: st.DrawFn, data: bytes) -> tuple[bytes, str]:
    """Damage any file: flips, a cut, a byte range repeated or removed."""
    if not data:
        return data, "empty"
    kind = draw(st.sampled_from(["flip", "truncate", "repeat", "remove"]))
    if kind == "flip":
        out = bytearray(data)
        count = draw(st.integers(1, 16))
        for _ in range(count):
            at = draw(st.integers(0, len(out) - 1))
            out[at] ^= 1 << draw(st.integers(0, 7))
        return bytes(out), f"{count} bits flipped"
    at = draw(st.integers(0, len(data) - 1))
    if kind == "truncate":
        return data[:at], f"cut at byte {at}"
    length = draw(st.integers(1, min(4096, len(data) - at)))
    if kind == "repeat":
        return data[: at + length] + data[at:], f"{length} bytes at {at} repeated"
    return data[:at] + data[at + length :], f"{length} bytes at {at} removed"


@st.composite
def text_damage(draw: st.DrawFn, data: bytes) -> tuple[bytes, str]:
    """Damage a text file (or a glTF's JSON): lines, numbers, long tokens, or bytes."""
    kind = draw(st.sampled_from(["bytes", "line", "line", "number", "number", "token"]))
    if kind == "bytes":
        return draw(byte_damage(data))
    if kind == "line":
        lines = data.split(b"\n")
        at = draw(st.integers(0, len(lines) - 1))
        if draw(st.booleans()):
            times = draw(st.integers(1, 50))
            return b"\n".join(lines[:at] + [lines[at]] * (times + 1) + lines[at + 1 :]), (
                f"line {at + 1} repeated {times}x"
            )
        return b"\n".join(lines[:at] + lines[at + 1 :]), f"line {at + 1} removed"
    numbers = list(NUMBER.finditer(data))
    if kind == "number" and numbers:
        match = numbers[draw(st.integers(0, len(numbers) - 1))]
        value = draw(st.sampled_from(SPECIAL_NUMBERS))
        return data[: match.start()] + value + data[match.end() :], (
            f"number at byte {match.start()} -> {value[:20].decode()}"
        )
    spaces = [m.start() for m in re.finditer(rb"\s", data)] or [0]
    at = spaces[draw(st.integers(0, len(spaces) - 1))]
    shape = draw(st.sampled_from(["letters", "digits", "number_word"]))
    if shape == "number_word":
        token = b"1" * draw(st.integers(1, LONG_NUMBER_WORD)) + b"e"
    else:
        token = (b"x" if shape == "letters" else b"7") * draw(st.integers(1, LONG_TOKEN))
    return data[: at + 1] + token + b" " + data[at + 1 :], f"{len(token)}-byte {shape} at {at}"


@st.composite
def float_damage(draw: st.DrawFn, binary: bytes) -> tuple[bytes, str]:
    """Overwrite float32 values of a glTF binary chunk with non-finite or extreme ones."""
    if len(binary) < 4:
        return binary, "no binary"
    values = np.frombuffer(binary[: len(binary) // 4 * 4], dtype="<f4").copy()
    count = draw(st.integers(1, 8))
    for _ in range(count):
        values[draw(st.integers(0, len(values) - 1))] = draw(st.sampled_from(SPECIAL_FLOATS))
    return values.tobytes() + binary[len(values) * 4 :], f"{count} float32 values replaced"


@st.composite
def damaged_part(draw: st.DrawFn, source: Source, data: bytes, text: bool) -> tuple[bytes, str]:
    chunks = glb_chunks(data) if source.container else None
    if chunks is not None and draw(st.booleans()):
        chunk, binary = chunks
        if draw(st.booleans()):
            chunk, note = draw(text_damage(chunk))
            return repack_glb(chunk, binary), f"JSON chunk: {note}"
        binary, note = draw(st.one_of(float_damage(binary), byte_damage(binary)))
        return repack_glb(chunk, binary), f"binary chunk: {note}"
    return draw(text_damage(data) if text else byte_damage(data))


@dataclass(frozen=True)
class FuzzCase:
    source: str
    parts: dict[str, tuple[str, bytes]] = field(repr=False)
    damage: tuple[str, ...]
    read_route: str

    @property
    def name(self) -> str:
        digest = hashlib.sha256()
        for role, (filename, data) in sorted(self.parts.items()):
            digest.update(f"{role}:{filename}:".encode() + data)
        return f"fuzz_{self.source}_{digest.hexdigest()[:12]}"

    def __repr__(self) -> str:  # what hypothesis prints for a failing example
        sizes = {role: (name, len(data)) for role, (name, data) in self.parts.items()}
        return f"FuzzCase({self.source}, {sizes}, {list(self.damage)}, {self.read_route})"

    def _repr_pretty_(self, printer: Any, cycle: bool) -> None:
        # Hypothesis's printer would otherwise spell out every byte of the files (up to 1 MB).
        printer.text(repr(self))


@st.composite
def fuzz_cases(draw: st.DrawFn, choices: Sequence[Source] = SOURCES) -> FuzzCase:
    source = draw(st.sampled_from(choices))
    parts = dict(source.parts)
    role = draw(st.sampled_from(sorted(parts)))
    filename, data = parts[role]
    text = Path(filename).suffix in (".bvh", ".asf", ".amc", ".gltf")
    damage = []
    for _ in range(draw(st.integers(1, 3))):
        data, note = draw(damaged_part(source, data, text))
        damage.append(f"{role}: {note}")
    if role == "file" and draw(st.integers(0, 9)) == 0:
        extension = draw(st.sampled_from(WRONG_EXTENSIONS))
        filename = Path(filename).stem + extension
        damage.append(f"named {filename}")
    parts[role] = (filename, data)
    return FuzzCase(source.name, parts, tuple(damage), draw(st.sampled_from(READ_ROUTES)))


# -- the rules every answer keeps --------------------------------------------------------------


class HealthWatch:
    """Asks ``/health`` every :data:`HEALTH_EVERY` s on its own connection while a request
    runs; ``slowest`` is the longest answer (or wait without one), ``bad`` the non-200s."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.slowest = 0.0
        self.bad: list[str] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        with httpx.Client(base_url=self.url, timeout=ANSWER_LIMIT) as client:
            while not self._stop.is_set():
                started = time.monotonic()
                try:
                    status = client.get("/health").status_code
                except httpx.HTTPError as error:
                    status = 0
                    self.bad.append(f"/health: {type(error).__name__}")
                self.slowest = max(self.slowest, time.monotonic() - started)
                if status not in (0, 200):
                    self.bad.append(f"/health answered {status}")
                self._stop.wait(HEALTH_EVERY)

    def __enter__(self) -> HealthWatch:
        self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        self._thread.join(timeout=ANSWER_LIMIT + 5)


def stored_state(server: LiveServer, client: httpx.Client) -> tuple[Any, ...]:
    """What a refused upload must leave as it was: clip count, index sizes, stored files."""
    health = client.get("/health").json()
    files = sorted(str(p.relative_to(server.data_dir)) for p in server.data_dir.glob("files/**/*"))
    sizes = tuple(sorted((name, index["size"]) for name, index in health["indexes"].items()))
    return health["clips"], sizes, tuple(files)


def send(
    server: LiveServer, client: httpx.Client, url: str, parts: dict[str, tuple[str, bytes]]
) -> tuple[httpx.Response | None, list[str]]:
    """POST ``parts`` to ``url`` while watching ``/health``; the answer and what was wrong."""
    headers = {"X-API-Key": KEY} if url == "/clips" else {}
    problems = []
    response = None
    with HealthWatch(server.url) as watch:
        started = time.monotonic()
        try:
            response = client.post(url, files=parts, headers=headers, timeout=ANSWER_LIMIT)
        except httpx.HTTPError as error:
            problems.append(f"{url}: no answer within {ANSWER_LIMIT} s ({type(error).__name__})")
        elapsed = time.monotonic() - started
    if watch.slowest > HEALTH_LIMIT or watch.bad:
        problems.append(
            f"{url}: /health took {watch.slowest:.2f} s during the request (limit "
            f"{HEALTH_LIMIT} s){'; ' + ', '.join(watch.bad[:3]) if watch.bad else ''}"
        )
    if response is not None:
        if response.status_code >= 500:
            problems.append(f"{url}: {response.status_code} {response.text[:300]}")
        elif response.status_code >= 400:
            try:
                body = response.json()
            except ValueError:
                body = None
            if not (isinstance(body, dict) and set(body) == {"error", "detail"}):
                problems.append(f"{url}: {response.status_code} not in the error shape")
        if elapsed > ANSWER_LIMIT:
            problems.append(f"{url}: answered after {elapsed:.1f} s (limit {ANSWER_LIMIT} s)")
    return response, problems


def check_upload(
    server: LiveServer, client: httpx.Client, parts: dict[str, tuple[str, bytes]], read_route: str
) -> tuple[int, list[str]]:
    """Every rule of the module docstring for one upload: ``POST /clips``'s status and the
    problems found (the read route is tried only when ``/clips`` kept every rule)."""
    before = stored_state(server, client)
    response, problems = send(server, client, "/clips", parts)
    status = 0 if response is None else response.status_code
    if status in (200, 201):
        assert response is not None
        clip = response.json()["id"]
        deleted = client.delete(f"/clips/{clip}", headers={"X-API-Key": KEY})
        if deleted.status_code != 204:
            problems.append(f"could not delete the accepted clip {clip}: {deleted.status_code}")
    after = stored_state(server, client)
    if after != before:
        problems.append(f"/clips left something behind: {before} -> {after}")
    if problems:
        return status, problems
    problems += send(server, client, read_route, parts)[1]
    if stored_state(server, client) != before:
        problems.append(f"{read_route} stored something")
    return status, problems


# -- the tests ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    data_dir = tmp_path_factory.mktemp("upload-fuzz") / "data"
    env = {
        "MOCAP_API_KEY": KEY,
        "MOCAP_DESCRIBE_TIMEOUT_SECONDS": str(LIMIT_SECONDS),
        "MOCAP_PARSER_TIMEOUT_SECONDS": str(LIMIT_SECONDS),
        "MOCAP_ORPHAN_FILE_GRACE_SECONDS": "0",
    }
    with LiveServer(data_dir, env) as live:
        yield live
    assert "Traceback" not in live.log(), live.log()[-3000:]


@pytest.fixture(scope="module")
def client(server: LiveServer) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=server.url, timeout=ANSWER_LIMIT) as http:
        yield http


def test_every_source_is_accepted_undamaged(server: LiveServer, client: httpx.Client) -> None:
    """The starting points are good uploads: the damage, not the source, makes a refusal."""
    for source in SOURCES:
        status, problems = check_upload(server, client, source.parts, "/search")
        assert status == 201 and not problems, (source.name, status, problems)


class BudgetSpent(Exception):
    """A format's share of the fuzzing budget ran out (not a failure)."""


def fuzz_one_source(
    server: LiveServer, client: httpx.Client, source: Source, deadline: float, seen: dict[str, int]
) -> None:
    """Damaged uploads of ``source`` until ``deadline`` (at least one)."""

    @settings(
        max_examples=max(1, EXAMPLES // len(SOURCES)),
        deadline=None,
        database=None,
        derandomize=not RANDOM,
        phases=[Phase.generate],  # a failing input is kept as found, not shrunk
        suppress_health_check=list(HealthCheck),
    )
    @given(case=fuzz_cases(choices=(source,)))
    def one(case: FuzzCase) -> None:
        if time.monotonic() > deadline and seen.get(case.source) and not failures:
            # Ends the run: returning would let hypothesis draw its remaining examples,
            # each a damaged file (35-110 s of drawing after a 60-s budget).
            raise BudgetSpent
        seen[case.source] = seen.get(case.source, 0) + 1
        _status, problems = check_upload(server, client, case.parts, case.read_route)
        if problems:
            found = "; ".join(problems)[:1000]
            why = f"upload fuzz: {case.source}, {'; '.join(case.damage)}"[:500]
            make_corpus.record_found(Case(case.name, why, case.parts, 0, "", ""), found)
            failures.append(f"{found}\nkept as {case.name} in tests/hostile/found.json: commit it")
            raise AssertionError(failures[0])

    # A failure is kept aside: hypothesis replays a failing example, and a replay past the
    # budget must fail again, not end the run as spent.
    failures: list[str] = []
    with contextlib.suppress(BudgetSpent):
        one()
    assert not failures, failures[0]


def test_damaged_uploads_keep_every_rule(server: LiveServer, client: httpx.Client) -> None:
    """Each format gets an equal share of the budget: drawn from all of them, a format the
    draws reach late went unfuzzed on a slow machine."""
    start = time.monotonic()
    seen: dict[str, int] = {}
    for number, source in enumerate(SOURCES, start=1):
        fuzz_one_source(server, client, source, start + SECONDS * number / len(SOURCES), seen)
    print(f"\nupload fuzz: {sum(seen.values())} damaged uploads in {SECONDS:.0f} s: {seen}")
    assert set(seen) == {s.name for s in SOURCES}


FOUND = make_corpus.load_cases(make_corpus.FOUND)


@pytest.mark.parametrize(
    "case",
    [
        pytest.param(c, marks=pytest.mark.xfail(strict=True, reason=c.xfail) if c.xfail else ())
        for c in FOUND
    ],
    ids=[c.name for c in FOUND],
)
def test_every_failure_ever_found_stays_fixed(
    server: LiveServer, client: httpx.Client, case: Case
) -> None:
    for route in READ_ROUTES:  # a find may have failed on any of them (a /skeleton 500)
        status, problems = check_upload(server, client, case.parts, route)
        assert not problems, (route, problems)
        if case.status:  # a found failure whose right answer is known
            assert status == case.status, (status, case.status)
