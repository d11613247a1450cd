"""Finding clips in folders: BVH files, ASF/AMC pairing, orphans, order, content hashes."""

from __future__ import annotations

import hashlib
from pathlib import Path

from app.discovery import ClipSource, content_hash, content_hash_of_bytes, discover


def _touch(path: Path, text: str = "x") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _tree(root: Path) -> None:
    _touch(root / "b" / "walk.BVH")
    _touch(root / "a" / "run.bvh")
    _touch(root / "a" / "notes.txt")
    # Subject folder: prefix match wins over the other skeleton.
    _touch(root / "cmu" / "02" / "02.asf")
    _touch(root / "cmu" / "02" / "other.asf")
    _touch(root / "cmu" / "02" / "02_01.amc")
    _touch(root / "cmu" / "02" / "02_02.AMC")
    # The only skeleton of its folder, whatever its name.
    _touch(root / "cmu" / "131" / "skeleton.asf")
    _touch(root / "cmu" / "131" / "131_01.amc")
    # No skeleton at all; and two skeletons, none matching.
    _touch(root / "orphan" / "07_01.amc")
    _touch(root / "ambiguous" / "x.asf")
    _touch(root / "ambiguous" / "y.asf")
    _touch(root / "ambiguous" / "09_01.amc")
    # A skeleton in the parent folder does not count.
    _touch(root / "nested" / "05.asf")
    _touch(root / "nested" / "deeper" / "05_01.amc")
    # Hidden folders are skipped.
    _touch(root / ".eval-cache" / "stale.bvh")


def test_pairs_and_orders_clips(tmp_path: Path) -> None:
    _tree(tmp_path)
    result = discover([tmp_path])
    found = [(s.kind, s.relative_path, s.name) for s in result.sources]
    assert found == [
        ("bvh", "a/run.bvh", "run"),
        ("bvh", "b/walk.BVH", "walk"),
        ("asf/amc", "cmu/02/02_01.amc", "02_01"),
        ("asf/amc", "cmu/02/02_02.AMC", "02_02"),
        ("asf/amc", "cmu/131/131_01.amc", "131_01"),
    ]
    by_name = {s.name: s for s in result.sources}
    assert by_name["02_01"].skeleton == tmp_path / "cmu" / "02" / "02.asf"
    assert by_name["02_02"].skeleton == tmp_path / "cmu" / "02" / "02.asf"
    assert by_name["131_01"].skeleton == tmp_path / "cmu" / "131" / "skeleton.asf"
    assert by_name["02_01"].paths == (
        tmp_path / "cmu" / "02" / "02.asf",
        tmp_path / "cmu" / "02" / "02_01.amc",
    )
    assert by_name["run"].paths == (tmp_path / "a" / "run.bvh",)
    assert all(s.root == tmp_path for s in result.sources)


def test_reports_amc_files_without_a_usable_skeleton(tmp_path: Path) -> None:
    _tree(tmp_path)
    failures = {
        f.path.relative_to(tmp_path).as_posix(): f.reason for f in discover([tmp_path]).failures
    }
    assert set(failures) == {"ambiguous/09_01.amc", "nested/deeper/05_01.amc", "orphan/07_01.amc"}
    assert "no .asf" in failures["orphan/07_01.amc"]
    assert "none is named 09.asf" in failures["ambiguous/09_01.amc"]
    assert "x.asf" in failures["ambiguous/09_01.amc"]


def test_is_deterministic_and_deduplicates(tmp_path: Path) -> None:
    _tree(tmp_path)
    once = discover([tmp_path]).sources
    twice = discover([tmp_path, tmp_path / "a"]).sources
    assert [s.motion for s in twice] == [s.motion for s in once]


def test_single_files_and_missing_paths(tmp_path: Path) -> None:
    _tree(tmp_path)
    result = discover(
        [tmp_path / "cmu" / "02" / "02_01.amc", tmp_path / "a" / "run.bvh", tmp_path / "nope"]
    )
    assert [(s.kind, s.relative_path) for s in result.sources] == [
        ("asf/amc", "02_01.amc"),
        ("bvh", "run.bvh"),
    ]
    assert result.sources[0].skeleton == tmp_path / "cmu" / "02" / "02.asf"
    assert [f.reason for f in result.failures] == ["no such file or folder"]
    assert discover([tmp_path / "a" / "notes.txt"]).failures[0].reason == "not a .bvh or .amc file"


def test_content_hash(tmp_path: Path) -> None:
    bvh = _touch(tmp_path / "a.bvh", "HIERARCHY")
    asf = _touch(tmp_path / "02.asf", "skeleton")
    amc = _touch(tmp_path / "02_01.amc", "motion")
    bvh_source = ClipSource("bvh", bvh, None, "a", "a.bvh", tmp_path)
    pair = ClipSource("asf/amc", amc, asf, "02_01", "02_01.amc", tmp_path)

    assert content_hash(bvh_source) == hashlib.sha256(b"HIERARCHY").hexdigest()
    hex_pair = hashlib.sha256(b"skeleton").hexdigest() + hashlib.sha256(b"motion").hexdigest()
    assert content_hash(pair) == hashlib.sha256(hex_pair.encode()).hexdigest()
    assert content_hash_of_bytes(b"motion", b"skeleton") == content_hash(pair)
    assert content_hash_of_bytes(b"HIERARCHY") == content_hash(bvh_source)
    # Swapping the roles changes the hash.
    assert content_hash_of_bytes(b"skeleton", b"motion") != content_hash(pair)
