"""The commands that open a library and work on its stored clips: ``reindex`` (recompute
outdated vectors), ``fill-synthetic`` (benchmark clips), ``delete`` (by label) and ``export``
(clips as files)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from app.cli.command import Command
from app.cli.progress import ProgressBar
from app.config import Settings

# -- reindex -------------------------------------------------------------------------------


def _configure_reindex(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--all",
        action="store_true",
        help="recompute every vector, not only the missing or outdated ones",
    )
    progress = parser.add_mutually_exclusive_group()
    progress.add_argument(
        "--progress",
        action="store_true",
        default=None,
        help="show a progress bar (default: when stderr is a terminal)",
    )
    progress.add_argument("--no-progress", dest="progress", action="store_false")


def _reindex(args: argparse.Namespace, settings: Settings) -> int:
    from app.services.library import open_library
    from app.services.reindex import reindex

    show = sys.stderr.isatty() if args.progress is None else args.progress
    bar = ProgressBar("reindexing")

    def progress(done: int, total: int, clip: Any) -> None:
        bar.total = total
        bar.set_done(done)

    library = open_library(settings)
    try:
        report = reindex(library, everything=args.all, progress=progress if show else None)
    finally:
        bar.stop()
        library.close()
    for clip_id, why in report.failed.items():
        print(f"clip {clip_id}: {why}", file=sys.stderr)
    sizes = ", ".join(f"{name} {size}" for name, size in report.index_sizes.items())
    print(f"recomputed {report.recomputed} clips, {len(report.failed)} failed; indexes: {sizes}")
    return 1 if report.failed else 0


REINDEX = Command(
    "reindex",
    "recompute outdated descriptor vectors and rebuild the indexes (stop the service first)",
    configure=_configure_reindex,
    run=_reindex,
)


# -- fill-synthetic ------------------------------------------------------------------------


def _configure_fill(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--count",
        type=int,
        required=True,
        help="clips the library should hold afterwards (synthetic ones are added up to it)",
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument(
        "--noise",
        type=float,
        default=0.25,
        help="noise around the real clips, in standard deviations of each number (0.25)",
    )


def _fill_synthetic(args: argparse.Namespace, settings: Settings) -> int:
    from app.services.synthetic import fill_synthetic

    if args.count < 0:
        print("mocap-index: --count must not be negative", file=sys.stderr)
        return 2
    result = fill_synthetic(
        settings,
        args.count,
        seed=args.seed,
        noise=args.noise,
        report=lambda message: print(message, file=sys.stderr),
    )
    print(
        f"added {result.added} synthetic clips in {result.seconds:.1f} s; the library holds "
        f"{result.total} clips; indexes: "
        + ", ".join(f"{name} {kind}" for name, kind in result.index_kinds.items())
    )
    return 0


FILL_SYNTHETIC = Command(
    "fill-synthetic",
    "add synthetic clips (label and format 'synthetic', no stored file) for benchmarks. They "
    "show up in searches: use a separate --data-dir (a copy of a library), never your own "
    "library; 'mocap-index delete --label synthetic --yes' removes them",
    configure=_configure_fill,
    run=_fill_synthetic,
)


# -- delete --------------------------------------------------------------------------------


def _configure_delete(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--label",
        action="append",
        required=True,
        metavar="LABEL",
        help="delete the clips carrying this label (repeat, or separate with commas, for "
        "clips carrying all of them; any case)",
    )
    parser.add_argument(
        "--yes",
        action="store_true",
        help="really delete; without it, only say how many clips would go (exit status 1)",
    )


def _delete(args: argparse.Namespace, settings: Settings) -> int:
    from app.labels import label_filter
    from app.services import clips as clip_service
    from app.services.library import open_library

    labels = label_filter(args.label)
    if not labels:
        print("mocap-index: --label: name the label of the clips to delete", file=sys.stderr)
        return 2
    named = ", ".join(labels)
    library = open_library(settings)
    try:
        if not args.yes:
            count = len(clip_service.clips_with_labels(library, labels))
            print(
                f"would delete {count} clip{'s' if count != 1 else ''} labelled {named} "
                f"(of {library.clip_count()}); add --yes to delete them"
            )
            return 1 if count else 0
        deleted = clip_service.delete_clips_with(library, labels)
        remaining = library.clip_count()
    finally:
        library.close()
    print(f"deleted {deleted} clip{'s' if deleted != 1 else ''} labelled {named}; {remaining} left")
    return 0


DELETE = Command(
    "delete",
    "delete every clip carrying a label (e.g. the synthetic ones), with its files and vectors",
    configure=_configure_delete,
    run=_delete,
)


# -- export ----------------------------------------------------------------------------------


def _configure_export(parser: argparse.ArgumentParser) -> None:
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument(
        "--clip",
        action="extend",
        nargs="+",
        type=int,
        metavar="ID",
        help="the clips to export, by id (several after one --clip, or repeat it)",
    )
    which.add_argument(
        "--label",
        action="append",
        metavar="LABEL",
        help="export every clip carrying this label (repeat, or separate with commas, for "
        "clips carrying all of them)",
    )
    parser.add_argument("--format", choices=("bvh", "fbx", "glb"), default="bvh")
    parser.add_argument("--rig", type=int, metavar="ID", help="retarget onto this stored rig")
    parser.add_argument("--root", choices=("keep", "in-place", "extract"), default="keep")
    parser.add_argument("--units", choices=("cm", "m", "in"), help="BVH/FBX lengths")
    parser.add_argument("--fps", type=float, help="frame rate of the files")
    parser.add_argument(
        "--out", type=Path, required=True, metavar="DIR", help="folder for the files"
    )
    parser.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="show a progress bar (default: when stderr is a terminal)",
    )


def _export(args: argparse.Namespace, settings: Settings) -> int:
    from app.labels import label_filter
    from app.services.export import Exporter, ExportOptions, Manifest, export_each, export_items
    from app.services.library import open_library

    options = ExportOptions(
        format=args.format, units=args.units, fps=args.fps, root=args.root, rig=args.rig
    )
    show = sys.stderr.isatty() if args.progress is None else args.progress
    bar = ProgressBar("exporting")
    library = open_library(settings)
    failed = written = 0
    try:
        exporter = Exporter(library, options)
        if args.clip:
            items = export_items(library, clips=[(c, None, None) for c in args.clip])
        else:
            items = export_items(library, labels=list(label_filter(args.label)))
        args.out.mkdir(parents=True, exist_ok=True)
        manifest = Manifest(options)
        bar.total = len(items)
        for done, (item, exported, error) in enumerate(export_each(exporter, items), start=1):
            filename = manifest.add(item, exported, error)
            if exported is not None and filename is not None:
                (args.out / filename).write_bytes(exported.data)
                written += 1
            else:
                failed += 1
                print(f"clip {item.clip.id}: {error}", file=sys.stderr)
            if show:
                bar.set_done(done)
        (args.out / "manifest.csv").write_text(manifest.text(), encoding="utf-8")
    finally:
        bar.stop()
        library.close()
    print(f"wrote {written} files and manifest.csv to {args.out}; {failed} failed")
    return 1 if failed else 0


EXPORT = Command(
    "export",
    "write clips as BVH, FBX or GLB files (on a rig, root motion handled) into a folder",
    configure=_configure_export,
    run=_export,
)
