"""Retargeting speed (issue 22: "retargeting adds <= 50 ms per 1,000 frames").

    .venv/bin/python bench/bench_retarget.py [--baseline DIR] [--rounds N]   # ../shared/data

The clip: CMU 02_01 (a walk, 38 joints, 120 fps) repeated to 60 s = 7,200 frames (as
bench/bench_export.py), retargeted onto the Bandai rig (27 joints) and the Mixamo rig (78
joints, fingers). Each figure comes with forward kinematics of the same clip measured in
the same process (the ratio is what survives a shared machine's load). ``--baseline DIR``:
a checkout of other code (``git worktree add DIR <commit>``) measured in the same run, in
alternating child processes (this code, the baseline, this code, ...), best of each.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
RIGS = {
    "Bandai": "bandai-ds1/data/dataset-1_walk_normal_001.bvh",
    "Mixamo": "wild-bvh/mixamo/ortiz_thankful.bvh",
}


def child(repeat: int) -> None:
    """Measure the code importable from ``sys.path[0]`` (set by the parent); print JSON."""
    from app.motion.body import build_body
    from app.motion.formats import read_bvh
    from app.motion.kinematics import forward_kinematics
    from app.motion.retarget import retarget
    from bench.bench_export import long_clip, rig_of
    from bench.common import shared_data

    def best(run: object) -> float:
        times = []
        for _ in range(repeat):
            start = time.perf_counter()
            run()  # type: ignore[operator]
            times.append(time.perf_counter() - start)
        return min(times)

    clip = long_clip()
    source_map = build_body(clip).mapping
    out = {"frames": clip.frame_count, "fk": best(lambda: forward_kinematics(clip))}
    for name, relative in RIGS.items():
        rig, rig_map = rig_of(read_bvh((shared_data() / relative).read_bytes()))
        out[name] = best(lambda rig=rig, rig_map=rig_map: retarget(clip, source_map, rig, rig_map))
    print(json.dumps(out))


def measure(root: Path, repeat: int) -> dict[str, float]:
    env = {**os.environ, "MOCAP_SHARED_DATA": str(shared_data_dir())}
    script = HERE / "bench" / "bench_retarget.py"
    code = (
        f"import sys; sys.path.insert(0, {str(root)!r}); "
        f"sys.argv = ['bench_retarget', '--child', '--repeat', '{repeat}']; "
        f"__file__ = {str(script)!r}; exec(open(__file__).read())"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    )
    return json.loads(done.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def shared_data_dir() -> Path:
    sys.path.insert(0, str(HERE))
    from bench.common import shared_data

    return shared_data().resolve()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--baseline", type=Path, help="a checkout of the code to compare with")
    parser.add_argument("--rounds", type=int, default=3, help="child processes per side")
    parser.add_argument("--repeat", type=int, default=3, help="runs per child (best kept)")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.repeat)
        return
    sys.path.insert(0, str(HERE))
    from bench.common import machine

    print(f"machine: {machine()}")
    sides = {"this": HERE}
    if args.baseline:
        sides["baseline"] = args.baseline.resolve()
    results: dict[str, list[dict[str, float]]] = {side: [] for side in sides}
    for _ in range(args.rounds):
        for side, root in sides.items():
            results[side].append(measure(root, args.repeat))
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    frames = results["this"][0]["frames"]
    print(
        f"clip: {frames:.0f} frames (CMU 02_01 repeated to 60 s); best of "
        f"{args.rounds} x {args.repeat} runs per side"
    )
    best = {side: {k: min(r[k] for r in runs) for k in runs[0]} for side, runs in results.items()}
    for side, figures in best.items():
        print(f"{side:9s} forward kinematics of the clip {figures['fk'] * 1000:8.1f} ms")
        for name in RIGS:
            per = figures[name] / frames * 1e6
            print(
                f"{side:9s} retarget onto {name:7s}          {figures[name] * 1000:8.1f} ms = "
                f"{per:6.1f} ms per 1,000 frames ({figures[name] / figures['fk']:.2f}x FK)"
            )
    if args.baseline:
        for name in RIGS:
            ratio = best["this"][name] / best["baseline"][name]
            print(f"this / baseline, {name}: {ratio:.2f}")


if __name__ == "__main__":
    main()
