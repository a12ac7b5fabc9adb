// sweepdepth live view: subscribes over the Foxglove WebSocket protocol (foxglove.sdk.v1) to
// the node's point cloud, depth and confidence (ROS 2 CDR) and draws them with three.js.
// With fusion it also subscribes to the mesh (visualization_msgs/MarkerArray deltas: one
// TRIANGLE_LIST per block) and draws it, one THREE.Mesh per block.
// When it has drawn a point cloud and a depth image it sets document.body.dataset.drawn = "1",
// when it has drawn mesh blocks document.body.dataset.mesh = "1" (the browser test waits for
// them); window.sweepdepthState counts what it drew.
import * as THREE from 'three';
import { OrbitControls } from './OrbitControls.js';

const state = {
  clouds: 0, points: 0, depthFrames: 0, confidenceFrames: 0, errors: [],
  meshUpdates: 0, meshBlocks: 0, meshTriangles: 0, show: 'points', cloudFrame: '', meshFrame: '',
};
window.sweepdepthState = state;
const $ = (id) => document.getElementById(id);

// ---- CDR (little-endian, XCDR1 as ROS 2 writes it; alignment from the body's start) ----
class Cdr {
  constructor(buffer) {
    this.view = new DataView(buffer.buffer, buffer.byteOffset, buffer.byteLength);
    this.bytes = buffer;
    if (this.view.getUint8(1) !== 1) throw new Error('not little-endian CDR');
    this.pos = 4;
  }
  align(n) { const rel = this.pos - 4; this.pos += (n - (rel % n)) % n; }
  u8() { return this.view.getUint8(this.pos++); }
  u32() { this.align(4); const v = this.view.getUint32(this.pos, true); this.pos += 4; return v; }
  f32() { this.align(4); const v = this.view.getFloat32(this.pos, true); this.pos += 4; return v; }
  f64() { this.align(8); const v = this.view.getFloat64(this.pos, true); this.pos += 8; return v; }
  i32() { this.align(4); const v = this.view.getInt32(this.pos, true); this.pos += 4; return v; }
  string() {
    const n = this.u32();
    const s = new TextDecoder().decode(this.bytes.subarray(this.pos, this.pos + Math.max(0, n - 1)));
    this.pos += n; return s;
  }
  bytesSeq() { const n = this.u32(); const b = this.bytes.subarray(this.pos, this.pos + n); this.pos += n; return b; }
  header() { const sec = this.i32(); const nanosec = this.u32(); return { sec, nanosec, frame_id: this.string() }; }
}

function decodeImage(buf) {
  const r = new Cdr(buf);
  const header = r.header();
  const height = r.u32(), width = r.u32(), encoding = r.string();
  const bigEndian = r.u8(); const step = r.u32(); const data = r.bytesSeq();
  return { header, height, width, encoding, bigEndian, step, data };
}

function decodeCloud(buf) {
  const r = new Cdr(buf);
  const header = r.header();
  const height = r.u32(), width = r.u32();
  const fields = [];
  for (let n = r.u32(); n > 0; n--) {
    fields.push({ name: r.string(), offset: r.u32(), datatype: r.u8(), count: r.u32() });
  }
  const bigEndian = r.u8(); const pointStep = r.u32(); const rowStep = r.u32();
  const data = r.bytesSeq();
  return { header, height, width, fields, bigEndian, pointStep, rowStep, data };
}

/** sRGB to linear (three.js wants vertex colours linear). */
const srgbToLinear = (c) => (c < 0.04045 ? c * 0.0773993808 : Math.pow(c * 0.9478672986 + 0.0521327014, 2.4));

