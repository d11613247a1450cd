"""Moments search on real data: exact moments and localisation across styles (issue 13).

Run from the repository root::

    .venv/bin/python bench/bench_moments.py exact [--spans 500] [--seed 0]
    .venv/bin/python bench/bench_moments.py styles [--seed 0]
    .venv/bin/python bench/bench_moments.py scale [--hours 100] [--data-dir DIR] [--baseline DIR]
    .venv/bin/python bench/bench_moments.py recall --data-dir DIR [--against FLOAT32_COPY]
    .venv/bin/python bench/bench_moments.py alternate --data-dir DIR --baseline MAIN_CHECKOUT

``exact``
    Imports Bandai dataset 1, the CMU ASF/AMC trials and their MotionBuilder BVH twins of
    ``../shared/data`` into a fresh temporary library, then cuts ``--spans`` random spans of
    1.25-4 s out of random clips (the stored file cut with ``app.motion.formats.cut``, as
    ``GET /clips/{id}/file?start=&end=`` does) and searches each twice: by upload (``POST
    /search/moments`` in-process) and stored as a clip of its own (searched by clip, then
    deleted). Counts the spans whose source comes first (or tied first with a clip of the
    very same motion), placed within one of its frames (target: every span).
``styles``
    Builds one long take per Bandai style: that style's clips joined into one BVH in a
    random order, each clip's root moved on the floor so it starts where the previous one
    ended (no teleports), imported with the style as label. Every ds1 clip is then a query
    by upload: the top moment in a take of *another* style (``per_clip=1``, the first result
    of another style) must overlap a segment of the same action with IoU >= 0.5 (target:
    70 % of the queries whose action appears in another style's take). Also printed: IoU >=
    0.3 / 0.7, and the whole-clip baselines — the whole take as the moment, and the 1-NN
    action accuracy of whole clips of other styles under the same descriptor.
``recall``
    Recall of the compressed window indexes' candidate search (``MOCAP_WINDOW_CODES=sq8``:
    8-bit lists, candidates re-ranked by their exact vectors) against exact search, and
    (``--against`` a copy of the library with float32 lists) how many moments answers are
    identical.
``alternate``
    Main's moments search (``--baseline``: its checkout, whose three moments modules are
    loaded under other names) and this checkout's in one process on the library at
    ``--data-dir``, alternating query by query: thread CPU, identical answers, (part, window)
    measurements a search. Run with ``OPENBLAS_NUM_THREADS=1`` (this script loads numpy
    before ``app`` sets it).
``scale``
    Fills ``DIR`` (default ``$TMPDIR/mocap-bench-moments-100h``) with ``--hours`` of motion
    windows: Bandai dataset 1 imported, then ``mocap-index fill-synthetic`` clips (each a
    noisy copy of a real clip with its windows) up to that many hours. Times three server
    starts, then ``wrk`` (``bench/search.lua``) on ``GET /search/moments?clip=<random>&k=10``
    (the whole clip as the query) at 1 and 32 connections, alternating with the HTTP floor
    (``bench/floor_app.py``, same uvicorn and worker count) over ``--rounds`` rounds, with the
    server's CPU time per request and its peak memory (VmRSS summed over its processes, and
    PSS). ``--baseline CHECKOUT`` starts and serves another checkout (with its own
    ``.venv``) on the same library in the same rounds and prints the ratios. The server runs
    ``--workers`` processes (default: one per core). Targets (issue
    23, at 100 h): start-up <= 5 s; >= 50 % more requests/s than before the issue at 32
    connections (or >= 25 % of the floor); median <= 10 ms. Needs ``wrk``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from common import machine, shared_data  # bench/common.py (scripts run from bench/)

from app.config import Settings
from app.db import clips as clip_db
from app.errors import MocapError
from app.importer import run_import
from app.motion.formats import decode_text
from app.motion.formats.cut import cut_amc, cut_bvh
from app.services.clips import delete_clip
from app.services.ingest import ingest, ingest_many
from app.services.library import Library, open_library
from app.services.moments import search_moments_by_clip, search_moments_by_upload
from app.services.search import search_by_upload
from app.services.uploads import Upload

DESCRIPTOR = "motion"


def iou(a: tuple[float, float], b: tuple[float, float]) -> float:
    inter = max(0.0, min(a[1], b[1]) - max(a[0], b[0]))
    union = max(a[1], b[1]) - min(a[0], b[0])
    return inter / union if union > 0 else 0.0


def fresh_library(tmp: Path, sources: list[Path], **settings_given: str) -> Library:
    settings = Settings(data_dir=tmp / "data", log_level="warning", **settings_given)
    started = time.perf_counter()
    report = run_import(settings, sources)
    print(
        f"imported {len(report.imported)} clips ({len(report.failed)} failed) in "
        f"{time.perf_counter() - started:.1f} s"
    )
    return open_library(settings)


def cut_upload(library: Library, clip: clip_db.ClipRecord, first: int, stop: int) -> Upload:
    """The stored clip cut to frames ``[first, stop)``, as an upload."""
    roles = {f.role: f for f in clip.files}
    if "file" in roles:
        text = cut_bvh(decode_text(library.blobs.read(roles["file"].sha256)), first, stop)
        return Upload.from_files(file=("cut.bvh", text.encode()))
    asf = library.blobs.read(roles["skeleton"].sha256)
    amc = cut_amc(decode_text(library.blobs.read(roles["motion"].sha256)), first, stop)
    return Upload.from_files(skeleton=("cut.asf", asf), motion=("cut.amc", amc.encode()))


def found_first(moments: list, clip: clip_db.ClipRecord, truth: float) -> bool:
    """The source clip first (or tied first with another clip of the very same motion),
    placed within one of its frames."""
    best = moments[0].distance
    for moment in moments:
        if moment.distance > best:
            break
        if moment.clip.id == clip.id:
            return abs(moment.start - truth) <= clip.frame_time + 1e-6
    return False


def exact(args: argparse.Namespace) -> int:
    data = shared_data()
    sources = [data / "bandai-ds1", data / "cmu" / "asf-amc", data / "cmu" / "bvh-mb"]
    rng = np.random.default_rng(args.seed)
    found = {"file": [], "clip": []}
    times: dict[str, list[float]] = {"file": [], "clip": []}
    misses: list[tuple[object, ...]] = []
    with tempfile.TemporaryDirectory(prefix="mocap-bench-moments-") as tmp:
        given = {"index_type": args.index_type, "window_codes": args.window_codes}
        library = fresh_library(Path(tmp), sources, **given)
        kinds = {n: f"{i.kind}/{i.codes}" for n, i in library.window_indexes.items()}
        print(f"window indexes: {kinds}")
        try:
            with library.reads() as session:
                stored = clip_db.get_clips(session, clip_db.all_clip_ids(session)).values()
            # By name and format: the draw must not depend on the order the import stored them.
            clips = sorted(stored, key=lambda clip: (clip.name, clip.format))
            while len(found["file"]) < args.spans:
                clip = clips[int(rng.integers(len(clips)))]
                usable = (clip.frame_count - clip.lead_in_frames) * clip.frame_time
                if usable < 1.25:
                    continue
                seconds = float(rng.uniform(1.25, min(4.0, usable)))
                frames = round(seconds / clip.frame_time)
                first = clip.lead_in_frames + int(
                    rng.integers(0, clip.frame_count - clip.lead_in_frames - frames + 1)
                )
                truth = first * clip.frame_time
                upload = cut_upload(library, clip, first, first + frames)
                for mode in ("file", "clip"):
                    started = time.perf_counter()
                    try:
                        moments = _exact_search(library, upload, mode)
                    except MocapError as error:  # e.g. the cut's skeleton not recognised
                        moments = []
                        misses.append((mode, clip.name, truth, error.code, error.detail))
                    times[mode].append(time.perf_counter() - started)
                    ok = bool(moments) and found_first(moments, clip, truth)
                    found[mode].append(ok)
                    if not ok and moments:
                        top = [(m.clip.name, m.format, m.start, m.distance) for m in moments[:2]]
                        misses.append((mode, clip.name, clip.format, truth, seconds, top))
        finally:
            library.close()
    print(f"machine: {machine()}")
    for mode, what in (("file", "by uploaded file"), ("clip", "by stored clip")):
        hits, total = sum(found[mode]), len(found[mode])
        print(
            f"exact copies {what}: {hits}/{total} = {hits / total:.1%} random spans of "
            f"1.25-4 s found first in their source, placed within one of its frames; "
            f"median {statistics.median(times[mode]) * 1000:.0f} ms a search"
            + (" (parse + describe + search)" if mode == "file" else " (store, search, delete)")
        )
    for miss in misses[:20]:
        print("  miss:", miss)
    return 0 if not misses else 1


def _exact_search(library: Library, upload: Upload, mode: str) -> list:
    """The cut searched by upload, or stored as a clip of its own, searched by clip and
    deleted."""
    if mode == "file":
        return search_moments_by_upload(
            library, upload, DESCRIPTOR, start=None, end=None, k=3, per_clip=1, label=None
        )[1]
    result = ingest(library, dataclasses.replace(upload, name="probe"))
    try:
        return search_moments_by_clip(
            library, result.clip.id, DESCRIPTOR, start=None, end=None, k=3, per_clip=1, label=None
        )[1]
    finally:
        if result.created:
            delete_clip(library, result.clip.id)


def _bvh_parts(text: str) -> tuple[str, list[str], str]:
    """Header up to MOTION, frame lines, ``Frame Time:`` line of a BVH text."""
    lines = text.replace("\r\n", "\n").split("\n")
    motion = next(i for i, line in enumerate(lines) if line.strip().upper() == "MOTION")
    rest = [line for line in lines[motion + 1 :] if line.strip()]
    return "\n".join(lines[: motion + 1]), rest[2:], rest[1].strip()


def _channel_columns(header: str) -> list[tuple[str, str]]:
    """(joint, channel) per frame column, from the hierarchy."""
    columns, joint = [], ""
    for line in header.split("\n"):
        words = line.split()
        if words and words[0] in ("ROOT", "JOINT"):
            joint = words[1]
        elif words and words[0] == "CHANNELS":
            columns += [(joint, name) for name in words[2:]]
    return columns


def build_take(paths: list[Path]) -> tuple[str, list[tuple[str, int, int]]]:
    """One BVH of ``paths`` in order, each clip's mover (the first joint whose horizontal
    position channels change) shifted so it starts where the previous clip ended; returns
    the text and each clip's (name, first frame, stop frame)."""
    header, _, frame_time = _bvh_parts(paths[0].read_text())
    columns = _channel_columns(header)
    frames: list[np.ndarray] = []
    segments = []
    end: np.ndarray | None = None
    for path in paths:
        clip_header, lines, _ = _bvh_parts(path.read_text())
        if _channel_columns(clip_header) != columns:
            raise SystemExit(f"{path.name}: another hierarchy than {paths[0].name}")
        values = np.loadtxt(lines, ndmin=2)
        mover = next(
            joint
            for joint, _ in columns
            if np.ptp(values[:, columns.index((joint, "Xposition"))]) > 1e-6
        )
        x, z = columns.index((mover, "Xposition")), columns.index((mover, "Zposition"))
        if end is not None:
            values[:, x] += end[0] - values[0, x]
            values[:, z] += end[1] - values[0, z]
        end = values[-1, [x, z]]
        start = sum(len(f) for f in frames)
        segments.append((path.stem, start, start + len(values)))
        frames.append(values)
    joined = np.concatenate(frames)
    body = "\n".join(" ".join(f"{v:.6f}" for v in row) for row in joined)
    return f"{header}\nFrames: {len(joined)}\n{frame_time}\n{body}\n", segments


