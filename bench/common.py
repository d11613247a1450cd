"""What every benchmark needs: where the shared data is, and what machine ran it."""

from __future__ import annotations

import os
import platform
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def shared_data() -> Path:
    """``../shared/data`` beside the repository, or ``$MOCAP_SHARED_DATA``."""
    override = os.environ.get("MOCAP_SHARED_DATA")
    return Path(override) if override else ROOT.parent / "shared" / "data"


def machine() -> str:
    """Architecture, cores, CPU model, memory, Python and the current load: the figures'
    context (the 2-core machines here are shared, so load changes results)."""
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return (
        f"{platform.machine()}, {os.cpu_count()} cores ({cpu}), {memory:.0f} GB RAM, "
        f"Python {platform.python_version()}, load average {os.getloadavg()[0]:.2f}"
    )
