"""Describing clips for the evaluation: vectors, the cache, worker processes that die."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.discovery import discover
from app.evaluation import describe
from app.evaluation.describe import VectorCache, describe_clips
from app.motion.descriptors import REGISTRY
from tests.evaluation.clips import clip_tree

REAL_DESCRIBE = describe.describe_source
DESCRIPTORS = ("posture", "kinetic", "motion")


def test_describe_skips_bad_clips_and_caches(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    clips = clip_tree(tmp_path)
    sources = discover([clips]).sources
    assert len(sources) == 5
    cache = tmp_path / "cache"
    done, skipped = describe_clips(sources, DESCRIPTORS, cache_dir=cache, workers=1)
    assert [s.path.name for s in skipped] == ["broken.bvh"]
    assert skipped[0].reason
    assert len(done) == 4
    for _source, digest, vectors in done:
        assert set(vectors) == {*DESCRIPTORS, "three_man"}
        assert vectors["three_man"].shape == (3,)
        assert np.all(np.isfinite(vectors["kinetic"]))
        code = describe.motion_code_fingerprint()
        assert (
            cache
            / "v1"
            / digest[:2]
            / digest
            / f"three_man-kinetic-v{REGISTRY['kinetic'].version}-{code}.npy"
        ).is_file()

    # A second run reads every vector from the cache: describing is never called.
    def fail(*_args: Any) -> Any:
        raise AssertionError("described again despite the cache")

    good = [s for s in sources if s.motion.name != "broken.bvh"]
    monkeypatch.setattr(describe, "describe_source", fail)
    again, skipped_again = describe_clips(good, DESCRIPTORS, cache_dir=cache, workers=1)
    assert not skipped_again
    for (_s1, h1, v1), (_s2, h2, v2) in zip(done, again, strict=True):
        assert h1 == h2
        for name in v1:
            np.testing.assert_array_equal(v1[name], v2[name])


def test_describe_in_worker_processes(tmp_path: Path) -> None:
    clips = clip_tree(tmp_path)
    sources = discover([clips]).sources
    serial, _ = describe_clips(sources, ("kinetic",), cache_dir=None, workers=1, progress=False)
    parallel, skipped = describe_clips(
        sources, ("kinetic",), cache_dir=None, workers=2, progress=False
    )
    assert [s.path.name for s in skipped] == ["broken.bvh"]
    assert [s.motion for s, _, _ in parallel] == [s.motion for s, _, _ in serial]
    for (_, _, a), (_, _, b) in zip(serial, parallel, strict=True):
        np.testing.assert_allclose(a["kinetic"], b["kinetic"])


def crash_on_broken(kind: str, paths: tuple[str, ...], names: tuple[str, ...]) -> Any:
    """``describe_source``, except that the worker process dies on ``broken.bvh``."""
    if paths[-1].endswith("broken.bvh"):
        os._exit(3)
    return REAL_DESCRIBE(kind, paths, names)


def test_a_dying_worker_costs_only_its_clip(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    clips = clip_tree(tmp_path)
    sources = discover([clips]).sources
    # Runs in the worker processes: they import this module, not the monkeypatched module.
    monkeypatch.setattr(describe, "describe_source", crash_on_broken)
    done, skipped = describe_clips(sources, ("kinetic",), cache_dir=None, workers=2)
    assert [(s.path.name, s.reason) for s in skipped] == [
        ("broken.bvh", "the worker process describing it died")
    ]
    assert len(done) == 4


def test_unwritable_cache_only_warns(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    cache = VectorCache(blocker)
    cache.store("ab" * 32, {"x": "x-v1"}, {"x": np.zeros(2)})
    assert cache.load("ab" * 32, {"x": "x-v1"}) is None
