"""A ``.gltf`` and the files it refers to, packed into one GLB.

Most glTF in the wild is not one file: a ``.gltf`` JSON document beside a ``.bin`` of its
buffers and the images of its textures (Blender's "glTF Separate", the Khronos samples'
``glTF/`` folders, three.js examples, Sketchfab's downloads). The service reads and stores
one file, and never reads a path or an address a file names; so the files the user sent
beside the document (:func:`pack_gltf`'s ``resources``, by the names the document uses)
are put inside it, as glTF 2.0 lays out a binary file ("GLB File Format Specification"):
every buffer becomes a part of the one binary chunk (each part aligned to 8 bytes), every
buffer view points into it, and every image the user sent becomes a view of its own. An
image that was not sent (textures do not matter to motion) is replaced by a one-pixel PNG,
so the file stays valid for every other reader; a buffer that was not sent is refused,
naming it (the motion is in the buffers).
"""

from __future__ import annotations

import base64
import binascii
import json
import re
import struct
from collections.abc import Mapping
from pathlib import PurePosixPath
from typing import Any
from urllib.parse import unquote, urlsplit

from app.errors import ParseError

GLB_MAGIC = b"glTF"
ALIGN = 8  # every part of the binary chunk starts at a multiple of this (doubles, too)
# A 1x1 transparent PNG: what an image that was not uploaded becomes.
PLACEHOLDER_PNG = base64.b64decode(
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNkYPhfDwAChwGA60e6kgAAAABJRU5ErkJggg=="
)
IMAGE_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}
IMAGE_TYPES |= {".webp": "image/webp", ".ktx2": "image/ktx2"}


# A "uri" whose value is not a data URI: a document without one has nothing to pack (and is
# not parsed here: large documents are read in the parser workers).
EXTERNAL_URI = re.compile(rb'"uri"\s*:\s*"(?!data:)')


def refers_to_files(data: bytes) -> bool:
    """Whether ``data`` is a JSON glTF document naming files or addresses (not ``data:``)
    for its buffers or images: what :func:`pack_gltf` is for."""
    if data[:4] == GLB_MAGIC or EXTERNAL_URI.search(data) is None:
        return False
    try:
        document = json.loads(data)
    except (ValueError, RecursionError):
        return False  # the reader says what is wrong with it
    if not isinstance(document, dict):
        return False
    items = [*_list(document, "buffers"), *_list(document, "images")]
    return any(_external(item.get("uri")) for item in items if isinstance(item, dict))


def pack_gltf(
    data: bytes, resources: Mapping[str, bytes], *, what: str = "the .gltf file"
) -> bytes:
    """The GLB holding the JSON glTF ``data`` and the ``resources`` it refers to.

    Parameters
    ----------
    data:
        A ``.gltf`` (JSON) document.
    resources:
        The files sent with it, by name: a relative path as the document writes it
        (``"textures/skin.png"``) or a bare file name; a ``uri`` is looked up as it is
        (percent-decoded), then by its last part.
    what:
        How errors name the document.

    Raises
    ------
    ParseError
        For a document that is not a JSON glTF, a buffer whose file was not sent (naming
        it), an absolute or parent path, an address, a damaged data URI, or a file shorter
        than the buffer's ``byteLength``.
    """
    try:
        document = json.loads(data)
    except (ValueError, RecursionError):
        raise ParseError(f"{what} is not a JSON glTF document") from None
    if not isinstance(document, dict):
        raise ParseError(f"{what} is not a JSON glTF document")
    chunk = bytearray()
    starts: list[int] = []
    for i, buffer in enumerate(_list(document, "buffers")):
        if not isinstance(buffer, dict):
            raise ParseError(f"{what}: buffer {i} is not an object")
        length = buffer.get("byteLength")
        if not isinstance(length, int) or length < 0:
            raise ParseError(f"{what}: buffer {i} has no valid byteLength")
        uri = buffer.get("uri")
        content = b"" if uri is None else _content(uri, resources, f"{what}: buffer {i}")
        if uri is not None and len(content) < length:
            raise ParseError(
                f"{what}: buffer {i} ({_shown(uri)}) holds {len(content)} bytes, "
                f"fewer than its byteLength {length}"
            )
        starts.append(_append(chunk, content[:length]))
    views = _list(document, "bufferViews")
    for i, view in enumerate(views):
        index = view.get("buffer") if isinstance(view, dict) else None
        if not isinstance(index, int) or not 0 <= index < len(starts):
            raise ParseError(f"{what}: bufferView {i} names no buffer of the file")
        offset = view.get("byteOffset", 0)
        view["buffer"], view["byteOffset"] = (
            0,
            starts[index] + (offset if isinstance(offset, int) else 0),
        )
    for i, image in enumerate(_list(document, "images")):
        uri = image.get("uri") if isinstance(image, dict) else None
        if uri is None:
            continue
        name = _path(uri, f"{what}: image {i}") if _external(uri) else None
        if name is not None and _lookup(name, resources) is None:
            content, mime = PLACEHOLDER_PNG, "image/png"
        else:
            content = _content(uri, resources, f"{what}: image {i}")
            mime = image.get("mimeType") or _image_type(uri)
        start = _append(chunk, content)
        views.append({"buffer": 0, "byteOffset": start, "byteLength": len(content)})
        del image["uri"]
        image["bufferView"], image["mimeType"] = len(views) - 1, mime
    if views:
        document["bufferViews"] = views
    if starts or views:
        document["buffers"] = [{"byteLength": len(chunk)}]
    return _glb(document, bytes(chunk))


