"""Humanoid rigs of avatar tools, capture systems and body models (issue 20; see
:mod:`tests.motion.industry_rigs`): VRoid, MMD, Perception Neuron, OptiTrack Motive, Kinect
v2, ARKit, SMPL-X, Xsens MVN, Rokoko."""

from __future__ import annotations

from tests.motion.rig_building import Rig, fingers, rig, sides


@rig("sure: VRoid Studio's J_Bip_/J_Adj_/J_Sec_ names; hair and skirt chains shortened")
def vroid() -> Rig:
    r = Rig("vroid", pose="T", unit=1.0)
    r.add("Root", None, "ground")
    r.add("J_Bip_C_Hips", "Root", "pelvis", "pelvis", truth="pelvis")
    r.add("J_Bip_C_Spine", "J_Bip_C_Hips", "spine", "abdomen")
    r.add("J_Bip_C_Chest", "J_Bip_C_Spine", "chest", "chest")
    r.add("J_Bip_C_UpperChest", "J_Bip_C_Chest", "chest@neck:0.5", "chest")
    r.add("J_Bip_C_Neck", "J_Bip_C_UpperChest", "neck", "neck")
    r.add("J_Bip_C_Head", "J_Bip_C_Neck", "head", "head", truth="head")
    r.add("J_Adj_L_FaceEye", "J_Bip_C_Head", "eye", "head", side="l")
    r.add("J_Adj_R_FaceEye", "J_Bip_C_Head", "eye", "head", side="r")
    for i, x in enumerate((-0.06, 0.0, 0.06), start=1):
        parent = "J_Bip_C_Head"
        for k in range(1, 4):  # hair hangs down the back, to the shoulders
            place = f"hair+{x},{-0.1 * k},{-0.02 * k}"
            parent = r.add(f"J_Sec_Hair{k}_{i:02d}", parent, place, "head")

    def side(s: str, w: str) -> None:
        p = f"J_Bip_{w.upper()}_"
        r.add(p + "Shoulder", "J_Bip_C_UpperChest", "clav", "s_clav", side=s)
        r.add(p + "UpperArm", p + "Shoulder", "shoulder", "s_upper", side=s, truth="s_shoulder")
        r.add(p + "LowerArm", p + "UpperArm", "elbow", "s_fore", side=s, truth="s_elbow")
        r.add(p + "Hand", p + "LowerArm", "wrist", "s_hand", side=s, truth="s_wrist")
        r.add(
            f"J_Sec_{w.upper()}_TopsUpperArmInside",
            p + "UpperArm",
            "shoulder@elbow:0.3+0,-0.03,0",
            "s_upper",
            side=s,
        )
        fingers(r, s, p + "Hand", lambda f, k: None if k == 0 else f"{p}{f.title()}{k}")
        r.add(p + "UpperLeg", "J_Bip_C_Hips", "hip", "s_thigh", side=s, truth="s_hip")
        r.add(p + "LowerLeg", p + "UpperLeg", "knee", "s_shin", side=s, truth="s_knee")
        r.add(p + "Foot", p + "LowerLeg", "ankle", "s_foot", side=s, truth="s_ankle")
        r.add(p + "ToeBase", p + "Foot", "ball", "s_foot", side=s)
        r.add(f"J_Sec_{w.upper()}_Bust1", "J_Bip_C_Chest", "chest+0.09,0,0.08", "chest", side=s)
        parent = "J_Bip_C_Hips"
        for k in range(1, 4):  # a skirt hanging from the hips, down past the thigh
            place = f"skirt+0,{-0.12 * k},0.01"
            parent = r.add(f"J_Sec_{w.upper()}_SkirtFront_{k:02d}", parent, place, "pelvis", side=s)

    sides(side)
    return r


@rig("fairly sure: the PMX standard bone names of MMD models; D-bones and hand IK left out")
def mmd() -> Rig:
    return _mmd(semi_standard=False)


