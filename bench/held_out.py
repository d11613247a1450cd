"""Files nobody here has seen, judged as the dev sets are (issue 20, docs/skeletons.md
"a held-out set").

A held-out set is real files from repositories in none of the dev sets, collected by hand
(not in this repository: their licences are unknown) into one folder with a manifest,
``manifest.tsv``, one tab-separated row a file: its path in the folder, the source
repository, its path there, the commit, what the service should do with it (``human``,
``nonhuman``, ``partial-body``, ``malformed``, ``rig-only``) and a note.
``bench/held_out_manifest.tsv`` is the set of 2026-11-28. Each file is read, mapped and
described as the service does and judged:

* ``human``: stored, finite vectors, the canonical-body checks of
  ``tests/motion/canonical.py`` (upright, rigid limbs, sides, knees, proportions), and no
  mapped side against what the joint's name says (``LeftArm`` mapped as the right arm);
* ``rig-only``: refused (a 4xx) or stored with the still-pose warning;
* anything else: refused with a 4xx; a crash (a 500 in the service) is never as expected.

    .venv/bin/python bench/held_out.py FOLDER [--json OUT] [FILES...]
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.errors import InvalidInput, MocapError
from app.importer.workers import MAX_RESOURCE_BYTES
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.formats.gltf_pack import pack_gltf, refers_to_files
from app.motion.mapping.runs import _ARM, _COMPARABLE, _LEG
from app.motion.model import Motion, ParseLimits
from app.motion.pipeline import analyse
from app.motion.skeleton_map import CANONICAL_INDEX
from app.services.parser_pool import parse_scene
from app.services.upload_files import FolderFiles
from tests.motion.canonical import LIMBS, check_canonical_body

FORMATS = (".bvh", ".asf", ".fbx", ".glb", ".gltf", ".vrma")
_LEFT = re.compile(r"(^|[^a-z])(l|left)([^a-z]|$)", re.IGNORECASE)
_RIGHT = re.compile(r"(^|[^a-z])(r|right)([^a-z]|$)", re.IGNORECASE)


def named_side(name: str) -> str | None:
    """``"l"`` or ``"r"`` where a joint's name says a side (``LeftArm``, ``l_hip``,
    ``Bip01 R Thigh``, ``mixamorig:LeftLeg``), else None."""
    words = re.sub(r"([a-z])([A-Z])", r"\1_\2", name)
    left, right = bool(_LEFT.search(words)), bool(_RIGHT.search(words))
    if left == right:
        return None
    return "l" if left else "r"


def read(path: Path) -> Motion:
    """The clip the service would store from ``path`` (an ASF with the first AMC beside it
    whose name starts with its stem; a ``.gltf`` with the files it names from its folder, as
    ``mocap-index import`` reads them)."""
    suffix = path.suffix.lower()
    if suffix == ".bvh":
        return read_bvh(path.read_bytes())
    if suffix == ".asf":
        amc = next(path.parent.glob(path.stem + "*.amc"), None)
        if amc is None:  # what the upload route answers (app/services/uploads.py), a 422
            raise InvalidInput("field 'motion': the .asf skeleton must come with an .amc 'motion'")
        return read_asf_amc(path.read_bytes(), amc.read_bytes())
    data = path.read_bytes()
    if suffix == ".gltf" and refers_to_files(data):
        files = FolderFiles(path.parent, MAX_RESOURCE_BYTES)
        data = pack_gltf(data, files, what=path.name)
    kind = "fbx" if suffix == ".fbx" else "gltf"
    return parse_scene(kind, data, None, ParseLimits()).motion


def part_ratios(body: Any) -> list[str]:
    """What is wrong with the mapped limbs' upper : lower part ratios (medians over the
    frames), each side: "l leg 0.28 (a person's 1.00)" when further from a person's than the
    mapper's own "comparable parts" allow (a factor of two, ``app/motion/mapping/runs.py``).
    The canonical checks pass a leg mapped one joint high whose parts are rigid (the foot for
    the shin gives 2.2 x, a thigh from a connector at the pelvis 0.28 x); its proportions do
    not."""
    found = []
    for kind in (_LEG, _ARM):
        for side in "lr":
            top, middle, end = (
                body.positions[:, CANONICAL_INDEX[f"{side}_{part}"]] for part in kind.parts
            )
            upper = float(np.median(np.linalg.norm(middle - top, axis=-1)))
            lower = float(np.median(np.linalg.norm(end - middle, axis=-1)))
            off = math.log(max(upper, 1e-12) / max(lower, 1e-12) / kind.upper)
            if abs(off) > _COMPARABLE:
                found.append(
                    f"{side} {kind.what} {upper / max(lower, 1e-12):.2f} "
                    f"(a person's {kind.upper:.2f})"
                )
    return found


def own_stretch(motion: Motion, body: Any) -> dict[tuple[str, str, str], np.ndarray] | None:
    """Per limb (side, upper, lower), ``(F,)`` the length of the file's own bones from the
    upper joint down to the lower along the chain, frame by frame, where the file writes a
    translation for every joint (a Kinect solver's, whose bones stretch): the limb's length
    follows it when the joints are right; a wrong joint, two bones apart, adds the bend
    between them. None where the offsets are fixed."""
    if motion.local_translations is None or body.mapping is None:
        return None
    parents = motion.skeleton.parents
    frames = len(body.positions)
    lead = body.lead_in_frames
    out = {}
    for side in "lr":
        for upper, lower in LIMBS:
            top = int(body.mapping.joints[CANONICAL_INDEX[f"{side}_{upper}"]])
            joint = int(body.mapping.joints[CANONICAL_INDEX[f"{side}_{lower}"]])
            chain = []
            while joint != top and joint >= 0:
                chain.append(joint)
                joint = int(parents[joint])
            if joint != top:
                return None  # not one chain: nothing to compare
            bones = np.linalg.norm(motion.local_translations[lead : lead + frames, chain], axis=2)
            out[(side, upper, lower)] = bones.sum(axis=1)
    return out


def judge(path: Path, expected: str) -> dict[str, object]:
    """One file's outcome (``refused`` / ``accepted`` / ``crash``), why, and whether that
    is what ``expected`` asks (see the module docstring)."""
    row: dict[str, object] = {"expected": expected}
    try:
        motion = read(path)
        analysis = analyse(motion)
    except MocapError as error:
        row.update(outcome="refused", why=str(error)[:300], ok=expected != "human")
        return row
    except Exception as error:  # a crash (a 500 in the service) is what this looks for
        row.update(outcome="crash", why=f"{type(error).__name__}: {error}"[:300], ok=False)
        return row
    warnings = [str(w) for w in analysis.warnings]
    problems = []
    if not all(np.isfinite(v).all() for v in analysis.descriptors.values()):
        problems.append("a descriptor is not finite")
    try:
        check_canonical_body(
            analysis.body, path.name, upright=None, stretch=own_stretch(motion, analysis.body)
        )
    except AssertionError as error:
        problems.append(f"canonical: {error}"[:200])
    problems += part_ratios(analysis.body)
    joints = analysis.joint_mapping.get("joints", {})
    against = [
        f"{canonical}<-{place['joint']}"
        for canonical, place in (joints.items() if isinstance(joints, dict) else ())
        if canonical[:2] in ("l_", "r_")
        and named_side(str(place["joint"])) not in (None, canonical[0])
    ]
    if against:
        problems.append("sides against the names: " + ", ".join(against[:6]))
    if expected == "human":
        ok = not problems
    else:
        ok = expected == "rig-only" and any("still pose" in w for w in warnings)
    row.update(outcome="accepted", family=analysis.skeleton_family, problems=problems, ok=ok)
    row["warnings"] = warnings
    return row


def manifest(folder: Path) -> dict[str, str]:
    """Path in ``folder`` -> expected outcome, from its ``manifest.tsv``."""
    table = {}
    path = folder / "manifest.tsv"
    for line in path.read_text().splitlines() if path.is_file() else []:
        cells = line.split("\t")
        if len(cells) >= 5 and not line.startswith("#"):
            table[cells[0]] = cells[4]
    return table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("files", nargs="*", type=Path)
    parser.add_argument("--json", type=Path, help="write every file's outcome here")
    args = parser.parse_args()
    folder = args.folder.resolve()
    expected = manifest(folder)
    files = [f.resolve() for f in args.files] or sorted(
        p for p in folder.rglob("*") if p.suffix.lower() in FORMATS
    )
    rows = {}
    for path in files:
        name = str(path.relative_to(folder))
        row = rows[name] = judge(path, expected.get(name, "human"))
        detail = row.get("why") or "; ".join(row.get("problems", [])) or row.get("family")  # type: ignore[arg-type]
        print(f"{'ok ' if row['ok'] else 'BAD'} {row['outcome']:8} {name}: {detail}", flush=True)
    print(f"\n{sum(bool(r['ok']) for r in rows.values())} of {len(rows)} as expected")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=str))


if __name__ == "__main__":
    main()
