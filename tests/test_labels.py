"""Label sources: a TSV keyed by clip, a regex over the relative path."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.errors import InvalidInput
from app.labels import compile_label_regex, labels_from_regex, labels_from_tsv
from tests.conftest import shared_data_dir

BANDAI = r"dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_\d+"


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def test_tsv_with_header(tmp_path: Path) -> None:
    path = _write(
        tmp_path / "labels.tsv",
        "\ufeffclip\tcoarse\tfine\tdescription\n"
        "01_01\tjump\tjump\tplayground - forward jumps, turn around\r\n"
        "02_05\tupper-body\tpunch\n"  # fewer cells: no description
        "02_06\tupper-body\t\tbend over\n"  # empty cell: no fine label
        "\n",
    )
    assert labels_from_tsv(path) == {
        "01_01": {
            "coarse": "jump",
            "fine": "jump",
            "description": "playground - forward jumps, turn around",
        },
        "02_05": {"coarse": "upper-body", "fine": "punch"},
        "02_06": {"coarse": "upper-body", "description": "bend over"},
    }


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty"),
        ("clip\n01_01\n", "at least one label column"),
        ("01_01\tjump\tjump\n02_01\twalk\twalk\n", "no header row"),
        ("a\tb\n1\twalk\n2\tb\n", "no header row"),
        ("clip\tfine\tfine\n", "repeats"),
        ("clip\t\tfine\n", "empty column name"),
        ("clip\tfine\n01\twalk\textra\n", "line 2: 3 cells"),
        ("clip\tfine\n01\twalk\n01\trun\n", "listed twice"),
    ],
)
def test_tsv_errors(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(InvalidInput, match=message):
        labels_from_tsv(_write(tmp_path / "labels.tsv", text))


def test_tsv_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InvalidInput, match="cannot read"):
        labels_from_tsv(tmp_path / "absent.tsv")


def test_real_cmu_labels() -> None:
    path = shared_data_dir() / "cmu" / "labels.tsv"
    if not path.is_file():
        pytest.skip(f"{path} is absent (set MOCAP_SHARED_DATA to the shared data folder)")
    table = labels_from_tsv(path)
    assert len(table) == 28
    assert table["02_01"] == {"coarse": "locomotion", "fine": "walk", "description": "walk"}


def test_regex_named_groups() -> None:
    assert compile_label_regex(BANDAI).groupindex.keys() == {"content", "style"}
    assert labels_from_regex(BANDAI, "data/dataset-1_walk-back_not-confident_001.bvh") == {
        "content": "walk-back",
        "style": "not-confident",
    }
    assert labels_from_regex(BANDAI, "other/file.bvh") == {}
    # Windows separators are matched as "/".
    assert labels_from_regex(r"^(?P<subject>\d+)/", "02\\02_01.amc") == {"subject": "02"}
    # A group that did not take part in the match is left out.
    assert labels_from_regex(r"(?P<a>x)|(?P<b>y)", "y") == {"b": "y"}


@pytest.mark.parametrize(
    ("pattern", "message"),
    [("(?P<content>[^_]+", "invalid labels regex"), (r"dataset-1_(\w+)", "no named group")],
)
def test_regex_errors(pattern: str, message: str) -> None:
    with pytest.raises(InvalidInput, match=message):
        labels_from_regex(pattern, "x")


# -- issue #14 -------------------------------------------------------------------------------


def test_normalise_labels_is_case_insensitive_and_keeps_the_first_spelling() -> None:
    from app.labels import label_filter, merge_labels, normalise_labels

    assert normalise_labels([" Walk , Happy ,,walk", "HAPPY"]) == ("Walk", "Happy")
    assert label_filter(["walk,happy", ""]) == ("walk", "happy")
    assert label_filter("") == label_filter([""]) == label_filter(None) == ()
    assert merge_labels(["Walk"], ["walk", "Run", "RUN"]) == ("Walk", "Run")


@pytest.mark.parametrize(
    "pattern",
    [
        r"dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_\d+",
        r"dataset-1_(?<content>[^_]+)_(?<style>[^_]+)_\d+",
    ],
)
def test_both_named_group_spellings(pattern: str) -> None:
    assert labels_from_regex(pattern, "x/dataset-1_walk_happy_001.bvh") == {
        "content": "walk",
        "style": "happy",
    }


def test_javascript_spelling_keeps_lookbehind_and_backreferences() -> None:
    from app.labels import python_regex

    assert python_regex(r"(?<=a)(?<!b)(?<x>c)\k<x>\(?<y>") == r"(?<=a)(?<!b)(?P<x>c)(?P=x)\(?<y>"


def test_free_text_columns_are_left_out_by_default() -> None:
    from app.labels import choose_label_columns

    table = {
        "01_01": {"coarse": "jump", "description": "playground - forward jumps, turn around"},
        "01_02": {"coarse": "climb", "description": "climb"},
    }
    chosen, left_out = choose_label_columns(table)
    assert left_out == ("description",) and chosen["01_02"] == {"coarse": "climb"}
    chosen, left_out = choose_label_columns(table, ["description"])
    assert left_out == ("coarse",) and chosen["01_02"] == {"description": "climb"}
    with pytest.raises(InvalidInput, match="no column 'mood'"):
        choose_label_columns(table, ["coarse,mood"])
