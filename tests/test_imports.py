"""A worker's start imports only what serving needs: modules that few requests use are imported
where they are used, and this keeps a later change from bringing them back to start-up (each
one costs every worker of every replica its import time, issue 23)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Modules a plain start (``import app.main``, then ``create_app``) must not import, and why.
NOT_AT_START = {
    # The export pipeline: retargeting, root motion, resampling, the writers (~55 ms).
    "app.services.export": "imported by the download and export routes",
    "app.services.rigs": "imported by the /rigs routes and the exports",
    "app.motion.retarget": "needed by exports onto a rig and by storing a rig",
    # Kept out already; checked here so that they stay out.
    "sqlalchemy.dialects.postgresql": "imported where a PostgreSQL blob is written",
    "alembic": "imported by the lifespan only when the database needs migrating",
    "app.motion.formats.fbx": "the scene readers run in the parser workers",
    "app.motion.formats.gltf": "the scene readers run in the parser workers",
    "app.motion.formats.gltf_data": "the scene readers run in the parser workers",
    "app.evaluation": "the `eval` command",
    "app.importer": "the `import` command",
    "rich": "the CLI's progress bar and reports",
}

START = """
import json, sys
from pathlib import Path
import app.main
from app.config import Settings
app.main.create_app(Settings(data_dir=Path(sys.argv[1])))
print(json.dumps(sorted(sys.modules)))
"""


def test_a_plain_start_does_not_import_what_few_requests_use(tmp_path: Path) -> None:
    # A fresh interpreter: this test process has imported everything already.
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-c", START, str(tmp_path / "data")],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    loaded = set(json.loads(done.stdout))
    assert "app.api.clips" in loaded  # the routes were built
    imported = {
        name: why
        for name, why in NOT_AT_START.items()
        if any(m == name or m.startswith(name + ".") for m in loaded)
    }
    assert not imported, f"imported at start-up, but only needed later: {imported}"