def _list(document: dict[str, Any], key: str) -> list[Any]:
    value = document.get(key)
    return value if isinstance(value, list) else []


def _external(uri: Any) -> bool:
    return isinstance(uri, str) and not uri.startswith("data:")


def _shown(uri: Any) -> str:
    return repr(str(uri)[:80])


def _append(chunk: bytearray, content: bytes) -> int:
    chunk.extend(b"\0" * (-len(chunk) % ALIGN))
    start = len(chunk)
    chunk.extend(content)
    return start


def _path(uri: str, what: str) -> str:
    """A relative ``uri``'s path, percent-decoded; an address, an absolute path or one
    leaving the document's folder is refused (the service reads no disk and no network)."""
    parts = urlsplit(uri)
    path = unquote(parts.path).replace("\\", "/")
    pure = PurePosixPath(path)
    if parts.scheme or parts.netloc or pure.is_absolute() or ".." in pure.parts or not path:
        raise ParseError(
            f"{what} refers to {_shown(uri)}, an address or a path outside the document's "
            "folder: only files sent with it (by relative name) are read"
        )
    return str(pure)


def _lookup(path: str, resources: Mapping[str, bytes]) -> bytes | None:
    if path in resources:
        return resources[path]
    return resources.get(PurePosixPath(path).name)


def _content(uri: Any, resources: Mapping[str, bytes], what: str) -> bytes:
    if not isinstance(uri, str):
        raise ParseError(f"{what}: its uri is not a string")
    if uri.startswith("data:"):
        return decode_data_uri(uri, what)
    path = _path(uri, what)
    content = _lookup(path, resources)
    if content is None:
        raise ParseError(
            f"{what} is in {_shown(uri)}, which was not sent: send it with the .gltf (another "
            "'file' field), or a .glb"
        )
    return content


def decode_data_uri(uri: str, what: str) -> bytes:
    """The bytes of a base64 ``data:`` URI (``what`` names it in errors)."""
    header, _, payload = uri.partition(",")
    if not header.endswith(";base64"):
        raise ParseError(f"{what}: only base64 data URIs are supported")
    try:
        return base64.b64decode(payload, validate=True)
    except (binascii.Error, ValueError):
        raise ParseError(f"{what}: the base64 data URI is damaged") from None


def _image_type(uri: str) -> str:
    if uri.startswith("data:"):
        return uri[5:].partition(";")[0] or "image/png"
    return IMAGE_TYPES.get(PurePosixPath(urlsplit(uri).path).suffix.lower(), "image/png")


def _glb(document: dict[str, Any], binary: bytes) -> bytes:
    text = json.dumps(document, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text
    if binary:
        binary += b"\0" * (-len(binary) % 4)
        chunks += struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return struct.pack("<4sII", GLB_MAGIC, 2, 12 + len(chunks)) + chunks
