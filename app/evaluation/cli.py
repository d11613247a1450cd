"""The ``eval`` subcommand: ``mocap-index eval PATH... [options]``.

:func:`add_eval_parser` registers it on an argparse ``subparsers`` object (and sets
``func=run_eval`` as the parser default); :func:`run_eval` runs it and returns the exit code:

* 0 — scores written (clips that could not be read are skipped with a warning);
* 1 — no clip could be described;
* 2 — bad arguments (bad regex or TSV, unknown descriptor or label kind, missing path).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from rich.console import Console
from rich.markup import escape

from app.errors import InvalidInput
from app.evaluation import COVARIANCE_TYPES, DEFAULT_COVARIANCE

DEFAULT_OUT = Path("eval-out")
DEFAULT_CACHE = Path(".eval-cache")
EXAMPLE_BANDAI = (
    "mocap-index eval ../shared/data/bandai-ds1 "
    "--labels-regex 'dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_\\d+' "
    "--exclude-same style --out docs/figures/bandai"
)


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError("must be at least 1")
    return value


def configure_parser(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``eval`` arguments to ``parser``."""
    parser.add_argument(
        "paths",
        nargs="+",
        type=Path,
        metavar="PATH",
        help="folders to search recursively for .bvh and .asf/.amc clips (or single files)",
    )
    parser.add_argument(
        "--labels-tsv",
        type=Path,
        metavar="FILE",
        help="tab-separated labels with a header row: clip (file stem), then one column per "
        "label kind",
    )
    parser.add_argument(
        "--labels-regex",
        metavar="REGEX",
        help="regular expression with named groups searched in each clip's relative path; each "
        "group is a label kind",
    )
    parser.add_argument(
        "--label-kind",
        dest="label_kinds",
        action="extend",
        nargs="+",
        metavar="KIND",
        help="label kinds to score (default: every kind the TSV/regex gives; the built-in "
        "'trial' (file stem) and 'format' kinds only when named or when no labels are given)",
    )
    parser.add_argument(
        "--descriptor",
        dest="descriptors",
        action="extend",
        nargs="+",
        metavar="NAME",
        help="descriptors to score (default: all registered)",
    )
    parser.add_argument(
        "--exclude-same",
        metavar="KIND",
        help="leave-one-out 1-NN also with neighbours sharing this label kind's value with the "
        "query excluded (e.g. style, trial)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=DEFAULT_OUT,
        metavar="DIR",
        help=f"where results.json and the figures go (default: {DEFAULT_OUT}/)",
    )
    parser.add_argument(
        "--cache-dir",
        type=Path,
        default=DEFAULT_CACHE,
        metavar="DIR",
        help=f"descriptor vector cache (default: {DEFAULT_CACHE}/ in the current folder)",
    )
    parser.add_argument(
        "--gmm-covariance",
        choices=COVARIANCE_TYPES,
        default=DEFAULT_COVARIANCE,
        help="covariance model of the Gaussian mixture whose BIC picks the number of Ward "
        f"clusters (default: {DEFAULT_COVARIANCE}, the model Ward's criterion assumes)",
    )
    parser.add_argument("--no-figures", action="store_true", help="write no PNG figures")
    parser.add_argument(
        "--workers",
        type=_positive_int,
        default=None,
        metavar="N",
        help="processes describing clips (default: number of CPUs)",
    )
    return parser


def add_eval_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``eval`` subcommand; its namespace gets ``func=run_eval``."""
    parser = subparsers.add_parser(
        "eval",
        help="score descriptors against labelled clips (LOO 1-NN, Ward/BIC clustering)",
        description="Describe every clip found under PATH... and score how well each "
        "descriptor's nearest neighbours and clusters agree with the clips' labels "
        "(Miura et al. 2013 protocol), plus how close the same capture in different file "
        "formats lands.",
        epilog=f"example: {EXAMPLE_BANDAI}",
    )
    configure_parser(parser)
    parser.set_defaults(func=run_eval)
    return parser


def run_eval(args: argparse.Namespace) -> int:
    """Run ``eval`` with parsed ``args``; prints the table and writes JSON (and figures)."""
    from app.evaluation.report import JSON_NAME, print_report, write_figures, write_json
    from app.evaluation.runner import EvalConfig, run

    err = Console(stderr=True, soft_wrap=True, highlight=False)
    missing = [p for p in args.paths if not Path(p).exists()]
    if missing:
        listed = escape(", ".join(map(str, missing)))
        err.print(f"[red]error:[/red] no such file or folder: {listed}")
        return 2
    config = EvalConfig(
        paths=[Path(p) for p in args.paths],
        labels_tsv=args.labels_tsv,
        labels_regex=args.labels_regex,
        label_kinds=args.label_kinds,
        descriptors=args.descriptors,
        exclude_same=args.exclude_same,
        cache_dir=args.cache_dir,
        workers=args.workers or os.cpu_count() or 1,
        progress=getattr(args, "progress", True),
        covariance_type=args.gmm_covariance,
    )
    try:
        result = run(config)
    except InvalidInput as error:
        err.print(f"[red]error:[/red] {escape(error.detail)}")
        return 2

    for failure in result.discovery_failures:
        err.print(f"[yellow]warning:[/yellow] {escape(f'{failure.path}: {failure.reason}')}")
    if result.skipped:
        err.print(f"[yellow]warning:[/yellow] {len(result.skipped)} clip(s) skipped, unreadable:")
        for skipped in result.skipped:
            err.print(f"  {escape(f'{skipped.path}: {skipped.reason}')}")
    if not result.records:
        err.print("[red]error:[/red] no clip could be described")
        return 1

    console = Console(file=sys.stdout)
    if not console.is_terminal:  # a log file or a pipe: room for the whole table
        console = Console(file=sys.stdout, width=120)
    print_report(result, console)
    figures = [] if args.no_figures else write_figures(result, args.out)
    path = write_json(result, args.out / JSON_NAME, figures)
    console.print(f"wrote {path}" + (f" and {len(figures)} figures" if figures else ""))
    return 0
