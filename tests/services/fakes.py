"""A stand-in for the motion core, so storage, search and API semantics can be tested with
vectors chosen by the test.

A fake "motion file" is JSON: ``{"posture": [x, y, z], "kinetic": [a, b]}`` (a missing
descriptor gets a vector derived from the bytes). For ASF/AMC the JSON is the motion part.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence

import numpy as np

from app.errors import ParseError
from app.motion.model import ParseLimits
from app.services.describe import Description, DescriptorInfo, check_vectors
from app.services.uploads import BVH, Upload

FAKE_DESCRIPTORS = {
    "posture": DescriptorInfo("posture", 3, 1, "fake posture"),
    "kinetic": DescriptorInfo("kinetic", 2, 1, "fake kinetic"),
}


def fake_motion(
    posture: Sequence[float] | None = None, kinetic: Sequence[float] | None = None, **extra: object
) -> bytes:
    content: dict[str, object] = dict(extra)
    if posture is not None:
        content["posture"] = list(posture)
    if kinetic is not None:
        content["kinetic"] = list(kinetic)
    return json.dumps(content).encode()


class FakeDescriber:
    def __init__(self, descriptors: Mapping[str, DescriptorInfo] = FAKE_DESCRIPTORS) -> None:
        self._descriptors = dict(descriptors)
        self.calls = 0

    @property
    def descriptors(self) -> Mapping[str, DescriptorInfo]:
        return self._descriptors

    def describe(
        self, upload: Upload, limits: ParseLimits, *, only: Sequence[str] | None = None
    ) -> Description:
        self.calls += 1
        part = upload.parts[0] if upload.format == BVH else upload.part("motion")
        try:
            content = json.loads(part.data)
        except ValueError as exc:
            raise ParseError(f"not JSON: {exc}", line=1, source=part.filename) from None
        if not isinstance(content, dict):
            raise ParseError("expected a JSON object", line=1, source=part.filename)
        seed = int(hashlib.sha256(part.data).hexdigest()[:8], 16)
        rng = np.random.default_rng(seed)
        vectors = {}
        for name in only or list(self._descriptors):
            info = self._descriptors[name]
            given = content.get(name)
            vectors[name] = (
                np.asarray(given, np.float32)
                if given is not None
                else rng.normal(size=info.dimension)
            )
        frames = int(content.get("frames", 10))
        return Description(
            frame_count=frames,
            frame_time=1 / 30,
            duration=frames / 30,
            joint_count=20,
            skeleton_family="fake",
            lead_in_frames=0,
            vectors=check_vectors(vectors, self._descriptors),
        )
