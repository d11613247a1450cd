"""``python -m app.evaluation [eval] PATH... [options]`` — the ``mocap-index eval`` command."""

from __future__ import annotations

import argparse
import sys

from app.evaluation.cli import add_eval_parser, run_eval


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] != "eval":
        argv = ["eval", *argv]
    parser = argparse.ArgumentParser(prog="mocap-index")
    add_eval_parser(parser.add_subparsers(dest="command", required=True))
    return run_eval(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
