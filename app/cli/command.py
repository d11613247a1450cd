"""What a ``mocap-index`` subcommand is: a name, a help line, ``run(args, settings) -> exit
code`` and, when it takes options, ``configure(parser)``."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass

from app.config import Settings

Run = Callable[[argparse.Namespace, Settings], int]
Configure = Callable[[argparse.ArgumentParser], None]


@dataclass(frozen=True)
class Command:
    name: str
    help: str
    run: Run
    configure: Configure | None = None


# Settings a command-line option may give (the rest come from MOCAP_* variables only).
COMMAND_LINE_SETTINGS = ("data_dir", "database_url", "host", "port")
