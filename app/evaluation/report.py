"""Showing an evaluation: a terminal table (rich), a JSON file and PNG figures (matplotlib).

Figures, per label kind (``<kind>`` and ``<descriptor>`` made file-name safe):

* ``confusion_<descriptor>_<kind>.png`` — the leave-one-out 1-NN confusion matrix (with
  ``--exclude-same`` applied when given), rows true, columns predicted, shaded by row share;
* ``three_man_<kind>.png`` — FMDistance's Figure 1 map: every clip at its 3-MAN features,
  ``e_all`` against ``r_u/l`` and ``r_u/l`` against ``r_l/t``, coloured by label;
* ``pca_<descriptor>_<kind>.png`` — the first two principal components of the descriptor
  (centred, not rescaled: the geometry the Euclidean search sees), coloured by label.

Clips without a value of the kind are drawn small and grey; marker shapes tell formats apart
when there are several.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from app.evaluation.describe import descriptor_versions
from app.evaluation.metrics import LooResult, TwinPairScore, format_order
from app.evaluation.runner import FORMAT, TRIAL, EvalResult, KindScore

JSON_NAME = "results.json"
SCHEMA_VERSION = 1


def _num(value: float | None, digits: int = 4) -> float | None:
    if value is None or not math.isfinite(value):
        return None
    return round(float(value), digits) + 0.0  # no -0.0


def _fmt(value: float | None, digits: int = 3) -> str:
    if value is None or not math.isfinite(value):
        return "-"
    text = f"{value:.{digits}f}"
    return text[1:] if text.startswith("-") and not text.strip("-0.") else text  # no "-0.000"


# ----------------------------------------------------------------------------------- JSON


def _loo_json(loo: LooResult, names: Sequence[str], truth: Sequence[str]) -> dict[str, Any]:
    errors = [
        {
            "clip": names[i],
            "label": truth[i],
            "predicted": loo.predicted[i],
            "neighbour": names[int(loo.neighbour[i])],
        }
        for i in range(len(names))
        if loo.predicted[i] is not None and loo.predicted[i] != truth[i]
    ]
    return {
        "accuracy": _num(loo.accuracy),
        "correct": loo.correct,
        "scored": loo.scored,
        "unscored": loo.unscored,
        "hopeless": loo.hopeless,
        "classes": loo.classes,
        "per_class": {c: _num(v) for c, v in loo.per_class.items()},
        "per_class_count": loo.per_class_count,
        "confusion": loo.confusion.tolist(),
        "errors": errors,
    }


def _score_json(result: EvalResult, score: KindScore) -> dict[str, Any]:
    records = [result.records[i] for i in score.clip_indices]
    names = [r.source.relative_path for r in records]
    truth = [r.labels[score.kind] for r in records]
    out: dict[str, Any] = {
        "clips": len(records),
        "missing": score.missing,
        "loo": _loo_json(score.loo, names, truth),
        "loo_exclude_same": None
        if score.loo_excluded is None
        else _loo_json(score.loo_excluded, names, truth),
        "clustering": None,
    }
    if score.note:
        out["note"] = score.note
    if score.clustering is not None:
        c = score.clustering
        out["clustering"] = {
            "method": "ward",
            "k": c.clustering.k,
            "k_selection": "max BIC = 2 log L - p log n (= -sklearn GaussianMixture.bic)",
            "covariance_type": c.clustering.covariance_type,
            "bic": {str(k): _num(v, 3) for k, v in c.clustering.bic.items()},
            "f_measure": _num(c.f.f),
            "recall": _num(c.f.recall),
            "precision": _num(c.f.precision),
            "recall_per_class": {k: _num(v) for k, v in c.f.recall_per_class.items()},
            "precision_per_class": {k: _num(v) for k, v in c.f.precision_per_class.items()},
            "ari": _num(c.ari),
            "clusters": {n: int(q) for n, q in zip(names, c.clustering.clusters, strict=True)},
        }
    return out


def _pair_json(pair: TwinPairScore) -> dict[str, Any]:
    return {
        "formats": list(pair.formats),
        "queries": pair.queries,
        "top1": _num(pair.top1),
        "median_rank": _num(pair.median_rank, 2),
        "mean_rank": _num(pair.mean_rank, 2),
    }


def to_json(result: EvalResult, figures: Sequence[Path] = ()) -> dict[str, Any]:
    """Everything the run found, as plain JSON-able values (``NaN`` as ``null``)."""
    config = result.config
    kinds_info: dict[str, Any] = {}
    for kind in sorted({k for r in result.records for k in r.labels}):
        counts: dict[str, int] = {}
        for r in result.records:
            if kind in r.labels:
                counts[r.labels[kind]] = counts.get(r.labels[kind], 0) + 1
        kinds_info[kind] = {
            "clips": sum(counts.values()),
            "missing": len(result.records) - sum(counts.values()),
            "classes": dict(sorted(counts.items())) if kind != TRIAL else len(counts),
            "scored": kind in result.label_kinds and kind not in result.skipped_kinds,
        }
    scores: dict[str, dict[str, Any]] = {}
    for (descriptor, kind), score in result.scores.items():
        scores.setdefault(descriptor, {})[kind] = _score_json(result, score)
    twins: dict[str, Any] | None = None
    if result.twins:
        twins = {}
        for descriptor, (pairs, nearest) in result.twins.items():
            twins[descriptor] = {
                "pairs": [_pair_json(p) for p in pairs],
                "any_other_format": _pair_json(TwinPairScore(("*", "*"), nearest))
                | {"formats": ["any", "any other"]},
                "rank_definition": "1 + number of clips of other trials strictly nearer the "
                "query than its twin (the same trial in the other format); queries from both "
                "formats; any_other_format: the rank of the query's nearest twin",
            }
    return {
        "schema_version": SCHEMA_VERSION,
        "settings": {
            "paths": [str(p) for p in config.paths],
            "labels_tsv": None if config.labels_tsv is None else str(config.labels_tsv),
            "labels_regex": config.labels_regex,
            "label_kinds": result.label_kinds,
            "descriptors": result.descriptors,
            "exclude_same": config.exclude_same,
            "gmm_covariance": config.covariance_type,
        },
        "descriptors": {
            name: {"version": v, "dimension": int(result.records[0].vectors[name].shape[0])}
            if result.records
            else {"version": v}
            for name, v in descriptor_versions(result.descriptors).items()
        },
        "clips": {
            "found": len(result.records) + len(result.skipped),
            "described": len(result.records),
            "skipped": [{"path": str(s.path), "reason": s.reason} for s in result.skipped],
            "discovery_failures": [
                {"path": str(f.path), "reason": f.reason} for f in result.discovery_failures
            ],
        },
        "label_kinds": kinds_info,
        "skipped_label_kinds": result.skipped_kinds,
        "scores": scores,
        "format_twins": twins,
        "notes": result.notes,
        "clip_table": [
            {
                "name": r.source.name,
                "relative_path": r.source.relative_path,
                "root": str(r.source.root),
                "kind": r.source.kind,
                "content_hash": r.content_hash,
                "labels": r.labels,
                "three_man": [_num(float(x), 5) for x in r.three_man],
            }
            for r in result.records
        ],
        "figures": [str(f) for f in figures],
    }


def write_json(result: EvalResult, path: Path, figures: Sequence[Path] = ()) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(to_json(result, figures), indent=2, allow_nan=False) + "\n")
    return path


# ---------------------------------------------------------------------------------- table


def print_report(result: EvalResult, console: Console | None = None) -> None:
    """Scores as rich tables: one per label kind, then the format twins."""
    console = console or Console()
    config = result.config
    exclude = config.exclude_same
    console.print(
        f"[bold]{len(result.records)} clips described[/bold]"
        + (f", {len(result.skipped)} skipped" if result.skipped else "")
        + (
            f", {len(result.discovery_failures)} not paired/readable"
            if result.discovery_failures
            else ""
        )
    )
    for kind in result.label_kinds:
        if kind in result.skipped_kinds:
            console.print(
                f"label kind [bold]{escape(kind)}[/bold] not scored: "
                f"{escape(result.skipped_kinds[kind])}"
            )
            continue
        first = next((s for (d, k), s in result.scores.items() if k == kind), None)
        if first is None:
            continue
        classes = len(first.loo.classes)
        title = f"{escape(kind)}: {len(first.clip_indices)} clips, {classes} classes"
        if first.missing:
            title += f" ({first.missing} clips without a {escape(kind)} value left out)"
        table = Table(title=title, title_justify="left")
        table.add_column("descriptor")
        table.add_column("A_e (LOO 1-NN)", justify="right")
        if exclude and exclude != kind:
            table.add_column(f"A_e excl. same {exclude}", justify="right")
        table.add_column("k (BIC)", justify="right")
        table.add_column("R", justify="right")
        table.add_column("P", justify="right")
        table.add_column("F", justify="right")
        table.add_column("ARI", justify="right")
        footnotes: list[str] = []
        for descriptor in result.descriptors:
            score = result.scores.get((descriptor, kind))
            if score is None:
                continue
            row = [
                descriptor,
                f"{_fmt(score.loo.accuracy)} ({score.loo.correct}/{score.loo.scored})",
            ]
            if exclude and exclude != kind:
                ex = score.loo_excluded
                row.append("-" if ex is None else f"{_fmt(ex.accuracy)} ({ex.correct}/{ex.scored})")
                if ex is not None and (ex.unscored or ex.hopeless) and not footnotes:
                    footnotes.append(
                        f"excluding same {exclude}: {ex.unscored} clips had no allowed neighbour "
                        f"(left out), {ex.hopeless} had none of their class (always wrong)"
                    )
            c = score.clustering
            if c is None:
                row += ["-"] * 5
            else:
                row += [
                    str(c.clustering.k),
                    _fmt(c.f.recall),
                    _fmt(c.f.precision),
                    _fmt(c.f.f),
                    _fmt(c.ari),
                ]
            table.add_row(*row)
        console.print(table)
        for note in footnotes:
            console.print(f"  [dim]{escape(note)}[/dim]")
    if result.twins:
        table = Table(
            title="format twins: rank of the same trial in the other format among the clips of "
            "other trials (1 = nearest)",
            title_justify="left",
        )
        table.add_column("descriptor")
        table.add_column("formats")
        table.add_column("queries", justify="right")
        table.add_column("nearest (top-1)", justify="right")
        table.add_column("median rank", justify="right")
        table.add_column("mean rank", justify="right")
        for descriptor, (pairs, nearest) in result.twins.items():
            rows = [(f"{p.formats[0]} vs {p.formats[1]}", p) for p in pairs]
            rows.append(("any other format", TwinPairScore(("*", "*"), nearest)))
            for label, pair in rows:
                table.add_row(
                    descriptor,
                    label,
                    str(pair.queries),
                    _fmt(pair.top1),
                    _fmt(pair.median_rank, 1),
                    _fmt(pair.mean_rank, 1),
                )
            table.add_section()
        console.print(table)
    for note in result.notes:
        console.print(f"[yellow]note:[/yellow] {escape(note)}")


# -------------------------------------------------------------------------------- figures


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("-") or "x"


def _colours(n: int) -> list[Any]:
    """``n`` distinct colours, never grey (grey marks clips without a label)."""
    import matplotlib

    if n <= 18:  # tab20 without its two greys: the strong shades first, then the light ones
        cmap = matplotlib.colormaps["tab20"]
        order = [i for i in range(0, 20, 2) if i != 14] + [i for i in range(1, 20, 2) if i != 15]
        return [cmap(i) for i in order[:n]]
    cmap = matplotlib.colormaps["turbo"]
    return [cmap(x) for x in np.linspace(0.05, 0.95, n)]


_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")


def _scatter(ax: Any, xy: np.ndarray, result: EvalResult, kind: str) -> list[Any]:
    """Points coloured by ``kind``'s label and shaped by format; returns legend handles."""
    from matplotlib.lines import Line2D

    labels = [r.labels.get(kind) for r in result.records]
    formats = [r.labels[FORMAT] for r in result.records]
    classes = sorted({lab for lab in labels if lab is not None})
    colours = dict(zip(classes, _colours(len(classes)), strict=True))
    format_names = sorted(set(formats), key=format_order)
    markers = {f: _MARKERS[i % len(_MARKERS)] for i, f in enumerate(format_names)}
    # Later formats are drawn smaller, on top: twins of one capture stay visible together.
    sizes = {f: max(12.0, 44.0 - 12.0 * i) for i, f in enumerate(format_names)}
    unlabelled = np.array([lab is None for lab in labels])
    for fmt in format_names:
        in_format = np.array([f == fmt for f in formats])
        grey = in_format & unlabelled
        if grey.any():
            ax.scatter(
                *xy[grey].T, s=sizes[fmt] * 0.4, c="#bbbbbb", marker=markers[fmt], linewidths=0
            )
        for cls in classes:
            mask = in_format & np.array([lab == cls for lab in labels])
            if mask.any():
                ax.scatter(
                    *xy[mask].T,
                    s=sizes[fmt],
                    color=colours[cls],
                    marker=markers[fmt],
                    edgecolors="black",
                    linewidths=0.3,
                )
    handles = [
        Line2D([], [], marker="o", linestyle="", color=colours[c], label=c, markersize=6)
        for c in classes
    ]
    if unlabelled.any():
        handles.append(
            Line2D([], [], marker="o", linestyle="", color="#bbbbbb", label="(no label)")
        )
    if len(format_names) > 1:
        handles += [
            Line2D([], [], marker=markers[f], linestyle="", color="black", label=f, markersize=6)
            for f in format_names
        ]
    return handles


