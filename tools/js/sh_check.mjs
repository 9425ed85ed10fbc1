// Loads an SH file written by `lumiprobe export` into three.js's own LightProbe
// (npm `three`) and prints the irradiance three.js computes from it at each
// direction given as x,y,z (unit vectors in the file's axes), as JSON
// [[r, g, b], ...]. Used by tests/export.rs.
import { readFileSync } from 'node:fs';
import { LightProbe, Vector3 } from 'three';

const json = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const probe = new LightProbe().fromJSON(json);
const out = process.argv.slice(3).map((arg) => {
  const [x, y, z] = arg.split(',').map(Number);
  const e = probe.sh.getIrradianceAt(new Vector3(x, y, z).normalize(), new Vector3());
  return [e.x * probe.intensity, e.y * probe.intensity, e.z * probe.intensity];
});
console.log(JSON.stringify(out));
