"""Tests about the codebase itself: the motion core stays framework-free, every setting is
documented, CI runs the README's test command."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from app.cli import COMMANDS
from app.config import Settings

ROOT = Path(__file__).resolve().parents[1]
FRAMEWORKS = {
    "fastapi",
    "starlette",
    "sqlalchemy",
    "alembic",
    "faiss",
    "uvicorn",
    "pydantic_settings",
}


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return found


def test_motion_core_imports_no_web_database_or_index_code() -> None:
    files = sorted((ROOT / "app" / "motion").rglob("*.py"))
    assert files
    for path in files:
        for module in imported_modules(path):
            assert module.split(".")[0] not in FRAMEWORKS, f"{path.relative_to(ROOT)}: {module}"


SCENE_READERS = {
    "app.motion.formats.fbx",
    "app.motion.formats.gltf",
    "app.motion.formats.gltf_data",
    "ufbx",
}
# Where the FBX/glTF readers may be called from: worker processes only (the parser pool's
# workers, and the bulk import's workers through its InlineParser).
SCENE_READER_CALLERS = {"app/services/parser_pool.py"}


def test_only_the_parser_workers_import_the_scene_readers() -> None:
    for path in sorted((ROOT / "app").rglob("*.py")):
        relative = path.relative_to(ROOT).as_posix()
        if relative.startswith("app/motion/formats/"):
            continue
        used = imported_modules(path) & SCENE_READERS
        assert not used or relative in SCENE_READER_CALLERS, f"{relative}: {used}"


def test_every_setting_is_documented() -> None:
    readme = (ROOT / "README.md").read_text()
    for name, field in Settings.model_fields.items():
        assert f"MOCAP_{name.upper()}" in readme, f"MOCAP_{name.upper()} missing from README.md"
        assert field.description, f"Settings.{name} has no description"


def test_every_command_is_documented() -> None:
    readme = (ROOT / "README.md").read_text()
    for name in COMMANDS:
        assert f"mocap-index {name}" in readme, name


def test_ci_runs_the_readme_test_command() -> None:
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    commands = re.findall(r"^make (\w+)$", readme, flags=re.MULTILINE)
    assert "serve" in commands and "test" in commands
    assert re.search(r"^make test$", ci, flags=re.MULTILINE)