def _action(stem: str) -> tuple[str, str]:
    """(action, style) of a Bandai file stem ``dataset-1_{action}_{style}_{id}``."""
    _, action, style, _ = stem.split("_")
    return action, style


def styles(args: argparse.Namespace) -> int:
    bandai = sorted((shared_data() / "bandai-ds1" / "data").glob("*.bvh"))
    rng = np.random.default_rng(args.seed)
    by_style: dict[str, list[Path]] = {}
    for path in bandai:
        by_style.setdefault(_action(path.stem)[1], []).append(path)
    with tempfile.TemporaryDirectory(prefix="mocap-bench-styles-") as tmp:
        settings = Settings(data_dir=Path(tmp) / "data", log_level="warning")
        library = open_library(settings)
        try:
            uploads, segments = [], {}
            started = time.perf_counter()
            for style, paths in sorted(by_style.items()):
                order = [paths[i] for i in rng.permutation(len(paths))]
                text, parts = build_take(order)
                name = f"take-{style}"
                segments[name] = parts
                uploads.append(
                    Upload.from_files(file=(f"{name}.bvh", text.encode()), labels=[style, "take"])
                )
            results = ingest_many(library, uploads, batch_size=4)
            take_of = {r.clip.id: r.clip for r in results}
            print(
                f"built and imported {len(take_of)} takes "
                f"({sum(c.duration for c in take_of.values()) / 60:.1f} min) in "
                f"{time.perf_counter() - started:.1f} s"
            )
            # The whole-clip baseline library: every ds1 clip stored alone (another library).
            clips_settings = Settings(data_dir=Path(tmp) / "clips", log_level="warning")
            run_import(clips_settings, [shared_data() / "bandai-ds1"])
            clip_library = open_library(clips_settings)
            scores: list[float] = []
            centred: list[bool] = []  # the moment's centre lies in a segment of the action
            whole_take: list[float] = []
            nn_hits, counted, skipped, times = 0, 0, 0, []
            for path in bandai:
                action, style = _action(path.stem)
                wanted = [
                    (name, first, stop)
                    for name, parts in segments.items()
                    if name != f"take-{style}"
                    for stem, first, stop in parts
                    if _action(stem)[0] == action
                ]
                if not wanted:
                    skipped += 1
                    continue
                counted += 1
                upload = Upload.from_files(file=(path.name, path.read_bytes()))
                t0 = time.perf_counter()
                _, moments = search_moments_by_upload(
                    library,
                    upload,
                    DESCRIPTOR,
                    start=None,
                    end=None,
                    k=20,
                    per_clip=1,
                    label=None,
                )
                times.append(time.perf_counter() - t0)
                top = next(m for m in moments if style not in m.clip.labels)
                take = f"take-{top.clip.labels[0]}"
                frame_time = next(c.frame_time for c in take_of.values() if c.id == top.clip.id)
                best = max(
                    (
                        iou((top.start, top.end), (first * frame_time, stop * frame_time))
                        for name, first, stop in wanted
                        if name == take
                    ),
                    default=0.0,
                )
                scores.append(best)
                centre = (top.start + top.end) / 2
                centred.append(
                    any(
                        first * frame_time <= centre < stop * frame_time
                        for name, first, stop in wanted
                        if name == take
                    )
                )
                duration = next(c.duration for c in take_of.values() if c.id == top.clip.id)
                whole_take.append(
                    max(
                        (
                            iou((0.0, duration), (first * frame_time, stop * frame_time))
                            for name, first, stop in wanted
                            if name == take
                        ),
                        default=0.0,
                    )
                )
                _, hits = search_by_upload(clip_library, upload, DESCRIPTOR, 30, label=None)
                other = next(h for h in hits if _action(h.clip.name)[1] != style)
                nn_hits += _action(other.clip.name)[0] == action
            clip_library.close()
        finally:
            library.close()
    share = {t: sum(s >= t for s in scores) / counted for t in (0.3, 0.5, 0.7)}
    print(f"machine: {machine()}")
    print(
        f"localisation across styles, {counted} queries ({skipped} left out: their action is "
        f"in no take of another style), top moment in a take of another style:"
    )
    print(
        f"  IoU >= 0.3: {share[0.3]:.1%}   IoU >= 0.5: {share[0.5]:.1%} (target 70 %)   "
        f"IoU >= 0.7: {share[0.7]:.1%}"
    )
    print(
        f"  the top moment's centre lies in a segment of the same action for "
        f"{sum(centred) / counted:.1%} (the action is found; IoU then says how well it is cut)"
    )
    print(
        f"  mean IoU {statistics.mean(scores):.3f}; search by upload median "
        f"{statistics.median(times) * 1000:.0f} ms"
    )
    print(
        f"  whole-clip baselines: the whole take as the moment, IoU >= 0.5 for "
        f"{sum(s >= 0.5 for s in whole_take) / counted:.1%} (mean IoU "
        f"{statistics.mean(whole_take):.3f}); 1-NN whole clip of another style has the same "
        f"action for {nn_hits / counted:.1%}"
    )
    print(json.dumps({"iou>=0.3": share[0.3], "iou>=0.5": share[0.5], "iou>=0.7": share[0.7]}))
    return 0 if share[0.5] >= 0.70 else 1


