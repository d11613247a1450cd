"""Write the corpus of hostile uploads: ``python -m tests.hostile.make_corpus``.

Every case is a small file (or an ASF + AMC pair) made from the real fixtures in
``tests/fixtures`` by one deliberate fault, with the answer the service must give: status,
error code and a fragment of the message. The small files are written to ``corpus/`` and the
table to ``expected.json`` (both committed); the big cases (a 10 MB line, 100,000 joints,
nesting 10,000 deep, a memory bomb...) come from :func:`big_cases` at test time, written into
a temporary directory, so the repository stays small.

The generator is deterministic: running it again rewrites the same bytes.

Beside it, ``found.json`` and ``found/`` keep every failure the upload fuzz suite
(``tests/hardening/test_upload_fuzz.py``) ever found, as it was found: :func:`record_found`
adds one, nothing rewrites them, and both that suite and this one replay them
(:func:`load_cases` reads either table).
"""

from __future__ import annotations

import gzip
import io
import json
import random
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
TESTS = HERE.parent
CORPUS = HERE / "corpus"
EXPECTED = HERE / "expected.json"
FOUND = HERE / "found.json"
FOUND_DIR = HERE / "found"
FIXTURES = TESTS / "fixtures"

BVH_FIXTURE = FIXTURES / "cmu_mb_02_01_first41.bvh"
ASF_FIXTURE = FIXTURES / "cmu_02.asf"
AMC_FIXTURE = FIXTURES / "cmu_02_01_first40.amc"
FBX_FIXTURE = FIXTURES / "ufbx_maya_human_ik_7400_binary.fbx"


@dataclass(frozen=True)
class Case:
    """One hostile upload and the answer it must get.

    ``parts`` maps the upload field (``file``, ``skeleton``, ``motion``) to ``(file name as
    uploaded, bytes)``.
    """

    name: str
    why: str
    parts: dict[str, tuple[str, bytes]] = field(repr=False)
    status: int  # 0: no fixed answer, only the fuzz suite's rules (a fuzzer's find)
    error: str
    detail: str  # a fragment the message must contain
    xfail: str = ""  # a known bug still open: why (the test is marked xfail, strict)


def base_bvh(frames: int = 5) -> str:
    """The real CMU MotionBuilder fixture cut to its first ``frames`` frames (LF line ends)."""
    text = BVH_FIXTURE.read_text().replace("\r\n", "\n")
    header, rest = text.split("MOTION\n", 1)
    lines = rest.split("\n")
    frame_lines = lines[2 : 2 + frames]
    return (
        f"{header}MOTION\nFrames: {frames}\nFrame Time: .0083333\n" + "\n".join(frame_lines) + "\n"
    )


def base_amc(frames: int = 3) -> str:
    """The real CMU AMC fixture cut to its first ``frames`` frames."""
    lines = AMC_FIXTURE.read_text().replace("\r\n", "\n").split("\n")
    out: list[str] = []
    count = 0
    for line in lines:
        if re.fullmatch(r"\d+", line.strip()):
            count += 1
            if count > frames:
                break
        out.append(line)
    return "\n".join(out) + "\n"


def _frame_line(text: str, index: int = 0) -> tuple[int, list[str]]:
    lines = text.split("\n")
    first = lines.index("MOTION") + 3
    return first + index, lines


def _edit_frame_value(text: str, value: str, *, frame: int = 1, column: int = 4) -> str:
    number, lines = _frame_line(text, frame)
    values = lines[number].split()
    values[column] = value
    lines[number] = " ".join(values)
    return "\n".join(lines)


def _bvh(name: str, text: str | bytes) -> dict[str, tuple[str, bytes]]:
    return {"file": (name, text.encode() if isinstance(text, str) else text)}


def _pair(asf: str | bytes, amc: str | bytes) -> dict[str, tuple[str, bytes]]:
    def raw(value: str | bytes) -> bytes:
        return value.encode() if isinstance(value, str) else value

    return {"skeleton": ("subject.asf", raw(asf)), "motion": ("trial.amc", raw(amc))}


