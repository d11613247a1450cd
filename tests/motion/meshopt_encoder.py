"""An ``EXT_meshopt_compression`` encoder for tests, written from the extension's
specification (Appendix A, mode 0; Appendix B, the quaternion and exponential filters) the
way an encoder may choose: each group of 16 deltas in the smallest of its four forms. The
decoder under test (app/motion/formats/meshopt.py) must read back what this writes."""

from __future__ import annotations

import numpy as np

GROUP = 16


def encode_attributes(elements: np.ndarray) -> bytes:
    """A mode-0 stream of ``elements`` ``(count, stride)`` uint8 (baseline: the first)."""
    count, stride = elements.shape
    block = min((8192 // stride) & ~(GROUP - 1), 256)
    out = bytearray([0xA0])
    last = elements[0].astype(np.int64)
    for start in range(0, count, block):
        chunk = elements[start : start + block].astype(np.int64)
        aligned = -(-len(chunk) // GROUP) * GROUP
        for byte in range(stride):
            before = np.concatenate([[last[byte]], chunk[:-1, byte]])
            delta = (chunk[:, byte] - before) & 0xFF
            zigzag = np.where(delta & 0x80, ~(delta << 1), delta << 1) & 0xFF
            out += _encode_bytes(np.concatenate([zigzag, np.zeros(aligned - len(chunk), int)]))
        last = chunk[-1]
    out += bytes(max(stride, 32) - stride) + elements[0].tobytes()  # the tail: the baseline
    return bytes(out)


def _encode_bytes(zigzag: np.ndarray) -> bytes:
    groups = zigzag.reshape(-1, GROUP)
    header = bytearray((len(groups) + 3) // 4)
    body = bytearray()
    for index, group in enumerate(groups):
        sizes = {
            1: 4 + int(np.sum(group >= 3)),
            2: 8 + int(np.sum(group >= 15)),
            3: GROUP,
        }
        kind = 0 if not group.any() else min(sizes, key=lambda k: (sizes[k], k))
        header[index // 4] |= kind << ((index % 4) * 2)
        if kind == 3:
            body += bytes(int(v) for v in group)
        elif kind:
            bits = 2 if kind == 1 else 4
            sentinel = (1 << bits) - 1
            codes = np.minimum(group, sentinel)
            for start in range(0, GROUP, 8 // bits):
                value = 0
                for code in codes[start : start + 8 // bits]:
                    value = (value << bits) | int(code)  # the first in the top bits
                body.append(value)
            body += bytes(int(v) for v in group if v >= sentinel)
    return bytes(header + body)


def quaternion_filter(quaternions: np.ndarray) -> np.ndarray:
    """``(N, 4)`` unit ``(x, y, z, w)`` as the quaternion filter's input ``(N, 8)`` uint8
    (16-bit components, the largest dropped, its index in the low bits of 1.0)."""
    q = np.asarray(quaternions, dtype=np.float64)
    largest = np.argmax(np.abs(q), axis=1)
    rows = np.arange(len(q))
    q = q * np.where(q[rows, largest] < 0, -1.0, 1.0)[:, None]
    one = 32767
    out = np.empty((len(q), 4), dtype="<i2")
    for k in range(3):
        out[:, k] = np.round(q[rows, (largest + 1 + k) % 4] * np.sqrt(2.0) * one)
    out[:, 3] = (one & ~3) | largest
    return out.view(np.uint8)


def exponential_filter(values: np.ndarray) -> np.ndarray:
    """``(N, C)`` floats as the exponential filter's input ``(N, 4 C)`` uint8 (each with its
    own exponent, a 24-bit mantissa)."""
    mantissa, exponent = np.frexp(np.asarray(values, dtype=np.float64))
    m = np.clip(np.round(mantissa * (1 << 22)), -(1 << 23) + 1, (1 << 23) - 1).astype(np.int64)
    e = np.where(m == 0, 0, exponent - 22).astype(np.int64)
    words = ((e & 0xFF) << 24) | (m & 0xFFFFFF)
    return words.astype(np.uint32).view(np.uint8).reshape(len(values), -1)