def scale(args: argparse.Namespace) -> int:
    import math
    import sqlite3
    import subprocess

    from bench_search import CLI, Floor, Server, baseline_server, environment, summary, timed_wrk

    data_dir: Path = args.data_dir
    database = data_dir / "mocap-index.sqlite3"
    print(f"machine: {machine()}")
    started = time.perf_counter()
    if not database.exists():
        subprocess.run(
            [
                CLI,
                "import",
                "--no-progress",
                "--data-dir",
                str(data_dir),
                str(shared_data() / "bandai-ds1"),
            ],
            check=True,
            env=environment(),
        )
    db = sqlite3.connect(database)
    clips, seconds = db.execute("SELECT count(*), sum(duration) FROM clips").fetchone()
    db.close()
    target = args.hours * 3600
    if seconds < 0.999 * target:  # not again for rounding
        count = clips + math.ceil((target - seconds) / (seconds / clips))
        subprocess.run(
            [CLI, "fill-synthetic", "--count", str(count), "--data-dir", str(data_dir)],
            check=True,
            env=environment(),
        )
        print(f"filled in {time.perf_counter() - started:.0f} s")
    db = sqlite3.connect(database)
    clips, seconds, top = db.execute(
        "SELECT count(*), sum(duration), max(id) FROM clips"
    ).fetchone()
    windows = db.execute("SELECT count(*) FROM clip_windows").fetchone()[0]
    db.close()
    print(
        f"library: {clips} clips, {seconds / 3600:.1f} h of motion, {windows} windows "
        f"({data_dir}, {database.stat().st_size / 2**30:.2f} GiB database)"
    )
    log = data_dir.parent / "mocap-bench-moments-server.log"
    workers = str(args.workers or os.cpu_count() or 1)
    # GET /search/moments is a heavy route: without an API key one client may have 4 in
    # progress (MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT), and wrk's 32 connections are one client.
    settings = {
        "MOCAP_WORKERS": workers,
        "MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT": "64",
        "MOCAP_WINDOW_CODES": args.window_codes,
    }
    print(f"server: {workers} worker processes (--workers)")

    def start(name: str) -> Server:
        if name == "baseline":
            return baseline_server(args.baseline, data_dir, log, **settings)
        return Server(data_dir, log, **settings)

    served = ["moments"] + (["baseline"] if args.baseline is not None else [])
    startups: dict[str, list[float]] = {name: [] for name in served}
    startup_cpu: dict[str, list[float]] = {name: [] for name in served}
    print(f"load average before the starts: {os.getloadavg()[0]:.2f}")
    for _ in range(3):  # interleaved: a slow spell of the machine hits both
        for name in served:
            started = start(name)
            startups[name].append(started.startup)
            startup_cpu[name].append(started.startup_cpu)
            started.stop()
    for name in served:
        print(
            f"start-up ({name}): median {statistics.median(startups[name]):.2f} s of "
            f"{', '.join(f'{s:.2f}' for s in startups[name])} (target 5 s); CPU "
            f"{', '.join(f'{s:.2f}' for s in startup_cpu[name])} s, all processes"
        )
    servers = {name: start(name) for name in served}
    floor = Floor(data_dir, log, MOCAP_WORKERS=workers)
    options = {"path": "/search/moments", "descriptor": DESCRIPTOR}
    runs: dict[tuple[str, int], list[dict[str, float]]] = {}
    try:
        print(f"load average before the load: {os.getloadavg()[0]:.2f}")
        for target in servers.values():
            timed_wrk(target, 32, 5, top, **options)  # warm-up
        timed_wrk(floor, 32, 3, top, **options)
        for connections in (1, 32):
            for _ in range(args.rounds):
                for name, target in (("floor", floor), *servers.items()):
                    result = timed_wrk(target, connections, args.duration, top, **options)
                    runs.setdefault((name, connections), []).append(result)
                    print(f"  {name:8s} {connections:2d} conn: {summary(result)}")
        load_after = os.getloadavg()[0]
    finally:
        floor.stop()
        for target in servers.values():
            target.stop()

    def median(name: str, connections: int, field: str) -> float:
        return statistics.median(r[field] for r in runs[(name, connections)])

    rps, floor_rps = median("moments", 32, "rps"), median("floor", 32, "rps")
    cpu, floor_cpu = median("moments", 32, "cpu_ms"), median("floor", 32, "cpu_ms")
    p50 = median("moments", 1, "p50_ms")
    print(
        f"moments: {rps:.0f} requests/s at 32 connections = {rps / floor_rps:.0%} of the floor "
        f"({floor_rps:.0f}); median {p50:.1f} ms at 1 connection (target 10); server CPU "
        f"{cpu:.2f} ms per request, floor {floor_cpu:.3f}"
    )
    if "baseline" in servers:
        base_rps, base_p50 = median("baseline", 32, "rps"), median("baseline", 1, "p50_ms")
        print(
            f"baseline {args.baseline}: {base_rps:.0f} requests/s at 32 connections = "
            f"{base_rps / floor_rps:.0%} of the floor; median {base_p50:.1f} ms at 1 "
            f"connection; server CPU {median('baseline', 32, 'cpu_ms'):.2f} ms per request "
            f"(32 conn), {median('baseline', 1, 'cpu_ms'):.2f} (1 conn); this checkout "
            f"{median('moments', 1, 'cpu_ms'):.2f} (1 conn)"
        )
        print(
            f"requests/s at 32 connections: {rps / base_rps:.2f} x the baseline's (target "
            f"1.5, or 25 % of the floor: {0.25 * floor_rps:.0f}/s, whichever is lower)"
        )
    for name, target in servers.items():
        print(
            f"server memory ({name}), peak: VmRSS {target.peak_rss / 2**30:.2f} GiB summed "
            f"over its processes, PSS {target.peak_pss / 2**30:.2f} GiB"
        )
    print(f"load average after: {load_after:.2f}")
    bad = sum(r["bad"] for rs in runs.values() for r in rs)
    ok = p50 <= 10 and statistics.median(startups["moments"]) <= 5 and bad == 0
    return 0 if ok else 1


