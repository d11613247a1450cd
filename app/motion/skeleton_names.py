"""Joint names as hints: which body part and which side a name says, compared whole.

A name is split into words: at separators (``_ - . : |`` and spaces), where a lower-case
letter meets a capital (``lShldrBend`` -> ``l shldr bend``, ``LeftUpLeg``), before the last
capital of a run of capitals followed by lower case (``LHipJoint`` -> ``l hip joint``),
between letters and digits (``Toe0``, ``Bip01``), and between cased letters and scripts
without case (``左足IK`` -> ``左足 ik``); full-width forms count as their ASCII twins. Numbers
say nothing and go (``spine_01``, ``DEF-forearm.L.001``, ``Bip01``), and so do the words of
:data:`NEUTRAL_WORDS`, which name what kind of bone a joint is without changing the part
(``lShldrBend``, ``DEF-upper_arm.L``, ``knee_jnt_l``). A name with a word of
:data:`NOT_THE_JOINT` (``upperarm_twist_01_l``, ``ik_foot_l``, ``MCH-forearm.L``) names a
bone beside or inside the part, never the part's joint: it hints no part (its side still
counts). Tool prefixes are whatever leading words make the rest a known name
(``mixamorig:LeftArm``, ``f_avg_L_Hip``, ``Bip01 L Thigh``, ``J_Bip_L_UpperArm``), so no list
of exporters is needed. What remains must *equal* a side form of a known base word
(``leftupleg``, ``lupleg``, ``uplegl``, ``uplegleft``, ``左足``). Substrings never count:
``LeftUpLegHelper`` says nothing.

The mapper (:mod:`app.motion.skeleton_map`) uses these hints only to break ties that the
skeleton's structure and rest-pose geometry leave open, and to name sides.
"""

from __future__ import annotations

import functools
import re
import unicodedata
from dataclasses import dataclass

_SEPARATORS = re.compile(r"[\s_\-.:|]+")

# Body part -> base words, best first. A base may hint more than one part (``shoulder`` is the
# clavicle in MotionBuilder rigs and the upper arm in 3ds Max and Kinect ones): its rank in
# each list says how strongly. The last words of each list are the Japanese standard bone
# names of MikuMikuDance models (PMX), which VRM models and MMD-derived exports keep: 肩 is
# the clavicle, 腕 the upper arm, 足 the thigh, つま先 the toe.
SIDED_PARTS: dict[str, tuple[str, ...]] = {
    "clavicle": ("clavicle", "collar", "shoulder", "肩"),
    "shoulder": (
        "arm",
        "upperarm",
        "uparm",
        "uarm",  # OptiTrack Motive: LUArm (below LShoulder, its clavicle)
        "shldr",
        "humerus",
        "shoulder",
        "bicep",
        "腕",
    ),
    "elbow": (
        "forearm",
        "lowerarm",
        "lowarm",
        "loarm",
        "elbow",
        "radius",
        "ulna",
        "farm",  # OptiTrack Motive: LFArm
        "ひじ",
        "肘",
    ),
    "wrist": ("wrist", "hand", "手首"),
    "hip": ("upleg", "upperleg", "thigh", "femur", "hip", "uleg", "足"),
    "knee": (
        "leg",
        "lowerleg",
        "lowleg",
        "loleg",
        "shin",
        "knee",
        "tibia",
        "calf",
        "lleg",
        "ひざ",
        "膝",
    ),
    # "ankle" before "foot": most rigs call the ankle joint the foot, but where a chain has
    # both words (SMPL's L_Ankle -> L_Foot, Kinect's AnkleLeft -> FootLeft) the foot is the
    # ball of the foot below it.
    "ankle": ("ankle", "foot", "足首"),
    "toe": ("toebase", "toe", "toes", "ball", "つま先", "爪先"),
}
UNSIDED_PARTS: dict[str, tuple[str, ...]] = {
    "pelvis": ("hips", "hip", "pelvis", "root", "下半身"),
    # DAZ Genesis 3/8 writes the part first: neckLower, neckUpper.
    "neck": ("lowerneck", "neck", "upperneck", "necklower", "neckupper", "首"),
    "head": ("head", "頭"),
}
ARM_PARTS = frozenset({"clavicle", "shoulder", "elbow", "wrist"})
LEG_PARTS = frozenset({"hip", "knee", "ankle", "toe"})

