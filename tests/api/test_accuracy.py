"""Leave-one-out 1-NN accuracy on Bandai dataset 1 through the API: every clip is uploaded,
then ``GET /search?clip=..&k=1`` must return a clip of the same action (content label) for at
least 35 % of the clips under each descriptor."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from tests.conftest import SharedData

MIN_ACCURACY = 0.35


def content_labels(bandai: Path) -> dict[str, str]:
    """Clip file name -> action, from each clip's .json and cfg/content_label.txt."""
    names = (bandai / "cfg" / "content_label.txt").read_text().split()
    labels = {}
    for clip in sorted((bandai / "data").glob("*.bvh")):
        content = json.loads(clip.with_suffix(".json").read_text())["content"]
        labels[clip.name] = names[content].removeprefix("dataset-1_")
    return labels


@pytest.mark.slow
def test_bandai_leave_one_out_accuracy(
    client: TestClient, shared_data: SharedData, capsys: pytest.CaptureFixture[str]
) -> None:
    bandai = shared_data("bandai-ds1")
    labels = content_labels(bandai)
    action_of: dict[int, str] = {}
    for filename, action in labels.items():
        data = (bandai / "data" / filename).read_bytes()
        response = client.post("/clips", files={"file": (filename, data)})
        assert response.status_code == 201, response.text
        action_of[response.json()["id"]] = action
    assert len(action_of) == 174

    descriptors = [d["name"] for d in client.get("/descriptors").json()["descriptors"]]
    accuracy = {}
    for descriptor in descriptors:
        hits = 0
        for clip_id, action in action_of.items():
            body = client.get(
                "/search", params={"clip": clip_id, "k": 1, "descriptor": descriptor}
            ).json()
            [nearest] = body["results"]
            hits += action_of[nearest["id"]] == action
        accuracy[descriptor] = hits / len(action_of)

    with capsys.disabled():
        chance = max(list(action_of.values()).count(a) for a in set(action_of.values()))
        print(f"\nBandai dataset 1, {len(action_of)} clips, leave-one-out 1-NN action accuracy:")
        for descriptor, value in accuracy.items():
            print(f"  {descriptor:10s} {value:6.1%}")
        print(f"  (always guessing the largest action would score {chance / len(action_of):.1%})")
    assert {"posture", "kinetic"} <= set(accuracy)
    for descriptor, value in accuracy.items():
        assert value >= MIN_ACCURACY, (descriptor, accuracy)
