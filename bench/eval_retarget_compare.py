"""Round trips of ``bench/eval_retarget.py`` looked up and compared (issue 22).

    .venv/bin/python bench/eval_retarget.py compare BEFORE.npz AFTER.npz   # two --dump files

A re-upload is found when its nearest clip is its source; or a twin (the same capture in
another format or folder, :func:`capture`); or tied (:func:`is_tie`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def is_tie(vectors: np.ndarray, distances: np.ndarray, index: int, nearest: int) -> bool:
    """Whether the ``nearest`` clip to a re-upload (``distances`` ``(N,)`` to the library's
    ``vectors`` ``(N, D)``) is no nearer than its source ``index``, or holds the source's
    vector (to 1e-6 of its length, as the count of clips sharing a vector reads it): a copy
    within float rounding of two identical vectors lands nearer one of them by rounding."""
    if distances[index] <= distances[nearest] * (1 + 1e-9):
        return True
    apart = np.linalg.norm(vectors[index] - vectors[nearest])
    return bool(apart <= 1e-6 * np.linalg.norm(vectors[index]))


def capture(name: str) -> str:
    """The capture a clip is of: its file stem (the CMU trials, the FBX/BVH pairs are one
    capture in several formats and folders, under one stem)."""
    return Path(name).stem.lower()


def outcomes(dump: Path) -> tuple[list[str], dict[str, list[tuple[str, float]]]]:
    """Per rig of a ``--dump``, each clip's outcome strictly — ``found``, ``twin`` (the same
    capture in another format is nearest), ``tie`` (the nearest clip is no nearer than the
    source: its vector is the source's), ``miss`` (another clip is nearer), ``unread`` (not
    read back) — and its distance to the source; as the table counts them."""
    data = np.load(dump)
    names = [str(n) for n in data["names"]]
    vectors = data["vectors"]
    out: dict[str, list[tuple[str, float]]] = {}
    for key in (k for k in data.files if k.startswith("rig: ")):
        rows = []
        for index, upload in enumerate(data[key]):
            if not np.all(np.isfinite(upload)):
                rows.append(("unread", float("nan")))
                continue
            distances = np.linalg.norm(vectors - upload, axis=1)
            nearest = int(np.argmin(distances))
            if nearest == index:
                kind = "found"
            elif capture(names[nearest]) == capture(names[index]):
                kind = "twin"
            elif is_tie(vectors, distances, index, nearest):
                kind = "tie"
            else:
                kind = "miss"
            rows.append((kind, float(distances[index])))
        out[key.removeprefix("rig: ")] = rows
    return names, out


def compare(argv: list[str]) -> None:
    """Per rig: strictly found (or twin; or tied) and the strict misses by kind, before ->
    after; per data folder of the clip (pairs over the rigs both dumps hold); the clips whose
    outcome changed."""
    before_names, before = outcomes(Path(argv[0]))
    names, after = outcomes(Path(argv[1]))
    assert names == before_names, "the two dumps hold other clips"
    rigs = [r for r in after if r in before]

    def shares(rows: list[tuple[str, float]]) -> str:
        kinds = [k for k, _ in rows]
        found = np.mean([k == "found" for k in kinds]) * 100
        twin = np.mean([k in ("found", "twin") for k in kinds]) * 100
        tied = np.mean([k in ("found", "twin", "tie") for k in kinds]) * 100
        missed = ", ".join(f"{k} {kinds.count(k)}" for k in ("twin", "tie", "miss", "unread"))
        return f"{found:.1f} % ({twin:.1f}; {tied:.1f}) [{missed}]"

    print("| rig | before: strictly (twin; tied) [strict misses] | after | median distance |")
    print("|---|---|---|---|")
    for rig in rigs:
        medians = [np.nanmedian([d for _, d in rows]) for rows in (before[rig], after[rig])]
        print(
            f"| {rig} | {shares(before[rig])} | {shares(after[rig])} | "
            f"{medians[0]:.3f} -> {medians[1]:.3f} |"
        )
    print("| data folder | pairs | strictly: before -> after | found, twin or tied |")
    print("|---|---|---|---|")
    folders = [n.split("/")[0] for n in names]
    for folder in sorted(set(folders)):
        clips = [i for i, f in enumerate(folders) if f == folder]
        pairs = len(clips) * len(rigs)
        counts = [
            sum(run[r][i][0] in kinds for r in rigs for i in clips)
            for kinds in (("found",), ("found", "twin", "tie"))
            for run in (before, after)
        ]
        print(
            f"| {folder} | {pairs} | {100 * counts[0] / pairs:.1f} % -> "
            f"{100 * counts[1] / pairs:.1f} % ({counts[0]} -> {counts[1]}) | "
            f"{100 * counts[2] / pairs:.1f} % -> {100 * counts[3] / pairs:.1f} % |"
        )
    for rig in rigs:
        for name, (was, dist_was), (now, dist_now) in zip(
            names, before[rig], after[rig], strict=True
        ):
            if was != now:
                print(f"  {rig} | {name}: {was} -> {now} ({dist_was:.3f} -> {dist_now:.3f})")


__all__ = ["capture", "compare", "is_tie", "outcomes"]
