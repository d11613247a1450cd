"""The same clips written by other exporters' settings: do they read and describe alike?

Each source file is opened in Blender (``bpy``, the ``fbx`` extra) and written again by its
FBX, glTF and BVH exporters with the options users change (leaf bones, key reduction, axes,
bone axes, scale, NLA, rotation orders, keyframes kept as authored), and, when ``npx`` can
run glTF Transform (``--gltf-transform``), each GLB through its ``resample``, ``meshopt``,
``optimize``, ``sparse``, ``quantize``, ``flatten``, ``center`` commands and as a ``.gltf``
with a separate ``.bin`` (read through :func:`app.motion.formats.gltf_pack.pack_gltf`). Every
variant is read by the service's readers, described, and compared with its source: the
relative distance of each descriptor's vector (0 = the same clip). A variant whose vectors
move far either lost information in the exporter (key reduction, leaf bones added, a take
cut to the scene's range) or shows a reader or mapper that depends on a writer's choice.

    .venv/bin/python bench/exporter_variants.py SOURCE... [--out DIR] [--gltf-transform]
    .venv/bin/python bench/exporter_variants.py --pairs PAIRS   # variants another tool wrote

``bench/threejs_bvh_to_glb.mjs`` is such a tool: three.js's BVHLoader and GLTFExporter, as
web converters use them (see its header).

Blender runs in a subprocess per source (its scene state is global). Findings: docs/skeletons.md
("Exporter variants").
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.motion.formats import read_bvh  # noqa: E402
from app.motion.formats.gltf_pack import pack_gltf  # noqa: E402
from app.motion.model import ParseLimits  # noqa: E402
from app.motion.pipeline import analyse  # noqa: E402
from app.services.parser_pool import parse_scene  # noqa: E402

# Written by Blender in a subprocess: ``python - SOURCE OUT`` with this program on stdin.
BLENDER_EXPORTS = r"""
import sys
from pathlib import Path
import bpy

src, out = Path(sys.argv[1]), Path(sys.argv[2])
bpy.ops.wm.read_factory_settings(use_empty=True)
suffix = src.suffix.lower()
if suffix == ".bvh":
    bpy.ops.import_anim.bvh(filepath=str(src), update_scene_fps=True, update_scene_duration=True)
elif suffix == ".fbx":
    bpy.ops.import_scene.fbx(filepath=str(src))
else:
    bpy.ops.import_scene.gltf(filepath=str(src))
armatures = [o for o in bpy.data.objects if o.type == "ARMATURE"]
if not armatures:
    sys.exit("no armature")
if bpy.data.actions:  # the whole take: the scene's range may be shorter
    first, last = bpy.data.actions[0].frame_range
    bpy.context.scene.frame_start, bpy.context.scene.frame_end = int(first), int(last)
stem = src.stem
fbx = {
    "default": {},
    "no-leaf-no-simplify": dict(add_leaf_bones=False, bake_anim_simplify_factor=0.0),
    "z-up": dict(axis_forward="Y", axis_up="Z"),
    "x-bones": dict(primary_bone_axis="X", secondary_bone_axis="-Y"),
    "scale-all": dict(apply_scale_options="FBX_SCALE_ALL", global_scale=0.01),
    "simplify-10": dict(bake_anim_simplify_factor=10.0),
    "deform-only": dict(use_armature_deform_only=True, bake_anim_force_startend_keying=False),
}
for name, options in fbx.items():
    bpy.ops.export_scene.fbx(filepath=str(out / f"{stem}__fbx-{name}.fbx"), **options)
gltf = {
    "default": {},
    "z-up": dict(export_yup=False),
    "keys": dict(export_force_sampling=False),
    "optimize": dict(export_optimize_animation_size=True),
    "separate": dict(export_format="GLTF_SEPARATE"),
}
for name, options in gltf.items():
    ext = ".gltf" if options.get("export_format") == "GLTF_SEPARATE" else ".glb"
    bpy.ops.export_scene.gltf(filepath=str(out / f"{stem}__gl-{name}{ext}"), **options)
