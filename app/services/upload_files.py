"""The files a bulk import's ``.gltf`` refers to, read from its folder.

A ``.gltf`` names its buffers and images by relative path. Over HTTP they come as further
``file`` fields (already in memory, within the request's size limit); a bulk import reads them
from the folder beside the document, through :class:`FolderFiles`: a read-only mapping from
such a name to bytes, read when the document asks for it and only then, within a limit of
bytes, never outside the folder. :func:`app.motion.formats.gltf_pack.pack_gltf` then makes
one GLB of them.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from pathlib import Path

from app.errors import PayloadTooLarge


class FolderFiles(Mapping[str, bytes]):
    """The files in ``folder`` and below it by relative path, read on demand (a bulk
    import's ``.gltf``), at most ``max_bytes`` of them in all; nothing outside the folder is
    ever read (a link leading out of it counts as missing)."""

    def __init__(self, folder: Path, max_bytes: int) -> None:
        self.folder = folder.resolve()
        self.max_bytes = max_bytes
        self.read = 0

    def _path(self, name: str) -> Path | None:
        path = (self.folder / name).resolve()
        if not path.is_relative_to(self.folder) or not path.is_file():
            return None
        return path

    def __getitem__(self, name: str) -> bytes:
        path = self._path(name)
        if path is None:
            raise KeyError(name)
        size = path.stat().st_size
        if self.read + size > self.max_bytes:
            raise PayloadTooLarge(
                f"{path}: reading it would pass {self.max_bytes} bytes, the most the files one "
                ".gltf refers to may hold"
            )
        self.read += size
        return path.read_bytes()

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and self._path(name) is not None

    def __iter__(self) -> Iterator[str]:
        return (str(p.relative_to(self.folder)) for p in self.folder.rglob("*") if p.is_file())

    def __len__(self) -> int:
        return sum(1 for _ in self)
