"""Write one BVH as FBX both ways with Blender (bpy), in a process of its own.

Run as ``python tests/motion/fbx_bake_runner.py IN.bvh OUT_DIR [refuse]``: writes
``OUT_DIR/numpy.fbx`` (``write_fbx``'s numpy bake) and ``OUT_DIR/blender.fbx`` (Blender's own
bake) in centimetres and prints, as JSON, why the numpy bake refused the scene each time it
was asked (``null``: it baked it). With ``refuse``, its check of the posed frame fails
(a tolerance below zero), as it would where Blender composed bones otherwise.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))


def main() -> None:
    source, folder = Path(sys.argv[1]), Path(sys.argv[2])
    refuse = sys.argv[3:] == ["refuse"]
    with open(os.devnull, "w") as devnull, contextlib.redirect_stderr(devnull):
        import bpy  # noqa: F401
    import app.motion.formats.fbx_bake as fbx_bake
    from app.motion.formats import read_bvh
    from app.motion.formats.fbx_writer import write_fbx

    refusals: list[str | None] = []
    bake = fbx_bake._bake

    def recorded(*args: object) -> object:
        baked = bake(*args)  # type: ignore[arg-type]
        refusals.append(baked if isinstance(baked, str) else None)
        return baked

    fbx_bake._bake = recorded  # type: ignore[assignment]
    if refuse:
        fbx_bake.MATCH_TOLERANCE = -1.0
    motion = read_bvh(source.read_bytes())
    with contextlib.redirect_stdout(sys.stderr):  # Blender talks
        (folder / "numpy.fbx").write_bytes(write_fbx(motion, bake="numpy"))
        (folder / "blender.fbx").write_bytes(write_fbx(motion, bake="blender"))
    print(json.dumps(refusals))


if __name__ == "__main__":
    main()
