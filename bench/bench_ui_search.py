"""The Search page with k = 50 in a real browser: how long until every figure has its frames.

Run from the repository root, after importing the dev library into a data directory::

    .venv/bin/mocap-index import --data-dir /tmp/devlib ../shared/data/cmu \\
        ../shared/data/bandai-ds1 ../shared/data/wild-bvh ../shared/data/fbx-gltf \\
        ../shared/data/wild-more
    .venv/bin/python bench/bench_ui_search.py --data /tmp/devlib [--baseline main]

For each of ``--queries`` query clips (spread over the library's ids), the page
``#/search?clip=ID&k=50`` is opened in a fresh headless chromium context and timed from
navigation until all 51 figures have their frames (or an error): what a user waits for.
Conditions, each with a freshly started server:

* **first view**: the server just started, nothing in memory; on disk the stored previews as
  the import left them (this branch stores each clip's preview when it stores the clip, so a
  library imported with it has them all; the baseline's are removed first, as a library it
  imported has none and every clip's file is parsed when first shown);
* **again**: the same queries once more on that server (previews in memory);
* **restarted** (this branch only): a new server process with the stored previews on disk.

With ``--baseline REF`` the same runs are made, back to back, with the code of that git
revision (``git archive``: its ``app/`` and ``tests/ui/serve.py``), so the figures come with
a ratio measured on the same machine at the same time. The data directory is only read, but
for its ``previews/`` cache: kept aside at the start and put back before each of this
branch's runs and at the end, so the runs (and the next) see the previews the import stored.
"""

from __future__ import annotations

import argparse
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
from common import ROOT, machine

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run"]
FILLED = (
    "(k) => window.__mocap && window.__mocap.figures().length === k + 1 && "
    "window.__mocap.figures().every(f => f.frameCount > 0 || f.error)"
)


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@contextmanager
def server(source: Path, data: Path) -> Iterator[str]:
    """uvicorn with the UI (``tests.ui.serve``) from the code at ``source`` on ``data``."""
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
    env.update(MOCAP_DATA_DIR=str(data), PYTHONPATH=str(source), OMP_NUM_THREADS="1")
    command = [sys.executable, "-m", "uvicorn", "--factory", "tests.ui.serve:create_ui_app"]
    command += ["--host", "127.0.0.1", "--port", str(port), "--log-level", "warning"]
    process = subprocess.Popen(command, cwd=source, env=env)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                if httpx.get(f"{base}/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the server on {data} did not start")
            time.sleep(0.3)
        yield base
    finally:
        process.terminate()
        process.wait(timeout=30)


def fill_seconds(browser: object, base: str, clip: int, k: int) -> float:
    context = browser.new_context(viewport={"width": 1280, "height": 900}, base_url=base)  # type: ignore[attr-defined]
    try:
        page = context.new_page()
        started = time.perf_counter()
        page.goto(f"/#/search?clip={clip}&k={k}")
        page.wait_for_function(FILLED, arg=k, timeout=300_000, polling=50)
        return time.perf_counter() - started
    finally:
        context.close()


def query_clips(base: str, count: int) -> list[int]:
    """``count`` clip ids spread over the library (clips with a stored file)."""
    items = []
    offset = 0
    while True:
        page = httpx.get(f"{base}/clips", params={"limit": 200, "offset": offset}).json()
        items += [c["id"] for c in page["items"] if c["filenames"]]
        offset += 200
        if offset >= page["total"]:
            break
    step = max(1, len(items) // count)
    return items[::step][:count]


def export(ref: str, into: Path) -> Path:
    """The code of git revision ``ref`` (app/, migrations/, tests/ui/) under ``into``."""
    archive = into / "code.tar"
    with archive.open("wb") as out:
        subprocess.run(
            [
                "git",
                "archive",
                ref,
                "app",
                "migrations",
                "alembic.ini",
                "tests/__init__.py",
                "tests/ui",
            ],
            cwd=ROOT,
            check=True,
            stdout=out,
        )
    with tarfile.open(archive) as tar:
        tar.extractall(into, filter="data")
    return into


def put_previews(data: Path, previews: Path | None) -> None:
    """Make ``data/previews`` a copy of ``previews`` (``None``: no stored preview)."""
    shutil.rmtree(data / "previews", ignore_errors=True)
    if previews is not None:
        shutil.copytree(previews, data / "previews")


def run(
    label: str,
    source: Path,
    data: Path,
    queries: list[int],
    k: int,
    stored: Path | None,
) -> dict[str, list[float]]:
    """Time the queries on ``data`` with the code at ``source``; ``stored``: the previews to
    put in ``data/previews`` first (and the condition *restarted* then measured), or
    ``None`` to start without any."""
    from playwright.sync_api import sync_playwright

    results: dict[str, list[float]] = {}
    put_previews(data, stored)
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        with server(source, data) as base:
            results["first view"] = [fill_seconds(browser, base, q, k) for q in queries]
            results["again"] = [fill_seconds(browser, base, q, k) for q in queries]
        if stored is not None:
            with server(source, data) as base:
                results["restarted"] = [fill_seconds(browser, base, q, k) for q in queries]
        browser.close()
    for condition, seconds in results.items():
        print(
            f"{label:8} {condition:11}: median {statistics.median(seconds):5.2f} s, "
            f"max {max(seconds):5.2f} s  ({', '.join(f'{s:.2f}' for s in seconds)})",
            flush=True,
        )
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, required=True, help="data directory of a library")
    parser.add_argument("--baseline", help="git revision to compare with (e.g. main)")
    parser.add_argument("--queries", type=int, default=5)
    parser.add_argument("-k", type=int, default=50)
    args = parser.parse_args()
    print(machine())
    with server(ROOT, args.data) as base:
        queries = query_clips(base, args.queries)
    print(f"queries: clips {queries}, k = {args.k}")
    with tempfile.TemporaryDirectory() as tmp:
        kept = Path(tmp) / "previews"
        if (args.data / "previews").is_dir():
            shutil.copytree(args.data / "previews", kept)
        else:
            kept.mkdir()
        count = sum(1 for _ in kept.rglob("*.npz"))
        print(f"stored previews in the data directory at the start: {count}")
        try:
            branch = run("branch", ROOT, args.data, queries, args.k, stored=kept)
            if args.baseline:
                code = Path(tmp) / "baseline"
                code.mkdir()
                baseline = run(
                    "baseline", export(args.baseline, code), args.data, queries, args.k, None
                )
                for condition in ("first view", "again"):
                    ratio = statistics.median(branch[condition]) / statistics.median(
                        baseline[condition]
                    )
                    print(f"{condition}: branch / baseline = {ratio:.2f}")
        finally:
            put_previews(args.data, kept)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
