// A BVH file converted to GLB the way web tools do it: three.js's BVHLoader and GLTFExporter.
//
//   mkdir -p /tmp/three && (cd /tmp/three && npm install three@0.170.0)
//   NODE_PATH=/tmp/three/node_modules node bench/threejs_bvh_to_glb.mjs IN.bvh OUT.glb
//
// The bones are exported as plain nodes (no skin), each BVH End Site as a leaf node named
// "ENDSITE", and the clip as one animation; tracks of bones whose names three.js cannot bind
// (a ':' as in "mixamorig:Hips") are dropped by the exporter with a warning. Compare the
// result with its source: bench/exporter_variants.py --pairs (findings: docs/skeletons.md).
import fs from 'node:fs';
import { createRequire } from 'node:module';

const require = createRequire(`${process.env.NODE_PATH || process.cwd()}/`);
const THREE = await import(require.resolve('three'));
const { BVHLoader } = await import(require.resolve('three/examples/jsm/loaders/BVHLoader.js'));
const { GLTFExporter } = await import(
  require.resolve('three/examples/jsm/exporters/GLTFExporter.js')
);

// GLTFExporter writes a GLB through FileReader, which Node does not have.
globalThis.FileReader = class {
  readAsArrayBuffer(blob) {
    blob.arrayBuffer().then((bytes) => {
      this.result = bytes;
      if (this.onloadend) this.onloadend();
    });
  }
};

const [, , input, output] = process.argv;
const { skeleton, clip } = new BVHLoader().parse(fs.readFileSync(input, 'utf8'));
const scene = new THREE.Scene();
const rig = new THREE.Group();
rig.name = 'rig';
rig.add(skeleton.bones[0]);
scene.add(rig);
new GLTFExporter().parse(
  scene,
  (glb) => fs.writeFileSync(output, Buffer.from(glb)),
  (error) => {
    console.error(error);
    process.exit(1);
  },
  { binary: true, animations: [clip], onlyVisible: false },
);
