"""Retarget quality and round trip on rigs from the development data (issue 22).

    .venv/bin/python bench/eval_retarget.py [--limit N] [--dump FILE.npz]   # ../shared/data
    .venv/bin/python bench/eval_retarget.py --rig-file RIG.bvh [--rig-file ...] [--sample N]
    .venv/bin/python bench/eval_retarget.py generalise [--round-trip FILE.npz]
    .venv/bin/python bench/eval_retarget.py compare BEFORE.npz AFTER.npz   # two --dump files

Every clip of ``../shared/data`` the service accepts (BVH, ASF/AMC, FBX, glTF; the longest
animation of a file; cut to its first 20 s, ``--seconds``, so the sweep fits an hour on a
shared machine) is described under ``motion``; then, for each of seven rigs (Mixamo,
CMU ASF, Bandai, Rokoko, Xsens, SMPL, a 19-joint game character), every clip is retargeted
onto the rig, written as BVH and read back (what a download and re-upload does), described
again and looked up among all the clips' vectors (Euclidean, as ``GET /search`` does): the
round trip holds when the nearest is the source — or, in brackets, its twin: the same
capture in another format or folder, by file stem (CMU trials as ASF/AMC, MotionBuilder BVH
and DAZ BVH; the FBX/BVH pairs), which the retargeted copy cannot tell from its source.
A third figure also counts a tie as found (besides a twin): the nearest clip is no nearer
than the source, or holds the source's vector to float rounding (the same motion stored
twice under other names, or rigs holding one rest pose: a copy that lands on that vector
is nearer one of them by rounding); the count of such clips is printed first, the ceiling
no retarget can pass.
Per rig the retarget quality of :mod:`app.motion.retarget_quality` is summarised.
``--rig-file`` evaluates onto any rig file instead (or, with ``--rig``, as well), ``--sample``
on a seeded spread of the clips (:mod:`bench.eval_retarget_rigs`); ``compare`` lives in
:mod:`bench.eval_retarget_compare`. FBX and
glTF files are read in parser
worker processes, as the service reads them.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.discovery import discover
from app.errors import MocapError
from app.motion.body import build_body
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.formats.bvh_writer import write_bvh
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion
from app.motion.pipeline import analyse
from app.motion.retarget import reference_pose, retarget
from app.motion.retarget_quality import RetargetQuality, retarget_quality
from app.motion.skeleton_map import SkeletonMap, map_skeleton
from app.services.parser_pool import ParserPool
from bench.common import machine, shared_data
from bench.eval_retarget_compare import capture, compare, is_tie
from bench.eval_retarget_rigs import read_rig_motion, rig_file_name, spread_sample
from bench.rig_variants import Draft, unseen_variants

RIGS = {
    "Mixamo (Ortiz, BVH)": "wild-bvh/mixamo/ortiz_thankful.bvh",
    "CMU ASF (subject 01)": "cmu/asf-amc/01/01.asf",
    "Bandai": "bandai-ds1/data/dataset-1_walk_normal_001.bvh",
    "Rokoko Newton (FBX)": "fbx-gltf/rokoko/Rokoko_Newton.FBX",
    "Xsens MVN (BVH)": "wild-bvh/xsens-mvn/jl_motionmatching_tpose.bvh",
    "SMPL (ROMP, BVH)": "wild-bvh/smpl-video/romp_dance2.bvh",
    "game: CesiumMan (GLB, 19 joints)": "fbx-gltf/khronos-samples/CesiumMan.glb",
}


@dataclass
class Clip:
    name: str
    motion: Motion
    mapping: SkeletonMap
    lead_in: int
    vector: np.ndarray


def load_clips(pool: ParserPool, limit: int | None, seconds: float) -> list[Clip]:
    found = discover([shared_data()], scenes=True)
    clips: list[Clip] = []
    for source in found.sources[: limit or None]:
        try:
            if source.kind == "asf/amc":
                assert source.skeleton is not None
                motion = read_asf_amc(source.skeleton.read_bytes(), source.motion.read_bytes())
            else:
                motion = read_rig_motion(source.motion, pool)
            keep = max(1, round(seconds / motion.frame_time))
            if motion.frame_count > keep:
                motion = motion.slice_frames(0, keep)
            analysis = analyse(motion, descriptors=["motion"])
        except (MocapError, ValueError):
            continue
        assert analysis.body.mapping is not None
        clips.append(
            Clip(
                source.relative_path,
                motion,
                analysis.body.mapping,
                analysis.lead_in_frames,
                analysis.descriptors["motion"],
            )
        )
    return clips


def load_rig(path: Path, pool: ParserPool) -> tuple[Motion, SkeletonMap]:
    motion = read_rig_motion(path, pool, rig=True)
    body = build_body(motion)
    assert body.mapping is not None
    rig = reference_pose(motion, body.mapping)
    _, positions = forward_kinematics(rig)
    return rig, map_skeleton(rig.skeleton, poses=[("frame 0", positions[0])])


def summary(
    name: str,
    joints: int,
    found: list[bool],
    twin: list[bool],
    tied: list[bool],
    qualities: list[RetargetQuality],
) -> str:
    n = len(qualities)

    def share(values: list[bool]) -> str:
        return f"{100 * np.mean(values):5.1f} %"

    slide_over = [q.slide - q.source_slide for q in qualities]
    travel_off = [abs(q.travel - q.source_travel) for q in qualities]
    return (
        f"| {name} | {joints} | {n} | {share(found)} ({share(twin)}; or tied {share(tied)}) | "
        f"{max(q.bone_error for q in qualities):.1e} | "
        f"{share([q.left_ok == 1.0 for q in qualities])} | "
        f"{share([q.feet_error <= 0.02 for q in qualities])} | "
        f"{share([s <= 0.01 for s in slide_over])} (median +{np.median(slide_over):.3f}) | "
        f"{share([q.finite for q in qualities])} | "
        f"{share([q.direction_ok >= 0.99 for q in qualities])} | "
        f"{np.median(travel_off):.3f} / {max(travel_off):.3f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--limit", type=int, help="only the first N clips (a quick look)")
    parser.add_argument(
        "--seconds",
        type=float,
        default=20.0,
        help="clips longer than this are cut to their first SECONDS (library and queries alike)",
    )
    parser.add_argument(
        "--rig", action="append", help="only these rigs (by the start of their name)"
    )
    parser.add_argument(
        "--rig-file",
        type=Path,
        action="append",
        default=[],
        help="also (without --rig: only) this rig file, BVH/ASF/FBX/GLB, read as an upload",
    )
    parser.add_argument(
        "--sample",
        type=int,
        help="retarget only a seeded spread of N clips over the families (every clip is "
        "still described: the round trip looks up among all)",
    )
    parser.add_argument("--seed", type=int, default=0, help="the --sample's seed")
    parser.add_argument(
        "--dump",
        type=Path,
        help="save every clip's name and vector and every re-upload's vector to this .npz "
        "(to break the round trip's distances down afterwards)",
    )
    args = parser.parse_args()
    print(f"machine: {machine()}")
    pool = ParserPool(1)
    try:
        started = time.perf_counter()
        clips = load_clips(pool, args.limit, args.seconds)
        vectors = np.stack([c.vector for c in clips])
        print(f"{len(clips)} clips described in {time.perf_counter() - started:.0f} s")
        dumped: dict[str, np.ndarray] = {
            "names": np.array([c.name for c in clips]),
            "vectors": vectors,
        }
        apart = np.linalg.norm(vectors[:, None] - vectors[None], axis=2)
        np.fill_diagonal(apart, np.inf)
        identical = apart.min(axis=1) <= 1e-6 * np.linalg.norm(vectors, axis=1)
        print(
            f"{int(identical.sum())} clips share their `motion` vector with another clip "
            "(no re-upload can be nearer to them than to it)"
        )
        rigs: dict[str, Path] = {
            name: shared_data() / relative
            for name, relative in RIGS.items()
            if (args.rig and any(name.startswith(r) for r in args.rig))
            or not (args.rig or args.rig_file)
        }
        rigs.update((rig_file_name(path), path) for path in args.rig_file)
        chosen = (
            set(spread_sample([c.name for c in clips], args.sample, args.seed))
            if args.sample
            else set(range(len(clips)))
        )
        if args.sample:
            print(f"{len(chosen)} clips retargeted (seed {args.seed})")
        print(
            "| rig | joints | clips | round trip: source is nearest (or a twin: same "
            "capture in another format; or tied with an identical clip) | bones (max error, "
            "body heights) | left stays left | feet within 2 % | sliding <= source + 1 %/s "
            "| finite | limb directions within 5 deg in 99 % of frames | net travel off the "
            "source's, leg lengths/s (median / max) |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for rig_name, path in rigs.items():
            try:
                rig, rig_map = load_rig(path, pool)
            except (MocapError, AssertionError) as error:
                print(f"| {rig_name} | not a rig: {getattr(error, 'detail', error)} |")
                continue
            found: list[bool] = []
            twin: list[bool] = []
            tied: list[bool] = []
            qualities: list[RetargetQuality] = []
            failures: list[str] = []
            uploads = np.full_like(vectors, np.nan)
            for index, clip in enumerate(clips):
                if index not in chosen:
                    continue
                try:
                    out = retarget(clip.motion, clip.mapping, rig, rig_map)
                    again = read_bvh(write_bvh(out))
                    vector = analyse(again, descriptors=["motion"]).descriptors["motion"]
                except MocapError as error:
                    failures.append(f"{clip.name}: {error.detail}")
                    found.append(False)
                    twin.append(False)
                    tied.append(False)
                    continue
                uploads[index] = vector
                distances = np.linalg.norm(vectors - vector, axis=1)
                nearest = int(np.argmin(distances))
                found.append(nearest == index)
                twin.append(capture(clips[nearest].name) == capture(clip.name))
                tie = is_tie(vectors, distances, index, nearest)
                tied.append(twin[-1] or tie)
                if not twin[-1]:
                    failures.append(
                        f"{clip.name} -> {clips[nearest].name} "
                        f"({distances[index]:.3f} vs {distances[nearest]:.3f})"
                    )
                qualities.append(
                    retarget_quality(clip.motion, clip.mapping, out, rig_map, skip=clip.lead_in)
                )
            print(
                summary(rig_name, rig.skeleton.joint_count, found, twin, tied, qualities),
                flush=True,
            )
            for failure in failures:
                print(f"  failed [{rig_name}]: {failure}", file=sys.stderr)
            if args.dump:
                dumped[f"rig: {rig_name}"] = uploads
                np.savez_compressed(args.dump, **dumped)  # per rig: a stopped run keeps some
    finally:
        pool.close()


# --- `generalise`: rigs from exporters we have not seen ----------------------------------

# Varied clips retargeted onto every rig: a walk, a run (ASF/AMC), hip-hop (Mixamo), a dance
# from video (SMPL), a cartwheel, a standing jump, and a MakeHuman pose, whose limbs are
# split in two (upperarm01/02...) at other points than a split rig's.
GENERALISE_CLIPS = (
    "bandai-ds1/data/dataset-1_walk_normal_001.bvh",
    "cmu/asf-amc/02/02_03.amc",
    "wild-bvh/mixamo/granny_hiphop_noprefix.bvh",
    "wild-bvh/smpl-video/romp_dance2.bvh",
    "wild-more/sfu-cmu-mix/emretanirgan_Cartwheel.bvh",
    "wild-more/sfu-cmu-mix/emretanirgan_jump_from_stand_.bvh",
    "wild-bvh/makehuman/fight01.bvh",
)
BARS = ("bones", "left", "feet", "sliding", "finite", "directions", "all")


def distinct_rigs(pool: ParserPool) -> list[tuple[str, Motion, SkeletonMap]]:
    """Every distinct humanoid rig of the development data (first file of each skeleton:
    same joint names, hierarchy and bone lengths), as ``load_rig`` reads it."""
    found = discover([shared_data()], scenes=True)
    seen: set[tuple[object, ...]] = set()
    out = []
    for source in found.sources:
        path = source.skeleton if source.kind == "asf/amc" else source.motion
        assert path is not None
        try:
            rig, rig_map = load_rig(path, pool)
        except (MocapError, ValueError, AssertionError):
            continue  # not a humanoid (an animal, a prop), or a file the service refuses
        skeleton = rig.skeleton
        lengths = np.linalg.norm(skeleton.offsets, axis=1)
        key = (
            skeleton.names,
            skeleton.parents.tobytes(),
            np.round(lengths / max(float(lengths.max()), 1e-12), 3).tobytes(),
        )
        if key not in seen:
            seen.add(key)
            out.append((source.relative_path, rig, rig_map))
    return out


def generalise(argv: list[str]) -> None:
    """Retarget :data:`GENERALISE_CLIPS` onto every distinct rig and its
    :data:`VARIANTS`; print, per kind of rig, the share of pairs passing each bar."""
    parser = argparse.ArgumentParser(prog="eval_retarget.py generalise")
    parser.add_argument("--seconds", type=float, default=8.0, help="clips cut to this")
    parser.add_argument("--rigs", type=int, help="only the first N distinct rigs")
    parser.add_argument("--failures", action="store_true", help="list failing pairs (stderr)")
    parser.add_argument(
        "--round-trip",
        type=Path,
        help="a `--dump` of the seven-rig sweep (same --seconds): also write each retarget as "
        "BVH, read it back and look it up among that sweep's library, as the table does",
    )
    args = parser.parse_args(argv)
    library = np.load(args.round_trip) if args.round_trip else None
    print(f"machine: {machine()}")
    started = time.perf_counter()
    pool = ParserPool(1)
    try:
        clips = []
        for relative in GENERALISE_CLIPS:
            path = shared_data() / relative
            if path.suffix == ".amc":
                asf = next(path.parent.glob("*.asf"))
                motion = read_asf_amc(asf.read_bytes(), path.read_bytes())
            else:
                motion = read_rig_motion(path, pool)
            keep = max(1, round(args.seconds / motion.frame_time))
            motion = motion.slice_frames(0, min(keep, motion.frame_count))
            analysis = analyse(motion, descriptors=["motion"])
            assert analysis.body.mapping is not None
            clips.append((relative, motion, analysis.body.mapping, analysis.lead_in_frames))
        rigs = distinct_rigs(pool)[: args.rigs or None]
    finally:
        pool.close()
    print(
        f"{len(clips)} clips, {len(rigs)} distinct rigs read in "
        f"{time.perf_counter() - started:.0f} s"
    )
    passed: dict[str, list[list[bool]]] = {}
    # Per kind of rig: the round trip found, or a twin, or tied (as in the seven-rig table).
    trips: dict[str, list[tuple[bool, bool, bool]]] = {}
    unmapped: dict[str, int] = {}
    for index, (name, rig, rig_map) in enumerate(rigs):
        candidates: list[tuple[str, Draft | None]] = [("as read", None)]
        candidates += unseen_variants(rig, rig_map, seed=index)
        for kind, draft in candidates:
            try:
                target, target_map = (rig, rig_map) if draft is None else draft.rig()
            except MocapError:
                unmapped[kind] = unmapped.get(kind, 0) + 1
                continue
            for clip_name, motion, mapping, lead_in in clips:
                out: Motion | None = None
                try:
                    out = retarget(motion, mapping, target, target_map)
                    q = retarget_quality(motion, mapping, out, target_map, skip=lead_in)
                    bars = [
                        q.bone_error <= 1e-9,
                        q.left_ok == 1.0,
                        q.feet_error <= 0.02,
                        q.slide <= q.source_slide + 0.01,
                        q.finite,
                        q.direction_ok >= 0.99,
                    ]
                except (MocapError, ValueError) as error:
                    bars = [False] * 6
                    q = error  # type: ignore[assignment]
                bars.append(all(bars))
                passed.setdefault(kind, []).append(bars)
                if library is not None:
                    trip = (False,) * 3 if out is None else round_trip(library, clip_name, out)
                    trips.setdefault(kind, []).append(trip)
                if args.failures and not bars[-1]:
                    print(f"  {kind} | {name} | {clip_name}: {q}", file=sys.stderr)
        print(
            f"  rig {index + 1}/{len(rigs)} done, {time.perf_counter() - started:.0f} s",
            file=sys.stderr,
            flush=True,
        )
    print("| rig | pairs | not mapped (rigs) | " + " | ".join(BARS) + " |")
    print("|---|---|---|" + "---|" * len(BARS))
    every: list[list[bool]] = []
    for kind, rows in passed.items():
        every.extend(rows if kind != "as read" else [])
        share = np.mean(np.array(rows, dtype=float), axis=0) * 100
        print(
            f"| {kind} | {len(rows)} | {unmapped.get(kind, 0)} | "
            + " | ".join(f"{s:.1f} %" for s in share)
            + " |"
        )
    share = np.mean(np.array(every, dtype=float), axis=0) * 100
    print(
        f"| every variant | {len(every)} | {sum(v for k, v in unmapped.items())} | "
        + " | ".join(f"{s:.1f} %" for s in share)
        + " |"
    )
    if trips:
        print("| rig | pairs | round trip: source nearest (or twin; or tied) |")
        print("|---|---|---|")
        for kind, found in [*trips.items(), ("every variant", every_trip(trips))]:
            share = np.mean(np.array(found, dtype=float), axis=0) * 100
            print(
                f"| {kind} | {len(found)} | {share[0]:.1f} % ({share[1]:.1f} %; {share[2]:.1f} %) |"
            )
    print(f"{time.perf_counter() - started:.0f} s in all; machine: {machine()}")


def round_trip(library: Any, name: str, out: Motion) -> tuple[bool, bool, bool]:
    """Whether ``out`` (``name`` retargeted), written as BVH and read back, has ``name`` as
    its nearest clip in a ``--dump``'s library, or a twin of it, or a tie with it; a
    re-upload the service refuses is a miss."""
    names = [str(n) for n in library["names"]]
    vectors = library["vectors"]
    try:
        vector = analyse(read_bvh(write_bvh(out)), descriptors=["motion"]).descriptors["motion"]
    except MocapError:
        return (False, False, False)
    index = names.index(name)
    distances = np.linalg.norm(vectors - vector, axis=1)
    nearest = int(np.argmin(distances))
    twin = capture(names[nearest]) == capture(name)
    tie = is_tie(vectors, distances, index, nearest)
    return (nearest == index, twin, twin or tie)


def every_trip(trips: dict[str, list[tuple[bool, bool, bool]]]) -> list[tuple[bool, bool, bool]]:
    """The round trips of every rewrite (not the rigs as read)."""
    return [t for kind, found in trips.items() if kind != "as read" for t in found]


if __name__ == "__main__":
    if sys.argv[1:2] == ["generalise"]:
        generalise(sys.argv[2:])
    elif sys.argv[1:2] == ["compare"]:
        compare(sys.argv[2:])
    else:
        main()
