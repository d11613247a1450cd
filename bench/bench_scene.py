"""FBX/glTF benchmark: one Mixamo FBX described through ``POST /clips``, and the import of
the whole ``fbx-gltf`` development folder.

Run from the repository root::

    .venv/bin/python bench/bench_scene.py [--requests 20] [--file PATH]

1. Starts ``mocap-index serve`` (default settings) on an empty data directory, warms the
   parser workers with two uploads, then times ``--requests`` sequential ``POST /clips`` of
   the file (default ``fbx-gltf/pairs-mixamo/ortiz_hiphop.fbx``, 2.4 MB, 826 frames, 65
   bones). Each request is read in a worker, described and checked against the library (an
   FBX's content hash needs its animation, so even a repeated upload is read): the first
   answers 201, the others 200. Target: median ≤ 300 ms.
2. Runs ``mocap-index import`` of the whole ``fbx-gltf`` folder into a new data directory
   and reports its summary line (clips/s), then runs it again (every clip a duplicate).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import httpx
from bench_upload import free_port, start_server  # bench/bench_upload.py
from common import ROOT, machine, shared_data  # bench/common.py (scripts run from bench/)

TARGET_MS = 300.0


def time_uploads(path: Path, requests: int) -> list[float]:
    data = path.read_bytes()
    with tempfile.TemporaryDirectory() as tmp:
        port = free_port()
        server = start_server(Path(tmp) / "data", port, Path(tmp) / "server.log")
        try:
            with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=120) as http:
                times = []
                for i in range(requests + 2):
                    started = time.perf_counter()
                    response = http.post("/clips", files={"file": (path.name, data)})
                    elapsed = time.perf_counter() - started
                    if response.status_code not in (200, 201):
                        raise SystemExit(f"{response.status_code}: {response.text}")
                    if i >= 2:  # the first two start and warm the worker
                        times.append(elapsed * 1000)
                return times
        finally:
            server.terminate()
            server.wait(timeout=30)


def run_import(folder: Path, data_dir: Path) -> tuple[float, str]:
    command = [str(ROOT / ".venv" / "bin" / "mocap-index"), "import", str(folder)]
    started = time.perf_counter()
    done = subprocess.run(
        [*command, "--data-dir", str(data_dir)], capture_output=True, text=True, check=False
    )
    seconds = time.perf_counter() - started
    summary = [line for line in done.stdout.splitlines() if line.startswith("imported")]
    return seconds, (summary[-1] if summary else done.stdout[-300:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    folder = shared_data() / "fbx-gltf"
    parser.add_argument("--file", type=Path, default=folder / "pairs-mixamo/ortiz_hiphop.fbx")
    parser.add_argument("--requests", type=int, default=20)
    args = parser.parse_args()
    print(machine())
    size = args.file.stat().st_size / 2**20
    times = time_uploads(args.file, args.requests)
    median = statistics.median(times)
    print(
        f"POST /clips {args.file.name} ({size:.1f} MB): median {median:.0f} ms, "
        f"min {min(times):.0f}, max {max(times):.0f} over {len(times)} requests "
        f"(target ≤ {TARGET_MS:.0f} ms: {'met' if median <= TARGET_MS else 'NOT met'})"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for run in ("first", "second"):
            seconds, summary = run_import(folder, Path(tmp) / "data")
            print(f"import of {folder.name} ({run} run, {seconds:.2f} s wall): {summary}")


if __name__ == "__main__":
    main()
