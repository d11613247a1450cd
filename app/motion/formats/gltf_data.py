"""glTF 2.0's containers and binary data: the GLB chunks, the JSON document, buffers
(embedded only; views compressed with ``EXT_meshopt_compression`` decoded) and accessors
(strided, normalised, sparse), as the glTF 2.0 specification
describes them. Every offset and length is checked against the bytes there are: the files
are untrusted input (read in a parser worker, :mod:`app.services.parser_pool`)."""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.errors import LimitExceeded, ParseError
from app.motion.formats.gltf_pack import decode_data_uri
from app.motion.formats.gltf_schema import (
    check_accessor,
    check_buffer_view,
    check_document,
    sizes_of,
)
from app.motion.formats.meshopt import compressed_view, decode_view, is_fallback_buffer
from app.motion.formats.text import refuse_lfs_pointer

GLB_MAGIC = b"glTF"
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_DTYPES = {5120: "i1", 5121: "u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_NORMALISE = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0}
UPLOAD_GLB = (
    "send the files it names with it (further 'file' fields) or a .glb (binary glTF) with "
    "everything embedded"
)


def load_document(data: bytes) -> tuple[Any, bytes | None, dict[int, str]]:
    """The JSON document, the GLB binary chunk (``None`` for JSON glTF) and the animations
    that break the specification's rules, emptied (index -> what is wrong; see
    :func:`~app.motion.formats.gltf_schema.check_document`)."""
    blob = None
    refuse_lfs_pointer(data, "glTF file")
    try:
        if data[:4] == GLB_MAGIC:
            text, blob = _glb_chunks(data)
        else:
            text = data.decode("utf-8-sig")
        document = json.loads(text)
    except UnicodeDecodeError:
        raise ParseError("not a glTF file (neither a GLB nor UTF-8 JSON)") from None
    except json.JSONDecodeError as error:
        raise ParseError(f"not a glTF file: JSON error at line {error.lineno}") from None
    except RecursionError:
        raise LimitExceeded("the glTF JSON is nested too deeply") from None
    if not isinstance(document, dict) or not isinstance(document.get("asset"), dict):
        raise ParseError("not a glTF file (no 'asset' object)")
    version = str(document["asset"].get("version", ""))
    if not version.startswith("2."):
        raise ParseError(f"glTF version {version!r}: only glTF 2.0 is read")
    for key in ("nodes", "accessors", "bufferViews", "buffers", "animations", "skins"):
        value = document.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise ParseError(f"not a usable glTF file ('{key}' is not a list of objects)")
    broken = check_document(document)
    return _Doc(document), blob, broken


class _Doc:
    """Attribute access to a glTF JSON object (``doc.nodes``, ``node.name``; None if absent).

    A key's value is wrapped once and kept on the instance (``__getattr__`` is then no longer
    called for it): reading ``doc.accessors[i]`` for each of a file's thousands of accessors
    wrapped the whole list each time, the better part of reading a large glTF.
    """

    def __init__(self, raw: dict[str, Any]) -> None:
        self._raw = raw

    @property
    def raw(self) -> dict[str, Any]:
        """The JSON object itself (a property: found before any key of the object)."""
        return self._raw

    def __getattr__(self, key: str) -> Any:
        if key.startswith("__"):  # copy, pickle and friends ask for these
            raise AttributeError(key)
        value = self._raw.get(key)
        if isinstance(value, dict) and key not in ("extensions", "extras"):
            value = _Doc(value)
        elif isinstance(value, list):
            value = [_Doc(v) if isinstance(v, dict) else v for v in value]
        self.__dict__[key] = value
        return value

    def replace(self, key: str, value: Any) -> None:
        """Sets ``key`` of the JSON object (and forgets its wrapped value)."""
        self._raw[key] = value
        self.__dict__.pop(key, None)


def _glb_chunks(data: bytes) -> tuple[str, bytes | None]:
    """The JSON text and binary chunk of a GLB container (glTF 2.0 spec, "GLB File Format")."""
    if len(data) < 20:
        raise ParseError("the GLB file is truncated")
    version, length = struct.unpack("<II", data[4:12])
    if version != 2:
        raise ParseError(f"GLB container version {version}: only version 2 is read")
    if length > len(data):
        raise ParseError(f"the GLB file is truncated ({len(data)} of {length} bytes)")
    offset, text, blob = 12, None, None
    while offset + 8 <= length:
        size, kind = struct.unpack("<I4s", data[offset : offset + 8])
        chunk = data[offset + 8 : offset + 8 + size]
        if len(chunk) != size:
            raise ParseError("a GLB chunk runs past the end of the file")
        if kind == b"JSON" and text is None:
            text = chunk.decode("utf-8-sig")
        elif kind == b"BIN\x00" and blob is None:
            blob = chunk
        offset += 8 + size + (-size % 4)
    if text is None:
        raise ParseError("the GLB file has no JSON chunk")
    return text, blob


@dataclass
class Buffers:
    """A file's buffers' bytes, and its compressed buffer views once decoded (by index)."""

    data: list[bytes]
    decoded_views: dict[int, bytes] = field(default_factory=dict)


def buffers_of(document: Any, blob: bytes | None) -> Buffers:
    """Every buffer's bytes; refuses a buffer ``uri`` that is not a ``data:`` URI. A buffer
    without data that compressed views decode into (``EXT_meshopt_compression``'s fallback)
    holds no bytes."""
    out = []
    for i, buffer in enumerate(document.buffers or []):
        uri = getattr(buffer, "uri", None)
        if uri is None:
            if i != 0 or blob is None:
                if is_fallback_buffer(buffer, document.extensionsRequired):
                    out.append(b"")
                    continue
                raise ParseError(f"buffer {i} has no data (no uri and no GLB binary chunk)")
            out.append(blob)
            continue
        out.append(data_uri_bytes(uri, f"buffer {i}"))
    # Images (textures) are never read, wherever their ``uri`` points: a .gltf whose buffers
    # are embedded but whose textures lie beside it is read as the skeleton and motion it is.
    return Buffers(out)


def _check_uri(uri: Any, what: str) -> None:
    if not isinstance(uri, str) or not uri.startswith("data:"):
        shown = str(uri)[:80]
        raise ParseError(
            f"{what} refers to an external file or address ({shown!r}), which is never "
            f"read; {UPLOAD_GLB}"
        )


def data_uri_bytes(uri: Any, what: str) -> bytes:
    _check_uri(uri, what)
    return decode_data_uri(uri, what)


def accessor_values(document: Any, buffers: Buffers, index: Any) -> np.ndarray:
    """``(count, components)`` float64 of accessor ``index`` (normalised integers scaled;
    sparse substitutions applied over the dense values, or over zeros without a view)."""
    accessors = document.accessors or []
    if not isinstance(index, int) or not 0 <= index < len(accessors):
        raise ParseError(f"accessor {index!r} does not exist")
    accessor = accessors[index]
    check_accessor(accessor.raw, sizes_of(document.raw), index)
    components = _COMPONENTS.get(accessor.type)
    dtype = _DTYPES.get(accessor.componentType)
    count = accessor.count
    if components is None or dtype is None:  # (count: gltf_schema.check_accessor)
        raise ParseError(f"accessor {index}: unknown type or component type")
    what = f"accessor {index}"
    if accessor.bufferView is None:
        values = np.zeros((count, components))
    else:
        raw = _view_items(
            document,
            buffers,
            accessor.bufferView,
            accessor.byteOffset,
            count,
            dtype,
            components,
            what,
        )
        values = raw.astype(np.float64)
    sparse = getattr(accessor, "sparse", None)
    if sparse is not None:
        _apply_sparse(document, buffers, sparse, values, dtype, components, what)
    if accessor.normalized and accessor.componentType in _NORMALISE:
        values = np.maximum(values / _NORMALISE.get(accessor.componentType, 1.0), -1.0)
    return values


def _view_items(
    document: Any,
    buffers: Buffers,
    view_index: Any,
    byte_offset: Any,
    count: int,
    dtype: str,
    components: int,
    what: str,
) -> np.ndarray:
    """``(count, components)`` items of ``dtype`` read from buffer view ``view_index``
    (its stride honoured), every byte checked to lie inside the view and its buffer."""
    view = document.bufferViews[view_index]  # an index of them: gltf_schema.check_accessor
    check_buffer_view(view.raw, sizes_of(document.raw), view_index)
    data = _view_bytes(view, view_index, buffers, what)
    item = np.dtype(dtype).itemsize * components
    compressed = compressed_view(view)
    if compressed is not None:  # decoded: the view's own bytes, from 0
        stride = compressed.get("byteStride") or item
        start = byte_offset or 0
        view_end = len(data)
    else:
        stride = view.byteStride or item
        start = (view.byteOffset or 0) + (byte_offset or 0)
        view_end = (view.byteOffset or 0) + (view.byteLength or 0)
    end_needed = start + (stride * (count - 1) + item if count else 0)
    if start < 0 or stride < item or end_needed > min(len(data), view_end):
        raise ParseError(f"{what}: reads past the end of its buffer")
    if count == 0:
        return np.zeros((0, components), dtype=dtype)
    raw = np.lib.stride_tricks.as_strided(
        np.frombuffer(data, dtype=np.uint8, count=end_needed - start, offset=start),
        shape=(count, item),
        strides=(stride, 1),
    )
    return np.ascontiguousarray(raw).view(dtype).reshape(count, components)


def _view_bytes(view: Any, view_index: int, buffers: Buffers, what: str) -> bytes:
    """The bytes a buffer view's offsets point into: its buffer's, or for a compressed view
    its own decoded bytes (decoded once a file)."""
    compressed = compressed_view(view)
    if compressed is None:  # ``buffer`` an index of the buffers: check_buffer_view
        return buffers.data[view.buffer]
    decoded = buffers.decoded_views.get(view_index)
    if decoded is None:
        source = compressed.get("buffer")
        if not isinstance(source, int) or not 0 <= source < len(buffers.data):
            raise ParseError(f"{what}: compressed buffer {source!r} does not exist")
        where = f"{what} (buffer view {view_index})"
        decoded = decode_view(compressed, buffers.data[source], where)
        buffers.decoded_views[view_index] = decoded
    return decoded


def _apply_sparse(
    document: Any,
    buffers: Buffers,
    sparse: Any,
    values: np.ndarray,
    dtype: str,
    components: int,
    what: str,
) -> None:
    """Substitute a sparse accessor's values into ``values`` ``(count, components)`` in
    place. The spec: ``sparse.count`` indices (unsigned byte, short or int, strictly
    increasing, each below the accessor's count) and as many tightly packed values."""
    count = getattr(sparse, "count", None)
    indices, substitutes = getattr(sparse, "indices", None), getattr(sparse, "values", None)
    if not isinstance(count, int) or count < 1 or indices is None or substitutes is None:
        raise ParseError(f"{what}: its sparse part needs a count of at least 1, indices and values")
    index_type = getattr(indices, "componentType", None)
    if index_type not in (5121, 5123, 5125):
        raise ParseError(f"{what}: sparse indices must be unsigned bytes, shorts or ints")
    where = _view_items(
        document,
        buffers,
        indices.bufferView,
        indices.byteOffset,
        count,
        _DTYPES[index_type],
        1,
        f"{what} (sparse indices)",
    )[:, 0].astype(np.int64)
    if np.any(np.diff(where) <= 0):
        raise ParseError(f"{what}: sparse indices must increase strictly")
    if where[-1] >= len(values):  # unsigned and increasing: the last is the largest
        raise ParseError(f"{what}: sparse indices must stay below its count {len(values)}")
    values[where] = _view_items(
        document,
        buffers,
        substitutes.bufferView,
        substitutes.byteOffset,
        count,
        dtype,
        components,
        f"{what} (sparse values)",
    )
