"""Every example of the README runs as written (issue 24, item 18).

The ``sh`` blocks are read from README.md itself, so an example cannot drift from what the
test runs: each ``curl`` command is run by curl, in order, against ``mocap-index serve``
holding the library the README names (Bandai dataset 1 imported first), from a folder
holding the files the examples upload (copies of development data files); each must answer
2xx. The API-key block runs against a server started with a key, the command-line blocks
(``mocap-index import``, ``reindex``) in a folder of their own, and the JSON answers shown
must name fields the real answers have. Blocks that install or deploy (make, pip, docker,
PostgreSQL) are listed in :data:`NOT_RUN`: CI itself runs ``make test``, tests/test_deploy.py
checks the Docker files.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import sqlite3
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import pytest

from app.config import Settings
from app.importer import run_import
from tests.api.test_restart import _free_port
from tests.conftest import REPO_ROOT, shared_data_dir

README = REPO_ROOT / "README.md"
README_URL = "http://127.0.0.1:8000"
# The files the examples name, and the development data file each stands for.
EXAMPLE_FILES = {
    "walk.bvh": "cmu/bvh-mb/02/02_01.bvh",
    "02.asf": "cmu/asf-amc/02/02.asf",
    "02_01.amc": "cmu/asf-amc/02/02_01.amc",
    "query.bvh": "cmu/bvh-daz/02/02_02.bvh",
    "jump.bvh": "cmu/bvh-mb/01/01_01.bvh",
    "character.fbx": "fbx-gltf/pairs-mixamo/ortiz_hiphop.fbx",
    "my_character.fbx": "fbx-gltf/pairs-mixamo/ortiz_situp_to_idle.fbx",
    "soldier.glb": "wild-more/threejs-examples/danielrmz18_Soldier.glb",
}
# Blocks not run here, by their first command.
NOT_RUN = {
    "make serve": "CI runs the README's commands through `make test`",
    "make test": "CI itself",
    "pip install -e '.[postgres]'          # psycopg 3 (make install includes it)": (
        "needs a PostgreSQL server the README's URL names; tests/api runs every route on one"
    ),
    "docker compose up --build": "tests/test_deploy.py",
}


def sh_blocks(text: str) -> list[list[str]]:
    """The README's ``sh`` (and unlabelled) code blocks, each as its commands: continued
    lines joined, comment lines dropped."""
    blocks = []
    for language, body in re.findall(r"```(\w*)\n(.*?)```", text, re.S):
        if language not in ("sh", ""):
            continue
        joined = re.sub(r"\\\n\s*", " ", body)
        blocks.append(
            [line.strip() for line in joined.splitlines() if line.strip() and line[0] != "#"]
        )
    return blocks


def json_blocks(text: str) -> list[Any]:
    return [json.loads(body) for body in re.findall(r"```json\n(.*?)```", text, re.S)]


@pytest.fixture(scope="module")
def data() -> Path:
    path = shared_data_dir()
    needed = {"bandai-ds1", *(name.split("/")[0] for name in EXAMPLE_FILES.values())}
    if not all((path / name).is_dir() for name in needed):
        pytest.skip(f"needs ../shared/data ({', '.join(sorted(needed))}) at {path}")
    return path


@pytest.fixture(scope="module")
def examples_folder(data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("readme")
    for name, source in EXAMPLE_FILES.items():
        shutil.copy(data / source, folder / name)
    return folder


def environment(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return {**env, **extra}


@contextmanager
def serving(data_dir: Path, log: Path, **extra: str) -> Iterator[str]:
    """``mocap-index serve`` on a free port (environment ``extra``): its base URL."""
    from tests.api.test_restart import running_server

    if not extra:
        with running_server(data_dir, log) as client:
            yield str(client.base_url).rstrip("/")
        return
    port = _free_port()
    command = [sys.executable, "-m", "app.cli", "serve", "--data-dir", str(data_dir)]
    with open(log, "ab") as out:
        process = subprocess.Popen(
            [*command, "--port", str(port)],
            cwd=REPO_ROOT,
            env=environment(**extra),
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    base = f"http://127.0.0.1:{port}"
    try:
        for _ in range(300):
            try:
                if httpx.get(f"{base}/health").status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert process.poll() is None, log.read_text()
            subprocess.run(["sleep", "0.2"], check=True)
        yield base
    finally:
        process.terminate()
        process.wait(timeout=30)


def run_curl(command: str, base: str, folder: Path, **env: str) -> tuple[int, str]:
    """Run one README curl command against ``base``: its HTTP status and body."""
    line = command.replace(README_URL, base) + " -sS -w '\\n%{http_code}'"
    done = subprocess.run(
        ["bash", "-c", line], cwd=folder, env=environment(**env), capture_output=True, text=True
    )
    assert done.returncode == 0, (command, done.stderr)
    body, _, status = done.stdout.rpartition("\n")
    return int(status), body


def test_every_sh_block_is_run_or_listed() -> None:
    blocks = sh_blocks(README.read_text())
    assert blocks
    for commands in blocks:
        run = ("curl", "mocap-index import", "mocap-index reindex")
        runnable = any(c.startswith(run) for c in commands)
        assert runnable or commands[0] in NOT_RUN, commands


def test_the_readme_examples_run_as_written(
    data: Path, examples_folder: Path, tmp_path: Path
) -> None:
    settings = Settings(data_dir=tmp_path / "library")
    report = run_import(settings, [data / "bandai-ds1"], workers=1)
    assert not report.failed and len(report.imported) == 174
    text = README.read_text()
    blocks = sh_blocks(text)
    keyed = [b for b in blocks if any("MOCAP_API_KEY" in c for c in b)]
    plain = [c for b in blocks if b not in keyed for c in b if c.startswith("curl")]
    assert len(plain) >= 25
    with serving(settings.data_dir, tmp_path / "serve.log") as base:
        clip_7 = httpx.get(f"{base}/clips/7").json()
        assert clip_7["name"] == "dataset-1_bow_happy_001", "the README's clip 7"
        for command in plain:
            status, body = run_curl(command, base, examples_folder)
            assert 200 <= status < 300, (command, status, body)
        # The answers shown: fields the real answers have.
        search, moments = json_blocks(text)
        real = httpx.get(f"{base}/search", params={"clip": 2, "k": 1}).json()
        assert set(search) <= set(real) and set(search["results"][0]) <= set(real["results"][0])
        real = httpx.get(f"{base}/search/moments", params={"clip": 7, "k": 1}).json()
        assert set(moments) <= set(real)
        assert set(moments["query"]) - {"clip"} <= set(real["query"])
        assert set(moments["results"][0]) <= set(real["results"][0])
    for commands in keyed:  # a server started with the key the block exports
        key = "readme-example-key"
        with serving(tmp_path / "keyed", tmp_path / "keyed.log", MOCAP_API_KEY=key) as base:
            for command in (c for c in commands if c.startswith("curl")):
                status, body = run_curl(command, base, examples_folder, MOCAP_API_KEY=key)
                assert 200 <= status < 300, (command, status, body)


def test_the_readme_command_lines_run_as_written(
    data: Path, examples_folder: Path, tmp_path: Path
) -> None:
    """``mocap-index import`` (the README's folders standing for a few development files)
    and ``reindex``, in a folder of their own (``./data``)."""
    bandai, cmu = tmp_path / "mnt" / "bandai", tmp_path / "mnt" / "cmu"
    bandai.mkdir(parents=True)
    for path in sorted((data / "bandai-ds1" / "data").glob("dataset-1_walk_*.bvh"))[:3]:
        shutil.copy(path, bandai / path.name)
    shutil.copytree(data / "cmu" / "asf-amc" / "03", cmu / "03")
    commands = [
        c
        for block in sh_blocks(README.read_text())
        for c in block
        if c.startswith(("mocap-index import", "mocap-index reindex"))
    ]
    assert len(commands) == 2
    work = tmp_path / "work"
    work.mkdir()
    for command in commands:
        line = command.replace("/mnt/mocap", str(tmp_path / "mnt"))
        done = subprocess.run(
            ["bash", "-c", line], cwd=work, env=environment(), capture_output=True, text=True
        )
        assert done.returncode == 0, (command, done.stdout, done.stderr)
    db = sqlite3.connect(work / "data" / "mocap-index.sqlite3")
    try:
        rows = db.execute("SELECT count(*) FROM clips").fetchone()[0]
        walks = db.execute("SELECT count(*) FROM clip_labels WHERE label = 'walk'").fetchone()[0]
    finally:
        db.close()
    assert rows == 3 + len(list((cmu / "03").glob("*.amc"))) and walks == 3