def _mmd(*, semi_standard: bool) -> Rig:
    r = Rig(
        "mmd_semi_standard" if semi_standard else "mmd", pose="A", unit=12.5
    )  # 1 MMD unit is about 8 cm
    r.add("全ての親", None, "ground")
    r.add("センター", "全ての親", "pelvis+0,-0.15,0", "pelvis", truth="pelvis")
    r.add("グルーブ", "センター", "pelvis+0,-0.1,0", "pelvis", truth="pelvis")
    r.add("腰", "グルーブ", "pelvis", "pelvis", truth="pelvis")
    r.add("下半身", "腰", "pelvis", "pelvis", truth="pelvis")
    r.add("上半身", "腰", "spine", "abdomen", truth="pelvis")
    r.add("上半身2", "上半身", "chest", "chest")
    r.add("首", "上半身2", "neck", "neck")
    r.add("頭", "首", "head", "head", truth="head")
    r.add("両目", "頭", "eye+-0.032,0.02,0", "head")
    r.add("左目", "頭", "eye", "head", side="l")
    r.add("右目", "頭", "eye", "head", side="r")
    names = {"thumb": "親指", "index": "人指", "middle": "中指", "ring": "薬指", "pinky": "小指"}

    def side(s: str, w: str) -> None:
        p = "左" if s == "l" else "右"
        r.add(p + "肩", "上半身2", "clav", "s_clav", side=s)
        r.add(p + "腕", p + "肩", "shoulder", "s_upper", side=s, truth="s_shoulder")
        r.add(p + "腕捩", p + "腕", "shoulder@elbow:0.6", "s_upper", side=s)
        r.add(p + "ひじ", p + "腕捩", "elbow", "s_fore", side=s, truth="s_elbow")
        r.add(p + "手捩", p + "ひじ", "elbow@wrist:0.6", "s_fore", side=s)
        r.add(p + "手首", p + "手捩", "wrist", "s_hand", side=s, truth="s_wrist")
        fingers(
            r,
            s,
            p + "手首",
            lambda f, k: (
                (f"{p}親指０" if f == "thumb" else None)
                if k == 0
                else f"{p}{names[f]}{'１２３'[k - 1]}"
            ),
        )
        top = "下半身"
        if semi_standard:  # waist cancel between the lower body and the thigh
            top = r.add("腰キャンセル" + p, "下半身", "hip", "pelvis", side=s)
        r.add(p + "足", top, "hip", "s_thigh", side=s, truth="s_hip")
        r.add(p + "ひざ", p + "足", "knee", "s_shin", side=s, truth="s_knee")
        r.add(p + "足首", p + "ひざ", "ankle", "s_foot", side=s, truth="s_ankle")
        r.add(p + "つま先", p + "足首", "ball", "s_foot", side=s)
        if semi_standard:  # D-bones: the deforming leg chain on the same places, moving alike
            r.add(p + "足D", top, "hip", "s_thigh", side=s, truth="s_hip")
            r.add(p + "ひざD", p + "足D", "knee", "s_shin", side=s, truth="s_knee")
            r.add(p + "足首D", p + "ひざD", "ankle", "s_foot", side=s, truth="s_ankle")
            r.add(p + "足先EX", p + "足首D", "ball", "s_foot", side=s)
        r.add(p + "足ＩＫ", "全ての親", "ankle", side=s, follows=p + "足首")
        r.add(p + "つま先ＩＫ", p + "足ＩＫ", "ball", side=s, follows=p + "つま先")

    sides(side)
    return r


@rig("fairly sure: PMX semi-standard bones: D-bones beside the leg chain, waist cancel")
def mmd_semi_standard() -> Rig:
    return _mmd(semi_standard=True)


