"""Buffer views compressed with glTF's ``EXT_meshopt_compression`` (what gltfpack and
glTF-Transform's ``optimize`` write), decoded as the extension's specification describes
(KhronosGroup/glTF, ``extensions/2.0/Vendor/EXT_meshopt_compression``, Appendix A, mode 0
"attributes", and Appendix B, the filters).

Only what a skeleton and its animation use is decoded: mode 0 (keyframe times and values;
the index modes 1 and 2 hold mesh indices, which this service never reads) with the
``NONE``, ``QUATERNION`` and ``EXPONENTIAL`` filters (``OCTAHEDRAL`` holds normals). Every
read is checked against the bytes there are: the files are untrusted input.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from app.errors import ParseError

EXTENSION = "EXT_meshopt_compression"
ATTRIBUTES_HEADER = 0xA0  # mode 0, bitstream version 0
BLOCK_BYTES = 8192  # an attribute block holds at most this many bytes of elements ...
BLOCK_MAX_ELEMENTS = 256  # ... and at most this many elements
GROUP = 16  # elements whose deltas share one header entry
TAIL_MIN = 32  # the baseline element is padded to this many bytes at the stream's end


def compressed_view(view: Any) -> dict[str, Any] | None:
    """A buffer view's ``EXT_meshopt_compression`` object, or None when it is stored plain."""
    extensions = getattr(view, "extensions", None)
    found = extensions.get(EXTENSION) if isinstance(extensions, dict) else None
    return found if isinstance(found, dict) else None


def is_fallback_buffer(buffer: Any, required: Any) -> bool:
    """Whether a buffer without data is the placeholder the compressed views decode into."""
    extensions = getattr(buffer, "extensions", None)
    tagged = isinstance(extensions, dict) and isinstance(extensions.get(EXTENSION), dict)
    return tagged or (isinstance(required, list) and EXTENSION in required)


def decode_view(settings: dict[str, Any], source: bytes, what: str) -> bytes:
    """The plain bytes (``count * byteStride``) of a compressed buffer view whose extension
    object is ``settings`` and whose compressed buffer's bytes are ``source``."""
    mode = settings.get("mode", "ATTRIBUTES")
    stride, count = settings.get("byteStride"), settings.get("count")
    offset, length = settings.get("byteOffset", 0), settings.get("byteLength")
    if not all(isinstance(v, int) and v >= 0 for v in (stride, count, offset, length)):
        raise ParseError(
            f"{what}: its {EXTENSION} object lacks a valid byte stride, count, offset or length"
        )
    assert isinstance(stride, int) and isinstance(count, int)  # for the type checker
    assert isinstance(offset, int) and isinstance(length, int)
    if mode != "ATTRIBUTES":
        raise ParseError(f"{what}: {EXTENSION} mode {mode!r} holds mesh indices, not animation")
    if offset + length > len(source):
        raise ParseError(f"{what}: its compressed data runs past the end of its buffer")
    elements = decode_attributes(source[offset : offset + length], count, stride, what)
    return apply_filter(elements, str(settings.get("filter", "NONE")), what).tobytes()


