"""glTF's binary data (app/motion/formats/gltf_data.py): sparse accessors, as the glTF 2.0
specification describes them (a base of zeros or of a buffer view, values substituted at
strictly increasing indices). Files built from a real BVH fixture's motion."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from app.errors import ParseError
from app.motion.formats import read_bvh
from app.motion.formats.gltf import read_gltf
from tests.conftest import FIXTURES_DIR
from tests.motion.gltf_builder import gltf_parts, pack_glb


@pytest.fixture(scope="module")
def motion():
    return read_bvh((FIXTURES_DIR / "cmu_mb_02_01_first41.bvh").read_bytes())


def _append(document: dict[str, Any], binary: bytes, data: bytes) -> tuple[bytes, int]:
    """``binary`` with ``data`` appended (4-byte aligned) in a new buffer view."""
    binary += bytes(-len(binary) % 4)
    document["bufferViews"].append(
        {"buffer": 0, "byteOffset": len(binary), "byteLength": len(data)}
    )
    binary += data
    document["buffers"][0]["byteLength"] = len(binary)
    return binary, len(document["bufferViews"]) - 1


def _sparse(
    document: dict[str, Any], binary: bytes, accessor: int, rows: np.ndarray, values: np.ndarray
) -> bytes:
    """Give ``accessor`` a sparse part: ``values`` ``(R, C)`` at ``rows`` ``(R,)``."""
    binary, indices_view = _append(document, binary, rows.astype("<u2").tobytes())
    binary, values_view = _append(document, binary, values.astype("<f4").tobytes())
    document["accessors"][accessor]["sparse"] = {
        "count": len(rows),
        "indices": {"bufferView": indices_view, "componentType": 5123},
        "values": {"bufferView": values_view},
    }
    return binary


def _translation(document: dict[str, Any], binary: bytes) -> tuple[int, np.ndarray]:
    """The root translation channel's accessor and its values ``(F, 3)``."""
    sampler = document["animations"][0]["samplers"][-1]
    accessor = document["accessors"][sampler["output"]]
    view = document["bufferViews"][accessor["bufferView"]]
    start = view["byteOffset"]
    values = np.frombuffer(binary, "<f4", accessor["count"] * 3, start).reshape(-1, 3)
    return sampler["output"], values.copy()


def test_sparse_values_over_zeros_read_as_the_dense_accessor(motion) -> None:
    document, binary = gltf_parts(motion)
    accessor, values = _translation(document, binary)
    values[::3] = 0.0  # rows of zeros stay out of the sparse part, as a writer leaves them
    start = document["bufferViews"][document["accessors"][accessor]["bufferView"]]["byteOffset"]
    dense = binary[:start] + values.astype("<f4").tobytes() + binary[start + values.nbytes :]
    expected, _, _ = read_gltf(pack_glb(document, dense))
    rows = np.flatnonzero(np.any(values != 0.0, axis=1))
    del document["accessors"][accessor]["bufferView"]
    binary = _sparse(document, binary, accessor, rows, values[rows])
    sparse, _, _ = read_gltf(pack_glb(document, binary))
    np.testing.assert_array_equal(sparse.root_translation, expected.root_translation)
    np.testing.assert_array_equal(sparse.local_rotations, expected.local_rotations)


def test_sparse_values_replace_rows_of_a_buffer_view(motion) -> None:
    document, binary = gltf_parts(motion)
    plain, _, _ = read_gltf(pack_glb(document, binary))
    accessor, values = _translation(document, binary)
    rows = np.arange(1, len(values), 4)
    view = document["bufferViews"][document["accessors"][accessor]["bufferView"]]
    damaged = values.copy()
    damaged[rows] = 99.0  # the base says otherwise where the sparse part substitutes
    start = view["byteOffset"]
    binary = binary[:start] + damaged.astype("<f4").tobytes() + binary[start + damaged.nbytes :]
    binary = _sparse(document, binary, accessor, rows, values[rows])
    sparse, _, _ = read_gltf(pack_glb(document, binary))
    np.testing.assert_array_equal(sparse.root_translation, plain.root_translation)
    np.testing.assert_array_equal(sparse.local_rotations, plain.local_rotations)


@pytest.mark.parametrize(
    "rows, problem",
    [([3, 2, 5], "increase strictly"), ([0, 1, 10_000], "below its count")],
)
def test_sparse_indices_out_of_order_or_range_are_refused(motion, rows, problem) -> None:
    document, binary = gltf_parts(motion)
    accessor, values = _translation(document, binary)
    binary = _sparse(document, binary, accessor, np.asarray(rows), values[:3])
    with pytest.raises(ParseError, match=f"accessor {accessor}: sparse indices must") as error:
        read_gltf(pack_glb(document, binary))
    assert problem in str(error.value)


def test_sparse_values_past_their_view_are_refused(motion) -> None:
    document, binary = gltf_parts(motion)
    accessor, values = _translation(document, binary)
    binary = _sparse(document, binary, accessor, np.arange(4), values[:4])
    document["accessors"][accessor]["sparse"]["count"] = 40  # more values than stored
    document["accessors"][accessor]["sparse"]["indices"]["componentType"] = 5121
    with pytest.raises(ParseError, match="reads past the end"):
        read_gltf(pack_glb(document, binary))
