"""Humanoid rigs of the industry's tools, built from their documented default hierarchies
(issue 20): game engines and animation tools here, avatars, capture systems and body models
in :mod:`tests.motion.industry_rigs_capture`. Both fill :data:`RIGS`.

Each rig is written from what the tool documents (or ships as its default skeleton), never
from a dev-set file: its joint names and tree, its typical extra bones (twist, roll, IK,
face, hair, footsteps), its rest pose (T or A), length unit and up axis, with each joint's
truth (which canonical joint it is). How sure each rig is: :data:`CERTAINTY`.
"""

from __future__ import annotations

from tests.motion.rig_building import CERTAINTY, FINGERS, RIGS, Rig, fingers, rig, sides, twists


def _unreal(version: int, *, ik_follows: bool = True) -> Rig:
    r = Rig(f"unreal{version}", pose="A", unit=100.0, z_up=True)
    r.add("root", None, "ground")
    r.add("pelvis", "root", "pelvis", "pelvis", truth="pelvis")
    spines = 5 if version == 5 else 3
    parent = "pelvis"
    for i in range(1, spines + 1):
        t = i / (spines + 1)
        place = f"pelvis@neck:{t:.3f}"
        parent = r.add(f"spine_{i:02d}", parent, place, "abdomen" if t < 0.4 else "chest")
    chest = parent
    r.add("neck_01", chest, "neck", "neck")
    neck = r.add("neck_02", "neck_01", "neck@head:0.5", "neck") if version == 5 else "neck_01"
    r.add("head", neck, "head", "head", truth="head")
    twist_count = 2 if version == 5 else 1

    def side(s: str, w: str) -> None:
        r.add(f"clavicle_{w}", chest, "clav", "s_clav", side=s)
        r.add(f"upperarm_{w}", f"clavicle_{w}", "shoulder", "s_upper", side=s, truth="s_shoulder")
        r.add(f"lowerarm_{w}", f"upperarm_{w}", "elbow", "s_fore", side=s, truth="s_elbow")
        names = [f"upperarm_twist_{i:02d}_{w}" for i in range(1, twist_count + 1)]
        twists(r, s, f"upperarm_{w}", names, "shoulder", "elbow", "s_upper")
        r.add(f"hand_{w}", f"lowerarm_{w}", "wrist", "s_hand", side=s, truth="s_wrist")
        names = [f"lowerarm_twist_{i:02d}_{w}" for i in range(1, twist_count + 1)]
        twists(r, s, f"lowerarm_{w}", names, "elbow", "wrist", "s_fore")
        fingers(
            r,
            s,
            f"hand_{w}",
            lambda f, k: (
                (f"{f}_metacarpal_{w}" if version == 5 and f != "thumb" else None)
                if k == 0
                else f"{f}_{k:02d}_{w}"
            ),
        )
        r.add(f"thigh_{w}", "pelvis", "hip", "s_thigh", side=s, truth="s_hip")
        r.add(f"calf_{w}", f"thigh_{w}", "knee", "s_shin", side=s, truth="s_knee")
        names = [f"thigh_twist_{i:02d}_{w}" for i in range(1, twist_count + 1)]
        twists(r, s, f"thigh_{w}", names, "hip", "knee", "s_thigh")
        names = [f"calf_twist_{i:02d}_{w}" for i in range(1, twist_count + 1)]
        twists(r, s, f"calf_{w}", names, "knee", "ankle", "s_shin")
        r.add(f"foot_{w}", f"calf_{w}", "ankle", "s_foot", side=s, truth="s_ankle")
        r.add(f"ball_{w}", f"foot_{w}", "ball", "s_foot", side=s)

    sides(side)
    # IK bones under the root, each on the hand or foot it controls: a trap for the mapper.
    r.add("ik_foot_root", "root", "ground")
    r.add("ik_foot_l", "ik_foot_root", "ankle", side="l", follows="foot_l" if ik_follows else None)
    r.add("ik_foot_r", "ik_foot_root", "ankle", side="r", follows="foot_r" if ik_follows else None)
    r.add("ik_hand_root", "root", "ground")
    r.add(
        "ik_hand_gun", "ik_hand_root", "wrist", side="r", follows="hand_r" if ik_follows else None
    )
    r.add("ik_hand_r", "ik_hand_gun", "wrist", side="r", follows="hand_r" if ik_follows else None)
    r.add("ik_hand_l", "ik_hand_gun", "wrist", side="l", follows="hand_l" if ik_follows else None)
    return r