bpy.context.view_layer.objects.active = armatures[0]
armatures[0].select_set(True)
for name, options in {"zyx": dict(rotate_mode="ZYX"), "yxz": dict(rotate_mode="YXZ")}.items():
    bpy.ops.export_anim.bvh(filepath=str(out / f"{stem}__bvh-{name}.bvh"), **options)
"""
GLTF_TRANSFORM = ("resample", "meshopt", "optimize", "sparse", "quantize", "flatten", "center")


def describe(path: Path) -> dict[str, np.ndarray]:
    """Every descriptor's vector of the file at ``path`` (its longest animation)."""
    data = path.read_bytes()
    suffix = path.suffix.lower()
    if suffix == ".bvh":
        motion = read_bvh(data)
    else:
        if suffix == ".gltf":
            beside = {p.name: p.read_bytes() for p in path.parent.iterdir() if p.is_file()}
            data = pack_gltf(data, beside)
        kind = "fbx" if suffix == ".fbx" else "gltf"
        motion = parse_scene(kind, data, None, ParseLimits()).motion
    return analyse(motion).descriptors


def variants(source: Path, out: Path, gltf_transform: bool) -> list[Path]:
    folder = out / source.stem
    folder.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(
        [sys.executable, "-", str(source), str(folder)],
        input=BLENDER_EXPORTS,
        text=True,
        capture_output=True,
        timeout=900,
    )
    if done.returncode:
        print(f"{source.name}: Blender failed: {done.stderr.strip()[-300:]}", file=sys.stderr)
    if gltf_transform and (folder / f"{source.stem}__gl-default.glb").is_file():
        glb = folder / f"{source.stem}__gl-default.glb"
        for command in GLTF_TRANSFORM:
            target = folder / f"{source.stem}__gt-{command}.glb"
            subprocess.run(
                ["npx", "--yes", "@gltf-transform/cli", command, str(glb), str(target)],
                capture_output=True,
                timeout=300,
            )
    kinds = (".bvh", ".fbx", ".glb", ".gltf")
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in kinds)


def compare(original: dict[str, np.ndarray], variant: Path, table: dict[str, object]) -> None:
    """Describe ``variant`` and record (and print) its distance from ``original``'s vectors."""
    try:
        vectors = describe(variant)
    except Exception as error:  # a refusal is a result here
        table[variant.name] = str(error)[:200]
        print(f"{variant.name}: REFUSED {str(error)[:200]}")
        return
    distances = {
        name: float(np.linalg.norm(vectors[name] - v) / max(np.linalg.norm(v), 1e-12))
        for name, v in original.items()
    }
    table[variant.name] = distances
    shown = " ".join(f"{name} {d:.4f}" for name, d in distances.items())
    print(f"{variant.name}: {shown}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sources", nargs="*", type=Path)
    parser.add_argument("--out", type=Path, default=Path("/tmp/exporter-variants"))
    parser.add_argument("--gltf-transform", action="store_true")
    parser.add_argument(
        "--pairs",
        type=Path,
        help="compare the variants another tool wrote instead: lines 'SOURCE VARIANT'",
    )
    parser.add_argument("--json", type=Path, help="write every distance here")
    args = parser.parse_args()
    table: dict[str, object] = {}
    for source in args.sources:
        original = describe(source)
        for variant in variants(source, args.out, args.gltf_transform):
            compare(original, variant, table)
    for line in args.pairs.read_text().splitlines() if args.pairs else []:
        source, variant = (Path(p) for p in line.split())
        try:
            original = describe(source)
        except Exception as error:  # the source itself refused: nothing to compare with
            print(f"{source.name}: source REFUSED {str(error)[:200]}")
            continue
        compare(original, variant, table)
    if args.json:
        args.json.write_text(json.dumps(table, indent=1))


if __name__ == "__main__":
    main()
