"""Every human rig of the development data, rewritten as unseen exporters write rigs, alone
and COMBINED (issue 20): does the mapper find the same joints?

Run: ``nice -n 10 .venv/bin/python bench/probe_mapping.py [--workers 2] [--frames 300]
[--only FAMILY ...] [--skip FAMILY ...] [--json OUT]``

Rigs: one file per distinct rig (names, tree, bone proportions) of ``wild-bvh``, ``fbx-gltf``
and ``wild-more`` that the service maps (a file it refuses is no human rig here), and the
first clip of each ``cmu`` and ``bandai-ds1`` folder; each cut to its first ``--frames``
frames. A probe is a list of steps (the helpers of
``tests/motion/test_mapping_probes.py`` and ``test_mapping_properties.py``); each step
rewrites the motion and says which joint each canonical joint should now be (a step that
cuts a joint moves the expectation to the joint that now ends the chain). Outcome per rig
and probe: ``same`` (the canonical joints by name, and not mirrored), ``refused``
(a :class:`MocapError`), ``differ`` (which joints), ``ERROR`` (anything else: a 500), or not
applicable (none of the probe's cuts or moves applies: a rig of two spine bones, no
clavicles, no fingers or toes is a short game rig already; the steps that do apply are run).
The table counts same / applicable.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.discovery import discover  # noqa: E402
from app.errors import MocapError  # noqa: E402
from app.motion.formats import read_asf_amc, read_bvh  # noqa: E402
from app.motion.kinematics import forward_kinematics  # noqa: E402
from app.motion.mapping.canonical import SkeletonMap  # noqa: E402
from app.motion.mapping.skeleton import _CANDIDATES, _known  # noqa: E402
from app.motion.model import Motion, ParseLimits  # noqa: E402
from app.motion.pipeline import describable_body  # noqa: E402
from app.motion.skeleton_map import CANONICAL_INDEX  # noqa: E402
from app.services.parser_pool import parse_scene  # noqa: E402
from bench.common import machine, shared_data  # noqa: E402
from tests.motion.synthetic import below, grown, with_cloth_chains  # noqa: E402
from tests.motion.test_mapping_probes import (  # noqa: E402
    _arrays,
    frame_as_rest,
    kept,
    own_axes,
    without,
)
from tests.motion.test_mapping_properties import _with_small_bones  # noqa: E402

Expected = dict[str, str]  # canonical joint -> the rig's joint name it should map to
# A step: the motion rewritten and the expectation moved, or None (not applicable).
Step = Callable[[Motion, Expected], tuple[Motion, Expected] | None]
FOLDERS = ("wild-bvh", "fbx-gltf", "wild-more")
FIRST_ONLY = ("cmu", "bandai-ds1")


def _index(motion: Motion, name: str) -> int:
    return motion.skeleton.names.index(name)


def _below(motion: Motion, joint: int) -> list[int]:
    """Every joint strictly below ``joint``."""
    return below(motion.skeleton, joint)


def _path(motion: Motion, top: int, end: int) -> list[int]:
    """Joints from ``top`` (excluded) down to ``end`` (included); empty if not below."""
    parents = motion.skeleton.parents
    path = []
    j = end
    while j >= 0 and j != top:
        path.append(j)
        j = int(parents[j])
    return path[::-1] if j == top else []


def _cut(motion: Motion, drop: set[int]) -> Motion:
    keep = [j for j in range(motion.skeleton.joint_count) if j not in drop]
    return kept(motion, keep, _arrays(motion))


def nameless(motion: Motion, expected: Expected) -> tuple[Motion, Expected]:
    """Names that say nothing (``bone017``): what the mapper reads is the structure."""
    names = [f"bone{j:03d}" for j in range(motion.skeleton.joint_count)]
    renamed = dict(zip(motion.skeleton.names, names, strict=True))
    skeleton = dataclasses.replace(motion.skeleton, names=tuple(names))
    return dataclasses.replace(motion, skeleton=skeleton), {
        c: renamed[n] for c, n in expected.items()
    }


def first_rest(motion: Motion, expected: Expected) -> tuple[Motion, Expected]:
    """The first frame written as the rest pose (a video-derived or baked export): each
    bone's offset its translation in that frame, each joint's axes its world axes there."""
    if motion.local_translations is not None:
        # Translations that change per frame (a joint cut by ``without`` leaves its
        # children's turning with it) make the offsets' pose another than the frame's.
        offsets = motion.skeleton.offsets.copy()
        bones = [j for j, p in enumerate(motion.skeleton.parents) if p >= 0]
        offsets[bones] = motion.local_translations[0, bones]
        skeleton = dataclasses.replace(motion.skeleton, offsets=offsets)
        motion = dataclasses.replace(motion, skeleton=skeleton)
    return frame_as_rest(motion), expected


def odd_axes(motion: Motion, expected: Expected) -> tuple[Motion, Expected]:
    """Every bone in random axes of its own: a rest pose that is no figure."""
    return own_axes(motion), expected


def _swing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(F, 3, 3)`` the least rotation turning each ``(F, 3)`` ``a`` along ``b``."""
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    axis = np.cross(a, b)
    sin, cos = np.linalg.norm(axis, axis=1), np.einsum("fi,fi->f", a, b)
    axis = axis / np.maximum(sin, 1e-12)[:, None]
    angle = np.arctan2(sin, cos)
    k = np.zeros((len(a), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    k -= np.transpose(k, (0, 2, 1))
    return (
        np.eye(3) + np.sin(angle)[:, None, None] * k + (1 - np.cos(angle))[:, None, None] * (k @ k)
    )


def hips_at_pelvis(motion: Motion, expected: Expected) -> tuple[Motion, Expected] | None:
    """Both hip joints moved onto the pelvis joint in the rest pose: the thighs start at the
    pelvis and the legs part at the knees (SMPL-derived and some game rigs). The thigh from
    the pelvis is turned each frame towards where the knee was (the shin keeps its world
    rotation), as a rig built so would carry the same capture."""
    skeleton = motion.skeleton
    parents = skeleton.parents
    pelvis = _index(motion, expected["pelvis"])
    rest = np.zeros_like(skeleton.offsets)  # (J, 3) the offsets' rest pose
    for j, p in enumerate(parents):
        rest[j] = skeleton.offsets[j] if p < 0 else rest[p] + skeleton.offsets[j]
    size = float(np.ptp(rest, axis=0).max())
    world, positions = forward_kinematics(motion)
    parents_list, offsets, rotations, translations, names, end_site = _arrays(motion)
    moved = False
    for side in "lr":
        hip, knee = (_index(motion, expected[f"{side}_{part}"]) for part in ("hip", "knee"))
        shift = rest[hip] - rest[pelvis]
        if np.linalg.norm(shift) <= 1e-3 * size or knee == hip or parents[knee] != hip:
            continue
        moved = True
        up = int(parents[hip])
        offsets[hip] -= shift
        translations[:, hip] -= shift
        kids = [c for c, p in enumerate(parents) if p == hip]
        for child in kids:
            offsets[child] += shift
            translations[:, child] += shift
        at = positions[:, up] + np.einsum("fab,fb->fa", world[:, up], translations[:, hip])
        turned = (
            _swing(
                np.einsum("fab,fb->fa", world[:, hip], translations[:, knee]),
                positions[:, knee] - at,
            )
            @ world[:, hip]
        )  # (F, 3, 3) the hip's new world rotation
        rotations[:, hip] = np.transpose(world[:, up], (0, 2, 1)) @ turned
        for child in kids:
            rotations[:, child] = np.transpose(turned, (0, 2, 1)) @ world[:, child]
    if not moved:
        return None
    arrays = (parents_list, offsets, rotations, translations, names, end_site)
    return kept(motion, list(range(skeleton.joint_count)), arrays), expected


def clavicles_out(motion: Motion, expected: Expected) -> tuple[Motion, Expected] | None:
    """The clavicles left out (the arms hang from the chest), where the rig has them."""
    parents = motion.skeleton.parents
    collars = {
        motion.skeleton.names[int(parents[_index(motion, expected[f"{s}_shoulder"])])] for s in "lr"
    }
    if expected["chest"] in collars or len(collars) != 2:
        return None
    if collars & set(expected.values()):
        return None
    for name in sorted(collars):
        motion = without(motion, _index(motion, name))
    return motion, expected


def spine_of_two(motion: Motion, expected: Expected) -> tuple[Motion, Expected] | None:
    """Every spine joint between the pelvis and the neck left out but the two the rig maps
    as spine and chest (a game rig of two spine bones)."""
    pelvis, neck = _index(motion, expected["pelvis"]), _index(motion, expected["neck"])
    mapped = set(expected.values())
    drop = [
        motion.skeleton.names[j]
        for j in _path(motion, pelvis, neck)[:-1]
        if motion.skeleton.names[j] not in mapped
    ]
    if not drop:
        return None
    for name in drop:
        motion = without(motion, _index(motion, name))
    return motion, expected


def _end_cut(
    motion: Motion, expected: Expected, base: str, tip: str, siblings: bool
) -> tuple[Motion, Expected] | None:
    """Below each side's ``base`` joint only its first joint towards ``tip`` is kept, as a
    leaf (``siblings``: the base's other branches cut too); ``tip`` is then that leaf."""
    drop: set[int] = set()
    moved = dict(expected)
    for side in "lr":
        top = _index(motion, expected[f"{side}_{base}"])
        path = _path(motion, top, _index(motion, expected[f"{side}_{tip}"]))
        if not path:
            continue
        first = path[0]
        cut = set(_below(motion, first))
        if siblings:
            for kid in _below(motion, top):
                if motion.skeleton.parents[kid] == top and kid != first:
                    cut |= {kid, *_below(motion, kid)}
        if cut & {_index(motion, n) for c, n in expected.items() if not c.endswith(tip)}:
            return None
        drop |= cut
        moved[f"{side}_{tip}"] = motion.skeleton.names[first]
    if not drop:
        return None
    return _cut(motion, drop), moved


def toes_cut(motion: Motion, expected: Expected) -> tuple[Motion, Expected] | None:
    """No toe bones (nor heel or other foot bones): the foot ends at the joint after the ankle."""
    return _end_cut(motion, expected, "ankle", "toe", siblings=True)


def fingers_cut(motion: Motion, expected: Expected) -> tuple[Motion, Expected] | None:
    """No fingers: one hand joint beyond the wrist, a leaf (SMPL's hand, a game rig's)."""
    return _end_cut(motion, expected, "wrist", "hand_tip", siblings=True)


def leaves_150(motion: Motion, expected: Expected) -> tuple[Motion, Expected]:
    """150 small face and finger bones on the head, the hands and the feet."""
    return _with_small_bones(motion, 150), expected


def twist_leaves(motion: Motion, expected: Expected) -> tuple[Motion, Expected] | None:
    """Twist bones as game rigs hang them (Unreal's mannequin): a leaf half-way along the
    upper arm, forearm, thigh and shin, a sibling of the next joint, never moving."""
    skeleton = motion.skeleton
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    for side in "lr":
        for top, end in (
            ("shoulder", "elbow"),
            ("elbow", "wrist"),
            ("hip", "knee"),
            ("knee", "ankle"),
        ):
            joint = _index(motion, expected[f"{side}_{end}"])
            if skeleton.parents[joint] == _index(motion, expected[f"{side}_{top}"]):
                parents.append(int(skeleton.parents[joint]))
                offsets.append(0.5 * skeleton.offsets[joint])
    return (grown(motion, parents, offsets), expected) if parents else None


def _hung_from_a_joint(
    motion: Motion, parent: int, tops: list[int], shift: np.ndarray, name: str
) -> Motion:
    """``motion`` with a still joint ``name`` added under ``parent`` at ``shift`` and the
    joints ``tops`` (children of ``parent``) hung from it instead, where they were."""
    parents, offsets, rotations, translations, names, end_site = _arrays(motion)
    branch, frames = len(parents), motion.frame_count
    parents.append(parent)
    offsets = np.concatenate([offsets, shift[None]])
    rotations = np.concatenate([rotations, np.broadcast_to(np.eye(3), (frames, 1, 3, 3))], 1)
    translations = np.concatenate([translations, np.broadcast_to(shift, (frames, 1, 3))], 1)
    names.append(name)
    end_site.append(False)
    for top in tops:
        parents[top] = branch
        offsets[top] = offsets[top] - shift
        translations[:, top] = translations[:, top] - shift
    arrays = (parents, offsets, rotations, translations, names, end_site)
    return kept(motion, list(range(branch + 1)), arrays)


def legs_on_a_branch(motion: Motion, expected: Expected) -> tuple[Motion, Expected] | None:
    """The thighs hang from a joint of their own between the hips, a sibling of the spine
    (DAZ Genesis's ``pelvis`` under ``hip``), never moving."""
    pelvis = _index(motion, expected["pelvis"])
    hips = [_index(motion, expected[f"{side}_hip"]) for side in "lr"]
    parents = motion.skeleton.parents
    if any(parents[hip] != pelvis for hip in hips):
        return None
    offsets = motion.skeleton.offsets
    shift = 0.5 * (offsets[hips[0]] + offsets[hips[1]])
    return _hung_from_a_joint(motion, pelvis, hips, shift, "legs_branch"), expected


def shoulders_on_a_branch(motion: Motion, expected: Expected) -> tuple[Motion, Expected] | None:
    """The arms hang from a joint of their own halfway from the chest to the shoulders, a
    sibling of the neck (a few BVH writers' ``Chest2``), never moving; that joint is where
    the arms branch, the chest."""
    chest = _index(motion, expected["chest"])
    tops = []
    for side in "lr":
        path = _path(motion, chest, _index(motion, expected[f"{side}_shoulder"]))
        if not path:
            return None
        tops.append(path[0])
    head = _path(motion, chest, _index(motion, expected["head"]))
    if not head or head[0] in tops:
        return None
    offsets = motion.skeleton.offsets
    shift = 0.25 * (offsets[tops[0]] + offsets[tops[1]])
    hung = _hung_from_a_joint(motion, chest, tops, shift, "shoulders_branch")
    return hung, {**expected, "chest": "shoulders_branch"}


def root_above(motion: Motion, expected: Expected) -> tuple[Motion, Expected]:
    """A still ``root`` joint at the origin above the rig's own root (Unreal's ``root``)."""
    parents, offsets, rotations, translations, names, end_site = _arrays(motion)
    top, frames = parents.index(-1), motion.frame_count
    parents.append(-1)
    parents[top] = len(parents) - 1
    offsets = np.concatenate([offsets, np.zeros((1, 3))])
    rotations = np.concatenate([rotations, np.broadcast_to(np.eye(3), (frames, 1, 3, 3))], 1)
    translations = np.concatenate([translations, np.zeros((frames, 1, 3))], 1)
    names.append("root_above")
    end_site.append(False)
    arrays = (parents, offsets, rotations, translations, names, end_site)
    return kept(motion, list(range(len(parents))), arrays), expected


def secondary_chains(motion: Motion, expected: Expected) -> tuple[Motion, Expected]:
    """Hair and cloth chains (:func:`tests.motion.synthetic.with_cloth_chains`) hanging in
    the rig's rest pose where it shows the figure (a character's bind pose), else in the
    first frame (a rest pose of bones in axes of their own would hold the cloth in axes of
    its own too)."""
    in_rest = isinstance(_known(motion.skeleton, _CANDIDATES).rest_result, SkeletonMap)
    mapping = describable_body(motion).mapping
    assert mapping is not None
    chest, pelvis, left, right = (
        _index(motion, expected[c]) for c in ("chest", "pelvis", "l_hip", "r_hip")
    )
    # Hair hangs from the skull (the head joint), not from the top of the head.
    skull = mapping.head_joint
    dressed = with_cloth_chains(motion, skull, chest, pelvis, (left, right), in_rest=in_rest)
    return dressed, expected


# Steps that rewrite how the rig is written, not its joints.
WRITING = (nameless, first_rest, odd_axes)
GAME = [clavicles_out, spine_of_two, toes_cut, fingers_cut]
SMPL = [fingers_cut, toes_cut]
PROBES: dict[str, list[Step]] = {
    "nameless": [nameless],
    "first frame as rest": [first_rest],
    "bones in axes of their own": [odd_axes],
    "nameless + first frame as rest": [first_rest, nameless],
    "nameless + axes of their own": [odd_axes, nameless],
    "hips at the pelvis": [hips_at_pelvis],
    "hips at the pelvis + nameless": [hips_at_pelvis, nameless],
    "hips at the pelvis + nameless + axes of their own": [hips_at_pelvis, odd_axes, nameless],
    "short game rig": GAME,
    "short game rig + nameless": [*GAME, nameless],
    "short game rig + nameless + first frame as rest": [*GAME, first_rest, nameless],
    "short game rig + nameless + axes of their own": [*GAME, odd_axes, nameless],
    "SMPL-like hands and feet": SMPL,
    "SMPL-like + nameless": [*SMPL, nameless],
    "SMPL-like + nameless + axes of their own": [*SMPL, odd_axes, nameless],
    "150 face/finger leaves": [leaves_150],
    "150 leaves + axes of their own": [leaves_150, odd_axes],
    "150 leaves + nameless + first frame as rest": [leaves_150, first_rest, nameless],
    "game rig + 150 leaves + nameless + axes of their own": [
        *GAME,
        leaves_150,
        odd_axes,
        nameless,
    ],
    "twist leaves + nameless": [twist_leaves, nameless],
    "legs on a branch + nameless": [legs_on_a_branch, nameless],
    "root above + nameless": [root_above, nameless],
    "shoulders on a branch": [shoulders_on_a_branch],
    "shoulders on a branch + nameless": [shoulders_on_a_branch, nameless],
    "shoulders on a branch + nameless + axes of their own": [
        shoulders_on_a_branch,
        odd_axes,
        nameless,
    ],
    "hair and skirt chains": [secondary_chains],
    "hair and skirt chains + nameless": [secondary_chains, nameless],
    "hair and skirt chains + nameless + axes of their own": [
        secondary_chains,
        odd_axes,
        nameless,
    ],
    "twist leaves + legs on a branch + root above + nameless + axes of their own": [
        twist_leaves,
        legs_on_a_branch,
        root_above,
        odd_axes,
        nameless,
    ],
}


def mapped_names(motion: Motion) -> tuple[Expected, bool]:
    """Canonical joint -> the joint name the service maps it to, and whether mirrored."""
    mapping = describable_body(motion).mapping
    assert mapping is not None
    names = motion.skeleton.names
    return {c: names[mapping.joints[i]] for c, i in CANONICAL_INDEX.items()}, mapping.mirrored


def outcome(motion: Motion, expected: Expected, mirrored: bool, steps: list[Step]) -> str | None:
    """``same``, ``refused: ...``, ``differ ...``, ``ERROR ...`` or None (not applicable)."""
    changed = False
    for step in steps:
        done = step(motion, expected)
        if done is None:
            continue  # the rig is that way already (no clavicles to cut)
        motion, expected = done
        changed = changed or step not in WRITING
    if not changed and not all(step in WRITING for step in steps):
        return None  # no rewrite of the rig applied: the probe says nothing new
    try:
        got, now_mirrored = mapped_names(motion)
    except MocapError as error:
        return f"refused: {str(error)[:160]}"
    except Exception as error:  # a 500 in the service
        return f"ERROR {type(error).__name__}: {error}"
    # A joint at the same place as the one expected (a zero-length bone apart: a leaf the
    # cut left at the wrist) is the same point.
    _, at = forward_kinematics(motion.slice_frames(0, 1))
    names = motion.skeleton.names
    tolerance = 1e-6 * float(np.ptp(at[0], axis=0).max())
    pairs = [
        f"{c}: {expected[c]} -> {got[c]}"
        for c in CANONICAL_INDEX
        if got[c] != expected[c]
        and np.linalg.norm(at[0, names.index(got[c])] - at[0, names.index(expected[c])]) > tolerance
    ]
    if now_mirrored != mirrored:
        pairs.append(f"mirrored {now_mirrored}")
    return "same" if not pairs else "differ " + "; ".join(pairs)


def read(source: object, frames: int) -> Motion:
    kind = source.kind  # type: ignore[attr-defined]
    path: Path = source.motion  # type: ignore[attr-defined]
    if kind == "asf/amc":
        motion = read_asf_amc(source.skeleton.read_bytes(), path.read_bytes())  # type: ignore[attr-defined]
    elif kind == "bvh":
        motion = read_bvh(path.read_bytes())
    else:
        motion = parse_scene(kind, path.read_bytes(), None, ParseLimits()).motion
    return motion.slice_frames(0, frames) if motion.frame_count > frames else motion


def rig_outcomes(job: tuple[str, object, int]) -> tuple[str, dict[str, str | None] | None]:
    """One rig: every probe's outcome, or None when the plain rig is refused (no human)."""
    name, source, frames = job
    try:
        motion = read(source, frames)
        expected, mirrored = mapped_names(motion)
        forward_kinematics(motion.slice_frames(0, 1))
    except (MocapError, ValueError):
        return name, None
    found: dict[str, str | None] = {}
    for probe, steps in PROBES.items():
        try:
            found[probe] = outcome(motion, dict(expected), mirrored, steps)
        except MocapError as error:  # a probe's own mapping of a rig that maps only so
            found[probe] = f"refused: {str(error)[:160]}"
        except Exception as error:
            found[probe] = f"ERROR {type(error).__name__}: {error}"
    return name, found


def rig_key(job: tuple[str, object, int]) -> tuple[str, bytes | None]:
    """A file's rig (joint names, tree and bone lengths to 1e-3 of the longest), or None
    when the file does not parse: one file per rig is probed."""
    name, source, _ = job
    try:
        skeleton = read(source, 1).skeleton
    except (MocapError, ValueError):
        return name, None
    lengths = np.linalg.norm(skeleton.offsets, axis=1)
    rounded = np.round(lengths / max(float(lengths.max()), 1e-12), 3)
    return name, repr((skeleton.names, skeleton.parents.tolist(), rounded.tolist())).encode()


def run_jobs(
    work: Callable[[tuple], tuple[str, object]], jobs: Iterable[tuple], workers: int
) -> tuple[dict[str, object], list[str]]:
    """``work`` on every job (``job[0]`` its name) in ``workers`` niced processes: the
    results by name, and the names whose process died (a segfault in a native reader).

    ``multiprocessing.Pool`` waits forever for a result a dead worker never sends; an
    executor reports the death (``BrokenProcessPool``) to every job it still held, so those
    are run again one process each, and a job that kills its own process is the one that
    crashed."""
    results: dict[str, object] = {}
    crashed: list[str] = []
    pending = list(jobs)
    alone = False  # after a death: each job in a process of its own, to find the culprit
    while pending:
        batch = [[job] for job in pending] if alone else [pending]
        pending = []
        for group in batch:
            size = 1 if alone else workers
            with ProcessPoolExecutor(size, initializer=os.nice, initargs=(5,)) as pool:
                futures: dict[Future, tuple] = {pool.submit(work, job): job for job in group}
                for future in as_completed(futures):
                    try:
                        name, value = future.result()
                    except BrokenProcessPool:
                        if alone:
                            crashed.append(futures[future][0])
                        else:
                            pending.append(futures[future])
                        continue
                    results[name] = value
        alone = True
    return results, crashed


def sources(only: list[str], skip: list[str]) -> list[tuple[str, object]]:
    data = shared_data()
    out: list[tuple[str, object]] = []
    for folder in (*FOLDERS, *FIRST_ONLY):
        if not (data / folder).is_dir():
            continue
        seen: set[Path] = set()
        for source in discover([data / folder], scenes=True).sources:
            family = f"{folder}/{source.relative_path.split('/')[0]}"
            if (only and not any(family.startswith(o) for o in only)) or any(
                family.startswith(s) for s in skip
            ):
                continue
            if folder in FIRST_ONLY:
                if source.motion.parent in seen:
                    continue
                seen.add(source.motion.parent)
            out.append((f"{folder}/{source.relative_path}", source))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--frames", type=int, default=300, help="clips cut to this")
    parser.add_argument("--only", nargs="*", default=[], help="families (folder/sub) to run")
    parser.add_argument("--skip", nargs="*", default=[], help="families left out (held out)")
    parser.add_argument("--json", type=Path, help="write every outcome here")
    parser.add_argument("--probes", nargs="*", default=[], help="only probes naming these")
    args = parser.parse_args()
    print(machine(), flush=True)
    if args.probes:
        for probe in list(PROBES):
            if not any(word in probe for word in args.probes):
                del PROBES[probe]
    jobs = [(name, source, args.frames) for name, source in sources(args.only, args.skip)]
    keys, unread = run_jobs(rig_key, jobs, args.workers)
    first: dict[bytes, str] = {}
    for job in jobs:  # the files' order, so the rig's first file is the one probed
        key = keys.get(job[0])
        if isinstance(key, bytes):
            first.setdefault(key, job[0])
    unique = set(first.values())
    results, crashed = run_jobs(rig_outcomes, [j for j in jobs if j[0] in unique], args.workers)
    # A rig whose probing killed its process failed every probe (a 500 at least).
    for name in crashed:
        results[name] = {probe: "ERROR the process died" for probe in PROBES}
    rigs = {k: v for k, v in sorted(results.items()) if isinstance(v, dict)}
    print(
        f"{len(rigs)} human rigs of {len(results)} distinct rigs, {len(jobs)} files; "
        f"load average {os.getloadavg()[0]:.2f}"
    )
    for name in unread + crashed:
        print(f"the process died on {name} ({'reading' if name in unread else 'probing'} it)")
    print("| probe | same / applicable | refused | differ | ERROR |")
    print("|---|---|---|---|---|")
    for probe in PROBES:
        got = [v[probe] for v in rigs.values() if v.get(probe) is not None]
        same = sum(g == "same" for g in got)
        refused = sum(g.startswith("refused") for g in got)  # type: ignore[union-attr]
        error = sum(g.startswith("ERROR") for g in got)  # type: ignore[union-attr]
        differ = len(got) - same - refused - error
        print(f"| {probe} | {same} / {len(got)} | {refused} | {differ} | {error} |")
    if args.json:
        args.json.write_text(json.dumps(rigs, indent=1, sort_keys=True))


if __name__ == "__main__":
    main()