# Side words. Read glued to a base word at either end of the name (``lhip``, ``uplegl``,
# ``左足``, ``腰キャンセル左``) when the rest is a known base; alone, when they are a word of
# their own (the one-letter and short forms) or stand at an end of the name (the rest).
# English and its short forms (``Bip01 L Thigh``, ``LeftArm``, ``lt_arm``); 左/右 (Japanese
# and Chinese: MMD models, VRM's Japanese names); German links/rechts; French
# gauche/droite; Spanish izquierda/derecha (and -o forms); Italian sinistra/destra;
# Portuguese esquerda/direita: the words animators of those languages name sides with.
_SIDE_WORDS = {
    "left": "l",
    "right": "r",
    "l": "l",
    "r": "r",
    "lt": "l",
    "rt": "r",
    "lft": "l",
    "rgt": "r",
    "左": "l",
    "右": "r",
    "links": "l",
    "rechts": "r",
    "gauche": "l",
    "droite": "r",
    "izquierda": "l",
    "derecha": "r",
    "izquierdo": "l",
    "derecho": "r",
    "sinistra": "l",
    "destra": "r",
    "sinistro": "l",
    "destro": "r",
    "esquerda": "l",
    "direita": "r",
    "esquerdo": "l",
    "direito": "r",
}
# Side words read at an end of a name that says no known part (``LeftFooBar``, ``左ダミー``):
# long enough, or a script's own side character, not to be the start of another word.
_END_SIDE_WORDS = {w: s for w, s in _SIDE_WORDS.items() if len(w) >= 4 or not w.isascii()}

# Words that say what kind of bone a joint is, not which: DAZ Genesis 3/8's "Bend" bone is the
# joint (its "Twist" bone follows it); Blender Rigify's DEF- (deforming) and ORG- (original)
# bones are copies of one bone; "_jnt", "_bn", "_bone" are Maya and game-engine naming
# suffixes for a joint.
NEUTRAL_WORDS = frozenset({"bend", "def", "org", "jnt", "bn", "bone"})
# Words of bones that are not the part's joint: twist and roll bones inside a limb bone (Unreal
# "upperarm_twist_01_l", Maya/MotionBuilder "ForeArmRoll", 3ds Max Biped "ForeTwist"), IK/FK
# controls, poles and targets (Unreal "ik_foot_l"), Rigify's MCH- (mechanism) bones, helper
# and corrective bones, and the nubs and ends a writer adds past a leaf (Biped "Toe0Nub").
NOT_THE_JOINT = frozenset(
    {
        "twist",
        "roll",
        "ik",
        "fk",
        "pole",
        "target",
        "mch",
        "ctrl",
        "control",
        "helper",
        "aux",
        "corrective",
        "nub",
        "end",
        "tip",
        "dummy",
    }
)
# Tails of words that can name a part: a side, prefixes of no use beyond this many words.
_MAX_WORDS = 6


@dataclass(frozen=True)
class NameHint:
    """What one joint name says: ``side`` ``"l"``/``"r"``/None and part -> rank (0 = best)."""

    side: str | None
    parts: dict[str, int]


def normalise_name(name: str) -> str:
    """Lower-case ``name`` without namespace or separators: ``mixamorig:LeftArm`` ->
    ``leftarm``, ``UpperLeg_L`` -> ``upperlegl``."""
    lowered = name.strip().lower()
    if ":" in lowered:
        lowered = lowered.rsplit(":", 1)[1]
    return _SEPARATORS.sub("", lowered)