// visualization_msgs/msg/MarkerArray, Marker in Jazzy's layout (Iron and later).
function decodeMarkerArray(buf) {
  const r = new Cdr(buf);
  const markers = [];
  for (let n = r.u32(); n > 0; n--) {
    const header = r.header();
    const ns = r.string(), id = r.i32(), type = r.i32(), action = r.i32();
    const pose = { x: r.f64(), y: r.f64(), z: r.f64(), qx: r.f64(), qy: r.f64(), qz: r.f64(), qw: r.f64() };
    r.f64(); r.f64(); r.f64(); // scale
    const color = [r.f32(), r.f32(), r.f32(), r.f32()];
    r.i32(); r.u32(); r.u8(); // lifetime, frame_locked
    const np = r.u32();
    r.align(8);
    const points = new Float32Array(3 * np);
    for (let i = 0; i < 3 * np; i++) { points[i] = r.view.getFloat64(r.pos, true); r.pos += 8; }
    const nc = r.u32();
    const colors = new Float32Array(3 * nc);
    for (let i = 0; i < nc; i++) {
      // ColorRGBA is sRGB; three.js wants vertex colours linear.
      for (let c = 0; c < 3; c++) colors[3 * i + c] = srgbToLinear(r.view.getFloat32(r.pos + 4 * c, true));
      r.pos += 16;
    }
    r.string(); // texture_resource
    r.header(); r.string(); r.bytesSeq(); // texture
    for (let nu = r.u32(); nu > 0; nu--) { r.f32(); r.f32(); } // uv_coordinates
    r.string(); r.string(); // text, mesh_resource
    r.string(); r.bytesSeq(); // mesh_file
    r.u8(); // mesh_use_embedded_materials
    markers.push({ header, ns, id, type, action, pose, color, points, colors });
  }
  return markers;
}

/** The q-quantiles of finite values (from at most 4096 evenly spread samples). */
function quantiles(values, qs) {
  const step = Math.max(1, Math.floor(values.length / 4096));
  const sample = [];
  for (let i = 0; i < values.length; i += step) if (Number.isFinite(values[i])) sample.push(values[i]);
  sample.sort((a, b) => a - b);
  return qs.map((q) => (sample.length ? sample[Math.min(sample.length - 1, Math.floor(q * sample.length))] : NaN));
}

// ---- 3D view ----
const container = $('cloud');
const renderer = new THREE.WebGLRenderer({ antialias: false, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio || 1);
renderer.setClearColor(0x14161a);
container.appendChild(renderer.domElement);
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(60, 1, 0.01, 1000);
camera.position.set(0, 0, -1);
const controls = new OrbitControls(camera, renderer.domElement);
// The mesh is lit by a soft ambient light and a light at the eye.
scene.add(new THREE.AmbientLight(0xffffff, 2.2));
const headlight = new THREE.DirectionalLight(0xffffff, 1.6);
headlight.position.set(0, 0, 1);
headlight.target.position.set(0, 0, -1);
camera.add(headlight, headlight.target);
scene.add(camera);
// ROS optical frame (x right, y down, z forward) into three.js (y up): turn about x by pi.
const cloudFrame = new THREE.Group();
cloudFrame.rotation.x = Math.PI;
scene.add(cloudFrame);
const geometry = new THREE.BufferGeometry();
const material = new THREE.PointsMaterial({ size: 2, sizeAttenuation: false, vertexColors: true });
const cloudPoints = new THREE.Points(geometry, material);
cloudFrame.add(cloudPoints);
let framed = false;
// The mesh, in its header's frame: the reference camera's optical frame (as the points) when
// the rig does not move, else the world frame (REP 103: z up). The page has no transforms:
// with different frames it shows the mesh or the points, not both.
const meshFrame = new THREE.Group();
scene.add(meshFrame);
const meshMaterial = new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.DoubleSide });
const blocks = new Map(); // `${ns}/${id}` -> THREE.Mesh
let meshFramed = false;

