"""Which parts an upload may have, its name, labels and content hash."""

from __future__ import annotations

import hashlib

import pytest

from app.errors import InvalidInput, UnsupportedMediaType
from app.services.uploads import Upload, normalise_labels


def test_bvh_upload() -> None:
    upload = Upload.from_files(file=("dir/Walk.BVH", b"abc"), labels=["a, b", "b", " c "])
    assert upload.format == "bvh"
    assert upload.parts[0].filename == "Walk.BVH"  # path dropped, case kept
    assert upload.clip_name == "Walk"
    assert upload.labels == ("a", "b", "c")
    assert upload.content_hash == hashlib.sha256(b"abc").hexdigest()


def test_asf_amc_upload_hash_depends_on_both_parts_and_their_roles() -> None:
    upload = Upload.from_files(skeleton=("02.asf", b"S"), motion=("02_01.amc", b"M"), name=" x ")
    assert upload.format == "asf/amc"
    assert upload.clip_name == "x"
    # The one rule, shared with the bulk import: sha256 of the hex digests, skeleton first.
    pair = hashlib.sha256(b"S").hexdigest() + hashlib.sha256(b"M").hexdigest()
    assert upload.content_hash == hashlib.sha256(pair.encode("ascii")).hexdigest()
    swapped = Upload.from_files(skeleton=("02.asf", b"M"), motion=("02_01.amc", b"S"))
    assert swapped.content_hash != upload.content_hash
    assert swapped.clip_name == "02_01"  # default: the motion file's name


@pytest.mark.parametrize(
    ("parts", "field"),
    [
        ({}, "file"),
        ({"skeleton": ("a.asf", b"x")}, "motion"),
        ({"motion": ("a.amc", b"x")}, "skeleton"),
        ({"file": ("a.bvh", b"x"), "skeleton": ("a.asf", b"x")}, "skeleton"),
        ({"file": ("a.bvh", b"x"), "motion": ("a.amc", b"x")}, "motion"),
        ({"file": ("a.bvh", b"")}, "file"),
        ({"file": (None, b"x")}, "file"),
    ],
)
def test_missing_or_surplus_parts_name_the_field(
    parts: dict[str, tuple[str | None, bytes]], field: str
) -> None:
    with pytest.raises(InvalidInput, match=f"'{field}'"):
        Upload.from_files(**parts)


@pytest.mark.parametrize(
    "parts",
    [
        {"file": ("walk.obj", b"x")},
        {"file": ("walk.asf", b"x")},
        {"file": ("walk.amc", b"x")},
        {"file": ("walk", b"x")},
        {"skeleton": ("a.bvh", b"x"), "motion": ("a.amc", b"x")},
        {"skeleton": ("a.asf", b"x"), "motion": ("a.txt", b"x")},
    ],
)
def test_wrong_file_types_are_unsupported(parts: dict[str, tuple[str, bytes]]) -> None:
    with pytest.raises(UnsupportedMediaType):
        Upload.from_files(**parts)


def test_label_limits() -> None:
    assert normalise_labels(None) == ()
    assert normalise_labels([",,", " "]) == ()
    with pytest.raises(InvalidInput):
        normalise_labels(["x" * 101])
    with pytest.raises(InvalidInput):
        normalise_labels([",".join(str(i) for i in range(101))])