@rig("sure: Axis Neuron's BVH (Hips, Spine..Spine3, Neck1, InHand metacarpals); no toe joints")
def perception_neuron() -> Rig:
    r = Rig("perception_neuron", pose="T", unit=100.0)
    r.add("Hips", None, "pelvis", "pelvis", truth="pelvis")
    parent = "Hips"
    for i, place in enumerate(["spine", "spine@chest:0.5", "chest", "chest@neck:0.5"]):
        parent = r.add(
            "Spine" + (str(i) if i else ""), parent, place, "abdomen" if i < 2 else "chest"
        )
    r.add("Neck", "Spine3", "neck", "neck")
    r.add("Neck1", "Neck", "neck@head:0.5", "neck")
    r.add("Head", "Neck1", "head", "head", truth="head")

    def side(s: str, w: str) -> None:
        p = "Left" if s == "l" else "Right"
        r.add(p + "UpLeg", "Hips", "hip", "s_thigh", side=s, truth="s_hip")
        r.add(p + "Leg", p + "UpLeg", "knee", "s_shin", side=s, truth="s_knee")
        r.add(p + "Foot", p + "Leg", "ankle", "s_foot", side=s, truth="s_ankle")
        r.add(p + "Shoulder", "Spine3", "clav", "s_clav", side=s)
        r.add(p + "Arm", p + "Shoulder", "shoulder", "s_upper", side=s, truth="s_shoulder")
        r.add(p + "ForeArm", p + "Arm", "elbow", "s_fore", side=s, truth="s_elbow")
        r.add(p + "Hand", p + "ForeArm", "wrist", "s_hand", side=s, truth="s_wrist")
        fingers(
            r,
            s,
            p + "Hand",
            lambda f, k: (
                (None if f == "thumb" else f"{p}InHand{f.title()}")
                if k == 0
                else f"{p}Hand{f.title()}{k}"
            ),
        )

    sides(side)
    return r


@rig("fairly sure: Motive's baseline skeleton names after the asset prefix; cm as its BVH export")
def optitrack_motive() -> Rig:
    r = Rig("optitrack_motive", pose="T", unit=100.0)
    r.add("Skeleton_Hip", None, "pelvis", "pelvis", truth="pelvis")
    r.add("Skeleton_Ab", "Skeleton_Hip", "spine", "abdomen")
    r.add("Skeleton_Chest", "Skeleton_Ab", "chest", "chest")
    r.add("Skeleton_Neck", "Skeleton_Chest", "neck", "neck")
    r.add("Skeleton_Head", "Skeleton_Neck", "head", "head", truth="head")

    def side(s: str, w: str) -> None:
        p = f"Skeleton_{w.upper()}"
        r.add(p + "Shoulder", "Skeleton_Chest", "clav", "s_clav", side=s)
        r.add(p + "UArm", p + "Shoulder", "shoulder", "s_upper", side=s, truth="s_shoulder")
        r.add(p + "FArm", p + "UArm", "elbow", "s_fore", side=s, truth="s_elbow")
        r.add(p + "Hand", p + "FArm", "wrist", "s_hand", side=s, truth="s_wrist")
        r.add(p + "Thigh", "Skeleton_Hip", "hip", "s_thigh", side=s, truth="s_hip")
        r.add(p + "Shin", p + "Thigh", "knee", "s_shin", side=s, truth="s_knee")
        r.add(p + "Foot", p + "Shin", "ankle", "s_foot", side=s, truth="s_ankle")
        r.add(p + "Toe", p + "Foot", "ball", "s_foot", side=s)

    sides(side)
    return r


@rig("sure: the Kinect v2 SDK's 25 JointType names and their tree")
def kinect_v2() -> Rig:
    r = Rig("kinect_v2", pose="T", unit=1.0)
    r.add("SpineBase", None, "pelvis", "pelvis", truth="pelvis")
    r.add("SpineMid", "SpineBase", "spine@chest:0.5", "abdomen")
    r.add("SpineShoulder", "SpineMid", "chest@neck:0.7", "chest")
    r.add("Neck", "SpineShoulder", "neck", "neck")
    r.add("Head", "Neck", "head", "head", truth="head")

    def side(s: str, w: str) -> None:
        p = "Left" if s == "l" else "Right"
        r.add("Shoulder" + p, "SpineShoulder", "shoulder", "s_upper", side=s, truth="s_shoulder")
        r.add("Elbow" + p, "Shoulder" + p, "elbow", "s_fore", side=s, truth="s_elbow")
        r.add("Wrist" + p, "Elbow" + p, "wrist", "s_hand", side=s, truth="s_wrist")
        r.add("Hand" + p, "Wrist" + p, "middle1", "s_hand", side=s)
        r.add("HandTip" + p, "Hand" + p, "middle4", "s_hand", side=s)
        r.add("Thumb" + p, "Hand" + p, "thumb3", "s_hand", side=s)
        r.add("Hip" + p, "SpineBase", "hip", "s_thigh", side=s, truth="s_hip")
        r.add("Knee" + p, "Hip" + p, "knee", "s_shin", side=s, truth="s_knee")
        r.add("Ankle" + p, "Knee" + p, "ankle", "s_foot", side=s, truth="s_ankle")
        r.add("Foot" + p, "Ankle" + p, "ball", "s_foot", side=s)

    sides(side)
    return r