def recall(args: argparse.Namespace) -> int:
    """Recall of each compressed window index's candidate search (what a moments probe asks:
    its nearest few hundred windows, re-ranked) against exact search over the same vectors;
    then, with ``--against``, how many whole-clip moments answers (k = 10) are identical to
    those of the same library with float32 lists."""
    import faiss

    from app.services.moment_finder import PROBE_AHEAD
    from app.services.moments import FIRST_FETCH

    print(f"machine: {machine()}")
    faiss.omp_set_num_threads(1)
    given = {"window_codes": args.window_codes}  # as the files are: no rebuild
    settings = Settings(data_dir=args.data_dir, log_level="warning", **given)
    library = open_library(settings)
    rng = np.random.default_rng(0)
    wanted = (FIRST_FETCH + 10) * PROBE_AHEAD  # a first probe's search at k = 10
    try:
        for name, index in library.window_indexes.items():
            ids, vectors = index.all_vectors()
            rows = rng.choice(ids.size, min(args.queries, ids.size), replace=False)
            noise = rng.normal(0, 0.01, (rows.size, vectors.shape[1])).astype(np.float32)
            queries = vectors[rows] + noise  # a query part is near, not on, a stored window
            started = time.process_time()
            _, found = index.search_batch(queries, wanted)
            took = (time.process_time() - started) / rows.size
            _, truth = faiss.knn(queries, vectors, wanted)
            truth_ids = ids[truth]
            share = [
                len(set(a.tolist()) & set(b.tolist())) / wanted
                for a, b in zip(found, truth_ids, strict=True)
            ]
            top = [
                len(set(a[:10].tolist()) & set(b[:10].tolist())) / 10
                for a, b in zip(found, truth_ids, strict=True)
            ]
            print(
                f"{name}: {index.kind}/{index.codes}, {index.size} windows, nprobe "
                f"{index.nprobe}: recall@{wanted} {np.mean(share):.4f}, recall@10 "
                f"{np.mean(top):.4f} against exact search ({rows.size} queries, "
                f"{took * 1e3:.2f} ms CPU each)"
            )
        if args.against is not None:
            other = open_library(
                Settings(data_dir=args.against, log_level="warning", window_codes="float32")
            )
            try:
                with library.reads() as session:
                    top_id = max(clip_db.all_clip_ids(session))
                same = 0
                clips = rng.integers(1, top_id + 1, args.clips)
                for clip in clips.tolist():
                    answers = [
                        [
                            (m.clip.id, m.start, m.end, m.distance)
                            for m in search_moments_by_clip(
                                lib,
                                clip,
                                DESCRIPTOR,
                                start=None,
                                end=None,
                                k=10,
                                per_clip=3,
                                label=None,
                            )[1]
                        ]
                        for lib in (library, other)
                    ]
                    same += answers[0] == answers[1]
                print(
                    f"moments (whole clip, k = 10) identical to the float32 lists' for "
                    f"{same}/{clips.size} random clips"
                )
            finally:
                other.close()
    finally:
        library.close()
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


