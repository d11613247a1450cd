"""The files a bulk import's .gltf refers to, read from its folder (upload_files.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.errors import PayloadTooLarge
from app.services.upload_files import FolderFiles


def test_only_files_in_the_folder_are_read_and_only_up_to_the_limit(tmp_path: Path) -> None:
    folder = tmp_path / "scene"
    (folder / "buffers").mkdir(parents=True)
    (folder / "buffers" / "a.bin").write_bytes(b"x" * 60)
    (folder / "b.bin").write_bytes(b"y" * 60)
    (tmp_path / "secret.bin").write_bytes(b"s")
    (folder / "link.bin").symlink_to(tmp_path / "secret.bin")
    files = FolderFiles(folder, max_bytes=100)
    assert files["buffers/a.bin"] == b"x" * 60
    # Outside the folder, by a parent path or by a link: as if missing.
    for name in ("../secret.bin", "link.bin", str(tmp_path / "secret.bin")):
        assert name not in files
        with pytest.raises(KeyError):
            files[name]
    with pytest.raises(PayloadTooLarge, match="100 bytes"):
        files["b.bin"]  # 60 + 60 read: past the limit, refused before reading