def _legend(fig: Any, handles: list[Any]) -> None:
    if handles:
        columns = 1 if len(handles) <= 24 else 2
        fig.legend(
            handles=handles,
            loc="center left",
            bbox_to_anchor=(1.0, 0.5),
            ncol=columns,
            fontsize=8,
            frameon=False,
        )


def _confusion_figure(result: EvalResult, score: KindScore, path: Path) -> None:
    import matplotlib.pyplot as plt

    loo = score.loo_excluded or score.loo
    matrix = loo.confusion
    rows = matrix.sum(axis=1, keepdims=True)
    share = np.divide(matrix, rows, out=np.zeros(matrix.shape), where=rows > 0)
    n = len(loo.classes)
    size = max(4.0, 0.42 * n + 2.5)
    fig, ax = plt.subplots(figsize=(size, size * 0.9))
    ax.imshow(share, cmap="Blues", vmin=0, vmax=1)
    ax.set_xticks(range(n), loo.classes, rotation=90, fontsize=8)
    ax.set_yticks(range(n), loo.classes, fontsize=8)
    ax.set_xlabel("predicted (label of the nearest neighbour)")
    ax.set_ylabel("true")
    if n <= 40:
        for i in range(n):
            for j in range(n):
                if matrix[i, j]:
                    ax.text(
                        j,
                        i,
                        str(matrix[i, j]),
                        ha="center",
                        va="center",
                        fontsize=7,
                        color="white" if share[i, j] > 0.6 else "black",
                    )
    excluded = (
        f", excluding same {result.config.exclude_same}" if score.loo_excluded is not None else ""
    )
    ax.set_title(
        f"{score.descriptor} / {score.kind}: LOO 1-NN A_e = {_fmt(loo.accuracy)}{excluded}",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def _three_man_figure(result: EvalResult, kind: str, path: Path) -> None:
    import matplotlib.pyplot as plt

    values = np.stack([r.three_man for r in result.records])
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.8))
    handles = _scatter(axes[0], values[:, [0, 1]], result, kind)
    _scatter(axes[1], values[:, [1, 2]], result, kind)
    axes[0].set_xlabel("e_all = log(E_total + 1)")
    axes[0].set_ylabel("r_u/l = log((E_upper + 1) / (E_lower + 1))")
    axes[1].set_xlabel("r_u/l")
    axes[1].set_ylabel("r_l/t = log((E_limbs + 1) / (E_trunk + 1))")
    fig.suptitle(f"FMDistance 3-MAN features, coloured by {kind}")
    _legend(fig, handles)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def pca_2d(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Projection of the centred rows of ``X`` on its first two principal axes, and the share
    of variance each explains."""
    X = np.asarray(X, dtype=np.float64)
    centred = X - X.mean(axis=0)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    components = vt[:2]
    xy = centred @ components.T
    if xy.shape[1] < 2:
        xy = np.column_stack([xy, np.zeros(len(xy))])
    total = float((s**2).sum())
    explained = (s[:2] ** 2) / total if total > 0 else np.zeros(min(2, len(s)))
    return xy, np.pad(explained, (0, 2 - len(explained)))


def _pca_figure(result: EvalResult, descriptor: str, kind: str, path: Path) -> None:
    import matplotlib.pyplot as plt

    xy, explained = pca_2d(result.matrix(descriptor))
    fig, ax = plt.subplots(figsize=(6.5, 5.2))
    handles = _scatter(ax, xy, result, kind)
    ax.set_xlabel(f"PC1 ({explained[0]:.0%} of variance)")
    ax.set_ylabel(f"PC2 ({explained[1]:.0%} of variance)")
    ax.set_title(f"{descriptor}: PCA, coloured by {kind}")
    _legend(fig, handles)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def write_figures(result: EvalResult, out_dir: Path) -> list[Path]:
    """Every figure for every scored label kind; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    if len(result.records) < 2:
        return written
    kinds = [k for k in result.label_kinds if k not in result.skipped_kinds]
    for kind in kinds:
        path = out_dir / f"three_man_{_safe(kind)}.png"
        _three_man_figure(result, kind, path)
        written.append(path)
        for descriptor in result.descriptors:
            score = result.scores.get((descriptor, kind))
            if score is not None:
                path = out_dir / f"confusion_{_safe(descriptor)}_{_safe(kind)}.png"
                _confusion_figure(result, score, path)
                written.append(path)
            path = out_dir / f"pca_{_safe(descriptor)}_{_safe(kind)}.png"
            _pca_figure(result, descriptor, kind, path)
            written.append(path)
    return written
