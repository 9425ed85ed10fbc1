// The page `lumiprobe view` writes: scrub through a run's frames, each with its
// SDR frame, its predicted probe (exposure slider) and a model lit by the probe
// and its lights. `#frame=K` in the address opens frame K. What the page shows
// is summarised as JSON in #status (read by lumiprobe's tests).
import * as THREE from 'three';
import { RGBELoader } from 'three/addons/loaders/RGBELoader.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const $ = (id) => document.getElementById(id);
const status = { ready: false };
const say = (more) => { Object.assign(status, more); $('status').textContent = JSON.stringify(status); };
window.addEventListener('error', (e) => say({ error: String(e.message) }));
window.addEventListener('unhandledrejection', (e) => say({ error: String(e.reason) }));

const view = await (await fetch('view.json', { cache: 'no-cache' })).json();
const frames = view.frames;

// The model's viewport.
const holder = $('model');
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.toneMapping = THREE.ACESFilmicToneMapping;
renderer.shadowMap.enabled = true;
renderer.setPixelRatio(1);
holder.prepend(renderer.domElement);
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(45, 1, 0.01, 1000);
camera.position.set(0, 0.25, 1.2);
const controls = new OrbitControls(camera, renderer.domElement);
controls.target.set(0, 0, 0);
controls.update();
const pmrem = new THREE.PMREMGenerator(renderer);

// The model stands at the frame's position (the origin here), half a metre
// across; without one, three spheres: diffuse, glossy, mirror.
const model = new THREE.Group();
scene.add(model);
if (view.model) {
  const gltf = await new GLTFLoader().loadAsync(view.model);
  const box = new THREE.Box3().setFromObject(gltf.scene);
  const size = box.getSize(new THREE.Vector3()).length() || 1;
  const centre = box.getCenter(new THREE.Vector3());
  gltf.scene.position.sub(centre);
  const wrap = new THREE.Group();
  wrap.add(gltf.scene);
  wrap.scale.setScalar(0.5 / size);
  model.add(wrap);
} else {
  const geo = new THREE.SphereGeometry(0.08, 64, 32);
  const mats = [
    new THREE.MeshStandardMaterial({ color: 0xcccccc, roughness: 1, metalness: 0 }),
    new THREE.MeshStandardMaterial({ color: 0xcccccc, roughness: 0.35, metalness: 1 }),
    new THREE.MeshStandardMaterial({ color: 0xffffff, roughness: 0, metalness: 1 }),
  ];
  mats.forEach((m, i) => {
    const s = new THREE.Mesh(geo, m);
    s.position.set((i - 1) * 0.2, 0, 0);
    model.add(s);
  });
}
model.traverse((o) => { if (o.isMesh) { o.castShadow = true; o.receiveShadow = true; } });
const ground = new THREE.Mesh(new THREE.CircleGeometry(0.6, 64), new THREE.ShadowMaterial({ opacity: 0.5 }));
ground.rotation.x = -Math.PI / 2;
ground.position.y = -0.25;
ground.receiveShadow = true;
scene.add(ground);

