"""``mocap-index import``: its options (folders, labels from a table, a pattern or the command
line, workers, batches, progress) and the run: every clip under the folders imported in
parallel by :func:`app.importer.run_import`, a report printed, and the exit status
(:func:`import_status`). :mod:`app.cli` lists the command.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from app.cli.progress import ProgressBar
from app.config import Settings


def configure_import(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "paths", nargs="+", type=Path, metavar="PATH", help="folders (walked) or clip files"
    )
    parser.add_argument(
        "--workers",
        type=int,
        help="worker processes (default: one per core, MOCAP_IMPORT_WORKERS)",
    )
    parser.add_argument(
        "--batch-size",
        type=int,
        default=64,
        help="clips per database transaction and index update (default 64)",
    )
    parser.add_argument(
        "--labels-tsv",
        type=Path,
        metavar="FILE",
        help="TSV with a header row: clip key (file stem), then one column per label kind; "
        "columns named 'source' and 'licence' give those fields instead",
    )
    parser.add_argument(
        "--label-columns",
        action="append",
        metavar="COLUMN[,COLUMN...]",
        help="the --labels-tsv columns to use as labels (default: every column except those "
        "holding free text: a value over 40 characters or 3 words, like a description)",
    )
    parser.add_argument(
        "--labels-regex",
        metavar="REGEX",
        help="regular expression with named groups over each clip's path relative to the "
        r"folder given, e.g. 'dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_\d+' "
        "(JavaScript's (?<content>...) works too)",
    )
    parser.add_argument(
        "--label",
        action="append",
        default=[],
        metavar="LABEL",
        help="a label for every imported clip (repeat for more)",
    )
    parser.add_argument(
        "--source",
        metavar="TEXT",
        help="where the clips come from (a URL, a dataset), for every clip whose --labels-tsv "
        "row gives none; a duplicate gets it too",
    )
    parser.add_argument(
        "--licence",
        "--license",
        dest="licence",
        metavar="TEXT",
        help="the clips' licence (e.g. 'CC BY 4.0'), for every clip whose --labels-tsv row "
        "gives none; a duplicate gets it too",
    )
    parser.add_argument(
        "--strict",
        action="store_true",
        help="exit with 1 when any file failed, also one an earlier run already reported as "
        "refused (default: only new failures make the exit status 1)",
    )
    progress = parser.add_mutually_exclusive_group()
    progress.add_argument(
        "--progress",
        dest="progress",
        action="store_true",
        default=None,
        help="show a progress bar (default: when stderr is a terminal)",
    )
    progress.add_argument("--no-progress", dest="progress", action="store_false")
    parser.add_argument(
        "--verbose", "-v", action="store_true", help="list every clip, not only the failures"
    )


def run_import_command(args: argparse.Namespace, settings: Settings) -> int:
    from app.importer import LabelRules, run_import

    rules = LabelRules.build(
        tsv=args.labels_tsv,
        regex=args.labels_regex,
        fixed=args.label,
        columns=args.label_columns,
        source=args.source,
        licence=args.licence,
    )
    if rules.left_out:
        print(
            f"mocap-index: labels file columns left out (free text): {', '.join(rules.left_out)}; "
            "choose columns with --label-columns",
            file=sys.stderr,
        )
    if args.workers is not None and args.workers < 1:
        print("mocap-index: --workers must be at least 1", file=sys.stderr)
        return 2
    show = sys.stderr.isatty() if args.progress is None else args.progress
    bar = ProgressBar()
    try:
        report = run_import(
            settings,
            args.paths,
            labels=rules,
            workers=args.workers,
            batch_size=args.batch_size,
            progress=bar.update if show else None,
            on_start=bar.start,
        )
    finally:
        bar.stop()
    if args.verbose:
        for clip in report.imported:
            paired = f" (skeleton {clip.skeleton})" if clip.skeleton else ""
            print(f"imported  {clip.path} as clip {clip.clip_id}{paired}")
        for dup in report.duplicates:
            news = "; given new labels, source or licence" if dup.updated else ""
            print(
                f"duplicate {dup.path}: same content as clip {dup.clip_id} {dup.clip_name!r}{news}"
            )
    for skeleton, count in sorted(report.skeletons().items()):
        print(f"skeleton {skeleton} used for {count} .amc clip{'s' if count != 1 else ''}")
    if report.failed:
        print("failed:")
        for failure in sorted(report.failed, key=lambda f: str(f.path)):
            before = " (refused before)" if failure.path in report.known_refusals else ""
            print(f"  {failure.path}: {failure.reason}{before}")
    rate = report.done / report.seconds if report.seconds else 0.0
    updated = sum(d.updated for d in report.duplicates)
    known = len(report.known_refusals)
    print(
        f"{'interrupted: ' if report.interrupted else ''}"
        f"imported {len(report.imported)}, skipped {len(report.duplicates)} as duplicates"
        f"{f' ({updated} given new labels, source or licence)' if updated else ''}, "
        f"failed {len(report.failed)}{f' ({known} refused before)' if known else ''} "
        f"of {report.found} clips found, in {report.seconds:.2f} s "
        f"({rate:.0f} clips/s, {report.workers} worker{'s' if report.workers != 1 else ''})"
    )
    if report.interrupted:
        print("run the same command again to finish the import", file=sys.stderr)
        return 130
    return import_status(report, strict=args.strict)


def import_status(report: Any, *, strict: bool) -> int:
    """``import``'s exit status: 1 when a clip failed that no earlier run reported (any
    failure with ``strict``), else 0 — re-running an import over files known to be
    unreadable is not an error."""
    failures = report.failed if strict else report.new_failures
    return 1 if failures else 0
