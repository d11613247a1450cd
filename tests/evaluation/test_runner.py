"""The evaluation runner and the ``eval`` command, end to end on real (small) clips."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import pytest

from app.discovery import ClipSource
from app.evaluation.cli import add_eval_parser, run_eval
from app.evaluation.runner import builtin_labels, clip_format
from tests.conftest import shared_data_dir
from tests.evaluation.clips import clip_tree

BANDAI_REGEX = r"dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_\d+"
DESCRIPTORS = ("posture", "kinetic", "motion")
FIXTURE_FILES = (
    "bandai_walk_normal_001_first40.bvh",
    "cmu_mb_02_01_first41.bvh",
    "cmu_02.asf",
    "cmu_02_01_first40.amc",
)


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="mocap-index")
    add_eval_parser(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(["eval", *argv])


# ------------------------------------------------------------------------------- labels


def _source(path: Path, kind: str = "bvh") -> ClipSource:
    skeleton = path.with_name("02.asf") if kind == "asf/amc" else None
    return ClipSource(kind, path, skeleton, path.stem, path.name, path.parent)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("relative", "kind", "expected"),
    [
        ("cmu/bvh-mb/02/02_01.bvh", "bvh", "bvh-mb"),
        ("cmu/BVH-DAZ/02/02_01.bvh", "bvh", "bvh-daz"),
        ("cmu/bvh-max/131_01.bvh", "bvh", "bvh-max"),
        ("cmu/asf-amc/02/02_01.amc", "asf/amc", "asf-amc"),
        ("bandai-ds1/data/dataset-1_walk_normal_001.bvh", "bvh", "bvh"),
        ("bvhacker/x.bvh", "bvh", "bvh"),
    ],
)
def test_format_and_trial_labels(tmp_path: Path, relative: str, kind: str, expected: str) -> None:
    source = _source(tmp_path / relative, kind)
    assert clip_format(source) == expected
    assert builtin_labels(source) == {"trial": source.motion.stem, "format": expected}


# ------------------------------------------------------------------------ the command


def test_eval_command_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    clips = clip_tree(tmp_path)
    out = tmp_path / "out"
    args = _parse(
        [
            str(clips),
            "--labels-tsv", str(tmp_path / "labels.tsv"),
            "--labels-regex", BANDAI_REGEX,
            "--exclude-same", "trial",
            "--out", str(out),
            "--cache-dir", str(tmp_path / "cache"),
            "--workers", "1",
        ]
    )  # fmt: skip
    assert run_eval(args) == 0
    printed = capsys.readouterr()
    assert "broken.bvh" in printed.err and "09_01.amc" in printed.err
    assert "A_e" in printed.out and "format twins" in printed.out

    data = json.loads((out / "results.json").read_text())
    assert data["settings"]["exclude_same"] == "trial"
    assert data["settings"]["label_kinds"] == ["action", "content", "style"]
    assert data["clips"]["found"] == 5 and data["clips"]["described"] == 4
    assert [Path(s["path"]).name for s in data["clips"]["skipped"]] == ["broken.bvh"]
    assert [Path(f["path"]).name for f in data["clips"]["discovery_failures"]] == ["09_01.amc"]
    # content: both Bandai clips are "walk"; style: two unique values. Neither can be scored.
    assert set(data["skipped_label_kinds"]) == {"content", "style"}
    assert set(data["descriptors"]) == set(DESCRIPTORS)
    for descriptor in DESCRIPTORS:
        score = data["scores"][descriptor]["action"]
        assert score["clips"] == 4 and score["missing"] == 0
        loo = score["loo"]
        assert loo["classes"] == ["run", "walk"]
        assert loo["scored"] == 4
        assert sum(map(sum, loo["confusion"])) == 4
        assert 0.0 <= loo["accuracy"] <= 1.0
        # Excluding the same trial drops the ASF/AMC <-> BVH twin as a neighbour.
        assert score["loo_exclude_same"]["scored"] == 4
        clustering = score["clustering"]
        assert 2 <= clustering["k"] <= 3
        assert 0.0 <= clustering["f_measure"] <= 1.0
        assert set(clustering["clusters"]) == {
            "asf-amc/02/02_01.amc",
            "bvh-mb/02/02_01.bvh",
            "bandai/dataset-1_walk_happy_001.bvh",
            "bandai/dataset-1_walk_normal_001.bvh",
        }
        twins = data["format_twins"][descriptor]
        assert [p["formats"] for p in twins["pairs"]] == [["asf-amc", "bvh-mb"]]
        assert twins["pairs"][0]["queries"] == 2
    # The same capture read from ASF/AMC and from BVH lands nearest to itself.
    assert data["format_twins"]["kinetic"]["pairs"][0]["top1"] == 1.0
    table = {row["relative_path"]: row for row in data["clip_table"]}
    assert table["bvh-mb/02/02_01.bvh"]["labels"] == {
        "trial": "02_01",
        "format": "bvh-mb",
        "action": "walk",
    }
    assert table["bandai/dataset-1_walk_happy_001.bvh"]["labels"]["style"] == "happy"
    assert len(table["asf-amc/02/02_01.amc"]["three_man"]) == 3

    figures = {Path(f).name for f in data["figures"]}
    assert figures == {
        "three_man_action.png",
        *(f"confusion_{d}_action.png" for d in DESCRIPTORS),
        *(f"pca_{d}_action.png" for d in DESCRIPTORS),
    }
    for name in figures:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_eval_command_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    clips = clip_tree(tmp_path)
    common = ["--out", str(tmp_path / "out"), "--cache-dir", str(tmp_path / "c"), "--workers", "1"]
    assert run_eval(_parse([str(clips), "--labels-regex", "(?P<x", *common])) == 2
    assert "invalid labels regex" in capsys.readouterr().err
    assert run_eval(_parse([str(clips), "--label-kind", "genre", *common])) == 2
    assert "genre" in capsys.readouterr().err
    assert run_eval(_parse([str(clips), "--descriptor", "nope", *common])) == 2
    assert run_eval(_parse([str(tmp_path / "absent"), *common])) == 2
    only_broken = tmp_path / "only-broken"
    only_broken.mkdir()
    (only_broken / "x.bvh").write_text("garbage")
    assert run_eval(_parse([str(only_broken), *common])) == 1
    assert not (tmp_path / "out" / "results.json").exists()


def test_builtin_kinds_without_label_sources(tmp_path: Path) -> None:
    clips = clip_tree(tmp_path)
    out = tmp_path / "out"
    args = _parse(
        [str(clips), "--out", str(out), "--cache-dir", str(tmp_path / "c"), "--workers", "1",
         "--no-figures", "--descriptor", "kinetic"]
    )  # fmt: skip
    assert run_eval(args) == 0
    data = json.loads((out / "results.json").read_text())
    assert data["settings"]["label_kinds"] == ["trial", "format"]
    assert data["figures"] == []
    assert data["scores"]["kinetic"]["format"]["loo"]["classes"] == ["asf-amc", "bvh", "bvh-mb"]
    assert list(data["scores"]["kinetic"]) == ["trial", "format"]


# ----------------------------------------------------------------------- the real data


def _shared(*parts: str) -> Path:
    path = shared_data_dir().joinpath(*parts)
    if not path.exists():
        pytest.skip(f"{path} is absent (set MOCAP_SHARED_DATA to the shared data folder)")
    return path


@pytest.mark.slow
def test_bandai_dataset(tmp_path: Path) -> None:
    out = tmp_path / "out"
    args = _parse(
        [
            str(_shared("bandai-ds1")),
            "--labels-regex", BANDAI_REGEX,
            "--exclude-same", "style",
            "--out", str(out),
            "--cache-dir", str(tmp_path / "cache"),
            "--workers", str(os.cpu_count() or 1),
            "--no-figures",
        ]
    )  # fmt: skip
    assert run_eval(args) == 0
    data = json.loads((out / "results.json").read_text())
    assert data["clips"]["described"] == 174 and not data["clips"]["skipped"]
    assert data["settings"]["label_kinds"] == ["content", "style"]
    assert data["label_kinds"]["content"]["clips"] == 174
    assert len(data["label_kinds"]["content"]["classes"]) == 16  # dance-long is absent
    assert len(data["label_kinds"]["style"]["classes"]) == 15
    assert data["format_twins"] is None
    for descriptor in DESCRIPTORS:
        for kind in ("content", "style"):
            score = data["scores"][descriptor][kind]
            assert score["loo"]["scored"] == 174
            assert len(score["loo"]["confusion"]) == len(data["label_kinds"][kind]["classes"])
            assert 2 <= score["clustering"]["k"] <= 30
            assert set(score["clustering"]) >= {"f_measure", "recall", "precision", "ari", "bic"}
        content = data["scores"][descriptor]["content"]
        assert content["loo_exclude_same"]["scored"] == 174
        # Well above chance (1/16): the descriptors do tell motions apart.
        assert content["loo"]["accuracy"] > 0.25
    assert data["scores"]["posture"]["style"]["loo_exclude_same"] is None


@pytest.mark.slow
def test_cmu_format_twins(tmp_path: Path) -> None:
    cmu = _shared("cmu")
    out = tmp_path / "out"
    args = _parse(
        [
            str(cmu / "asf-amc" / "02"), str(cmu / "bvh-mb" / "02"), str(cmu / "bvh-daz" / "02"),
            "--labels-tsv", str(cmu / "labels.tsv"),
            "--label-kind", "fine",
            "--exclude-same", "trial",
            "--out", str(out),
            "--cache-dir", str(tmp_path / "cache"),
            "--workers", str(os.cpu_count() or 1),
            "--no-figures",
        ]
    )  # fmt: skip
    assert run_eval(args) == 0
    data = json.loads((out / "results.json").read_text())
    assert data["clips"]["described"] == 24
    assert "18 key(s) of labels.tsv match no clip" in data["notes"]
    for descriptor in DESCRIPTORS:
        fine = data["scores"][descriptor]["fine"]
        assert fine["clips"] == 24
        assert fine["loo_exclude_same"]["scored"] == 24
        pairs = {tuple(p["formats"]): p for p in data["format_twins"][descriptor]["pairs"]}
        assert set(pairs) == {("asf-amc", "bvh-daz"), ("asf-amc", "bvh-mb"), ("bvh-daz", "bvh-mb")}
        assert pairs[("asf-amc", "bvh-mb")]["queries"] == 20
        assert pairs[("asf-amc", "bvh-daz")]["queries"] == 8
    # The MotionBuilder conversion is the same motion as the original.
    kinetic_pairs = data["format_twins"]["kinetic"]["pairs"]
    assert next(p for p in kinetic_pairs if p["formats"] == ["asf-amc", "bvh-mb"])["top1"] == 1.0