@rig("fairly sure: ARKit's ARSkeleton3D joint names; the hand joints reduced to Start + 1..3")
def arkit_body() -> Rig:
    r = Rig("arkit_body", pose="T", unit=1.0)
    r.add("root", None, "ground")
    r.add("hips_joint", "root", "pelvis", "pelvis", truth="pelvis")
    parent = "hips_joint"
    for i in range(1, 8):
        place = f"pelvis@neck:{i / 8:.3f}"
        parent = r.add(f"spine_{i}_joint", parent, place, "abdomen" if i < 4 else "chest")
    for i in range(1, 5):
        parent = r.add(f"neck_{i}_joint", parent, f"neck@head:{(i - 1) / 4:.3f}", "neck")
    r.add("head_joint", parent, "head", "head", truth="head")
    r.add("jaw_joint", "head_joint", "jaw", "head")
    r.add("left_eye_joint", "head_joint", "eye", "head", side="l")
    r.add("right_eye_joint", "head_joint", "eye", "head", side="r")

    def side(s: str, w: str) -> None:
        p = "left_" if s == "l" else "right_"
        r.add(p + "shoulder_1_joint", "spine_7_joint", "clav", "s_clav", side=s)
        r.add(
            p + "arm_joint",
            p + "shoulder_1_joint",
            "shoulder",
            "s_upper",
            side=s,
            truth="s_shoulder",
        )
        r.add(p + "forearm_joint", p + "arm_joint", "elbow", "s_fore", side=s, truth="s_elbow")
        r.add(p + "hand_joint", p + "forearm_joint", "wrist", "s_hand", side=s, truth="s_wrist")
        fingers(
            r,
            s,
            p + "hand_joint",
            lambda f, k: f"{p}hand{f.title()}{'Start' if k == 0 else '_' + str(k)}_joint",
        )
        r.add(p + "upLeg_joint", "hips_joint", "hip", "s_thigh", side=s, truth="s_hip")
        r.add(p + "leg_joint", p + "upLeg_joint", "knee", "s_shin", side=s, truth="s_knee")
        r.add(p + "foot_joint", p + "leg_joint", "ankle", "s_foot", side=s, truth="s_ankle")
        r.add(p + "toes_joint", p + "foot_joint", "ball", "s_foot", side=s)
        r.add(p + "toesEnd_joint", p + "toes_joint", "toe_tip", "s_foot", side=s)

    sides(side)
    return r


@rig("sure: SMPL-X's 55 joint names and kinematic tree (hands reduced to 3 joints a finger)")
def smplx() -> Rig:
    r = Rig("smplx", pose="T", unit=1.0)
    r.add("pelvis", None, "pelvis", "pelvis", truth="pelvis")
    r.add("spine1", "pelvis", "spine", "abdomen")
    r.add("spine2", "spine1", "spine@chest:0.6", "abdomen")
    r.add("spine3", "spine2", "chest", "chest")
    r.add("neck", "spine3", "neck", "neck")
    r.add("head", "neck", "head", "head", truth="head")
    r.add("jaw", "head", "jaw", "head")
    r.add("left_eye_smplhf", "head", "eye", "head", side="l")
    r.add("right_eye_smplhf", "head", "eye", "head", side="r")

    def side(s: str, w: str) -> None:
        p = "left_" if s == "l" else "right_"
        r.add(p + "hip", "pelvis", "hip", "s_thigh", side=s, truth="s_hip")
        r.add(p + "knee", p + "hip", "knee", "s_shin", side=s, truth="s_knee")
        r.add(p + "ankle", p + "knee", "ankle", "s_foot", side=s, truth="s_ankle")
        r.add(p + "foot", p + "ankle", "ball", "s_foot", side=s)
        r.add(p + "collar", "spine3", "clav", "s_clav", side=s)
        r.add(p + "shoulder", p + "collar", "shoulder", "s_upper", side=s, truth="s_shoulder")
        r.add(p + "elbow", p + "shoulder", "elbow", "s_fore", side=s, truth="s_elbow")
        r.add(p + "wrist", p + "elbow", "wrist", "s_hand", side=s, truth="s_wrist")
        fingers(r, s, p + "wrist", lambda f, k: None if k == 0 else f"{p}{f}{k}")

    sides(side)
    return r


