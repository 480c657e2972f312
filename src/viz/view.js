// shapeforest view: the scan (left) and the reference (right), coloured through the map.
// Data comes from the JSON block #sf-data written by shapeforest (src/viz/html.rs).
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const D = JSON.parse(document.getElementById('sf-data').textContent);
const status = document.getElementById('status');

function bytes(b64) {
  const bin = atob(b64);
  const out = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
  return out;
}
const f32 = (s) => new Float32Array(bytes(s).buffer);
const u32 = (s) => new Uint32Array(bytes(s).buffer);

const canvas = document.getElementById('view');
let renderer;
try {
  renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
} catch (e) {
  status.textContent = 'WebGL is not available in this browser: ' + e.message;
  throw e;
}
renderer.setPixelRatio(window.devicePixelRatio || 1);
renderer.setClearColor(0xf6f6f6, 1);

// One scene per shape, each centred at the origin and scaled to unit radius, seen through one
// camera (so orbiting turns both the same way), rendered into its half of the canvas.
function makeSide(shape) {
  const positions = f32(shape.positions);
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
  geometry.setIndex(new THREE.BufferAttribute(u32(shape.faces), 1));
  geometry.computeBoundingSphere();
  const { center, radius } = geometry.boundingSphere;
  geometry.translate(-center.x, -center.y, -center.z);
  geometry.scale(1 / radius, 1 / radius, 1 / radius);
  geometry.computeVertexNormals();
  geometry.computeBoundingSphere();
  const mapColors = bytes(shape.colors);
  const color = new THREE.BufferAttribute(new Uint8Array(mapColors), 3, true);
  geometry.setAttribute('color', color);
  const material = new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.DoubleSide });
  const mesh = new THREE.Mesh(geometry, material);
  const scene = new THREE.Scene();
  scene.add(mesh);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x888888, 1.6));
  const light = new THREE.DirectionalLight(0xffffff, 1.6);
  scene.add(light);
  const marker = new THREE.Mesh(
    new THREE.SphereGeometry(0.035, 16, 12),
    new THREE.MeshBasicMaterial({ color: 0xff00ff, depthTest: false })
  );
  marker.renderOrder = 1;
  marker.visible = false;
  scene.add(marker);
  return { name: shape.name, scene, mesh, geometry, light, marker, mapColors, n: positions.length / 3 };
}

const sides = [makeSide(D.scan), makeSide(D.reference)];
const map = u32(D.map);
const errors = D.errors ? f32(D.errors.values) : null;

const camera = new THREE.PerspectiveCamera(35, 1, 0.01, 100);
camera.position.set(0, 0, 3.0);
const controls = new OrbitControls(camera, canvas);
controls.addEventListener('change', render);

function halfWidth() {
  return canvas.clientWidth / 2;
}

function resize() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  renderer.setSize(w, h, false);
  camera.aspect = w / 2 / h;
  camera.updateProjectionMatrix();
  render();
}

function render() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  renderer.setScissorTest(true);
  sides.forEach((s, i) => {
    s.light.position.copy(camera.position);
    renderer.setViewport(i * w / 2, 0, w / 2, h);
    renderer.setScissor(i * w / 2, 0, w / 2, h);
    renderer.render(s.scene, camera);
  });
}

// Colour modes: through the map, or the error heat map on the scan (when ground truth is known).
function errorColor(e, max) {
  const stops = [[40, 60, 160], [60, 190, 210], [240, 220, 60], [200, 30, 30]];
  const t = Math.min(Math.max(e / max, 0), 1) * 3;
  const i = Math.min(Math.floor(t), 2), f = t - i;
  return stops[i].map((a, k) => Math.round(a + f * (stops[i + 1][k] - a)));
}
function setMode(mode) {
  const scan = sides[0];
  const attr = scan.geometry.getAttribute('color');
  if (mode === 'error' && errors) {
    for (let v = 0; v < scan.n; v++) attr.array.set(errorColor(errors[v], D.errors.max), 3 * v);
  } else {
    attr.array.set(scan.mapColors);
  }
  attr.needsUpdate = true;
  document.querySelectorAll('[data-mode]').forEach((b) => b.classList.toggle('on', b.dataset.mode === mode));
  api.mode = mode;
  render();
}
document.querySelectorAll('[data-mode]').forEach((b) => b.addEventListener('click', () => setMode(b.dataset.mode)));

