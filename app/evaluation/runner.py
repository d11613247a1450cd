"""From folders of clips to scores: discover, label, describe (cached, in parallel), score.

Describing
    :mod:`app.evaluation.describe`: parse each clip, run the descriptors, cache the vectors
    by content hash (in worker processes with ``workers > 1``); failed clips are reported.

Labels
    Every clip gets two built-in label kinds derived from its path: ``trial`` (the file stem,
    shared by a CMU trial's ASF/AMC and BVH twins) and ``format`` (``asf-amc``; for a BVH the
    nearest enclosing folder named ``bvh`` or ``bvh-...``, e.g. ``bvh-mb``, else ``bvh``).
    A TSV (looked up by file stem) and a regex over the relative path add more; on a clash the
    TSV overrides the built-ins and the regex overrides both.

Scoring
    For every descriptor and label kind, over the clips that have a value of that kind:
    leave-one-out 1-NN (also with ``exclude_same``), Ward + BIC clustering, F-measure and ARI.
    When clips of one trial exist in several formats, the format-twin ranks too.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePath

import numpy as np

from app.discovery import ClipSource, DiscoveryFailure, discover
from app.errors import InvalidInput
from app.evaluation.describe import THREE_MAN, SkippedClip, describe_clips
from app.evaluation.metrics import (
    DEFAULT_COVARIANCE,
    ClusteringResult,
    FMeasure,
    LooResult,
    TwinPairScore,
    adjusted_rand,
    f_measure,
    loo_1nn,
    pairwise_distances,
    twin_ranks,
    ward_bic_clustering,
)
from app.labels import compile_label_regex, labels_from_regex, labels_from_tsv

TRIAL = "trial"
FORMAT = "format"
BUILTIN_KINDS = (TRIAL, FORMAT)
ASF_AMC_FORMAT = "asf-amc"
_BVH_FOLDER = re.compile(r"^bvh([-_ .].+)?$", re.IGNORECASE)


# ------------------------------------------------------------------------------- labels


def builtin_labels(source: ClipSource) -> dict[str, str]:
    """``trial`` = file stem; ``format`` = ``asf-amc`` or the BVH's ``bvh*`` folder name."""
    return {TRIAL: source.name, FORMAT: clip_format(source)}


def clip_format(source: ClipSource) -> str:
    """``"asf-amc"``, or the nearest enclosing folder called ``bvh``/``bvh-*``, else ``"bvh"``.

    The folder chain above the given root counts too, so ``eval data/cmu/bvh-mb`` still
    labels its clips ``bvh-mb``.
    """
    if source.kind == "asf/amc":
        return ASF_AMC_FORMAT
    for parent in source.motion.absolute().parents:
        if _BVH_FOLDER.match(parent.name):
            return parent.name.lower()
    return "bvh"


def clip_labels(
    source: ClipSource,
    tsv: dict[str, dict[str, str]] | None,
    regex: re.Pattern[str] | None,
) -> dict[str, str]:
    labels = builtin_labels(source)
    if tsv is not None:
        labels.update(tsv.get(source.name, {}))
    if regex is not None:
        labels.update(labels_from_regex(regex, source.relative_path))
    return labels


# -------------------------------------------------------------------------------- records


@dataclass(frozen=True)
class ClipRecord:
    """A described clip: where it came from, its labels, its vectors."""

    source: ClipSource
    content_hash: str
    labels: dict[str, str]
    vectors: dict[str, np.ndarray]
    three_man: np.ndarray


# -------------------------------------------------------------------------------- scoring


@dataclass(frozen=True)
class ClusteringScore:
    clustering: ClusteringResult
    f: FMeasure
    ari: float


@dataclass(frozen=True)
class KindScore:
    """Scores of one descriptor for one label kind, over the clips with a value of it."""

    descriptor: str
    kind: str
    clip_indices: np.ndarray
    missing: int
    loo: LooResult
    loo_excluded: LooResult | None
    clustering: ClusteringScore | None
    note: str | None = None


@dataclass
class EvalConfig:
    paths: list[Path]
    labels_tsv: Path | None = None
    labels_regex: str | None = None
    label_kinds: list[str] | None = None
    descriptors: list[str] | None = None
    exclude_same: str | None = None
    cache_dir: Path | None = Path(".eval-cache")
    workers: int = 1
    progress: bool = True
    covariance_type: str = DEFAULT_COVARIANCE


