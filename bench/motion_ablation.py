"""What each block of the ``motion`` descriptor is worth, and what was tried and dropped.

Describes the reference corpus (Bandai dataset 1 and the CMU clips of ``../shared/data``)
once, then scores weightings of ``motion``'s blocks and of candidate blocks that were tried
and not kept, with the evaluation's own metrics (:mod:`app.evaluation.metrics`):

* ``Bandai`` / ``Bandai xs``: leave-one-out 1-NN accuracy of the content label, and with
  neighbours of the query's own style excluded;
* ``Bandai A`` / ``Bandai B``: the same within two halves of the styles (alternate styles in
  name order), so a choice made on the whole set is checked on parts of it;
* ``CMU fine`` / ``CMU coarse``: 1-NN of the fine / coarse action label among clips of
  other trials (every format);
* ``twins``: fraction of CMU clips present in several formats whose nearest clip of another
  trial is farther than a twin.

Every block is divided by its corpus scale (as in the descriptor) before its weight. The
results table is printed as Markdown for ``docs/evaluation.md``.

Run: ``.venv/bin/python bench/motion_ablation.py [SHARED_DATA_DIR]``
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np

from app.discovery import discover
from app.evaluation.metrics import loo_1nn, pairwise_distances, twin_ranks
from app.evaluation.runner import clip_format
from app.labels import labels_from_tsv
from app.motion.body import Body, build_body
from app.motion.descriptors.kinetic import mean_energies, velocity_span
from app.motion.descriptors.motion import (
    BLOCK_WEIGHTS,
    TRAVEL_SPEED,
    limb_directions,
    motion_blocks,
)
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.skeleton_map import CANONICAL_INDEX
from app.motion.spans import whole_clip

BANDAI_NAME = re.compile(r"dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_\d+")


def candidate_blocks(body: Body) -> dict[str, np.ndarray]:
    """Blocks that were tried and not kept (see docs/evaluation.md), plus the kept ones."""
    blocks = {k: v[0] for k, v in motion_blocks(body, whole_clip(body.frame_count)).items()}
    directions = limb_directions(body).reshape(body.frame_count, -1)
    thirds = np.array_split(np.arange(body.frame_count), 3)
    blocks["limb thirds"] = np.concatenate(
        [directions[t].mean(axis=0) if len(t) else directions.mean(axis=0) for t in thirds]
    )
    local = body.local_positions()
    effectors = [CANONICAL_INDEX[n] for n in ("l_wrist", "r_wrist", "l_ankle", "r_ankle", "head")]
    points = local[:, effectors].reshape(body.frame_count, -1)
    blocks["effector positions"] = np.concatenate([points.mean(axis=0), points.std(axis=0)])
    span = velocity_span(body.frame_time, body.frame_count)
    if body.frame_count > span:
        velocity = (local[span:, effectors] - local[:-span, effectors]) / (span * body.frame_time)
        blocks["effector speeds"] = np.log1p((velocity**2).sum(axis=-1).mean(axis=0))
    else:
        blocks["effector speeds"] = np.zeros(len(effectors))
    joints, _ = mean_energies(body)
    total = joints.sum() + 1e-12
    blocks["energy share per DOF"] = np.log(joints.ravel() / total + 1e-4)
    blocks["total energy"] = np.array([np.log1p(total)])
    travel = blocks["travel"]
    speed = travel[3]
    gate = speed**2 / (speed**2 + TRAVEL_SPEED**2)
    blocks["travel direction (2-D)"] = travel[:2] / max(speed, 1e-9) * gate
    return blocks


def load(root: Path) -> list[tuple[str, dict[str, str], dict[str, np.ndarray]]]:
    tsv = labels_from_tsv(root / "cmu" / "labels.tsv")
    clips = []
    for dataset in ("bandai-ds1", "cmu"):
        for source in discover([root / dataset]).sources:
            data = [path.read_bytes() for path in source.paths]
            motion = read_bvh(data[0]) if source.kind == "bvh" else read_asf_amc(*data)
            labels = {"trial": source.name, "format": clip_format(source)}
            if dataset == "bandai-ds1":
                match = BANDAI_NAME.search(source.name)
                assert match is not None, source.name
                labels.update(match.groupdict())
            else:
                labels.update(tsv.get(source.name, {}))
            clips.append((dataset, labels, candidate_blocks(build_body(motion))))
    return clips


class Scorer:
    def __init__(self, clips: list[tuple[str, dict[str, str], dict[str, np.ndarray]]]) -> None:
        self.clips = clips
        names = clips[0][2].keys()
        self.blocks = {k: np.stack([c[2][k] for c in clips]) for k in names}
        self.scales = {
            k: float(np.sqrt(v.var(axis=0).sum())) or 1.0 for k, v in self.blocks.items()
        }
        self.bandai = [i for i, c in enumerate(clips) if c[0] == "bandai-ds1"]
        self.cmu = [i for i, c in enumerate(clips) if c[0] == "cmu"]
        self.cmu_labelled = [i for i in self.cmu if clips[i][1].get("fine")]
        styles = sorted({clips[i][1]["style"] for i in self.bandai})
        self.halves = (set(styles[::2]), set(styles[1::2]))

    def _labels(self, idx: list[int], kind: str) -> list[str]:
        return [self.clips[i][1][kind] for i in idx]

    def score(self, weights: dict[str, float]) -> dict[str, float]:
        X = np.concatenate(
            [self.blocks[k] * (w / self.scales[k]) for k, w in weights.items() if w], axis=1
        )
        b = self.bandai
        D = pairwise_distances(X[b])
        content, style = self._labels(b, "content"), self._labels(b, "style")
        out = {
            "Bandai": loo_1nn(X[b], content, distances=D).accuracy,
            "Bandai xs": loo_1nn(X[b], content, style, distances=D).accuracy,
        }
        for name, half in zip(("Bandai A", "Bandai B"), self.halves, strict=True):
            keep = [k for k, s in enumerate(style) if s in half]
            out[name] = loo_1nn(
                X[b][keep], [content[k] for k in keep], distances=D[np.ix_(keep, keep)]
            ).accuracy
        c = self.cmu_labelled
        trials = self._labels(c, "trial")
        Dc = pairwise_distances(X[c])
        out["CMU fine"] = loo_1nn(X[c], self._labels(c, "fine"), trials, distances=Dc).accuracy
        out["CMU coarse"] = loo_1nn(X[c], self._labels(c, "coarse"), trials, distances=Dc).accuracy
        everything = self.cmu
        _, nearest = twin_ranks(
            pairwise_distances(X[everything]),
            self._labels(everything, "trial"),
            self._labels(everything, "format"),
        )
        out["twins"] = float(np.mean(np.array(nearest) == 1))
        return out


def variants() -> list[tuple[str, dict[str, float]]]:
    kept = dict(BLOCK_WEIGHTS)
    version1 = {"limbs": 0.5, "energy": 1.0, "travel": 1.0}
    rows = [
        ("version 1 blocks (limbs 0.5, energy 1, travel 1)", version1),
        ("+ parts 0.5", {**version1, "parts": 0.5}),
        ("+ sideways 0.5", {**version1, "sideways": 0.5}),
        ("**version 2 (kept): + parts 0.5 + sideways 0.5**", kept),
        ("version 2, sideways 1.0", {**kept, "sideways": 1.0}),
        ("version 2, parts 1.0", {**kept, "parts": 1.0}),
        ("version 2, limbs 0.75", {**kept, "limbs": 0.75}),
        ("version 2, limbs 0.25", {**kept, "limbs": 0.25}),
        ("version 2, travel 1.5", {**kept, "travel": 1.5}),
        (
            "version 2 - sideways + 2-D travel direction 0.5",
            {
                **{k: v for k, v in kept.items() if k != "sideways"},
                "travel direction (2-D)": 0.5,
            },
        ),
    ]
    for tried in (
        "limb thirds",
        "effector positions",
        "effector speeds",
        "energy share per DOF",
        "total energy",
    ):
        rows.append((f"version 2 + {tried} 0.5", {**kept, tried: 0.5}))
    return rows


def main() -> None:
    root = (
        Path(sys.argv[1])
        if len(sys.argv) > 1
        else Path(__file__).resolve().parents[1].parent / "shared" / "data"
    )
    scorer = Scorer(load(root))
    rows = [(name, scorer.score(weights)) for name, weights in variants()]
    columns = list(rows[0][1])
    print("| variant | " + " | ".join(columns) + " |")
    print("|---|" + "---|" * len(columns))
    for name, scores in rows:
        print(f"| {name} | " + " | ".join(f"{scores[c]:.3f}" for c in columns) + " |")


if __name__ == "__main__":
    main()
