"""What every reader shares (app/motion/formats/text.py): a Git LFS pointer saved in place
of a file is refused as what it is, by every format's reader."""

from __future__ import annotations

import pytest

from app.errors import ParseError
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.formats.fbx import read_fbx
from app.motion.formats.gltf import read_gltf
from tests.motion.conftest import CMU_ASF_FIXTURE, fixture_bytes

# As a clone without Git LFS hands out a large file (the LFS spec's pointer format).
POINTER = (
    b"version https://git-lfs.github.com/spec/v1\n"
    b"oid sha256:475f11af9ed9606f79fb6e2bc236b6bb5a146d636df186af49ccbd0ba7d5b74e\n"
    b"size 669228\n"
)


@pytest.mark.parametrize(
    ("read", "kind"),
    [
        (read_bvh, "motion file"),
        (lambda data: read_gltf(data), "glTF file"),
        (lambda data: read_fbx(data), "FBX file"),
        (lambda data: read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), data), "motion file"),
        (lambda data: read_asf_amc(data.decode(), "1\nroot 0 0 0 0 0 0\n"), "motion file"),
    ],
    ids=["bvh", "gltf", "fbx", "amc", "asf"],
)
def test_a_git_lfs_pointer_is_refused_as_one(read, kind):
    with pytest.raises(ParseError) as raised:
        read(POINTER)
    detail = raised.value.detail
    assert "is a Git LFS pointer" in detail and f"not the {kind} itself" in detail
    assert "git lfs pull" in detail


def test_a_file_that_only_mentions_lfs_is_read_as_usual():
    with pytest.raises(ParseError, match="not a BVH file"):
        read_bvh(b"HIERARCHY-less text\n" + POINTER)