function resize() {
  const w = container.clientWidth, h = Math.max(300, container.clientHeight);
  renderer.setSize(w, h); camera.aspect = w / h; camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();
renderer.setAnimationLoop(() => { controls.update(); renderer.render(scene, camera); });

function showCloud(cloud) {
  const f = Object.fromEntries(cloud.fields.map((x) => [x.name, x.offset]));
  if (f.x === undefined || f.y === undefined || f.z === undefined) throw new Error('cloud without x, y, z');
  const n = cloud.width * cloud.height;
  const view = new DataView(cloud.data.buffer, cloud.data.byteOffset, cloud.data.byteLength);
  const pos = new Float32Array(n * 3), col = new Float32Array(n * 3);
  let k = 0;
  for (let i = 0; i < n; i++) {
    const o = i * cloud.pointStep;
    if (o + cloud.pointStep > cloud.data.byteLength) break;
    const x = view.getFloat32(o + f.x, true), y = view.getFloat32(o + f.y, true), z = view.getFloat32(o + f.z, true);
    if (!Number.isFinite(x) || !Number.isFinite(y) || !Number.isFinite(z)) continue;
    pos[3 * k] = x; pos[3 * k + 1] = y; pos[3 * k + 2] = z;
    if (f.rgb !== undefined) {
      const rgb = view.getUint32(o + f.rgb, true);
      col[3 * k] = ((rgb >> 16) & 255) / 255; col[3 * k + 1] = ((rgb >> 8) & 255) / 255; col[3 * k + 2] = (rgb & 255) / 255;
    } else { col[3 * k] = col[3 * k + 1] = col[3 * k + 2] = 0.8; }
    k++;
  }
  geometry.setAttribute('position', new THREE.BufferAttribute(pos.subarray(0, 3 * k), 3));
  geometry.setAttribute('color', new THREE.BufferAttribute(col.subarray(0, 3 * k), 3));
  geometry.computeBoundingSphere();
  if (!framed && k > 0) {
    // Look from the reference camera's origin towards the cloud's median (in three.js axes:
    // y and z flipped); the 5-95 % spread sets the clipping planes (a few far outliers must
    // not decide the view).
    const axis = (j) => quantiles(pos.subarray(0, 3 * k).filter((_, i) => i % 3 === j), [0.05, 0.5, 0.95]);
    const [ax, ay, az] = [axis(0), axis(1), axis(2)];
    const centre = new THREE.Vector3(ax[1], -ay[1], -az[1]);
    const span = Math.max(ax[2] - ax[0], ay[2] - ay[0], az[2], 1e-3);
    camera.near = span / 1000; camera.far = span * 100; camera.updateProjectionMatrix();
    // From beside the reference camera (a quarter of the distance to the right and up), so
    // the depth shows at once; orbit from there. `?view=above`: from above the cloud, looking
    // down at it (the depth runs up the screen: steps between planes show as stripes).
    const d = centre.length();
    if (new URLSearchParams(location.search).get('view') === 'above') {
      camera.position.set(centre.x, centre.y + 0.75 * d, centre.z + 0.4 * d);
    } else {
      camera.position.set(0.35 * d, 0.2 * d, 0);
    }
    controls.target.copy(centre);
    controls.update();
    framed = true;
  }
  state.points = k; state.clouds++; state.cloudFrame = cloud.header.frame_id;
  updateView();
}

// ---- mesh ----
function removeBlock(key) {
  const mesh = blocks.get(key);
  if (mesh) { meshFrame.remove(mesh); mesh.geometry.dispose(); blocks.delete(key); }
}

function applyMarkers(markers) {
  for (const m of markers) {
    const key = `${m.ns}/${m.id}`;
    if (m.action === 3) { for (const k of [...blocks.keys()]) removeBlock(k); continue; }
    if (m.action === 2) { removeBlock(key); continue; }
    if (m.action !== 0 || m.type !== 11) continue; // only TRIANGLE_LISTs
    removeBlock(key);
    state.meshFrame = m.header.frame_id;
    const n = Math.floor(m.points.length / 9) * 9;
    if (n === 0) continue;
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(m.points.subarray(0, n), 3));
    let colors = m.colors;
    if (colors.length < n) { // one colour for the marker
      colors = new Float32Array(n);
      for (let i = 0; i < n; i += 3) for (let c = 0; c < 3; c++) colors[i + c] = srgbToLinear(m.color[c]);
    }
    g.setAttribute('color', new THREE.BufferAttribute(colors.subarray(0, n), 3));
    g.computeVertexNormals();
    g.computeBoundingSphere();
    const mesh = new THREE.Mesh(g, meshMaterial);
    mesh.position.set(m.pose.x, m.pose.y, m.pose.z);
    if (m.pose.qx || m.pose.qy || m.pose.qz || m.pose.qw) mesh.quaternion.set(m.pose.qx, m.pose.qy, m.pose.qz, m.pose.qw);
    meshFrame.add(mesh);
    blocks.set(key, mesh);
  }
  let triangles = 0;
  for (const mesh of blocks.values()) triangles += mesh.geometry.attributes.position.count / 3;
  state.meshBlocks = blocks.size; state.meshTriangles = triangles; state.meshUpdates++;
  updateView();
}

