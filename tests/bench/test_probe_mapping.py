"""The probe sweep's process pool (``bench/probe_mapping.py``): a worker that dies is
reported, not waited for forever."""

from __future__ import annotations

import faulthandler
import os
import signal

from bench.probe_mapping import run_jobs


def _square_or_crash(job: tuple[str, int]) -> tuple[str, int]:
    name, value = job
    if value < 0:
        faulthandler.disable()  # pytest's traceback dump is noise here
        os.kill(os.getpid(), signal.SIGSEGV)  # as a native reader's segfault does
    return name, value * value


def test_a_dead_worker_fails_its_job_and_the_others_finish() -> None:
    jobs = [(f"job{i}", -1 if i == 3 else i) for i in range(6)]
    results, crashed = run_jobs(_square_or_crash, jobs, workers=2)
    assert crashed == ["job3"]
    assert results == {f"job{i}": i * i for i in range(6) if i != 3}


def test_no_death_no_crash() -> None:
    results, crashed = run_jobs(_square_or_crash, [("a", 2), ("b", 3)], workers=1)
    assert (results, crashed) == ({"a": 4, "b": 9}, [])