def small_cases() -> list[Case]:
    """The committed corpus: every file here is a few kilobytes at most."""
    bvh = base_bvh()
    asf = ASF_FIXTURE.read_text().replace("\r\n", "\n")
    amc = base_amc()
    rng = random.Random(6)
    garbage = bytes(rng.randrange(256) for _ in range(4096))
    high_bytes = bytes(rng.randrange(0x80, 0x100) for _ in range(2048))
    hierarchy, motion = bvh.split("MOTION\n", 1)
    cut_hierarchy = hierarchy[: len(hierarchy) // 2]
    number, lines = _frame_line(bvh, 2)
    truncated_motion = "\n".join(lines[:number]) + "\n" + lines[number][: len(lines[number]) // 2]
    few = "\n".join([*lines[:number], " ".join(lines[number].split()[:-5]), *lines[number + 1 :]])
    many = "\n".join([*lines[:number], lines[number] + " 1 2 3", *lines[number + 1 :]])
    zip_buffer = io.BytesIO()
    with zipfile.ZipFile(zip_buffer, "w") as archive:
        archive.writestr(zipfile.ZipInfo("walk.bvh", date_time=(2026, 1, 1, 0, 0, 0)), bvh)

    def frames(value: str) -> str:
        return re.sub(r"Frames: \d+", f"Frames: {value}", bvh)

    def frame_time(value: str) -> str:
        return bvh.replace("Frame Time: .0083333", f"Frame Time: {value}")

    P, L, I = "parse_error", "limit_exceeded", "invalid_input"  # noqa: E741
    U = "unsupported_media_type"
    cases = [
        Case("empty", "no bytes at all", _bvh("empty.bvh", b""), 422, I, "is empty"),
        Case("whitespace", "only blank lines", _bvh("blank.bvh", " \n\t\n"), 422, P, "empty"),
        Case("binary_garbage", "random bytes", _bvh("noise.bvh", garbage), 422, P, "binary"),
        Case(
            "not_utf8",
            # Read as another code page since a text in another encoding was accepted: the
            # bytes are then no BVH.
            "bytes >= 0x80 only",
            _bvh("high.bvh", high_bytes),
            422,
            P,
            "not a BVH file",
        ),
        Case(
            "latin1_name",
            "a joint name in Latin-1",
            _bvh("latin1.bvh", bvh.replace("LeftUpLeg", "LeftUpLég").encode("latin-1")),
            201,
            "",
            "not UTF-8",
        ),
        Case(
            "utf16",
            "UTF-16 with a byte-order mark",
            _bvh("utf16.bvh", bvh.encode("utf-16")),
            201,
            "",
            "UTF-16",
        ),
        Case(
            "truncated_hierarchy",
            "cut in the middle of the hierarchy",
            _bvh("cut.bvh", cut_hierarchy),
            422,
            P,
            "truncated",
        ),
        Case(
            "no_motion",
            "a hierarchy and no MOTION block: a rig",
            _bvh("nomotion.bvh", hierarchy),
            422,
            "no_animation",
            "no MOTION section",
        ),
        Case(
            "truncated_motion",
            "cut in the middle of a frame line",
            _bvh("cut.bvh", truncated_motion),
            422,
            P,
            "values",
        ),
        Case("too_few_values", "a frame line 5 short", _bvh("few.bvh", few), 422, P, "expected"),
        Case("too_many_values", "a frame line 3 long", _bvh("many.bvh", many), 422, P, "more"),
        Case(
            "nan",
            # Accepted since #10: nan is a missing value (pose estimators write it), filled
            # in from the neighbouring frames with a warning. inf stays damage.
            "nan in a frame",
            _bvh("nan.bvh", _edit_frame_value(bvh, "nan")),
            201,
            "",
            "filled in",
        ),
        Case(
            "inf",
            "-inf in a frame",
            _bvh("inf.bvh", _edit_frame_value(bvh, "-inf")),
            422,
            P,
            "not finite",
        ),
        Case(
            "overflow",
            "1e309 overflows a double",
            _bvh("big.bvh", _edit_frame_value(bvh, "1e309")),
            422,
            P,
            "not finite",
        ),
        Case(
            "sentinel_1e308",
            "1e308 (finite) for the root's position in one frame: no pose, and past float32 "
            "in the descriptors; refused alike by upload and both searches",
            _bvh("sentinel.bvh", _edit_frame_value(bvh, "1e308", frame=2, column=0)),
            422,
            P,
            "not a pose",
        ),
        Case(
            "sentinel_1e30_last_frame_but_one",
            "1e30 for the root's height in the frame before the last",
            _bvh("sentinel30.bvh", _edit_frame_value(bvh, "-1e30", frame=3, column=1)),
            422,
            P,
            "not a pose",
        ),
        Case(
            "frame_time_tiny",
            "Frame Time: 1e-300 (every step a speed past float32)",
            _bvh("ttiny.bvh", frame_time("1e-300")),
            422,
            P,
            "absurd",
        ),
        Case(
            "not_a_number",
            "a word among the numbers",
            _bvh("word.bvh", _edit_frame_value(bvh, "twelve")),
            422,
            P,
            "not a number",
        ),
        Case(
            "nan_offset",
            "nan in an OFFSET",
            _bvh("offset.bvh", bvh.replace("OFFSET 2.59720 -7.13576", "OFFSET nan -7.13576")),
            422,
            P,
            "not a finite number",
        ),
        Case(
            "frames_zero",
            "Frames: 0: a rig",
            _bvh("f0.bvh", frames("0")),
            422,
            "no_animation",
            "rig with no animation",
        ),
        Case("frames_negative", "Frames: -3", _bvh("fm3.bvh", frames("-3")), 422, P, "at least 1"),
        Case("frames_more", "Frames: 7 of 5", _bvh("f7.bvh", frames("7")), 422, P, "says 7"),
        # Accepted since #10: Frames: is a claim; lines beyond it are ignored with a warning.
        Case("frames_fewer", "Frames: 3 of 5", _bvh("f3.bvh", frames("3")), 201, "", "ignored"),
        Case(
            "frames_absurd",
            "Frames: 10**30",
            _bvh("fbig.bvh", frames("1" + "0" * 30)),
            422,
            L,
            "limit",
        ),
        Case("frames_word", "Frames: many", _bvh("fw.bvh", frames("many")), 422, P, "whole"),
        Case(
            "frame_time_zero",
            "Frame Time: 0",
            _bvh("t0.bvh", frame_time("0")),
            422,
            P,
            "greater than 0",
        ),
        Case(
            "frame_time_negative",
            "Frame Time: -0.01",
            _bvh("tneg.bvh", frame_time("-0.01")),
            422,
            P,
            "greater than 0",
        ),
        Case(
            "frame_time_absurd",
            "Frame Time: 1e6",
            _bvh("tbig.bvh", frame_time("1e6")),
            422,
            P,
            "absurd",
        ),
        Case(
            "frame_time_nan",
            "Frame Time: nan",
            _bvh("tnan.bvh", frame_time("nan")),
            422,
            P,
            "finite",
        ),
        Case(
            "channels_count",
            "CHANNELS 6 with three names",
            _bvh(
                "ch.bvh",
                bvh.replace(
                    "CHANNELS 3 Zrotation Yrotation Xrotation", "CHANNELS 6 Zrotation Yrotation", 1
                ),
            ),
            422,
            P,
            "CHANNELS says 6",
        ),
        Case(
            "unknown_channel",
            "Wrotation",
            _bvh(
                "wrot.bvh",
                bvh.replace("CHANNELS 3 Zrotation Yrotation Xrotation", "CHANNELS 3 Z Y Wrot", 1),
            ),
            422,
            P,
            "unknown channel",
        ),
        Case(
            "duplicate_joint",
            "two joints called LeftLeg",
            _bvh("dup.bvh", bvh.replace("JOINT LeftFoot", "JOINT LeftLeg", 1)),
            422,
            P,
            "duplicate joint name",
        ),
        Case(
            "second_root",
            # Two skeletons are read since multi-person files were (the largest); frames
            # for one of them are too short for both.
            "two ROOTs, frame lines for one",
            _bvh(
                "roots.bvh", hierarchy + hierarchy.replace("HIERARCHY\n", "") + "MOTION\n" + motion
            ),
            422,
            P,
            "one per channel",
        ),
        Case(
            "unmappable",
            # Joint names no longer decide (a rig called x0, x1... maps by its structure);
            # a skeleton without any shape does.
            "a valid file whose OFFSETs are all 0: no body shape to map",
            _bvh("flat.bvh", re.sub(r"OFFSET[^\n]*", "OFFSET 0 0 0", bvh)),
            422,
            "unmappable_skeleton",
            "every OFFSET is 0",
        ),
        Case(
            "gzip_file",
            "a gzip-compressed BVH",
            {"file": ("walk.bvh.gz", gzip.compress(bvh.encode(), mtime=0))},
            415,
            U,
            ".bvh",
        ),
        Case(
            "gzip_disguised",
            "gzip bytes named .bvh",
            _bvh("walk.bvh", gzip.compress(bvh.encode(), mtime=0)),
            422,
            P,
            "",
        ),
        Case(
            "zip_file",
            "a ZIP archive",
            {"file": ("walk.zip", zip_buffer.getvalue())},
            415,
            U,
            "expected a .bvh",
        ),
        Case(
            "wrong_extension",
            "a BVH named .txt",
            {"file": ("walk.txt", bvh.encode())},
            415,
            U,
            "expected a .bvh",
        ),
        Case(
            "amc_unknown_bone",
            "an AMC naming a bone the ASF lacks",
            _pair(asf, amc.replace("lowerback", "tail", 1)),
            422,
            P,
            "not in the ASF",
        ),
        Case(
            "amc_missing_bone",
            "an AMC frame without a bone",
            _pair(asf, re.sub(r"\nhead [^\n]*", "", amc, count=1)),
            422,
            P,
            "no values for bone",
        ),
        Case(
            "amc_nan",
            "nan in an AMC frame",
            _pair(asf, amc.replace("lowerback 7.86573", "lowerback nan", 1)),
            422,
            P,
            "not a finite number",
        ),
        Case(
            "asf_unknown_unit",
            "angle in grads",
            _pair(asf.replace("angle deg", "angle grad"), amc),
            422,
            P,
            "unknown angle unit",
        ),
        Case(
            "asf_unknown_units_keyword",
            "a length in furlongs",
            _pair(asf.replace("length 0.45", "furlong 0.45"), amc),
            422,
            P,
            "unknown :units keyword",
        ),
        Case(
            "asf_zero_length_unit",
            ":units length 0",
            _pair(asf.replace("length 0.45", "length 0"), amc),
            422,
            P,
            "greater than 0",
        ),
        Case(
            "asf_cycle",
            "a hierarchy with a cycle",
            _pair(asf.replace("lhipjoint lfemur", "lhipjoint lfemur\n  lfemur lhipjoint", 1), amc),
            422,
            P,
            "",
        ),
        Case(
            "asf_as_bvh",
            "an ASF sent as the BVH file",
            _bvh("skeleton.bvh", asf),
            422,
            P,
            "",
        ),
        Case(
            "swapped_pair",
            "the AMC sent as the skeleton and the ASF as the motion",
            {"skeleton": ("a.asf", amc.encode()), "motion": ("b.amc", asf.encode())},
            422,
            P,
            "skeleton",
        ),
    ]
    return cases + scene_cases()


def scene_cases() -> list[Case]:
    """Damaged FBX and glTF files (read in the parser workers): garbage, truncation, flipped
    bytes, non-finite numbers, references to other files, no skeleton, no animation."""

    import numpy as np

    from app.motion.formats import read_bvh
    from tests.motion.gltf_builder import gltf_parts, pack_glb

    P = "parse_error"
    rng = random.Random(12)
    fbx = FBX_FIXTURE.read_bytes()
    motion = read_bvh(base_bvh(3))
    document, binary = gltf_parts(motion)
    glb = pack_glb(document, binary)

    def flipped(data: bytes, count: int, start: int = 0) -> bytes:
        out = bytearray(data)
        for _ in range(count):
            i = rng.randrange(start, len(out))
            out[i] ^= 1 << rng.randrange(8)
        return bytes(out)

    def with_buffer(uri: str) -> bytes:
        changed = json.loads(json.dumps(document))
        changed["buffers"][0]["uri"] = uri
        return json.dumps(changed).encode()

    values = np.frombuffer(binary, dtype=np.float32).copy()
    values[-3] = np.inf
    huge = json.loads(json.dumps(document))
    huge["accessors"][1]["count"] = 1_000_000_000
    return [
        Case(
            "fbx_garbage",
            "random bytes named .fbx",
            {"file": ("a.fbx", garbage_bytes(rng))},
            422,
            P,
            "a.fbx",
        ),
        Case(
            "fbx_truncated",
            "the first 4 kB of a binary FBX",
            {"file": ("t.fbx", fbx[:4096])},
            422,
            P,
            "t.fbx",
        ),
        Case(
            "fbx_header_flipped",
            "a binary FBX's first 4 kB with 40 bits flipped",
            {"file": ("f.fbx", flipped(fbx[:4096], 40))},
            422,
            P,
            "f.fbx",
        ),
        Case(
            "fbx_ascii_garbage",
            "an ASCII FBX header then nonsense",
            {"file": ("a.fbx", b"; FBX 7.4.0 project file\n{{{ ::: }}}\n\x01\x02" * 50)},
            422,
            P,
            "a.fbx",
        ),
        Case(
            "glb_garbage",
            "random bytes after a GLB magic",
            {"file": ("g.glb", b"glTF\x02\x00\x00\x00" + garbage_bytes(rng))},
            422,
            P,
            "g.glb",
        ),
        Case(
            "glb_truncated",
            "half a GLB",
            {"file": ("t.glb", glb[: len(glb) // 2])},
            422,
            P,
            "truncated",
        ),
        Case(
            "glb_bad_json",
            "a GLB whose JSON chunk is random bytes",
            {"file": ("j.glb", pack_glb_raw(garbage_bytes(rng, 400), binary))},
            422,
            P,
            "j.glb",
        ),
        Case(
            "glb_inf",
            "an animated translation of +inf",
            {"file": ("i.glb", pack_glb(document, values.tobytes()))},
            422,
            P,
            "non-finite",
        ),
        Case(
            "glb_no_skeleton",
            "no skin, and an animation of morph weights only (no node turns or moves)",
            {"file": ("n.glb", pack_glb(_weights_only(dict(document, skins=[])), binary))},
            422,
            P,
            "no skeleton",
        ),
        Case(
            "glb_no_animation",
            "a skin but no animation: a rig",
            {"file": ("s.glb", pack_glb(dict(document, animations=[]), binary))},
            422,
            "no_animation",
            "rig with no animation",
        ),
        Case(
            "glb_huge_accessor",
            "an accessor claiming a billion values",
            {"file": ("h.glb", pack_glb(huge, binary))},
            422,
            P,
            "past the end",
        ),
        Case(
            "gltf_relative_uri",
            "a .gltf whose buffer is a file beside it",
            {"file": ("r.gltf", with_buffer("walk.bin"))},
            422,
            P,
            "which was not sent",
        ),
        Case(
            "gltf_parent_uri",
            "a .gltf whose buffer is ../ outside its folder",
            {"file": ("p.gltf", with_buffer("../../etc/passwd"))},
            422,
            P,
            "outside the document's folder",
        ),
        Case(
            "gltf_absolute_uri",
            "a .gltf whose buffer is an absolute path",
            {"file": ("a.gltf", with_buffer("/etc/passwd"))},
            422,
            P,
            "outside the document's folder",
        ),
        Case(
            "gltf_http_uri",
            "a .gltf whose buffer is on the network",
            {"file": ("h.gltf", with_buffer("http://127.0.0.1:9/a.bin"))},
            422,
            P,
            "outside the document's folder",
        ),
        Case(
            "gltf_bad_base64",
            "a data URI that is not base64",
            {"file": ("b.gltf", with_buffer("data:application/octet-stream;base64,@@@"))},
            422,
            P,
            "base64",
        ),
        Case(
            "vrma_not_json",
            "a .vrma that is a text file",
            {"file": ("v.vrma", b"hello" * 100)},
            422,
            P,
            "v.vrma",
        ),
        Case(
            "gltf_embedded_ok_but_version_1",
            "a glTF 1.0 document",
            {"file": ("o.gltf", json.dumps({"asset": {"version": "1.0"}}).encode())},
            422,
            P,
            "2.0",
        ),
    ]


def pack_glb_raw(json_chunk: bytes, binary: bytes) -> bytes:
    """A GLB container around any bytes as its JSON chunk."""
    import struct

    chunks = struct.pack("<I4s", len(json_chunk), b"JSON") + json_chunk
    chunks += struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def garbage_bytes(rng: random.Random, size: int = 4096) -> bytes:
    return bytes(rng.randrange(256) for _ in range(size))


def _deep_bvh(depth: int) -> str:
    parts = ["HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n"]
    parts += [f"JOINT j{i}\n{{\nOFFSET 0 1 0\nCHANNELS 1 Xrotation\n" for i in range(depth)]
    parts += ["}\n" * (depth + 1), "MOTION\nFrames: 1\nFrame Time: 0.01\n"]
    parts.append(" ".join(["0"] * (depth + 3)) + "\n")
    return "".join(parts)


def _wide_bvh(joints: int, *, frames: int = 1, channels: bool = True) -> str:
    """A root with ``joints - 1`` children; with ``channels=False`` only the root has one."""
    parts = ["HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 1 Xrotation\n"]
    child = "CHANNELS 1 Xrotation\n" if channels else ""
    parts += [f"JOINT j{i}\n{{\nOFFSET 0 1 0\n{child}}}\n" for i in range(joints - 1)]
    parts.append(f"}}\nMOTION\nFrames: {frames}\nFrame Time: 0.01\n")
    values = joints if channels else 1
    parts.append((" ".join(["0"] * values) + "\n") * frames)
    return "".join(parts)


def big_cases() -> list[Case]:
    """Hostile files too big to commit; built in memory (each under the 50 MB upload limit)."""
    bvh = base_bvh()
    asf = ASF_FIXTURE.read_text().replace("\r\n", "\n")
    amc = base_amc()
    number, lines = _frame_line(bvh, 0)
    ten_mb = "0 " * 5_000_000
    long_frame = "\n".join([*lines[:number], ten_mb, *lines[number + 1 :]])
    long_hierarchy = bvh.replace("JOINT LeftLeg", "JOINT " + "L" * 10_000_000, 1)
    P, L = "parse_error", "limit_exceeded"
    return [
        Case(
            "nesting_10000",
            "joints nested 10,000 deep",
            _bvh("deep.bvh", _deep_bvh(10_000)),
            422,
            L,
            "nested deeper than the limit",
        ),
        Case(
            "joints_100000",
            "100,000 joints",
            _bvh("wide.bvh", _wide_bvh(100_000)),
            422,
            L,
            "more joints",
        ),
        Case(
            "line_10mb_frame",
            "a 10 MB frame line",
            _bvh("longline.bvh", long_frame),
            422,
            P,
            "more than",
        ),
        Case(
            "line_10mb_hierarchy",
            "a 10 MB joint name",
            _bvh("longname.bvh", long_hierarchy),
            422,
            P,
            "",
        ),
        Case(
            "line_10mb_no_newline",
            "10 MB without a line end",
            _bvh("oneline.bvh", "HIERARCHY ROOT " + "x" * 10_000_000),
            422,
            P,
            "",
        ),
        Case(
            "braces_1m",
            "a million opening braces",
            _bvh("braces.bvh", "HIERARCHY\n" + "{\n" * 1_000_000),
            422,
            P,
            "",
        ),
        Case(
            "memory_bomb",
            "220 joints without channels x 100,000 one-value frames (200 kB -> 1.6 GB)",
            _bvh("bomb.bvh", _wide_bvh(220, frames=100_000, channels=False)),
            422,
            L,
            "values",
        ),
        Case(
            "frames_over_limit",
            "100,001 frames (MOCAP_MAX_FRAMES is 100,000)",
            _bvh("long.bvh", _wide_bvh(2, frames=100_001)),
            422,
            L,
            "100001 frames",
        ),
        Case(
            "number_200k_digits_frame",
            "one frame value of 200,000 digits then a letter (a regex backtracked on it for "
            "22 minutes with the GIL held)",
            _bvh("digits.bvh", _edit_frame_value(bvh, "1" * 200_000 + "x")),
            422,
            P,
            "longer than 100 characters",
        ),
        Case(
            "number_30k_digits_offset",
            "an OFFSET of 30,000 digits then a letter",
            _bvh(
                "offset.bvh",
                bvh.replace("OFFSET 2.59720 -7.13576", "OFFSET " + "1" * 30_000 + "x -7.13576", 1),
            ),
            422,
            P,
            "longer than 100 characters",
        ),
        Case(
            "number_200k_digits_amc",
            "an AMC value of 200,000 digits then a letter",
            _pair(asf, amc.replace("lowerback 7.86573", "lowerback " + "1" * 200_000 + "x", 1)),
            422,
            P,
            "longer than 100 characters",
        ),
        Case(
            "amc_10mb_line",
            "an AMC bone line of 10 MB",
            _pair(asf, amc.replace("lowerback 7.86573", "lowerback 7.86573 " + ten_mb, 1)),
            422,
            P,
            "lowerback",
        ),
        Case(
            "asf_100000_bones",
            "an ASF with 100,000 bones",
            _pair(
                asf.split(":bonedata")[0]
                + ":bonedata\n"
                + "".join(
                    f"begin\nname b{i}\ndirection 0 1 0\nlength 1\naxis 0 0 0 XYZ\nend\n"
                    for i in range(100_000)
                ),
                amc,
            ),
            422,
            L,
            "more joints",
        ),
    ]


def _weights_only(document: dict[str, Any]) -> dict[str, Any]:
    """``document`` with every animation channel retargeted to morph weights: a skinless
    file whose channels turn or move no node has no skeleton (an animation without its mesh
    is the nodes it moves)."""
    animations = [
        dict(a, channels=[dict(c, target=dict(c["target"], path="weights")) for c in a["channels"]])
        for a in document["animations"]
    ]
    return dict(document, animations=animations)


def load_cases(table: Path) -> list[Case]:
    """The cases of ``table`` (``expected.json`` or ``found.json``), files read from beside it."""
    if not table.exists():
        return []
    cases = []
    for name, entry in json.loads(table.read_text()).items():
        parts = {
            role: (part["filename"], (table.parent / part["path"]).read_bytes())
            for role, part in entry["parts"].items()
        }
        cases.append(
            Case(
                name,
                entry["why"],
                parts,
                entry.get("status", 0),
                entry.get("error", ""),
                entry.get("detail", ""),
                entry.get("xfail", ""),
            )
        )
    return cases


def record_found(case: Case, found: str) -> None:
    """Keep a failure the fuzz suite found: its files in ``found/`` and an entry in
    ``found.json`` saying what went wrong (commit both; mark a parser bug someone else is
    fixing with ``"xfail": "<why>"``)."""
    FOUND_DIR.mkdir(exist_ok=True)
    table = json.loads(FOUND.read_text()) if FOUND.exists() else {}
    parts = {}
    for role, (filename, data) in case.parts.items():
        stored = f"{case.name}.{role}{Path(filename).suffix or '.bin'}"
        (FOUND_DIR / stored).write_bytes(data)
        parts[role] = {"path": f"found/{stored}", "filename": filename}
    entry: dict[str, object] = {"why": case.why, "found": found, "parts": parts}
    if case.status:
        entry.update(status=case.status, error=case.error, detail=case.detail)
    if case.xfail:
        entry["xfail"] = case.xfail
    table[case.name] = entry
    FOUND.write_text(json.dumps(table, indent=2, ensure_ascii=False) + "\n")


def write_corpus() -> None:
    """(Re)write ``corpus/`` and ``expected.json`` from :func:`small_cases`."""
    CORPUS.mkdir(exist_ok=True)
    for old in CORPUS.iterdir():
        old.unlink()
    table = {}
    for case in small_cases():
        parts = {}
        for role, (filename, data) in case.parts.items():
            stored = f"{case.name}.{role}{Path(filename).suffix or '.bin'}"
            (CORPUS / stored).write_bytes(data)
            parts[role] = {"path": f"corpus/{stored}", "filename": filename}
        table[case.name] = {
            "why": case.why,
            "parts": parts,
            "status": case.status,
            "error": case.error,
            "detail": case.detail,
        }
    EXPECTED.write_text(json.dumps(table, indent=2, ensure_ascii=False) + "\n")


if __name__ == "__main__":
    write_corpus()
    print(f"wrote {len(small_cases())} cases to {CORPUS.relative_to(TESTS.parent)}")