/** Whether the mesh and the points are in the same frame (then both can be shown). */
function sameFrame() { return !state.cloudFrame || !state.meshFrame || state.cloudFrame === state.meshFrame; }

function updateView() {
  // The mesh's frame: the points' optical frame, else a z-up world frame.
  meshFrame.rotation.x = sameFrame() ? Math.PI : -Math.PI / 2;
  const select = $('show');
  const both = select.querySelector('option[value="both"]');
  both.disabled = !sameFrame();
  both.title = sameFrame() ? '' : `the mesh (${state.meshFrame}) and the points (${state.cloudFrame}) are in different frames`;
  let show = select.value;
  if (show === 'auto') show = state.meshBlocks > 0 ? 'mesh' : 'points';
  if (show === 'both' && !sameFrame()) show = 'mesh';
  state.show = show;
  cloudPoints.visible = show !== 'mesh';
  meshFrame.visible = show !== 'points';
  const parts = [];
  if (cloudPoints.visible) parts.push(`${state.points.toLocaleString()} points`);
  if (meshFrame.visible) parts.push(`${state.meshTriangles.toLocaleString()} triangles in ${state.meshBlocks.toLocaleString()} blocks`);
  $('count').textContent = parts.join(', ');
  if (meshFrame.visible && state.meshBlocks > 0) {
    if (!meshFramed) frameMesh();
    document.body.dataset.mesh = '1';
  }
}

/** Looks at the mesh (once, unless the points framed the same frame already). */
function frameMesh() {
  meshFramed = true;
  if (framed && sameFrame() && state.cloudFrame) return;
  meshFrame.updateMatrixWorld(true);
  const box = new THREE.Box3().setFromObject(meshFrame);
  if (box.isEmpty()) return;
  const centre = box.getCenter(new THREE.Vector3());
  const size = box.getSize(new THREE.Vector3());
  const span = Math.max(size.x, size.y, size.z, 1e-3);
  camera.near = span / 1000; camera.far = span * 100; camera.updateProjectionMatrix();
  if (sameFrame()) {
    // From beside the reference camera (its origin), as for the points.
    const d = centre.length();
    camera.position.set(0.35 * d, 0.2 * d, 0);
  } else {
    camera.position.copy(centre).add(new THREE.Vector3(0.8 * span, 0.7 * span, 0.8 * span));
  }
  controls.target.copy(centre);
  controls.update();
  framed = true;
}

$('show').addEventListener('change', updateView);

// ---- images ----
function turbo(t) { // a short polynomial fit of the Turbo colour map, t in [0, 1]
  const r = 34.61 + t * (1172.33 - t * (10793.56 - t * (33300.12 - t * (38394.49 - t * 14825.05))));
  const g = 23.31 + t * (557.33 + t * (1225.33 - t * (3574.96 - t * (1073.77 + t * 707.56))));
  const b = 27.2 + t * (3211.1 - t * (15327.97 - t * (27814 - t * (22569.18 - t * 6838.66))));
  return [r, g, b].map((v) => Math.max(0, Math.min(255, v)));
}

function showFloatImage(canvasId, img, colourise) {
  if (img.encoding !== '32FC1') throw new Error(`${canvasId}: encoding ${img.encoding}, expected 32FC1`);
  const canvas = $(canvasId);
  canvas.width = img.width; canvas.height = img.height;
  const view = new DataView(img.data.buffer, img.data.byteOffset, img.data.byteLength);
  const values = new Float32Array(img.width * img.height);
  for (let v = 0; v < img.height; v++) for (let u = 0; u < img.width; u++) {
    values[v * img.width + u] = view.getFloat32(v * img.step + 4 * u, !img.bigEndian);
  }
  // The colour scale spans the 2-98 % range (a few outliers would flatten it).
  const [lo, hi] = quantiles(values, [0.02, 0.98]);
  const ctx = canvas.getContext('2d');
  const out = ctx.createImageData(img.width, img.height);
  for (let i = 0; i < values.length; i++) {
    const x = values[i];
    let rgb = [0, 0, 0];
    if (Number.isFinite(x)) rgb = colourise(hi > lo ? Math.max(0, Math.min(1, (x - lo) / (hi - lo))) : 0.5, x);
    out.data.set([rgb[0], rgb[1], rgb[2], 255], 4 * i);
  }
  ctx.putImageData(out, 0, 0);
  return [lo, hi];
}