function resize() {
  // As tall as the two panoramas beside it (each half as tall as wide).
  const w = holder.clientWidth || 640;
  const h = Math.max(360, w - 24);
  renderer.setSize(w, h);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', () => { resize(); draw(); });
resize();

// What lights the model: `hdr` (the probe's residual environment and its
// lights, the default), `probe` (the whole probe as the environment, no
// lights) or `ktx2` (the exported GGX-prefiltered cube's mip 0, read with npm
// ktx-parse, no lights). `?env=` in the address chooses it.
const params = new URLSearchParams(location.search);
let envMode = params.get('env') || 'hdr';
if (!frames.every((f) => f.specular)) {
  $('env').querySelector('option[value="ktx2"]').remove();
  if (envMode === 'ktx2') envMode = 'hdr';
}
$('env').value = envMode;

// A KTX 2.0 cube (uncompressed RGBA half or single floats) as a three.js cube
// texture: level 0's six faces, in KTX 2.0's (OpenGL's) order and orientation.
async function loadKtx2Cube(url) {
  const { read } = await import('ktx-parse');
  const c = read(new Uint8Array(await (await fetch(url)).arrayBuffer()));
  if (c.faceCount !== 6 || c.supercompressionScheme !== 0 || !(c.typeSize === 2 || c.typeSize === 4)) {
    throw new Error(`${url}: not an uncompressed float cube map`);
  }
  const n = c.pixelWidth;
  const level = c.levels[0].levelData;
  const faceBytes = n * n * 4 * c.typeSize;
  const type = c.typeSize === 2 ? THREE.HalfFloatType : THREE.FloatType;
  const faces = [];
  for (let f = 0; f < 6; f++) {
    const bytes = level.slice(f * faceBytes, (f + 1) * faceBytes);
    const data = c.typeSize === 2 ? new Uint16Array(bytes.buffer) : new Float32Array(bytes.buffer);
    faces.push(new THREE.DataTexture(data, n, n, THREE.RGBAFormat, type));
  }
  const cube = new THREE.CubeTexture(faces);
  cube.format = THREE.RGBAFormat;
  cube.type = type;
  cube.generateMipmaps = false;
  cube.minFilter = cube.magFilter = THREE.LinearFilter;
  // three.js mirrors x when it samples a cube texture it did not render
  // itself; KTX 2.0 cubes follow OpenGL's convention, which it samples as
  // is for its own render targets.
  cube.isRenderTargetTexture = true;
  cube.needsUpdate = true;
  return cube;
}

// Frames: loaded once each per lighting, kept.
const hdr = new RGBELoader().setDataType(THREE.FloatType);
const cache = new Map();
const noLights = new THREE.Group();
async function load(i) {
  const key = `${i}/${envMode}`;
  if (cache.has(key)) return cache.get(key);
  const f = frames[i];
  const probe = await hdr.loadAsync(f.probe);
  probe.mapping = THREE.EquirectangularReflectionMapping;
  let entry;
  if (envMode === 'ktx2') {
    const cube = await loadKtx2Cube(f.specular);
    entry = { probe, background: cube, env: pmrem.fromCubemap(cube).texture, lights: noLights };
  } else if (envMode === 'probe') {
    entry = { probe, background: probe, env: pmrem.fromEquirectangular(probe).texture, lights: noLights };
  } else {
    const [residual, lights] = await Promise.all([hdr.loadAsync(f.residual), new GLTFLoader().loadAsync(f.lights)]);
    lights.scene.position.set(-f.position[0], -f.position[1], -f.position[2]);
    lights.scene.traverse((o) => {
      if (o.isSpotLight) {
        // A flat emitter (a ceiling panel) as glTF's 90-degree spot: its
        // shadows from a perspective map.
        o.castShadow = true;
        o.shadow.mapSize.set(1024, 1024);
        o.shadow.camera.near = 0.01;
      }
      if (o.isDirectionalLight) {
        o.castShadow = true;
        o.shadow.mapSize.set(1024, 1024);
        const c = o.shadow.camera;
        c.left = c.bottom = -0.7; c.right = c.top = 0.7; c.near = 0.01; c.far = 1e4;
      }
    });
    entry = { probe, background: probe, env: pmrem.fromEquirectangular(residual).texture, lights: lights.scene };
  }
  cache.set(key, entry);
  return entry;
}

const EQUIRECT_TURN = +(params.get('turn') ?? (Math.PI / 2));
let current = -1;
let shown = null;
let ev = 0;

// The predicted probe, tone-mapped here (exposure, then sRGB) from its floats.
function drawProbe() {
  if (!shown) return 0;
  const img = shown.probe.image;
  const c = $('probe');
  c.width = img.width; c.height = img.height;
  const ctx = c.getContext('2d');
  const out = ctx.createImageData(img.width, img.height);
  const k = frames[current].exposure * Math.pow(2, ev);
  const srgb = (x) => (x <= 0.0031308 ? 12.92 * x : 1.055 * Math.pow(x, 1 / 2.4) - 0.055);
  let sum = 0;
  const src = img.data;
  const n = img.width * img.height;
  const step = src.length / n;
  for (let p = 0; p < n; p++) {
    for (let ch = 0; ch < 3; ch++) {
      const v = Math.min(1, Math.max(0, srgb(src[p * step + ch] * k)));
      out.data[p * 4 + ch] = Math.round(v * 255);
      sum += v;
    }
    out.data[p * 4 + 3] = 255;
  }
  ctx.putImageData(out, 0, 0);
  return sum / (3 * n);
}

// Mean display value of the model's pixels, and how many there are: the model
// drawn once in flat white on black marks them.
function modelStats() {
  const gl = renderer.getContext();
  const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
  const read = () => { const b = new Uint8Array(w * h * 4); gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, b); return b; };
  const bg = scene.background, vis = ground.visible, tm = renderer.toneMapping;
  scene.background = new THREE.Color(0, 0, 0);
  ground.visible = false;
  scene.overrideMaterial = new THREE.MeshBasicMaterial({ color: 0xffffff });
  renderer.toneMapping = THREE.NoToneMapping;
  renderer.render(scene, camera);
  const mask = read();
  scene.overrideMaterial = null;
  scene.background = bg; ground.visible = vis; renderer.toneMapping = tm;
  renderer.render(scene, camera);
  const lit = read();
  let count = 0, sum = 0;
  // The whole view's mean display value on an 8 x 6 grid (rows from the top).
  const grid = new Array(48).fill(0), cells = new Array(48).fill(0);
  for (let i = 0; i < w * h; i++) {
    const v = (lit[i * 4] + lit[i * 4 + 1] + lit[i * 4 + 2]) / (3 * 255);
    if (mask[i * 4] > 128) { count++; sum += v; }
    const x = i % w, y = h - 1 - Math.floor(i / w);
    const cell = Math.min(5, Math.floor(y * 6 / h)) * 8 + Math.min(7, Math.floor(x * 8 / w));
    grid[cell] += v; cells[cell]++;
  }
  return { model_pixels: count, model_mean: count ? sum / count : 0, grid: grid.map((g, k) => g / Math.max(1, cells[k])) };
}

