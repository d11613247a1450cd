"""The FBX/glTF readers' worker processes (app/services/parser_pool.py): a worker that
crashes, hangs or runs out of memory costs one file (UnreadableFile), and the next file is
read by a fresh worker."""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from app.errors import ParseError, ServiceBusy, UnreadableFile
from app.motion.formats import read_bvh
from app.motion.model import ParseLimits
from app.services.parser_pool import ParserPool
from tests.conftest import FIXTURES_DIR
from tests.motion.gltf_builder import build_glb, gltf_parts, pack_glb

FBX = (FIXTURES_DIR / "ufbx_maya_human_ik_7400_binary.fbx").read_bytes()
LIMITS = ParseLimits()


@pytest.fixture
def pool() -> Iterator[ParserPool]:
    pool = ParserPool(1, time_limit=30.0, memory_mb=512)
    yield pool
    pool.close()


def kill_when_busy(pool: ParserPool) -> threading.Thread:
    """SIGKILL the worker as soon as it has a file to read (the file is in its pipe or
    being parsed: either way mid-parse for the caller)."""

    def kill() -> None:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            busy = pool.busy_pids()
            if busy:
                os.kill(busy[0], signal.SIGKILL)
                return
            time.sleep(0.0005)

    thread = threading.Thread(target=kill)
    thread.start()
    return thread


def test_workers_are_reused(pool):
    first = pool.parse("fbx", FBX, animation=None, limits=LIMITS)
    pids = pool.pids()
    second = pool.parse("fbx", FBX, animation=None, limits=LIMITS)
    assert pool.pids() == pids and len(pids) == 1
    assert first.motion.frame_count == second.motion.frame_count == 120
    assert first.animation == "Take 001"


def test_a_worker_killed_mid_parse_costs_that_file_only(pool):
    pool.parse("fbx", FBX, animation=None, limits=LIMITS)  # warm
    killer = kill_when_busy(pool)
    with pytest.raises(UnreadableFile, match="crashed"):
        pool.parse("fbx", FBX, animation=None, limits=LIMITS)
    killer.join()
    assert pool.crashes == 1
    parsed = pool.parse("fbx", FBX, animation=None, limits=LIMITS)
    assert parsed.motion.frame_count == 120


def test_an_idle_worker_that_died_is_replaced_unnoticed(pool):
    pool.parse("fbx", FBX, animation=None, limits=LIMITS)
    (pid,) = pool.pids()
    os.kill(pid, signal.SIGKILL)
    time.sleep(0.2)
    assert pool.parse("fbx", FBX, animation=None, limits=LIMITS).motion.frame_count == 120
    assert pool.pids() != [pid]


def test_a_file_over_the_time_limit_is_unreadable_and_the_next_one_reads():
    pool = ParserPool(1, time_limit=0.001, memory_mb=512)
    try:
        with pytest.raises(UnreadableFile, match="longer than"):
            pool.parse("fbx", FBX, animation=None, limits=LIMITS)
        pool.time_limit = 30.0
        assert pool.parse("fbx", FBX, animation=None, limits=LIMITS).motion.frame_count == 120
    finally:
        pool.close()


def test_a_file_over_the_memory_limit_is_unreadable_and_the_next_one_reads(pool):
    # Two keys a day apart at 24 keys/s: 2 million frames of 38 nodes, far over 512 MB.
    motion = read_bvh((FIXTURES_DIR / "cmu_mb_02_01_first41.bvh").read_bytes()).slice_frames(0, 2)
    document, binary = gltf_parts(motion)  # the key times come first in the buffer
    key_times = np.array([0.0, 86400.0], dtype=np.float32).tobytes()
    huge = pack_glb(document, key_times + binary[8:])
    no_limits = ParseLimits(max_frames=None, max_values=None)
    with pytest.raises(UnreadableFile, match="MB"):
        pool.parse("gltf", huge, animation=None, limits=no_limits)
    assert pool.parse("gltf", build_glb(motion), animation=None, limits=LIMITS).motion


def test_reader_errors_come_back_as_themselves(pool):
    with pytest.raises(ParseError, match="no skeleton"):
        pool.parse("gltf", b'{"asset": {"version": "2.0"}}', animation=None, limits=LIMITS)
    with pytest.raises(ParseError, match="'Take 001'"):
        pool.parse("fbx", FBX, animation="nope", limits=LIMITS)


def test_waiting_for_a_busy_reader_is_bounded():
    """With every worker taken, the next caller is turned away (503 busy) after
    ``wait_limit`` instead of queueing without end, and served once one is free again."""
    pool = ParserPool(1, time_limit=30.0, memory_mb=512, wait_limit=0.5)
    try:
        pool.parse("fbx", FBX, animation=None, limits=LIMITS)  # warm
        taken = pool._borrow()  # the only worker, as a request reading a file holds it
        started = time.monotonic()
        with pytest.raises(ServiceBusy, match="MOCAP_PARSER_WORKERS") as refused:
            pool.parse("fbx", FBX, animation=None, limits=LIMITS)
        assert 0.4 < time.monotonic() - started < 5.0
        assert refused.value.retry_after == 1
        pool._idle.put(taken)
        assert pool.parse("fbx", FBX, animation=None, limits=LIMITS).motion.frame_count == 120
    finally:
        pool.close()
