"""Named arrays in one file (app/index/array_file.py): a file whose checksum matched is
stamped (``<file>.verified``) and not hashed again while unchanged; a changed or replaced
file is hashed again, and one not matching its checksum is refused."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from app.index.array_file import (
    STAMP_SUFFIX,
    TOKEN_BYTES,
    has_checksum,
    read_arrays,
    verify_arrays,
    write_arrays,
)

STEM = "things"


def written(directory: Path, value: float = 1.0) -> Path:
    """``things.arrays`` of two arrays (and its metadata), returned."""
    arrays = {"ids": np.arange(1000, dtype=np.int64), "values": np.full((1000, 3), value)}
    write_arrays(directory, STEM, arrays, {"format": 1})
    return directory / f"{STEM}.arrays"


def overwrite_keeping_time(path: Path, data: bytes) -> None:
    """Change the file's bytes in place, keeping its size, inode and modification time: what
    a stamp cannot see (it is trusted; any rewrite through write_arrays changes all three)."""
    info = os.stat(path)
    with open(path, "r+b") as stream:
        stream.seek(info.st_size - TOKEN_BYTES - len(data))  # the last array's bytes
        stream.write(data)
    os.utime(path, ns=(info.st_atime_ns, info.st_mtime_ns))


def test_a_verified_file_is_stamped_and_not_hashed_again(tmp_path: Path) -> None:
    path = written(tmp_path)
    assert not isinstance(read_arrays(tmp_path, STEM, {"format": 1}), str)
    assert path.with_name(path.name + STAMP_SUFFIX).is_file()
    # Bytes changed behind the stamp's back are not seen: the file was not hashed again.
    overwrite_keeping_time(path, b"\x07" * 8)
    assert not isinstance(read_arrays(tmp_path, STEM, {"format": 1}), str)


def test_a_tampered_file_is_hashed_again_and_refused(tmp_path: Path) -> None:
    path = written(tmp_path)
    assert not isinstance(read_arrays(tmp_path, STEM, {"format": 1}), str)
    with open(path, "r+b") as stream:  # a new modification time
        stream.seek(-8 - TOKEN_BYTES, os.SEEK_END)  # the last array's bytes
        stream.write(b"\x07" * 8)
    os.utime(path, ns=(os.stat(path).st_atime_ns, os.stat(path).st_mtime_ns + 1_000_000))
    assert read_arrays(tmp_path, STEM, {"format": 1}) == f"{path.name} does not match its checksum"
    meta = json.loads((tmp_path / f"{STEM}.json").read_text())
    assert not has_checksum(path, meta["sha256"])


def test_a_replaced_file_is_verified_again(tmp_path: Path) -> None:
    path = written(tmp_path)
    assert not isinstance(read_arrays(tmp_path, STEM, {"format": 1}), str)
    written(tmp_path, value=2.0)  # a new file (inode) with its own checksum
    found = read_arrays(tmp_path, STEM, {"format": 1})
    assert not isinstance(found, str)
    assert float(found[0]["values"][0, 0]) == 2.0
    stamp = path.with_name(path.name + STAMP_SUFFIX).read_text()
    assert str(os.stat(path).st_ino) in stamp


def test_checked_later_stamps_then_skips(tmp_path: Path) -> None:
    path = written(tmp_path)
    found = read_arrays(tmp_path, STEM, {"format": 1}, verify=False)
    assert not isinstance(found, str)
    assert not path.with_name(path.name + STAMP_SUFFIX).exists()  # not hashed at read
    assert verify_arrays(*found) is None
    assert path.with_name(path.name + STAMP_SUFFIX).is_file()
    overwrite_keeping_time(path, b"\x07" * 8)
    again = read_arrays(tmp_path, STEM, {"format": 1}, verify=False)
    assert not isinstance(again, str)
    assert verify_arrays(*again) is None  # known from the stamp: not hashed


def test_checked_later_refuses_a_tampered_file(tmp_path: Path) -> None:
    path = written(tmp_path)
    with open(path, "r+b") as stream:
        stream.seek(-8 - TOKEN_BYTES, os.SEEK_END)  # the last array's bytes
        stream.write(b"\x07" * 8)
    found = read_arrays(tmp_path, STEM, {"format": 1}, verify=False)
    assert not isinstance(found, str)
    assert verify_arrays(*found) == "file does not match its checksum"
    assert not path.with_name(path.name + STAMP_SUFFIX).exists()


def test_missing_file(tmp_path: Path) -> None:
    written(tmp_path)
    (tmp_path / f"{STEM}.arrays").unlink()
    assert read_arrays(tmp_path, STEM, {"format": 1}) == f"missing {STEM}.arrays"
    with pytest.raises(FileNotFoundError):
        has_checksum(tmp_path / f"{STEM}.arrays", "0" * 64)


def test_arrays_and_metadata_from_different_writes_are_refused(tmp_path: Path) -> None:
    # The two files are replaced one after the other: a process killed between the renames
    # left new arrays beside the old metadata, whose layout read them as garbage at a start
    # that checks the checksum later (a replica's restart after kill -9 crashed on it).
    labels = {"labels": np.frombuffer(b'{"walk": 1}', np.uint8), "ids": np.arange(7)}
    write_arrays(tmp_path, STEM, labels, {"format": 1})
    old_meta = (tmp_path / f"{STEM}.json").read_text()
    path = written(tmp_path, 1.0)  # larger: the old layout fits inside it
    (tmp_path / f"{STEM}.json").write_text(old_meta)  # the second rename never happened
    for verify in (False, True):
        found = read_arrays(tmp_path, STEM, {"format": 1}, verify=verify)
        assert isinstance(found, str), found
    assert read_arrays(tmp_path, STEM, {"format": 1}, verify=False) == (
        f"{path.name} and {STEM}.json are from different writes"
    )
    written(tmp_path, 2.0)  # a whole write again: read as written
    found = read_arrays(tmp_path, STEM, {"format": 1}, verify=False)
    assert not isinstance(found, str) and float(found[0]["values"][0, 0]) == 2.0