@dataclass
class EvalResult:
    config: EvalConfig
    descriptors: list[str]
    label_kinds: list[str]
    records: list[ClipRecord]
    skipped: list[SkippedClip]
    discovery_failures: list[DiscoveryFailure]
    scores: dict[tuple[str, str], KindScore] = field(default_factory=dict)
    skipped_kinds: dict[str, str] = field(default_factory=dict)
    twins: dict[str, tuple[list[TwinPairScore], list[int]]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def matrix(self, descriptor: str) -> np.ndarray:
        return np.stack([r.vectors[descriptor].astype(np.float64) for r in self.records])

    def has_format_twins(self) -> bool:
        formats_by_trial: dict[str, set[str]] = {}
        for record in self.records:
            trial = record.labels[TRIAL]
            formats_by_trial.setdefault(trial, set()).add(record.labels[FORMAT])
        return any(len(f) > 1 for f in formats_by_trial.values())


def resolve_descriptors(requested: Sequence[str] | None) -> list[str]:
    from app.motion.descriptors import REGISTRY

    if not requested:
        return list(REGISTRY)
    unknown = [name for name in requested if name not in REGISTRY]
    if unknown:
        raise InvalidInput(
            f"unknown descriptor {', '.join(map(repr, unknown))}; known: {', '.join(REGISTRY)}"
        )
    return list(dict.fromkeys(requested))


def default_label_kinds(records: Sequence[ClipRecord], explicit_sources: bool) -> list[str]:
    """Every kind found, built-ins only when no TSV/regex gave any (they go last)."""
    found = sorted({kind for r in records for kind in r.labels if kind not in BUILTIN_KINDS})
    if found or explicit_sources:
        return found
    return list(BUILTIN_KINDS)


def score_kind(
    descriptor: str,
    kind: str,
    X: np.ndarray,
    distances: np.ndarray,
    records: Sequence[ClipRecord],
    exclude_same: str | None,
    clustering_cache: dict[tuple[str, str, tuple[int, ...]], ClusteringResult],
    covariance_type: str = DEFAULT_COVARIANCE,
) -> KindScore:
    """LOO 1-NN (plain and with ``exclude_same``) and clustering scores over labelled clips."""
    idx = np.array([i for i, r in enumerate(records) if kind in r.labels], dtype=int)
    labels = [records[i].labels[kind] for i in idx]
    sub = distances[np.ix_(idx, idx)]
    loo = loo_1nn(X[idx], labels, distances=sub)
    loo_excluded = None
    note = None
    if exclude_same is not None:
        if exclude_same == kind:
            note = (
                f"--exclude-same {kind} is the scored kind itself; its excluded score is left out"
            )
        else:
            groups = [records[i].labels.get(exclude_same) for i in idx]
            loo_excluded = loo_1nn(X[idx], labels, groups, distances=sub)
    clustering = None
    if len(idx) >= 3:
        key = (descriptor, covariance_type, tuple(int(i) for i in idx))
        if key not in clustering_cache:
            clustering_cache[key] = ward_bic_clustering(X[idx], covariance_type=covariance_type)
        result = clustering_cache[key]
        clustering = ClusteringScore(
            result, f_measure(labels, result.clusters), adjusted_rand(labels, result.clusters)
        )
    return KindScore(
        descriptor=descriptor,
        kind=kind,
        clip_indices=idx,
        missing=len(records) - len(idx),
        loo=loo,
        loo_excluded=loo_excluded,
        clustering=clustering,
        note=note,
    )


def _kind_problem(records: Sequence[ClipRecord], kind: str) -> str | None:
    counts = Counter(r.labels[kind] for r in records if kind in r.labels)
    if not counts:
        return "no clip has a value"
    if len(counts) < 2:
        return f"every labelled clip has the same value ({next(iter(counts))!r})"
    if max(counts.values()) < 2:
        return "every value is unique (no clip has a neighbour of its class)"
    return None


def evaluate(
    records: Sequence[ClipRecord],
    descriptors: Sequence[str],
    label_kinds: Sequence[str],
    exclude_same: str | None,
    covariance_type: str = DEFAULT_COVARIANCE,
) -> tuple[
    dict[tuple[str, str], KindScore],
    dict[str, str],
    dict[str, tuple[list[TwinPairScore], list[int]]],
]:
    """Every score of every descriptor for every label kind, plus format-twin ranks."""
    scores: dict[tuple[str, str], KindScore] = {}
    skipped_kinds = {k: p for k in label_kinds if (p := _kind_problem(records, k)) is not None}
    kinds = [k for k in label_kinds if k not in skipped_kinds]
    twins: dict[str, tuple[list[TwinPairScore], list[int]]] = {}
    trials = [r.labels[TRIAL] for r in records]
    formats = [r.labels[FORMAT] for r in records]
    by_trial: dict[str, set[str]] = {}
    for trial, fmt in zip(trials, formats, strict=True):
        by_trial.setdefault(trial, set()).add(fmt)
    with_twins = any(len(f) > 1 for f in by_trial.values())
    clustering_cache: dict[tuple[str, str, tuple[int, ...]], ClusteringResult] = {}
    for descriptor in descriptors:
        X = np.stack([r.vectors[descriptor].astype(np.float64) for r in records])
        distances = pairwise_distances(X)
        for kind in kinds:
            scores[(descriptor, kind)] = score_kind(
                descriptor,
                kind,
                X,
                distances,
                records,
                exclude_same,
                clustering_cache,
                covariance_type,
            )
        if with_twins:
            twins[descriptor] = twin_ranks(distances, trials, formats)
    return scores, skipped_kinds, twins


def collect(config: EvalConfig) -> EvalResult:
    """Discover, label and describe every clip (no scoring yet).

    Raises
    ------
    InvalidInput
        Bad regex, bad TSV, unknown descriptor.
    """
    descriptors = resolve_descriptors(config.descriptors)
    regex = compile_label_regex(config.labels_regex) if config.labels_regex else None
    tsv = labels_from_tsv(config.labels_tsv) if config.labels_tsv else None
    found = discover(config.paths)
    described, skipped = describe_clips(
        found.sources,
        descriptors,
        cache_dir=config.cache_dir,
        workers=config.workers,
        progress=config.progress,
    )
    records = [
        ClipRecord(
            source=source,
            content_hash=digest,
            labels=clip_labels(source, tsv, regex),
            vectors={name: vectors[name] for name in descriptors},
            three_man=np.asarray(vectors[THREE_MAN], dtype=np.float64),
        )
        for source, digest, vectors in described
    ]
    result = EvalResult(
        config=config,
        descriptors=descriptors,
        label_kinds=[],
        records=records,
        skipped=skipped,
        discovery_failures=list(found.failures),
    )
    if tsv is not None and config.labels_tsv is not None:
        stems = {s.name for s in found.sources}
        unmatched = [key for key in tsv if key not in stems]
        if len(unmatched) == len(tsv):
            result.notes.append(f"no clip file stem matches a key of {config.labels_tsv}")
        elif unmatched:
            result.notes.append(
                f"{len(unmatched)} key(s) of {PurePath(config.labels_tsv).name} match no clip"
            )
    if (
        regex is not None
        and records
        and not any(labels_from_regex(regex, r.source.relative_path) for r in records)
    ):
        result.notes.append("the labels regex matched no clip's relative path")
    return result


def run(config: EvalConfig) -> EvalResult:
    """:func:`collect`, then score every descriptor for every label kind.

    Raises
    ------
    InvalidInput
        As :func:`collect`, or a requested label kind / ``exclude_same`` kind no clip has.
    """
    result = collect(config)
    known = sorted({kind for r in result.records for kind in r.labels})
    explicit = config.labels_tsv is not None or config.labels_regex is not None
    if config.label_kinds:
        kinds = list(dict.fromkeys(config.label_kinds))
        unknown = [k for k in kinds if k not in known]
        if unknown and result.records:
            raise InvalidInput(
                f"no clip has a label of kind {', '.join(map(repr, unknown))}; "
                f"kinds found: {', '.join(known)}"
            )
    else:
        kinds = default_label_kinds(result.records, explicit)
    if config.exclude_same and result.records and config.exclude_same not in known:
        raise InvalidInput(
            f"--exclude-same {config.exclude_same!r}: no clip has a label of that kind; "
            f"kinds found: {', '.join(known)}"
        )
    result.label_kinds = kinds
    if result.records:
        result.scores, result.skipped_kinds, result.twins = evaluate(
            result.records, result.descriptors, kinds, config.exclude_same, config.covariance_type
        )
    return result
