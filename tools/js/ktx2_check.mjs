// Reads a KTX 2.0 file with a real client (npm ktx-parse, as three.js's
// KTX2Loader does) and prints what a renderer would see: the header, the data
// format descriptor, the key/value data, each level's size, and the brightest
// texel of level 0 (face, column, row, RGB) decoded from the file's own bytes.
// Used by tests/export.rs.
import { readFileSync } from 'node:fs';
import { read } from 'ktx-parse';

const path = process.argv[2];
const c = read(new Uint8Array(readFileSync(path)));

function half(bits) {
  const s = bits & 0x8000 ? -1 : 1;
  const e = (bits >> 10) & 0x1f;
  const m = bits & 0x3ff;
  if (e === 0) return s * m * 2 ** -24;
  if (e === 31) return m ? NaN : s * Infinity;
  return s * (1 + m / 1024) * 2 ** (e - 15);
}

const texel = c.typeSize * 4;
const n = c.pixelWidth;
const level0 = c.levels[0].levelData;
const view = new DataView(level0.buffer, level0.byteOffset, level0.byteLength);
const channel = (at) => (c.typeSize === 2 ? half(view.getUint16(at, true)) : view.getFloat32(at, true));
let best = { lum: -1 };
for (let f = 0; f < c.faceCount; f++) {
  for (let y = 0; y < n; y++) {
    for (let x = 0; x < n; x++) {
      const at = ((f * n + y) * n + x) * texel;
      const rgb = [0, 1, 2].map((k) => channel(at + k * c.typeSize));
      const lum = 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
      if (lum > best.lum) best = { lum, face: f, x, y, rgb };
    }
  }
}
const dfd = c.dataFormatDescriptor[0];
const text = (v) => (typeof v === 'string' ? v : new TextDecoder().decode(v)).replace(/\0+$/, '');
console.log(JSON.stringify({
  vkFormat: c.vkFormat,
  typeSize: c.typeSize,
  pixelWidth: c.pixelWidth,
  pixelHeight: c.pixelHeight,
  faceCount: c.faceCount,
  levelCount: c.levelCount,
  levelBytes: c.levels.map((l) => l.levelData.byteLength),
  colorModel: dfd.colorModel,
  colorPrimaries: dfd.colorPrimaries,
  transferFunction: dfd.transferFunction,
  samples: dfd.samples.map((s) => ({ channelType: s.channelType, bitOffset: s.bitOffset, bitLength: s.bitLength })),
  keyValue: Object.fromEntries(Object.entries(c.keyValue).map(([k, v]) => [k, text(v)])),
  brightest: best,
}));