@rig("sure: Xsens MVN's 23 segments (Pelvis, L5, L3, T12, T8...), as its BVH export writes them")
def xsens_mvn() -> Rig:
    r = Rig("xsens_mvn", pose="T", unit=100.0)
    r.add("Pelvis", None, "pelvis", "pelvis", truth="pelvis")
    r.add("L5", "Pelvis", "pelvis@chest:0.15", "abdomen")
    r.add("L3", "L5", "spine", "abdomen")
    r.add("T12", "L3", "spine@chest:0.5", "abdomen")
    r.add("T8", "T12", "chest", "chest")
    r.add("Neck", "T8", "neck", "neck")
    r.add("Head", "Neck", "head", "head", truth="head")

    def side(s: str, w: str) -> None:
        p = "Left" if s == "l" else "Right"
        r.add(p + "Shoulder", "T8", "clav", "s_clav", side=s)
        r.add(p + "UpperArm", p + "Shoulder", "shoulder", "s_upper", side=s, truth="s_shoulder")
        r.add(p + "ForeArm", p + "UpperArm", "elbow", "s_fore", side=s, truth="s_elbow")
        r.add(p + "Hand", p + "ForeArm", "wrist", "s_hand", side=s, truth="s_wrist")
        r.add(p + "UpperLeg", "Pelvis", "hip", "s_thigh", side=s, truth="s_hip")
        r.add(p + "LowerLeg", p + "UpperLeg", "knee", "s_shin", side=s, truth="s_knee")
        r.add(p + "Foot", p + "LowerLeg", "ankle", "s_foot", side=s, truth="s_ankle")
        r.add(p + "Toe", p + "Foot", "ball", "s_foot", side=s)

    sides(side)
    return r


@rig("fairly sure: Rokoko Studio's BVH names (Thigh/Shin, Spine1..Spine4, ToeEnd)")
def rokoko() -> Rig:
    r = Rig("rokoko", pose="T", unit=100.0)
    r.add("Hips", None, "pelvis", "pelvis", truth="pelvis")
    parent = "Hips"
    for i, place in enumerate(["spine", "spine@chest:0.5", "chest", "chest@neck:0.5"], start=1):
        parent = r.add(f"Spine{i}", parent, place, "abdomen" if i < 3 else "chest")
    r.add("Neck", "Spine4", "neck", "neck")
    r.add("Head", "Neck", "head", "head", truth="head")

    def side(s: str, w: str) -> None:
        p = "Left" if s == "l" else "Right"
        r.add(p + "Thigh", "Hips", "hip", "s_thigh", side=s, truth="s_hip")
        r.add(p + "Shin", p + "Thigh", "knee", "s_shin", side=s, truth="s_knee")
        r.add(p + "Foot", p + "Shin", "ankle", "s_foot", side=s, truth="s_ankle")
        r.add(p + "Toe", p + "Foot", "ball", "s_foot", side=s)
        r.add(p + "ToeEnd", p + "Toe", "toe_tip", "s_foot", side=s)
        r.add(p + "Shoulder", "Spine4", "clav", "s_clav", side=s)
        r.add(p + "Arm", p + "Shoulder", "shoulder", "s_upper", side=s, truth="s_shoulder")
        r.add(p + "ForeArm", p + "Arm", "elbow", "s_fore", side=s, truth="s_elbow")
        r.add(p + "Hand", p + "ForeArm", "wrist", "s_hand", side=s, truth="s_wrist")
        fingers(r, s, p + "Hand", lambda f, k: None if k == 0 else f"{p}{f.title()}{k}")

    sides(side)
    return r
