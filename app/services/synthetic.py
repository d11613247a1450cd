"""``mocap-index fill-synthetic``: a library filled with synthetic clips around its real ones,
for benchmarks at scale."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from app.config import Settings
    from app.services.library import Library

SYNTHETIC = "synthetic"
SYNTHETIC_BATCH = 20_000


@dataclass(frozen=True)
class FillResult:
    added: int
    total: int
    seconds: float
    index_kinds: dict[str, str]


def fill_synthetic(
    settings: Settings,
    count: int,
    *,
    seed: int = 0,
    noise: float = 0.25,
    batch: int = SYNTHETIC_BATCH,
    report: Callable[[str], None] = print,
) -> FillResult:
    """Add synthetic clips until the library holds ``count`` clips (benchmarks at scale).

    Each synthetic clip copies the measurements (and windows) of a real clip of the library
    picked at random and gets its vectors plus Gaussian noise of ``noise`` standard deviations
    (per number, over the real clips), so the vectors cluster like real ones. They are named
    ``synthetic-<n>``, have the format and the label ``synthetic`` and no stored file; their
    content hash is the sha256 of ``synthetic:<seed>:<n>``. Rows go in in batches of
    ``batch`` (one transaction each) through the repository; the indexes (and window
    indexes) are rebuilt from the database at the end (an IVF index above
    ``MOCAP_INDEX_AUTO_THRESHOLD`` with ``auto``) and saved.
    """
    import hashlib
    from datetime import UTC, datetime

    import numpy as np

    from app.db import clips as clip_db
    from app.db import label_filters as label_db
    from app.db import vectors as vector_db
    from app.db import windows as window_db
    from app.db.session import checkpoint
    from app.services.library import open_library

    started = time.perf_counter()
    library = open_library(settings)
    try:
        descriptors = list(library.descriptors.values())
        with library.reads() as session:
            total = clip_db.count_clips(session)
            top = clip_db.max_clip_id(session)
            synthetic = set(label_db.clip_ids_with_label(session, SYNTHETIC).tolist())
            stored = {}
            for info in descriptors:
                ids, vectors = vector_db.load_vectors(
                    session, info.name, info.version, info.dimension
                )
                real = np.array([i not in synthetic for i in ids.tolist()], dtype=bool)
                stored[info.name] = dict(zip(ids[real].tolist(), vectors[real], strict=True))
            common = sorted(set.intersection(*(set(v) for v in stored.values())))
            centres = clip_db.get_clips(session, common)
            windows = {
                key: window_db.load_window_rows(session, key, common)
                for key in library.window_keys.values()
            }
        need = count - total
        if need <= 0:
            report(f"the library already holds {total} clips")
            return FillResult(0, total, time.perf_counter() - started, _kinds(library))
        rng = np.random.default_rng(seed)
        if common:
            centre_vectors = {
                name: np.stack([by_id[i] for i in common]) for name, by_id in stored.items()
            }
            records = [centres[i] for i in common]
        else:
            report("no real clip to start from: synthetic vectors are standard normal noise")
            centre_vectors = {
                info.name: rng.normal(size=(64, info.dimension)).astype(np.float32)
                for info in descriptors
            }
            records = []
        spread = {
            name: np.maximum(vectors.std(axis=0), 1e-3 * (np.abs(vectors).mean() + 1e-3))
            for name, vectors in centre_vectors.items()
        }
        versions = {info.name: info.version for info in descriptors}
        window_spread = {
            key: np.maximum(np.concatenate([v[2] for v in rows.values()]).std(axis=0), 1e-3)
            for key, rows in windows.items()
            if rows
        }
        report(
            f"adding {need} synthetic clips around {len(centre_vectors[descriptors[0].name])} "
            f"{'real clips' if common else 'random points'}"
        )
        done = 0
        while done < need:
            n = min(batch, need - done)
            pick = rng.integers(0, len(centre_vectors[descriptors[0].name]), size=n)
            noisy = {
                name: (
                    centre_vectors[name][pick]
                    + rng.normal(size=(n, centre_vectors[name].shape[1])) * spread[name] * noise
                ).astype(np.float32)
                for name in centre_vectors
            }
            now = datetime.now(UTC)
            rows = []
            for row in range(n):
                number = top + done + row + 1
                centre = records[int(pick[row])] if records else None
                rows.append(
                    clip_db.NewClip(
                        name=f"{SYNTHETIC}-{number:07d}",
                        format=SYNTHETIC,
                        content_hash=hashlib.sha256(
                            f"{SYNTHETIC}:{seed}:{number}".encode()
                        ).hexdigest(),
                        frame_count=centre.frame_count if centre else 300,
                        frame_time=centre.frame_time if centre else 1 / 30,
                        duration=centre.duration if centre else 10.0,
                        joint_count=centre.joint_count if centre else 25,
                        skeleton_family=SYNTHETIC,
                        lead_in_frames=0,
                        labels=(SYNTHETIC,),
                        files=(),
                        vectors={
                            name: vector_db.StoredVector(versions[name], noisy[name][row])
                            for name in noisy
                        },
                        created_at=now,
                        windows=_synthetic_windows(
                            windows, window_spread, centre.id if centre else None, rng, noise
                        ),
                    )
                )
            with library.writes.begin() as session:
                clip_db.insert_clips(session, rows)
            done += n
            report(f"  {done}/{need} clips ({time.perf_counter() - started:.0f} s)")
        checkpoint(library.engine)
        for info in descriptors:
            report(f"building the {info.name} index")
            library.rebuild_index(info.name)
        if library.window_keys:
            report("building the window indexes")
            library.rebuild_window_indexes()
        report("building the catalogue")
        library.rebuild_catalogue()
        with library.reads() as session:
            total = clip_db.count_clips(session)
        return FillResult(need, total, time.perf_counter() - started, _kinds(library))
    finally:
        library.close()


def _kinds(library: Library) -> dict[str, str]:
    every = {**library.indexes, **library.window_indexes}
    return {name: index.kind for name, index in every.items()}


def _synthetic_windows(
    windows: dict[Any, dict[int, tuple[Any, Any, Any]]],
    spread: dict[Any, Any],
    centre: int | None,
    rng: Any,
    noise: float,
) -> tuple[Any, ...]:
    """The windows of real clip ``centre``, their vectors plus noise (see fill_synthetic)."""
    import numpy as np

    from app.db import windows as window_db

    found = []
    for key, by_clip in windows.items():
        if centre is None or centre not in by_clip:
            continue
        starts, stops, vectors = by_clip[centre]
        noisy = vectors + rng.normal(size=vectors.shape) * spread[key] * noise
        found.append(
            window_db.NewWindows(
                name=key.name,
                version=key.version,
                lengths=np.full(len(starts), key.length),
                starts=starts,
                stops=stops,
                vectors=noisy.astype(np.float32),
            )
        )
    return tuple(found)
