"""Every file of ../shared/data/wild-more through the real service (HTTP, parser workers).

The folder's README gives each file's kind and what the service should do with it: a
``human`` is stored and its canonical skeleton is a person (upright, constant limb lengths,
sides, proportions: :func:`tests.motion.canonical.check_canonical_body`), and its BVH export
uploaded again is the same clip; ``nonhuman``, ``partial-body`` and ``malformed`` files get a
4xx naming the problem; a ``rig-only`` file is refused saying it has no animation, or stored
as a still. Nothing ever gets a 5xx.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.motion.body import build_body
from app.motion.gravity import RESTS, floor_spread
from app.services.parser_pool import ParserPool
from tests.api.devset import check_bvh_export_round_trip, read_motion, upload_every
from tests.conftest import shared_data_dir
from tests.motion.canonical import check_canonical_body

FOLDER = shared_data_dir() / "wild-more"
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        not (FOLDER / "README.md").is_file(), reason=f"{FOLDER} not found (set MOCAP_SHARED_DATA)"
    ),
]
# Takes done on the floor, by a word of the file's name (a word that starts so: "Crawling";
# not inside another: "Soldier" holds no death).
ON_THE_FLOOR_WORDS = ("crawl", "fall", "die", "flair", "lying")
KINDS = ("human", "nonhuman", "partial-body", "malformed", "rig-only")

# Files not yet answered as the README says, the tests they fail and why (strict: a pass
# means the work named has landed, and the entry goes).
KNOWN_GAPS: dict[str, tuple[str, frozenset[str]]] = {
    # An animation-only GLB (no skin, no mesh): its nodes rest in the clip's own first pose,
    # no frame of a breakdance flair shows a standing figure, and the take read as a bent
    # person does not either (the feet rest on nothing in most of its poses): refused, so
    # there is no clip to export either.
    "mixamo-glb/nemutas_flair.glb": (
        "no pose of the file shows a standing figure",
        frozenset({"stored", "exported"}),
    ),
}


def _table() -> dict[str, tuple[str, str]]:
    """File (relative path) -> (kind, expected), from the folder README's table."""
    if not (FOLDER / "README.md").is_file():
        return {}
    table = {}
    for line in (FOLDER / "README.md").read_text().splitlines():
        cells = [c.strip() for c in line.split("|")]
        if len(cells) > 9 and cells[1].startswith("`") and cells[1].endswith("`"):
            table[cells[1].strip("`")] = (cells[6], cells[8])
    return table


TABLE = _table()


def _files(*kinds: str, test: str = "") -> list[object]:
    """The README's files of ``kinds``, those with a known gap in ``test`` marked xfail."""

    def marks(path: str) -> list[pytest.MarkDecorator]:
        reason, tests = KNOWN_GAPS.get(path, ("", frozenset()))
        return [pytest.mark.xfail(reason=reason, strict=True)] if test in tests else []

    return [
        pytest.param(path, marks=marks(path))
        for path, (kind, _) in sorted(TABLE.items())
        if kind in kinds
    ]


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings(data_dir=tmp_path_factory.mktemp("wild-more") / "data")
    with TestClient(create_app(settings)) as client:
        yield client


@pytest.fixture(scope="module")
def uploaded(live: TestClient) -> dict[str, tuple[int, dict]]:
    """Every file uploaded once: relative path -> (status, body)."""
    return upload_every(live, FOLDER, TABLE)


@pytest.fixture(scope="module")
def pool() -> Iterator[ParserPool]:
    pool = ParserPool(1)
    yield pool
    pool.close()


def test_the_readme_lists_every_file():
    on_disk = {p.relative_to(FOLDER).as_posix() for p in FOLDER.rglob("*") if p.is_file()}
    assert set(TABLE) == on_disk - {"README.md"}
    assert {kind for kind, _ in TABLE.values()} == set(KINDS)


def test_no_answer_is_a_server_error(uploaded):
    for path, (status, body) in uploaded.items():
        assert status < 500, (path, body)


@pytest.mark.parametrize("path", _files("nonhuman", "partial-body", "malformed"))
def test_what_is_not_a_person_is_refused_naming_the_problem(uploaded, path):
    status, body = uploaded[path]
    assert 400 <= status < 500, (path, body)
    assert body["error"] in ("parse_error", "unmappable_skeleton", "unreadable_file"), body
    assert Path(path).name in body["detail"], body


@pytest.mark.parametrize("path", _files("rig-only"))
def test_a_rig_without_motion_says_so_or_is_a_still(uploaded, path):
    status, body = uploaded[path]
    if status == 201:  # stored as a still: allowed, when it says so
        assert any("still pose" in warning for warning in body["warnings"]), (path, body)
        return
    assert status == 422, (path, body)
    assert "no animation" in body["detail"] or "without motion" in body["detail"], body


def _done_on_the_floor(path: str) -> bool:
    words = re.findall(r"[a-z]+", re.sub(r"([a-z])([A-Z])", r"\1 \2", Path(path).stem).lower())
    return any(w.startswith(floor) for w in words for floor in ON_THE_FLOOR_WORDS)


@pytest.mark.parametrize("path", _files("human", test="stored"))
def test_a_person_is_stored_and_looks_like_one(uploaded, pool, path):
    status, body = uploaded[path]
    assert status == 201, (path, body)
    body = build_body(read_motion(pool, FOLDER / path))
    if not _done_on_the_floor(path):
        check_canonical_body(body, path)
        return
    # A take done on the floor is no figure on its feet (its head is not above its pelvis in
    # most frames), but it rests on its floor along its vertical in most frames: read along
    # the trunk's mean (before 2026-11-28) its lowest point was on a floor in 2-34 % of them.
    check_canonical_body(body, path, upright=False)
    _, rests = floor_spread(body.positions, body.world_up, body.height)
    assert rests >= RESTS, (path, "no floor along its vertical", body.world_up.tolist(), rests)


@pytest.mark.parametrize("path", _files("human", test="exported"))
def test_a_bvh_export_re_uploaded_is_the_same_clip(live, uploaded, path):
    status, body = uploaded[path]
    assert status == 201, (path, body)
    check_bvh_export_round_trip(live, body["id"], path)