@rig("sure: the UE5 Manny/Quinn skeleton's bones as the engine ships them (no corrective bones)")
def unreal5() -> Rig:
    return _unreal(5)


@rig("sure of the bones; the IK bones left at rest, as a retarget that does not bake them")
def unreal5_ik_at_rest() -> Rig:
    return _unreal(5, ik_follows=False)


@rig("sure: the UE4 Mannequin skeleton (UE4_Mannequin_Skeleton), A-pose, cm, Z up")
def unreal4() -> Rig:
    return _unreal(4)


@rig("fairly sure of names and tree (CC3/CC4 CC_Base_ rig); share and breast bones left out")
def character_creator() -> Rig:
    r = Rig("character_creator", pose="A", unit=100.0)
    r.add("CC_Base_BoneRoot", None, "ground")
    r.add("CC_Base_Hip", "CC_Base_BoneRoot", "pelvis", "pelvis", truth="pelvis")
    r.add("CC_Base_Pelvis", "CC_Base_Hip", "pelvis", "pelvis", truth="pelvis")
    r.add("CC_Base_Waist", "CC_Base_Hip", "spine", "abdomen")
    r.add("CC_Base_Spine01", "CC_Base_Waist", "spine@chest:0.5", "abdomen")
    r.add("CC_Base_Spine02", "CC_Base_Spine01", "chest", "chest")
    r.add("CC_Base_NeckTwist01", "CC_Base_Spine02", "neck", "neck")
    r.add("CC_Base_NeckTwist02", "CC_Base_NeckTwist01", "neck@head:0.5", "neck")
    r.add("CC_Base_Head", "CC_Base_NeckTwist02", "head", "head", truth="head")
    r.add("CC_Base_FacialBone", "CC_Base_Head", "head+0,0.04,0.02", "head")
    r.add("CC_Base_JawRoot", "CC_Base_FacialBone", "jaw", "head")
    r.add("CC_Base_L_Eye", "CC_Base_FacialBone", "eye", "head", side="l")
    r.add("CC_Base_R_Eye", "CC_Base_FacialBone", "eye", "head", side="r")

    def side(s: str, w: str) -> None:
        p = f"CC_Base_{w.upper()}_"
        r.add(p + "Clavicle", "CC_Base_Spine02", "clav", "s_clav", side=s)
        r.add(p + "Upperarm", p + "Clavicle", "shoulder", "s_upper", side=s, truth="s_shoulder")
        r.add(p + "Forearm", p + "Upperarm", "elbow", "s_fore", side=s, truth="s_elbow")
        twists(
            r,
            s,
            p + "Upperarm",
            [p + "UpperarmTwist01", p + "UpperarmTwist02"],
            "shoulder",
            "elbow",
            "s_upper",
        )
        r.add(p + "Hand", p + "Forearm", "wrist", "s_hand", side=s, truth="s_wrist")
        twists(
            r,
            s,
            p + "Forearm",
            [p + "ForearmTwist01", p + "ForearmTwist02"],
            "elbow",
            "wrist",
            "s_fore",
        )
        fingers(r, s, p + "Hand", lambda f, k: None if k == 0 else f"{p}{f.title()}{k}")
        r.add(p + "Thigh", "CC_Base_Pelvis", "hip", "s_thigh", side=s, truth="s_hip")
        r.add(p + "Calf", p + "Thigh", "knee", "s_shin", side=s, truth="s_knee")
        twists(
            r, s, p + "Thigh", [p + "ThighTwist01", p + "ThighTwist02"], "hip", "knee", "s_thigh"
        )
        r.add(p + "Foot", p + "Calf", "ankle", "s_foot", side=s, truth="s_ankle")
        twists(r, s, p + "Calf", [p + "CalfTwist01", p + "CalfTwist02"], "knee", "ankle", "s_shin")
        r.add(p + "ToeBase", p + "Foot", "ball", "s_foot", side=s)

    sides(side)
    return r