function draw() {
  if (!shown) return;
  renderer.toneMappingExposure = frames[current].exposure * Math.pow(2, ev);
  renderer.render(scene, camera);
}

async function show(i) {
  i = Math.max(0, Math.min(frames.length - 1, i | 0));
  const f = frames[i];
  say({ ready: false, frame: i });
  const sdr = $('sdr');
  const sdrLoaded = new Promise((ok) => { sdr.onload = ok; sdr.onerror = ok; });
  sdr.src = f.sdr;
  const entry = await load(i);
  await sdrLoaded;
  if (shown) scene.remove(shown.lights);
  shown = entry;
  current = i;
  scene.add(entry.lights);
  scene.background = entry.background;
  scene.environment = entry.env;
  // three.js's equirect mapping puts +x at the image's centre column; the
  // probes (lumiprobe's convention, as exported) put -z there.
  const turn = entry.background.isCubeTexture ? 0 : EQUIRECT_TURN;
  scene.backgroundRotation.set(0, turn, 0);
  scene.environmentRotation.set(0, envMode === 'ktx2' ? 0 : EQUIRECT_TURN, 0);
  $('frame').value = i;
  $('frame-label').textContent = `${f.id} (${i + 1} of ${frames.length}), ${f.light_count} light${f.light_count === 1 ? '' : 's'}`;
  $('ev-label').textContent = `${ev >= 0 ? '+' : ''}${ev} EV (auto x${f.exposure.toPrecision(3)})`;
  history.replaceState(null, '', `#frame=${i}`);
  const probeMean = drawProbe();
  draw();
  const stats = modelStats();
  say({ ready: true, frame: i, id: f.id, env: envMode, lights: envMode === 'hdr' ? f.light_count : 0, sdr_width: sdr.naturalWidth, probe_mean: probeMean, ...stats });
}

$('frame').max = frames.length - 1;
$('env').addEventListener('change', (e) => { envMode = e.target.value; show(current); });
$('frame').addEventListener('input', (e) => show(+e.target.value));
$('ev').addEventListener('input', (e) => {
  ev = +e.target.value;
  if (current >= 0) {
    $('ev-label').textContent = `${ev >= 0 ? '+' : ''}${ev} EV (auto x${frames[current].exposure.toPrecision(3)})`;
    drawProbe();
    draw();
  }
});
let timer = null;
$('play').addEventListener('click', () => {
  if (timer) { clearInterval(timer); timer = null; $('play').textContent = 'play'; return; }
  $('play').textContent = 'pause';
  timer = setInterval(() => show((current + 1) % frames.length), 500);
});
controls.addEventListener('change', draw);
window.addEventListener('keydown', (e) => {
  if (e.key === 'ArrowRight') show(current + 1);
  if (e.key === 'ArrowLeft') show(current - 1);
});

// The eval report and plots, when the page was written with them.
if (view.eval.length) {
  const sec = $('eval');
  for (const p of view.eval) {
    if (p.endsWith('.html')) {
      const a = document.createElement('a');
      a.href = p; a.textContent = 'evaluation report';
      const d = document.createElement('p');
      d.append(a);
      sec.append(d);
    } else {
      const im = document.createElement('img');
      im.src = p; im.alt = p;
      sec.append(im);
    }
  }
}

const m = location.hash.match(/frame=(\d+)/);
await show(m ? +m[1] : 0);
