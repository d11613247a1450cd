"""Export speed (issue 22): GLB and FBX of a 60-s 120-fps clip, retargeting per 1,000
frames, and a 100-clip ZIP export in clips/s.

    .venv/bin/python bench/bench_export.py            # uses ../shared/data (Bandai, CMU)

Every figure comes with a baseline measured in the same run (the machine is shared): today's
BVH export of the same clip, and forward kinematics of the same frames. Best of 3 unless said.
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.config import Settings
from app.motion.body import build_body
from app.motion.formats import read_bvh
from app.motion.formats.bvh_writer import write_bvh
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion
from app.motion.retarget import reference_pose, retarget
from app.motion.skeleton_map import map_skeleton
from app.motion.transforms import rotate
from app.services.export import ExportOptions, export_motion, prepare_motion
from app.services.export_pool import ExportPool, fbx_unavailable_reason
from bench.common import machine, shared_data


def best(run: Callable[[], object], repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def long_clip(seconds: float = 60.0) -> Motion:
    """A CMU walk (120 fps) repeated to ``seconds``, its travel continued."""
    source = read_bvh((shared_data() / "cmu/bvh-mb/02/02_01.bvh").read_bytes()).slice_frames(1)
    frames = int(seconds * 120)
    reps = -(-frames // source.frame_count)
    step = source.root_translation[-1] - source.root_translation[0]
    root = np.concatenate([source.root_translation + i * step for i in range(reps)])[:frames]
    rotations = np.concatenate([source.local_rotations] * reps)[:frames]
    return Motion(source.skeleton, source.frame_time, root, rotations)


def rig_of(motion: Motion) -> tuple[Motion, object]:
    body = build_body(motion)
    rig = reference_pose(motion, body.mapping)  # type: ignore[arg-type]
    _, positions = forward_kinematics(rig)
    return rig, map_skeleton(rig.skeleton, poses=[("frame 0", positions[0])])


def main() -> None:
    print(f"machine: {machine()}")
    clip = long_clip()
    print(
        f"clip: {clip.frame_count} frames at {1 / clip.frame_time:.0f} fps, "
        f"{clip.skeleton.joint_count} joints (CMU walk repeated to 60 s)"
    )
    limit = Settings().max_frame_values * 10
    bvh = best(lambda: write_bvh(clip))
    print(f"baseline: today's BVH export (write_bvh)     {bvh * 1000:8.1f} ms")
    glb = best(
        lambda: export_motion(
            clip, ExportOptions(format="glb"), rig=None, max_values=limit, fbx=None
        )
    )
    print(
        f"GLB export (map, up axis, write)            {glb * 1000:8.1f} ms  "
        f"(target 300 ms; {glb / bvh:.2f}x the BVH export)"
    )

    bandai = read_bvh(
        next((shared_data() / "bandai-ds1/data").glob("*walk_normal_001.bvh")).read_bytes()
    )
    rig, rig_map = rig_of(bandai)
    source_map = build_body(clip).mapping
    fk = best(lambda: forward_kinematics(clip))
    took = best(lambda: retarget(clip, source_map, rig, rig_map))  # type: ignore[arg-type]
    per = took / clip.frame_count * 1000
    print(f"baseline: forward kinematics of the clip     {fk * 1000:8.1f} ms")
    print(
        f"retarget onto the Bandai rig                {took * 1000:8.1f} ms = {per * 1000:.1f} ms "
        f"per 1,000 frames (target 50; {took / fk:.1f}x FK)"
    )

    reason = fbx_unavailable_reason()
    if reason is not None:
        print(f"FBX: not measured ({reason})")
    else:
        pool = ExportPool(1, time_limit=600, memory_mb=8192)
        try:
            prepared = prepare_motion(clip, ExportOptions(format="fbx"), None)
            out = rotate(prepared.motion, prepared.up_rotation)
            short = out.slice_frames(0, 2)
            started = time.perf_counter()
            pool.write_fbx(short, metres_per_unit=prepared.metres, name="warm-up")
            print(
                "FBX worker start (Blender import) + tiny export "
                f"{time.perf_counter() - started:6.2f} s"
            )
            for frames in (600, 2400, clip.frame_count):
                part = out.slice_frames(0, frames)
                took = best(
                    lambda part=part: pool.write_fbx(
                        part, metres_per_unit=prepared.metres, name="bench"
                    ),
                    repeat=1,
                )
                print(
                    f"FBX export, warm worker, {frames:5d} frames        {took:8.2f} s "
                    f"({took / frames * 1000:.2f} ms per frame; target 2 s for 7200)"
                )
        finally:
            pool.close()

    zip_bench()


def zip_bench() -> None:
    """POST /exports of 100 Bandai clips through the real app, BVH, GLB and GLB on a rig."""
    from fastapi.testclient import TestClient

    from app.main import create_app

    files = sorted((shared_data() / "bandai-ds1/data").glob("*.bvh"))[:100]
    with tempfile.TemporaryDirectory() as folder:
        settings = Settings(data_dir=Path(folder) / "data", max_export_clips=100)
        with TestClient(create_app(settings), base_url="http://127.0.0.1") as client:
            for path in files:
                response = client.post(
                    "/clips",
                    files={"file": (path.name, path.read_bytes())},
                    data={"labels": "bench"},
                )
                assert response.status_code == 201, response.text
            rig = client.post("/rigs", files={"file": (files[0].name, files[0].read_bytes())})
            rig_id = rig.json()["id"]
            for body in (
                {"label": ["bench"], "format": "bvh"},
                {"label": ["bench"], "format": "glb"},
                {"label": ["bench"], "format": "glb", "rig": rig_id, "root": "in-place"},
            ):
                start = time.perf_counter()
                response = client.post("/exports", json=body)
                took = time.perf_counter() - start
                assert response.status_code == 200, response.text
                options = " ".join(f"{k}={v}" for k, v in body.items() if k != "label")
                print(
                    f"ZIP of 100 clips, {options:32s} {took:6.2f} s = {100 / took:6.1f} clips/s "
                    f"({len(response.content) / 2**20:.1f} MB)"
                )


if __name__ == "__main__":
    main()