def decode_attributes(data: bytes, count: int, stride: int, what: str) -> np.ndarray:
    """``(count, stride)`` uint8: the elements of a mode-0 stream (Appendix A). Each block
    stores, per byte of the element, zigzag-encoded deltas from the element before (the
    first block's from the baseline element in the tail), in groups of 16 whose two header
    bits say how: all zero, 2-bit or 4-bit with an all-ones sentinel meaning "a whole byte
    follows", or whole bytes."""
    if not 0 < stride <= 256 or stride % 4:
        raise ParseError(f"{what}: a compressed stride of {stride} bytes (must be 4-256, x4)")
    tail = max(stride, TAIL_MIN)
    if len(data) < 1 + tail:
        raise ParseError(f"{what}: the compressed data is truncated")
    if data[0] != ATTRIBUTES_HEADER:
        raise ParseError(
            f"{what}: compressed data with header 0x{data[0]:02x} (only the attribute "
            "codec's version 0, 0xa0, is read)"
        )
    end = len(data) - tail
    last = np.frombuffer(data[-stride:], dtype=np.uint8).copy()
    block_elements = min((BLOCK_BYTES // stride) & ~(GROUP - 1), BLOCK_MAX_ELEMENTS)
    # Two header bits a group of 16 at least: a count the data cannot hold is refused
    # before anything is allocated for it (a few bytes must not claim gigabytes).
    full, rest = divmod(count, block_elements)
    headers = full * -(-block_elements // (4 * GROUP)) + -(-rest // (4 * GROUP))
    if 1 + tail + stride * headers > len(data):
        raise ParseError(f"{what}: the compressed data is truncated ({count} elements claimed)")
    out = np.empty((count, stride), dtype=np.uint8)
    position, done = 1, 0
    while done < count:
        size = min(count - done, block_elements)
        for byte in range(stride):
            encoded, position = _decode_bytes(data, position, end, -(-size // GROUP) * GROUP, what)
            zigzag = encoded[:size]
            deltas = np.where(zigzag & 1, 255 - (zigzag >> 1), zigzag >> 1)
            column = (int(last[byte]) + np.cumsum(deltas, dtype=np.int64)) & 0xFF
            out[done : done + size, byte] = column
            last[byte] = column[-1]
        done += size
    if position != end:
        raise ParseError(f"{what}: the compressed data's length does not match its elements")
    return out


def _decode_bytes(
    data: bytes, position: int, end: int, size: int, what: str
) -> tuple[np.ndarray, int]:
    """``(size,)`` uint8 zigzag deltas of one byte of ``size`` elements (a multiple of 16)
    read at ``position``, and the position after them."""
    groups = size // GROUP
    header_end = position + (groups + 3) // 4
    if header_end > end:
        raise ParseError(f"{what}: the compressed data is truncated")
    header = data[position:header_end]
    position = header_end
    out = np.zeros(size, dtype=np.uint8)
    for group in range(groups):
        kind = (header[group // 4] >> ((group % 4) * 2)) & 3
        if kind == 0:
            continue  # sixteen zero deltas
        if kind == 3:
            raw = data[position : position + GROUP]
            if len(raw) != GROUP or position + GROUP > end:
                raise ParseError(f"{what}: the compressed data is truncated")
            out[group * GROUP : (group + 1) * GROUP] = np.frombuffer(raw, dtype=np.uint8)
            position += GROUP
            continue
        bits = 2 if kind == 1 else 4
        packed_end = position + GROUP * bits // 8
        if packed_end > end:
            raise ParseError(f"{what}: the compressed data is truncated")
        packed = np.frombuffer(data[position:packed_end], dtype=np.uint8)
        shifts = np.arange(8 - bits, -1, -bits, dtype=np.uint8)  # most significant first
        values = ((packed[:, None] >> shifts) & ((1 << bits) - 1)).reshape(GROUP)
        position = packed_end
        sentinels = np.flatnonzero(values == (1 << bits) - 1)
        if sentinels.size:  # each is a whole byte after the packed bits, in order
            if position + sentinels.size > end:
                raise ParseError(f"{what}: the compressed data is truncated")
            values[sentinels] = np.frombuffer(data, np.uint8, sentinels.size, position)
            position += sentinels.size
        out[group * GROUP : (group + 1) * GROUP] = values
    return out, position


def apply_filter(elements: np.ndarray, name: str, what: str) -> np.ndarray:
    """The elements ``(count, stride)`` uint8 after the named filter (Appendix B), as the
    bytes the view's accessors read."""
    count, stride = elements.shape
    if name == "NONE":
        return elements
    if name == "QUATERNION":  # three components and the largest's index, 16-bit
        if stride != 8:
            raise ParseError(f"{what}: the quaternion filter needs a stride of 8")
        raw = elements.view("<i2").reshape(count, 4)
        # The fourth component is 1.0 in K bits save its low two, the largest's index.
        one = (raw[:, 3] | 3).astype(np.float64)
        largest = raw[:, 3].astype(np.int64) & 3
        xyz = raw[:, :3] / one[:, None] * np.sqrt(0.5)
        w = np.sqrt(np.maximum(0.0, 1.0 - np.sum(xyz * xyz, axis=1)))
        quaternion = np.empty((count, 4))
        rows = np.arange(count)
        for k in range(3):
            quaternion[rows, (largest + 1 + k) % 4] = xyz[:, k]
        quaternion[rows, largest] = w
        return _normalised(quaternion, "<i2")
    if name == "EXPONENTIAL":  # 8-bit exponent and 24-bit mantissa, both signed
        if stride % 4:
            raise ParseError(
                f"{what}: the exponential filter needs a stride that is a multiple of 4"
            )
        words = elements.view("<i4").astype(np.int64)
        exponent = words >> 24
        mantissa = ((words & 0xFFFFFF) ^ 0x800000) - 0x800000  # the low 24 bits, signed
        return np.ldexp(mantissa.astype(np.float64), exponent).astype("<f4").view(np.uint8)
    if name == "OCTAHEDRAL":  # unit vectors: normals and tangents, never an animation's
        raise ParseError(f"{what}: the octahedral filter holds normals, not animation")
    raise ParseError(f"{what}: unknown {EXTENSION} filter {name!r}")


def _normalised(values: np.ndarray, kind: str) -> np.ndarray:
    """``values`` (in [-1, 1]) as signed normalised integers of ``kind``, as bytes."""
    top = float(np.iinfo(np.dtype(kind)).max)
    return np.round(np.clip(values, -1.0, 1.0) * top).astype(kind).view(np.uint8)
