"""FBX export speed (issue 22): the animation bake computed in numpy against Blender's own
bake (its exporter stepping the scene through every frame), on the same clip in one run.

    .venv/bin/python bench/bench_fbx_bake.py            # uses ../shared/data (CMU)

The clip is bench_export's: CMU 02_01 (a walk, 38 joints, 120 fps) repeated to 60 s = 7,200
frames, prepared as ``format=fbx`` prepares it. In this process (Blender imported once):
``write_fbx(bake="blender")`` (before: the exporter's own bake) and ``write_fbx()`` (now: the
numpy bake), interleaved, best of ``--repeat``; before them, ``format=fbx`` through a warm
export worker (the issue's target: 2 s). The two files' animation curves, read with ufbx, are
compared too (they must agree to Blender's single precision).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.motion.transforms import rotate
from app.services.export import ExportOptions, prepare_motion
from app.services.export_pool import ExportPool, fbx_unavailable_reason
from bench.bench_export import long_clip
from bench.common import machine


def curves(data: bytes) -> list[np.ndarray]:
    import ufbx

    scene = ufbx.load_memory(data)
    curves = list(scene.anim_curves)  # every object kept referenced: the binding frees them
    keys = [list(curve.keyframes) for curve in curves]
    return [np.array([key.value for key in one]) for one in keys]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--repeat", type=int, default=2, help="runs of Blender's bake")
    args = parser.parse_args()
    reason = fbx_unavailable_reason()
    if reason is not None:
        print(f"FBX: not measured ({reason})")
        return
    print(f"machine: {machine()}")
    clip = long_clip(args.seconds)
    prepared = prepare_motion(clip, ExportOptions(format="fbx"), None)
    out = rotate(prepared.motion, prepared.up_rotation)
    print(f"clip: {out.frame_count} frames, {out.skeleton.joint_count} joints")
    pool = ExportPool(1, time_limit=600, memory_mb=8192)
    try:
        pool.write_fbx(out.slice_frames(0, 2), metres_per_unit=prepared.metres, name="warm-up")
        took = []
        for _ in range(3):
            start = time.perf_counter()
            pool.write_fbx(out, metres_per_unit=prepared.metres, name="bench")
            took.append(time.perf_counter() - start)
        print(
            f"format=fbx through a warm export worker   {min(took):7.2f} s  "
            f"(best of 3; median {sorted(took)[1]:.2f} s; target 2 s); "
            f"load average {os.getloadavg()[0]:.2f}"
        )
    finally:
        pool.close()

    from app.motion.formats.fbx_writer import write_fbx

    # Blender in this process (after the worker: a spawned worker does not start beside it).
    write_fbx(out.slice_frames(0, 2), metres_per_unit=prepared.metres)

    old_times, new_times = [], []
    old = new = b""
    for _ in range(args.repeat):
        start = time.perf_counter()
        old = write_fbx(out, metres_per_unit=prepared.metres, bake="blender")
        old_times.append(time.perf_counter() - start)
        for _ in range(3):
            start = time.perf_counter()
            new = write_fbx(out, metres_per_unit=prepared.metres)
            new_times.append(time.perf_counter() - start)
        print(f"  load average {os.getloadavg()[0]:.2f}", flush=True)
    before, after = min(old_times), min(new_times)
    print(f"before: write_fbx, Blender's bake          {before:7.2f} s  ({len(old)} bytes)")
    print(f"after:  write_fbx, numpy bake              {after:7.2f} s  ({len(new)} bytes)")
    print(
        f"ratio after / before                       {after / before:7.4f}  ({before / after:.0f}x)"
    )
    old_curves, new_curves = curves(old), curves(new)
    assert len(old_curves) == len(new_curves)
    worst = max(
        float(np.abs(a - b).max() / max(1.0, float(np.abs(b).max())))
        for a, b in zip(new_curves, old_curves, strict=True)
    )
    print(
        f"curves: {len(new_curves)}, largest difference {worst:.1e} (relative to max(1, |value|))"
    )


if __name__ == "__main__":
    main()
