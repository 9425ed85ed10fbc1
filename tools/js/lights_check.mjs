// Loads a lights file written by `lumiprobe export` (glTF 2.0 with
// KHR_lights_punctual) with three.js's own GLTFLoader (npm `three`) and prints
// the lights three.js builds from it, as JSON [{type, color: [r, g, b],
// intensity, travel: [x, y, z], position: [x, y, z]}, ...]: `travel` is the
// way a directional or spot light shines, `position` where a point or spot
// light is, in world axes; spot lights add their cone `angle` and `penumbra`.
// Used by tests/export.rs.
import { readFileSync } from 'node:fs';
import { Vector3 } from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';

const text = readFileSync(process.argv[2], 'utf8');
new GLTFLoader().parse(text, '', (gltf) => {
  gltf.scene.updateMatrixWorld(true);
  const out = [];
  gltf.scene.traverse((o) => {
    if (!o.isLight) return;
    const from = new Vector3();
    o.getWorldPosition(from);
    const travel = new Vector3();
    if (o.target) {
      o.target.getWorldPosition(travel);
      travel.sub(from).normalize();
    }
    out.push({
      type: o.type,
      color: [o.color.r, o.color.g, o.color.b],
      intensity: o.intensity,
      travel: [travel.x, travel.y, travel.z],
      position: [from.x, from.y, from.z],
      ...(o.isSpotLight ? { angle: o.angle, penumbra: o.penumbra } : {}),
    });
  });
  console.log(JSON.stringify(out));
}, (err) => {
  console.error(String(err));
  process.exit(1);
});