# A word: a run of capitals before a capitalised word (``LHip`` -> ``L``), a capitalised or
# lower-case word, a run of capitals, a number, or a run of letters of a script without
# ASCII case (kana, kanji).
_WORD = re.compile(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+|[0-9]+|[^\W\d_A-Za-z]+")


def words(name: str) -> list[str]:
    """``name`` split into lower-case words (see the module docstring)."""
    return [w.lower() for w in _WORD.findall(unicodedata.normalize("NFKC", name))]


# A trailing "joint" set off by a separator is a tag saying the node is a joint, as "_jnt"
# is (ARKit's body skeleton names every joint so: ``left_upLeg_joint``, ``hips_joint``);
# glued to the word before it, it is part of the bone's own name (CMU's ``LHipJoint`` is the
# bone from the pelvis to the hip, not the hip) and stays.
_JOINT_TAG = re.compile(r"(?<=\w)[\s_\-.:|]+joint$", re.IGNORECASE)


def _name_words(name: str) -> list[str]:
    """The words of ``name`` that may say what it is: a separated ``joint`` tag dropped."""
    return words(_JOINT_TAG.sub("", name))


def _part_words(all_words: list[str]) -> list[str]:
    """The words that may name a part: numbers and neutral words dropped."""
    return [w for w in all_words if not w.isdecimal() and w not in NEUTRAL_WORDS]


def _index(table: dict[str, tuple[str, ...]]) -> dict[str, dict[str, int]]:
    """Base word -> part -> rank, for one lookup per reading."""
    out: dict[str, dict[str, int]] = {}
    for part, bases in table.items():
        for rank, base in enumerate(bases):
            out.setdefault(base, {}).setdefault(part, rank)
    return out


_SIDED_INDEX = _index(SIDED_PARTS)
_UNSIDED_INDEX = _index(UNSIDED_PARTS)
_SIDE_LENGTHS = sorted({len(word) for word in _SIDE_WORDS}, reverse=True)


def _split_side(compact: str) -> list[tuple[str, str]]:
    """Every (side, base) reading of ``compact`` with a side word at one end (the longest
    side word first)."""
    readings = []
    for size in _SIDE_LENGTHS:
        if len(compact) > size:
            if compact[:size] in _SIDE_WORDS:
                readings.append((_SIDE_WORDS[compact[:size]], compact[size:]))
            if compact[-size:] in _SIDE_WORDS:
                readings.append((_SIDE_WORDS[compact[-size:]], compact[:-size]))
    return readings


def name_hint(name: str) -> NameHint:
    """The side and body parts ``name`` names (empty when it names none)."""
    return _read(name)[0] if len(name) <= _CACHED_LENGTH else _hint(_name_words(name))


def name_side(name: str) -> str | None:
    """``"l"``/``"r"`` when ``name`` says a side in a whole-name form (any word), else None.

    ``lfemur``, ``LeftFooBar``, ``foo.L``, ``Bip01 R Bar``, ``lShldrTwist``, ``左ダミー``: a side
    word standing at either end of the name or as a word of its own.
    """
    if len(name) <= _CACHED_LENGTH:
        return _read(name)[1]
    all_words = _name_words(name)
    return _side(all_words, _hint(all_words))


# Rigs repeat the same few hundred names; every rig's first clip reads all of its names.
_CACHED_LENGTH = 200


@functools.lru_cache(maxsize=4096)
def _read(name: str) -> tuple[NameHint, str | None]:
    all_words = _name_words(name)
    hint = _hint(all_words)
    return hint, _side(all_words, hint)


def _hint(all_words: list[str]) -> NameHint:
    if any(w in NOT_THE_JOINT for w in all_words):
        return NameHint(None, {})
    tokens = _part_words(all_words)
    # Longest tail of tokens first: leading tokens are tool prefixes only when the rest is a
    # known name on its own.
    for start in range(max(len(tokens) - _MAX_WORDS, 0), len(tokens)):
        compact = "".join(tokens[start:])
        for side, base in _split_side(compact):
            parts = _SIDED_INDEX.get(base)
            if parts:
                return NameHint(side, dict(parts))
        parts = _UNSIDED_INDEX.get(compact)
        if parts:
            # The pelvis, neck and head are on the body's midline, one of each: a name that
            # says a side (``left_hand_root``) qualifies a limb's part by the word, and names
            # none of them.
            if any(token in _SIDE_WORDS for token in tokens[:start]):
                return NameHint(None, {})
            return NameHint(None, dict(parts))
    return NameHint(None, {})


def _side(all_words: list[str], hint: NameHint) -> str | None:
    tokens = _part_words(all_words)
    for token in tokens:
        if token in _SIDE_WORDS:
            return _SIDE_WORDS[token]
    if hint.side is not None:
        return hint.side
    compact = "".join(tokens)
    for word, side in _END_SIDE_WORDS.items():
        if compact.startswith(word) or compact.endswith(word):
            return side
    return None
