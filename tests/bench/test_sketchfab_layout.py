"""``bench/sketchfab_layout.py``: a skinned GLB under Sketchfab's chain of turned and scaled
parents, with renamed nodes and a created root joint, reads as the same motion."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from app.motion.formats import read_bvh
from app.motion.formats.gltf_writer import write_glb
from app.motion.model import ParseLimits
from app.motion.pipeline import analyse
from app.services.parser_pool import parse_scene
from bench.sketchfab_layout import relaid

CMU = Path(__file__).parents[1] / "fixtures" / "cmu_mb_02_01_first41.bvh"


def test_the_layout_changes_names_and_parents_not_the_motion() -> None:
    source = write_glb(read_bvh(CMU.read_bytes()))
    plain = parse_scene("gltf", source, None, ParseLimits()).motion
    moved = parse_scene("gltf", relaid(source), None, ParseLimits()).motion
    assert set(plain.skeleton.names).isdisjoint(moved.skeleton.names)  # every node renamed
    assert any(name.startswith("GLTF_created_0_rootJoint") for name in moved.skeleton.names)
    before, after = analyse(plain).descriptors, analyse(moved).descriptors
    for name, vector in before.items():
        assert np.linalg.norm(after[name] - vector) <= 1e-6 * np.linalg.norm(vector), name