@rig("sure: Daz Genesis 8's bones (face bones reduced to eyes, jaw and teeth)")
def daz_genesis8() -> Rig:
    r = Rig("daz_genesis8", pose="A", unit=100.0)
    r.add("hip", None, "pelvis", "pelvis", truth="pelvis")
    r.add("pelvis", "hip", "pelvis+0,-0.02,0", "pelvis", truth="pelvis")
    r.add("abdomenLower", "hip", "spine", "abdomen")
    r.add("abdomenUpper", "abdomenLower", "spine@chest:0.5", "abdomen")
    r.add("chestLower", "abdomenUpper", "chest", "chest")
    r.add("chestUpper", "chestLower", "chest@neck:0.5", "chest")
    r.add("neckLower", "chestUpper", "neck", "neck")
    r.add("neckUpper", "neckLower", "neck@head:0.5", "neck")
    r.add("head", "neckUpper", "head", "head", truth="head")
    r.add("lEye", "head", "eye", "head", side="l")
    r.add("rEye", "head", "eye", "head", side="r")
    r.add("upperTeeth", "head", "chin+0,0.03,0", "head")
    r.add("lowerJaw", "head", "jaw", "head")

    def side(s: str, w: str) -> None:
        r.add(f"{w}Collar", "chestUpper", "clav", "s_clav", side=s)
        r.add(f"{w}ShldrBend", f"{w}Collar", "shoulder", "s_upper", side=s, truth="s_shoulder")
        r.add(f"{w}ShldrTwist", f"{w}ShldrBend", "shoulder@elbow:0.4", "s_upper", side=s)
        r.add(f"{w}ForearmBend", f"{w}ShldrTwist", "elbow", "s_fore", side=s, truth="s_elbow")
        r.add(f"{w}ForearmTwist", f"{w}ForearmBend", "elbow@wrist:0.4", "s_fore", side=s)
        r.add(f"{w}Hand", f"{w}ForearmTwist", "wrist", "s_hand", side=s, truth="s_wrist")
        names = {
            "thumb": "Thumb",
            "index": "Index",
            "middle": "Mid",
            "ring": "Ring",
            "pinky": "Pinky",
        }
        carpal = {"index": 1, "middle": 2, "ring": 3, "pinky": 4}
        fingers(
            r,
            s,
            f"{w}Hand",
            lambda f, k: (
                (f"{w}Carpal{carpal[f]}" if f in carpal else None)
                if k == 0
                else f"{w}{names[f]}{k}"
            ),
        )
        r.add(f"{w}ThighBend", "pelvis", "hip", "s_thigh", side=s, truth="s_hip")
        r.add(f"{w}ThighTwist", f"{w}ThighBend", "hip@knee:0.4", "s_thigh", side=s)
        r.add(f"{w}Shin", f"{w}ThighTwist", "knee", "s_shin", side=s, truth="s_knee")
        r.add(f"{w}Foot", f"{w}Shin", "ankle", "s_foot", side=s, truth="s_ankle")
        r.add(f"{w}Metatarsals", f"{w}Foot", "ankle@ball:0.3", "s_foot", side=s)
        r.add(f"{w}Toe", f"{w}Metatarsals", "ball", "s_foot", side=s)

    sides(side)
    return r


@rig("sure of Rigify's DEF- names and split limbs; the deform-only export's parenting is a guess")
def blender_rigify() -> Rig:
    r = Rig("blender_rigify", pose="A", unit=1.0, z_up=True, bone_axis=1)
    r.add("root", None, "ground")
    r.add("DEF-spine", "root", "pelvis", "pelvis", truth="pelvis")
    places = ["spine", "spine@chest:0.5", "chest", "neck", "neck@head:0.5", "head"]
    segs = ["abdomen", "abdomen", "chest", "neck", "neck", "head"]
    parent = "DEF-spine"
    for i, (place, seg) in enumerate(zip(places, segs, strict=True), start=1):
        parent = r.add(f"DEF-spine.{i:03d}", parent, place, seg, truth="head" if i == 6 else None)

    def side(s: str, w: str) -> None:
        w = w.upper()
        r.add(f"DEF-shoulder.{w}", "DEF-spine.003", "clav", "s_clav", side=s)
        r.add(
            f"DEF-upper_arm.{w}",
            f"DEF-shoulder.{w}",
            "shoulder",
            "s_upper",
            side=s,
            truth="s_shoulder",
        )
        r.add(
            f"DEF-upper_arm.{w}.001", f"DEF-upper_arm.{w}", "shoulder@elbow:0.5", "s_upper", side=s
        )
        r.add(
            f"DEF-forearm.{w}", f"DEF-upper_arm.{w}.001", "elbow", "s_fore", side=s, truth="s_elbow"
        )
        r.add(f"DEF-forearm.{w}.001", f"DEF-forearm.{w}", "elbow@wrist:0.5", "s_fore", side=s)
        r.add(f"DEF-hand.{w}", f"DEF-forearm.{w}.001", "wrist", "s_hand", side=s, truth="s_wrist")
        fingers(
            r,
            s,
            f"DEF-hand.{w}",
            lambda f, k: (
                (f"DEF-palm.0{FINGERS.index(f)}.{w}" if f != "thumb" else None)
                if k == 0
                else f"DEF-{'thumb' if f == 'thumb' else 'f_' + f}.0{k}.{w}"
            ),
        )
        r.add(f"DEF-pelvis.{w}", "DEF-spine", "pelvis@hip:0.7", "pelvis", side=s)
        r.add(f"DEF-thigh.{w}", "DEF-spine", "hip", "s_thigh", side=s, truth="s_hip")
        r.add(f"DEF-thigh.{w}.001", f"DEF-thigh.{w}", "hip@knee:0.5", "s_thigh", side=s)
        r.add(f"DEF-shin.{w}", f"DEF-thigh.{w}.001", "knee", "s_shin", side=s, truth="s_knee")
        r.add(f"DEF-shin.{w}.001", f"DEF-shin.{w}", "knee@ankle:0.5", "s_shin", side=s)
        r.add(f"DEF-foot.{w}", f"DEF-shin.{w}.001", "ankle", "s_foot", side=s, truth="s_ankle")
        r.add(f"DEF-toe.{w}", f"DEF-foot.{w}", "ball", "s_foot", side=s)
        r.add(f"DEF-breast.{w}", "DEF-spine.003", "chest+0.1,0,0.1", "chest")

    sides(side)
    return r