// ---- rate and latency ----
const arrivals = [];
function onDepthArrived(logTimeNs, stamp) {
  const now = Date.now();
  arrivals.push(now);
  while (arrivals.length > 1 && now - arrivals[0] > 5000) arrivals.shift();
  if (arrivals.length > 1) {
    const hz = (arrivals.length - 1) / ((arrivals[arrivals.length - 1] - arrivals[0]) / 1000);
    $('rate').textContent = `${hz.toFixed(2)} Hz`;
  }
  const delivery = now - Number(logTimeNs / 1000000n);
  const age = now - (stamp.sec * 1000 + stamp.nanosec / 1e6);
  // Live: stamp to browser; a bag's old stamps: output to browser.
  $('latency').textContent = Math.abs(age) < 3600e3
    ? `latency ${age.toFixed(0)} ms (capture → here)`
    : `latency ${delivery.toFixed(0)} ms (output → here)`;
}

function markDrawn() {
  if (state.clouds > 0 && state.points > 0 && state.depthFrames > 0) document.body.dataset.drawn = '1';
}

// ---- Foxglove WebSocket protocol ----
const handlers = new Map(); // subscription id -> function(payload, logTime)
let nextSub = 1;

function subscribe(ws, channel) {
  let handle;
  if (channel.schemaName === 'sensor_msgs/msg/PointCloud2') {
    handle = (p) => { showCloud(decodeCloud(p)); markDrawn(); };
  } else if (channel.schemaName === 'sensor_msgs/msg/Image' && channel.topic.endsWith('depth/image')) {
    handle = (p, t) => {
      const img = decodeImage(p);
      const [lo, hi] = showFloatImage('depth', img, (s) => turbo(1 - s));
      $('depth-title').textContent = `depth ${lo.toFixed(2)}–${hi.toFixed(2)} m (${img.width}×${img.height})`;
      state.depthFrames++; onDepthArrived(t, img.header); markDrawn();
    };
  } else if (channel.schemaName === 'sensor_msgs/msg/Image' && channel.topic.endsWith('confidence/image')) {
    handle = (p) => {
      showFloatImage('confidence', decodeImage(p), (_s, x) => { const g = Math.max(0, Math.min(1, x)) * 255; return [g, g, g]; });
      state.confidenceFrames++;
    };
  } else if (channel.schemaName === 'visualization_msgs/msg/MarkerArray') {
    handle = (p) => applyMarkers(decodeMarkerArray(p));
  } else return;
  if (channel.encoding !== 'cdr') return;
  const id = nextSub++;
  handlers.set(id, handle);
  ws.send(JSON.stringify({ op: 'subscribe', subscriptions: [{ id, channelId: channel.id }] }));
}

async function connect() {
  const query = new URLSearchParams(location.search);
  let url = query.get('ws');
  if (!url) {
    const config = await (await fetch('config.json')).json();
    url = `ws://${location.hostname}:${config.websocket_port}`;
  }
  $('wsurl').textContent = url;
  const ws = new WebSocket(url, ['foxglove.sdk.v1']);
  ws.binaryType = 'arraybuffer';
  ws.onopen = () => { $('status').textContent = `connected to ${url}`; };
  ws.onclose = () => { $('status').textContent = 'disconnected; retrying…'; handlers.clear(); setTimeout(connect, 2000); };
  ws.onmessage = (event) => {
    try {
      if (typeof event.data === 'string') {
        const msg = JSON.parse(event.data);
        if (msg.op === 'advertise') for (const channel of msg.channels) subscribe(ws, channel);
        return;
      }
      const view = new DataView(event.data);
      if (view.getUint8(0) !== 1) return; // only message data
      const sub = view.getUint32(1, true);
      const logTime = view.getBigUint64(5, true);
      const handle = handlers.get(sub);
      if (handle) handle(new Uint8Array(event.data, 13), logTime);
    } catch (e) {
      state.errors.push(String(e));
      $('status').textContent = `error: ${e}`;
    }
  };
}
connect();
