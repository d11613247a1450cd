"""The search lane (app/api/search_lane.py): scans handed to it at once are answered as each
search alone would be, an error reaches only the searches it concerns, and the lane goes on."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path

import numpy as np
import pytest

from app.api.search_lane import SearchLane
from app.index.descriptor_index import DescriptorIndex
from tests.index.test_descriptor_index import D, make_data


@pytest.fixture
def indexes(tmp_path: Path) -> list[DescriptorIndex]:
    made = []
    for seed, name in enumerate(["posture", "kinetic"]):
        index = DescriptorIndex(name, D, 1, tmp_path / name)
        index.add(*make_data(60, seed=seed))
        made.append(index)
    return made


def test_scans_handed_at_once_answer_as_alone(indexes: list[DescriptorIndex]) -> None:
    lane = SearchLane()
    ids, vectors = make_data(60, seed=0)

    async def searches() -> list[list[tuple[int, float]]]:
        calls = [
            lane.nearest(indexes[at % 2], vectors[at], 1 + at % 4, int(ids[at])) for at in range(40)
        ]
        return await asyncio.gather(*calls)

    answers = asyncio.run(searches())
    for at, answer in enumerate(answers):
        alone = indexes[at % 2].search(vectors[at], 1 + at % 4, exclude=int(ids[at]))
        assert [i for i, _ in answer] == alone.ids.tolist()
        assert [d for _, d in answer] == alone.distances.tolist()
    assert lane.scanned == 40 and lane.calls < 40  # batched: fewer calls than searches


def test_an_error_reaches_only_its_searches_and_the_lane_goes_on(
    indexes: list[DescriptorIndex],
) -> None:
    lane = SearchLane()
    ids, vectors = make_data(60, seed=0)
    wrong = np.zeros(D + 1, np.float32)  # a vector the index cannot take

    async def searches() -> list[object]:
        calls = [lane.nearest(indexes[0], vectors[at], 5, int(ids[at])) for at in range(10)]
        calls.append(lane.nearest(indexes[1], wrong, 5, 0))
        return await asyncio.gather(*calls, return_exceptions=True)

    answers = asyncio.run(searches())
    assert isinstance(answers[-1], ValueError)
    assert all(isinstance(answer, list) and len(answer) == 5 for answer in answers[:-1])
    # ... and it answers the next searches, also from another event loop
    again = asyncio.run(lane.nearest(indexes[0], vectors[3], 3, int(ids[3])))
    assert again == indexes[0].nearest(vectors[3], 3, exclude=int(ids[3]))


def test_a_forked_process_gets_a_lane_of_its_own(indexes: list[DescriptorIndex]) -> None:
    """A server forks its workers: the parent's lane thread is not in the child."""
    lane = SearchLane()
    ids, vectors = make_data(60, seed=0)
    asyncio.run(lane.nearest(indexes[0], vectors[0], 3, int(ids[0])))  # the parent's lane
    child = os.fork()
    if child == 0:  # pragma: no cover - the child reports by its exit status
        try:
            answer = asyncio.run(
                asyncio.wait_for(lane.nearest(indexes[0], vectors[1], 3, int(ids[1])), 10)
            )
            os._exit(0 if answer == indexes[0].nearest(vectors[1], 3, exclude=int(ids[1])) else 1)
        except BaseException:
            os._exit(2)
    _, status = os.waitpid(child, 0)
    assert os.waitstatus_to_exitcode(status) == 0