@rig(
    "fairly sure: a Rigify rig exported whole: DEF-, ORG- and MCH- chains, IK controls on "
    "hands and feet"
)
def blender_rigify_full() -> Rig:
    r = blender_rigify()
    r.name = "blender_rigify_full"
    # ORG- bones: the metarig's bones, a second chain on the same places moving alike.
    for prefix in ("ORG-", "MCH-"):
        chain = ["spine", "spine.001", "spine.002", "spine.003"]
        parent = "root"
        for name in chain:
            src = r.names.index("DEF-" + name)
            parent = r.add(prefix + name, parent, "pelvis", r.segments[src])
            r.points[-1] = r.points[src].copy()
        for side, w in (("l", "L"), ("r", "R")):
            top = prefix + "spine.003"
            for bone in ("shoulder", "upper_arm", "forearm", "hand"):
                src = r.names.index(f"DEF-{bone}.{w}")
                top = r.add(f"{prefix}{bone}.{w}", top, "pelvis", r.segments[src], side=side)
                r.points[-1] = r.points[src].copy()
                r.truth.get(_truth_of(r, f"DEF-{bone}.{w}"), set()).add(f"{prefix}{bone}.{w}")
            top = prefix + "spine"
            for bone in ("thigh", "shin", "foot", "toe"):
                src = r.names.index(f"DEF-{bone}.{w}")
                top = r.add(f"{prefix}{bone}.{w}", top, "pelvis", r.segments[src], side=side)
                r.points[-1] = r.points[src].copy()
                r.truth.get(_truth_of(r, f"DEF-{bone}.{w}"), set()).add(f"{prefix}{bone}.{w}")
    for side, w in (("l", "L"), ("r", "R")):  # IK controls under the root, on hand and foot
        r.add(f"hand_ik.{w}", "root", "wrist", side=side, follows=f"DEF-hand.{w}")
        r.add(f"foot_ik.{w}", "root", "ankle", side=side, follows=f"DEF-foot.{w}")
        r.add(f"foot_heel_ik.{w}", f"foot_ik.{w}", "ankle+0,-0.06,-0.05", side=side)
    return r


def _truth_of(r: Rig, name: str) -> str:
    return next((c for c, names in r.truth.items() if name in names), "")