def alternate(args: argparse.Namespace) -> int:
    """Main's moments search and this checkout's in one process on one library, alternating
    query by query: ``--baseline``'s ``moments.py``, ``moment_finder.py``,
    ``moment_parts.py`` (and ``moment_arrays.py`` where it has one) loaded under other
    names. Thread CPU of the search, answers compared by SHA-1 of (clip, start, end,
    distance), (part, window) measurements counted. Each query
    runs once by both untimed first: a clip with a stored file is described from its file at
    its first query (a span cache per module), which would land on whichever ran first."""
    import hashlib

    from app.services import moment_finder

    base_dir = args.baseline / "app" / "services"

    def load(name: str, path: Path, replace: dict[str, str]) -> Any:
        text = path.read_text()
        for old, new in replace.items():
            text = text.replace(old, new)
        module = type(sys)(name)
        module.__file__ = str(path)
        sys.modules[name] = module
        exec(compile(text, str(path), "exec"), module.__dict__)
        return module

    load("base_moment_parts", base_dir / "moment_parts.py", {})
    finder_names: dict[str, str] = {}
    if (base_dir / "moment_arrays.py").exists():  # the finder's bookkeeping, split off later
        load("base_moment_arrays", base_dir / "moment_arrays.py", {})
        finder_names["app.services.moment_arrays"] = "base_moment_arrays"
    base_finder = load("base_moment_finder", base_dir / "moment_finder.py", finder_names)
    base = load(
        "base_moments",
        base_dir / "moments.py",
        {
            "app.services.moment_finder": "base_moment_finder",
            "app.services.moment_parts": "base_moment_parts",
        },
    )
    counts = {"nearest": 0, "fits": 0}
    for finder in (base_finder.MomentFinder, moment_finder.MomentFinder):
        nearest, fits = finder._nearest_parts_in_blocks, finder._fits_in_blocks

        def counted_nearest(self: Any, windows: Any, real: Any = nearest) -> Any:
            counts["nearest"] += len(windows)
            return real(self, windows)

        def counted_fits(self: Any, placed: Any, *rest: Any, real: Any = fits) -> Any:
            counts["fits"] += len(placed)
            return real(self, placed, *rest)

        finder._nearest_parts_in_blocks, finder._fits_in_blocks = counted_nearest, counted_fits
    library = open_library(Settings(data_dir=args.data_dir, log_level="warning"))
    library.load_window_places()
    every = np.array(sorted(library.catalogue.ids()), np.int64)
    queries = np.random.default_rng(args.seed).choice(every, args.queries, replace=False)

    def run(module: Any, clip: int) -> tuple[float, str, int, int]:
        counts["nearest"] = counts["fits"] = 0
        started = time.thread_time()
        _, found = module.search_moments_by_clip(
            library,
            clip,
            DESCRIPTOR,
            start=None,
            end=None,
            k=10,
            per_clip=args.per_clip,
            label=None,
        )
        used = time.thread_time() - started
        answer = repr([(m.clip.id, m.start, m.end, m.distance) for m in found])
        return used, hashlib.sha1(answer.encode()).hexdigest(), counts["nearest"], counts["fits"]

    from app.services import moments

    measured: dict[str, list[tuple[float, str, int, int]]] = {"main": [], "branch": []}
    load_before = os.getloadavg()[0]
    for number, clip in enumerate(int(c) for c in queries):
        run(base, clip)  # untimed (see the docstring)
        run(moments, clip)
        order = [("main", base), ("branch", moments)][:: 1 if number % 2 else -1]
        for name, module in order:
            measured[name].append(run(module, clip))
    same = sum(a[1] == b[1] for a, b in zip(measured["main"], measured["branch"], strict=True))
    print(f"{machine()}; load {load_before:.1f} -> {os.getloadavg()[0]:.1f}")
    for name, rows in measured.items():
        cpu = [1e3 * row[0] for row in rows]
        nearest = statistics.mean(row[2] for row in rows)
        fits = [row[3] for row in rows]
        print(
            f"  {name:6s} thread CPU median {statistics.median(cpu):.2f} ms, mean "
            f"{statistics.mean(cpu):.2f}; nearest parts a search {nearest:.0f}, fits "
            f"{statistics.mean(fits):.0f} (median {statistics.median(fits):.0f})"
        )
    print(
        f"  identical answers {same}/{len(queries)} ({args.queries} queries, seed {args.seed}, "
        f"per_clip {args.per_clip}, k 10)"
    )
    library.close()
    return 0 if same == len(queries) else 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    one = commands.add_parser("exact", help="random spans find their source span")
    one.add_argument("--spans", type=int, default=500)
    one.add_argument("--seed", type=int, default=0)
    one.add_argument(
        "--index-type", default="auto", help="MOCAP_INDEX_TYPE (ivf: IVF window indexes)"
    )
    one.add_argument("--window-codes", default="float32", help="MOCAP_WINDOW_CODES")
    two = commands.add_parser("styles", help="localisation across Bandai styles")
    two.add_argument("--seed", type=int, default=0)
    three = commands.add_parser("scale", help="moment search with 100 hours of windows")
    three.add_argument("--hours", type=float, default=100.0)
    three.add_argument(
        "--data-dir",
        type=Path,
        default=Path(tempfile.gettempdir()) / "mocap-bench-moments-100h" / "data",
    )
    three.add_argument("--duration", type=int, default=15, help="seconds per wrk run")
    three.add_argument("--rounds", type=int, default=2, help="wrk runs of each, interleaved")
    three.add_argument("--workers", type=int, help="server processes (default: one per core)")
    three.add_argument(
        "--baseline",
        type=Path,
        help="another checkout (e.g. main's, with its own .venv) served on the same library "
        "and measured in the same rounds",
    )
    three.add_argument(
        "--window-codes",
        default="float32",
        help="MOCAP_WINDOW_CODES (the library's files follow)",
    )
    four = commands.add_parser("recall", help="compressed window search against exact search")
    four.add_argument("--data-dir", type=Path, required=True)
    four.add_argument("--queries", type=int, default=200)
    four.add_argument("--against", type=Path, help="the same library with float32 lists")
    four.add_argument("--clips", type=int, default=100, help="moments queries compared")
    four.add_argument("--window-codes", default="sq8", help="MOCAP_WINDOW_CODES of --data-dir")
    five = commands.add_parser("alternate", help="main's search and this one's, in-process")
    five.add_argument("--data-dir", type=Path, required=True)
    five.add_argument("--baseline", type=Path, required=True, help="main's checkout")
    five.add_argument("--queries", type=int, default=300)
    five.add_argument("--seed", type=int, default=0)
    five.add_argument("--per-clip", type=int, default=1)
    args = parser.parse_args()
    run = {
        "exact": exact,
        "styles": styles,
        "scale": scale,
        "recall": recall,
        "alternate": alternate,
    }[args.command]
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