// Selection: a vertex on one side and its match on the other. A reference vertex's match is
// the scan vertex mapped closest to it.
function matchOf(side, v) {
  if (side === 0) return map[v];
  const p = sides[1].geometry.getAttribute('position').array;
  let best = 0, bestD = Infinity;
  for (let i = 0; i < map.length; i++) {
    const r = map[i];
    const d = (p[3 * r] - p[3 * v]) ** 2 + (p[3 * r + 1] - p[3 * v + 1]) ** 2 + (p[3 * r + 2] - p[3 * v + 2]) ** 2;
    if (d < bestD) { bestD = d; best = i; if (d === 0) break; }
  }
  return best;
}
function place(side, v) {
  const p = sides[side].geometry.getAttribute('position');
  sides[side].marker.position.set(p.getX(v), p.getY(v), p.getZ(v));
  sides[side].marker.visible = true;
}
function select(side, v) {
  const m = matchOf(side, v);
  const scanV = side === 0 ? v : m, refV = side === 0 ? m : v;
  place(0, scanV);
  place(1, refV);
  api.selection = { side: side === 0 ? 'scan' : 'reference', vertex: v, scanVertex: scanV, referenceVertex: refV };
  let text = `scan ${sides[0].name} vertex ${scanV} ↔ reference ${sides[1].name} vertex ${refV}`;
  if (errors) text += ` · error ${errors[scanV].toFixed(3)} (nearest evaluated point)`;
  document.getElementById('selection').textContent = text;
  render();
  return api.selection;
}

const raycaster = new THREE.Raycaster();
function pick(clientX, clientY) {
  const rect = canvas.getBoundingClientRect();
  const x = clientX - rect.left, y = clientY - rect.top, hw = rect.width / 2;
  const side = x < hw ? 0 : 1;
  const ndc = new THREE.Vector2(((x - side * hw) / hw) * 2 - 1, -(y / rect.height) * 2 + 1);
  raycaster.setFromCamera(ndc, camera);
  const hit = raycaster.intersectObject(sides[side].mesh)[0];
  if (!hit) return null;
  const p = sides[side].geometry.getAttribute('position');
  let best = hit.face.a, bestD = Infinity;
  for (const v of [hit.face.a, hit.face.b, hit.face.c]) {
    const d = new THREE.Vector3(p.getX(v), p.getY(v), p.getZ(v)).distanceToSquared(hit.point);
    if (d < bestD) { bestD = d; best = v; }
  }
  return { side, vertex: best };
}
let down = null;
canvas.addEventListener('pointerdown', (e) => { down = [e.clientX, e.clientY]; });
canvas.addEventListener('pointerup', (e) => {
  if (!down || Math.hypot(e.clientX - down[0], e.clientY - down[1]) > 4) return;
  const p = pick(e.clientX, e.clientY);
  if (p) select(p.side, p.vertex);
});

// Page coordinates of a vertex (for tests and scripts), or null when it is hidden behind the
// shape or off screen.
function project(side, v) {
  const p = sides[side].geometry.getAttribute('position');
  const world = new THREE.Vector3(p.getX(v), p.getY(v), p.getZ(v));
  const ndc = world.clone().project(camera);
  if (Math.abs(ndc.x) > 1 || Math.abs(ndc.y) > 1) return null;
  const rect = canvas.getBoundingClientRect(), hw = rect.width / 2;
  const x = rect.left + side * hw + (ndc.x + 1) / 2 * hw, y = rect.top + (1 - ndc.y) / 2 * rect.height;
  const hit = pick(x, y);
  if (!hit || hit.side !== side) return null;
  const q = sides[side].geometry.getAttribute('position');
  const seen = new THREE.Vector3(q.getX(hit.vertex), q.getY(hit.vertex), q.getZ(hit.vertex));
  return seen.distanceTo(world) < 0.05 ? { x, y } : null;
}

const api = { ready: false, selection: null, mode: 'map', select: (side, v) => select(side === 'scan' ? 0 : 1, v), project: (side, v) => project(side === 'scan' ? 0 : 1, v), setMode };
window.sfView = api;
window.addEventListener('resize', resize);
resize();
setMode('map');
status.textContent = '';
api.ready = true;
document.body.dataset.ready = '1';