@rig(
    "sure: 3ds Max Biped's default names; legs under Bip01 Pelvis (its default; 'Triangle "
    "Pelvis' links them to Bip01 Spine), clavicles under the neck"
)
def max_biped() -> Rig:
    r = Rig("max_biped", pose="T", unit=1 / 0.0254, z_up=True)
    r.add("Bip01", None, "pelvis", "pelvis", truth="pelvis")
    r.add("Bip01 Footsteps", "Bip01", "ground")
    r.add("Bip01 Pelvis", "Bip01", "pelvis", "pelvis", truth="pelvis")
    r.add("Bip01 Spine", "Bip01 Pelvis", "spine", "abdomen")
    r.add("Bip01 Spine1", "Bip01 Spine", "spine@chest:0.5", "abdomen")
    r.add("Bip01 Spine2", "Bip01 Spine1", "chest", "chest")
    r.add("Bip01 Spine3", "Bip01 Spine2", "chest@neck:0.5", "chest")
    r.add("Bip01 Neck", "Bip01 Spine3", "neck", "neck")
    r.add("Bip01 Head", "Bip01 Neck", "head", "head", truth="head")
    r.add("Bip01 HeadNub", "Bip01 Head", "head_top", "head")

    def side(s: str, w: str) -> None:
        p = f"Bip01 {w.upper()} "
        r.add(p + "Clavicle", "Bip01 Neck", "clav", "s_clav", side=s)
        r.add(p + "UpperArm", p + "Clavicle", "shoulder", "s_upper", side=s, truth="s_shoulder")
        r.add(p + "Forearm", p + "UpperArm", "elbow", "s_fore", side=s, truth="s_elbow")
        r.add(p + "Hand", p + "Forearm", "wrist", "s_hand", side=s, truth="s_wrist")
        r.add(p + "ForeTwist", p + "Forearm", "elbow@wrist:0.5", "s_fore", side=s)
        for i, f in enumerate(FINGERS):
            parent = p + "Hand"
            for k in range(3):
                parent = r.add(
                    f"{p}Finger{i}{'' if k == 0 else k}", parent, f"{f}{k + 1}", "s_hand", side=s
                )
            r.add(f"{p}Finger{i}Nub", parent, f"{f}4", "s_hand", side=s)
        r.add(p + "Thigh", "Bip01 Pelvis", "hip", "s_thigh", side=s, truth="s_hip")
        r.add(p + "Calf", p + "Thigh", "knee", "s_shin", side=s, truth="s_knee")
        r.add(p + "Foot", p + "Calf", "ankle", "s_foot", side=s, truth="s_ankle")
        r.add(p + "Toe0", p + "Foot", "ball", "s_foot", side=s)
        r.add(p + "Toe0Nub", p + "Toe0", "toe_tip", "s_foot", side=s)

    sides(side)
    return r


@rig("sure: HumanIK's names (Reference, Hips, Spine..Spine3, roll bones), cm, Y up")
def humanik() -> Rig:
    r = Rig("humanik", pose="T", unit=100.0)
    r.add("Reference", None, "ground")
    r.add("Hips", "Reference", "pelvis", "pelvis", truth="pelvis")
    parent = "Hips"
    for i, place in enumerate(["spine", "spine@chest:0.5", "chest", "chest@neck:0.5"]):
        parent = r.add(
            "Spine" + (str(i) if i else ""), parent, place, "abdomen" if i < 2 else "chest"
        )
    r.add("Neck", "Spine3", "neck", "neck")
    r.add("Head", "Neck", "head", "head", truth="head")

    def side(s: str, w: str) -> None:
        p = "Left" if s == "l" else "Right"
        r.add(p + "Shoulder", "Spine3", "clav", "s_clav", side=s)
        r.add(p + "Arm", p + "Shoulder", "shoulder", "s_upper", side=s, truth="s_shoulder")
        r.add(p + "ForeArm", p + "Arm", "elbow", "s_fore", side=s, truth="s_elbow")
        r.add(p + "ArmRoll", p + "Arm", "shoulder@elbow:0.5", "s_upper", side=s)
        r.add(p + "Hand", p + "ForeArm", "wrist", "s_hand", side=s, truth="s_wrist")
        r.add(p + "ForeArmRoll", p + "ForeArm", "elbow@wrist:0.5", "s_fore", side=s)
        fingers(r, s, p + "Hand", lambda f, k: None if k == 0 else f"{p}Hand{f.title()}{k}")
        r.add(p + "UpLeg", "Hips", "hip", "s_thigh", side=s, truth="s_hip")
        r.add(p + "Leg", p + "UpLeg", "knee", "s_shin", side=s, truth="s_knee")
        r.add(p + "UpLegRoll", p + "UpLeg", "hip@knee:0.5", "s_thigh", side=s)
        r.add(p + "Foot", p + "Leg", "ankle", "s_foot", side=s, truth="s_ankle")
        r.add(p + "LegRoll", p + "Leg", "knee@ankle:0.5", "s_shin", side=s)
        r.add(p + "ToeBase", p + "Foot", "ball", "s_foot", side=s)

    sides(side)
    return r


# The other rigs register themselves on import.
from tests.motion import industry_rigs_capture  # noqa: E402, F401

__all__ = ["CERTAINTY", "RIGS"]
