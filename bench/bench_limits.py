"""Memory and time of one upload at the size of a long real take (issue 20, item 6).

Run from the repository root::

    .venv/bin/python bench/bench_limits.py [--minutes 10] [--fps 120]

A ten-minute 120 fps take with a full finger rig must be accepted, and one upload's memory
must stay bounded and known. The take is built from a real Mixamo BVH of ``../shared/data``
(65 joints with fingers, 13 end sites: 78 joints) by playing its frames forwards and back
until it lasts ``--minutes`` at ``--fps``; the same take as a GLB. Each is described in a
fresh process, as the service does (``MotionDescriber``: parse, body, every descriptor,
windows), and the process's peak RSS over its RSS with the file's bytes loaded is printed,
with the values ``MOCAP_MAX_FRAME_VALUES`` counts for it and the bytes per value. The GLB is
read as a parser worker reads it (``parse_scene``): its peak is the worker's.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from common import machine, shared_data  # bench/common.py (scripts run from bench/)

ROOT = Path(__file__).resolve().parents[1]
SOURCE = "wild-bvh/mixamo/ortiz_salsa.bvh"

# Peak RSS from /proc (VmHWM): ru_maxrss survives exec, so a child would inherit its parent's.
PEAK = """
def peak_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
"""

DESCRIBE = (
    PEAK
    + """
import json, sys, time
from pathlib import Path
from app.services.describe import MotionDescriber
from app.services.uploads import Upload
from app.config import Settings
path = Path(sys.argv[1])
data = path.read_bytes()
loaded = peak_mb()
started = time.perf_counter()
limits = Settings().parse_limits
description = MotionDescriber().describe(Upload.from_files(file=(path.name, data)), limits)
print(json.dumps({
    "seconds": time.perf_counter() - started,
    "loaded_mb": loaded,
    "peak_mb": peak_mb(),
    "frames": description.frame_count,
    "joints": description.joint_count,
    "windows": len(description.windows.spans),
}))
"""
)

WORKER = (
    PEAK
    + """
import json, sys, time
from pathlib import Path
from app.services.parser_pool import parse_scene
from app.config import Settings
data = Path(sys.argv[1]).read_bytes()
loaded = peak_mb()
started = time.perf_counter()
motion = parse_scene("gltf", data, None, Settings().parse_limits).motion
print(json.dumps({
    "seconds": time.perf_counter() - started,
    "loaded_mb": loaded,
    "peak_mb": peak_mb(),
    "frames": motion.frame_count,
    "joints": motion.skeleton.joint_count,
}))
"""
)


def long_take(source: Path, frames: int, fps: float) -> str:
    """The source's frames played forwards and back for ``frames`` frames at ``fps``."""
    text = source.read_text().replace("\r\n", "\n")
    head, motion = text.split("MOTION\n", 1)
    lines = [line for line in motion.split("\n") if line.strip()]
    body = lines[2:]
    cycle = body + body[::-1]
    rows = "\n".join(cycle[i % len(cycle)] for i in range(frames))
    return f"{head}MOTION\nFrames: {frames}\nFrame Time: {1 / fps:.7f}\n{rows}\n"


def run(script: str, path: Path) -> dict[str, float]:
    done = subprocess.run(
        [str(ROOT / ".venv" / "bin" / "python"), "-c", script, str(path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--fps", type=float, default=120.0)
    args = parser.parse_args()
    print(machine())
    frames = round(args.minutes * 60 * args.fps)
    with tempfile.TemporaryDirectory() as folder:
        bvh = Path(folder) / "take.bvh"
        bvh.write_text(long_take(shared_data() / SOURCE, frames, args.fps))
        result = run(DESCRIBE, bvh)
        values = result["frames"] * 9 * result["joints"]
        added = result["peak_mb"] - result["loaded_mb"]
        size = bvh.stat().st_size / 1e6
        print(
            f"BVH {size:.0f} MB, {result['frames']:.0f} frames x {result['joints']:.0f} joints "
            f"= {values / 1e6:.1f} M values (limit {64:.0f} M): described in "
            f"{result['seconds']:.1f} s, {result['windows']:.0f} windows; peak RSS "
            f"{result['peak_mb']:.0f} MB, {added:.0f} MB over the loaded file = "
            f"{size:.0f} MB of text + {(added - size) * 1e6 / values:.1f} bytes per value"
        )
        sys.path.insert(0, str(ROOT))
        from app.motion.formats import read_bvh
        from app.motion.model import ParseLimits
        from tests.motion.gltf_builder import build_glb

        glb = Path(folder) / "take.glb"
        unlimited = ParseLimits(max_frames=None, max_values=None)
        glb.write_bytes(build_glb(read_bvh(bvh.read_bytes(), limits=unlimited), name="take"))
        bvh.unlink()
        worker = run(WORKER, glb)
        print(
            f"GLB {glb.stat().st_size / 1e6:.0f} MB, {worker['frames']:.0f} frames x "
            f"{worker['joints']:.0f} joints read as a parser worker does in "
            f"{worker['seconds']:.1f} s; worker peak RSS {worker['peak_mb']:.0f} MB "
            f"({worker['peak_mb'] - worker['loaded_mb']:.0f} MB over the loaded file)"
        )


if __name__ == "__main__":
    main()
