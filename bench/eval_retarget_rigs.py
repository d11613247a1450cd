"""Which rigs and which clips ``bench/eval_retarget.py`` evaluates (issue 22).

The seven development rigs are where the retarget's rules were developed; ``--rig-file PATH``
(repeatable) evaluates onto any other rig file, read as the service reads an uploaded rig
(BVH, also one with ``Frames: 0`` or no MOTION section; ASF; FBX, glTF/GLB through the
parser workers), in the same table row. ``--sample N`` retargets a seeded spread of N clips
over the data's families (folders) rather than every clip, while the round trip still looks
each re-upload up among every clip's vector: a quick look whose figures mean what the full
sweep's do.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from app.errors import NoAnimation
from app.motion.formats import read_bvh
from app.motion.formats.asf_amc import parse_asf_rest
from app.motion.formats.bvh import parse_bvh_rest
from app.motion.model import Motion, ParseLimits
from app.services.parser_pool import ParserPool

# Where the held-out rigs are gathered: a rig file under it is named by its path there (its
# manifest line), any other by its file name.
UNSEEN = Path("/work/unseen")


def read_rig_motion(path: Path, pool: ParserPool, *, rig: bool = False) -> Motion:
    """The motion of a BVH, ASF, FBX or glTF file; with ``rig``, as
    :func:`app.services.rigs.read_rig_file` reads an uploaded rig: a BVH with ``Frames: 0``
    or no MOTION section as its rest pose, an FBX/glTF's bind pose. (A clip with no frames
    is refused, as the service refuses it: the library holds no rest-only templates.)"""
    suffix = path.suffix.lower()
    limits = ParseLimits()
    if suffix == ".bvh":
        try:
            return read_bvh(path.read_bytes(), limits=limits)
        except NoAnimation:  # Frames: 0, or no MOTION section
            if not rig:
                raise
            return parse_bvh_rest(path.read_text(errors="replace"), limits=limits)
    if suffix == ".asf":
        return parse_asf_rest(path.read_text(), limits=limits)
    kind = "fbx" if suffix == ".fbx" else "gltf"
    return pool.parse(
        f"{kind}-rig" if rig else kind, path.read_bytes(), animation=None, limits=limits
    ).motion


def rig_file_name(path: Path) -> str:
    """A table row's name for a rig file given on the command line."""
    resolved = path.resolve()
    if resolved.is_relative_to(UNSEEN):
        return f"file: {resolved.relative_to(UNSEEN)}"
    return f"file: {path.name}"


def family(name: str) -> str:
    """The family a clip of ``../shared/data`` belongs to: its folder, two levels down
    (``wild-bvh/mixamo``, ``cmu/asf-amc``, ``bandai-ds1/data``)."""
    return "/".join(name.split("/")[:2])


def spread_sample(names: list[str], count: int, seed: int = 0) -> list[int]:
    """Indices of ``count`` of ``names`` spread over their families: each family's clips
    shuffled (seeded), then taken one per family in turn, so a family of 174 clips does not
    fill a sample a family of two is missing from. Sorted."""
    rng = np.random.default_rng(seed)
    groups: dict[str, list[int]] = defaultdict(list)
    for index, name in enumerate(names):
        groups[family(name)].append(index)
    queues = [list(rng.permutation(groups[key])) for key in sorted(groups)]
    picked: list[int] = []
    while len(picked) < min(count, len(names)):
        for queue in queues:
            if queue and len(picked) < count:
                picked.append(int(queue.pop()))
    return sorted(picked)


__all__ = ["family", "read_rig_motion", "rig_file_name", "spread_sample"]
