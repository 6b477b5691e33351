// fleetslam operator console: 3D map, live camera, network statistics and teleoperation.
import * as THREE from "three";
import { OrbitControls } from "/static/vendor/OrbitControls.js";

const COLORS = ["#39b5ff", "#ff7a45", "#3ddc84", "#c77dff", "#ffd166", "#ef476f"];
const state = {
  socket: null, agents: [], selected: null, camera: "rgb", limits: { max_linear: 0.5, max_angular: 1.2 },
  rtt: null, voxelCount: 0, renders: 0, voxelMessages: 0, received: 0, acked: 0, frameCount: 0, lastFrameSeq: 0, driveSent: 0,
  deadman: { key: false, button: false, pad: false }, keys: new Set(), stick: { v: 0, w: 0 }, estop: false,
};
window.fleetslam = state; // for tests and the curious

// ---------------------------------------------------------------- 3D view
const container = document.getElementById("view3d");
// Without a GPU (SwiftShader, llvmpipe) every fragment is computed on the CPU the robots' SLAM needs: there the view
// is drawn at half resolution without multisampling (a quarter of the pixels, one sample each). Measured in
// headless Chromium on two cores with the demo's maps: 85 % of a core for the page at full resolution with 4×
// multisampling, drawing five times a second.
function softwareGL() {
  const gl = document.createElement("canvas").getContext("webgl2") || document.createElement("canvas").getContext("webgl");
  const info = gl && gl.getExtension("WEBGL_debug_renderer_info");
  const name = info ? String(gl.getParameter(info.UNMASKED_RENDERER_WEBGL)) : "";
  return /swiftshader|llvmpipe|softpipe|software/i.test(name);
}
const SOFTWARE_GL = softwareGL();
const renderer = new THREE.WebGLRenderer({ antialias: !SOFTWARE_GL });
renderer.setPixelRatio(SOFTWARE_GL ? 0.5 : window.devicePixelRatio);
state.softwareGL = SOFTWARE_GL;
container.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color("#0f141a");
scene.up.set(0, 0, 1);
const camera3d = new THREE.PerspectiveCamera(55, 1, 0.05, 500);
camera3d.up.set(0, 0, 1);
camera3d.position.set(-8, -10, 12);
const controls = new OrbitControls(camera3d, renderer.domElement);
controls.target.set(5, 2, 0);
controls.update();
scene.add(new THREE.AmbientLight(0xffffff, 0.7));
const sun = new THREE.DirectionalLight(0xffffff, 0.8);
sun.position.set(10, -5, 20);
scene.add(sun);
const grid = new THREE.GridHelper(60, 60, 0x263140, 0x1a222c);
grid.rotation.x = Math.PI / 2;
scene.add(grid);
scene.add(new THREE.AxesHelper(1.0));

function resize() {
  const w = container.clientWidth, h = container.clientHeight;
  renderer.setSize(w, h);
  camera3d.aspect = w / Math.max(h, 1);
  camera3d.updateProjectionMatrix();
}
window.addEventListener("resize", resize);
resize();

const agentViews = new Map();
function agentColor(name) {
  if (name === "fleet") return "#aab4c0";
  const i = Math.max(0, state.agents.indexOf(name));
  return COLORS[i % COLORS.length];
}
function heightColor(z, out) {
  // Like octomap_server's height map: hue over the height band.
  const t = Math.min(1, Math.max(0, (z + 0.2) / 3.0));
  out.setHSL(0.66 * (1 - t), 0.85, 0.55);
  return out;
}
function view(agent) {
  let v = agentViews.get(agent);
  if (v) return v;
  v = { voxels: new Map(), count: 0, keys: null, positions: null, colors: null, up: null, recolour: false, cloud: null, size: 0.05, dirty: false, paths: {}, poses: {}, keyframes: null };
  agentViews.set(agent, v);
  return v;
}
// ---------------------------------------------------------------- frames
// An agent's map, SLAM path, keyframes and marker are in its map frame (its camera's at start: z ahead, y down): they
// are drawn in one group per agent, placed in the fleet frame by the agent's `fleet → <agent>/map` once its SLAM has
// placed it ("frame" messages), and until then beside what is in the fleet frame, labelled as its own. The fleet map
// is in the fleet frame. Frames are drawn upright through the cameras' mountings (T_base_camera): the fleet frame as
// seen from the base, at its start, of the first placed agent whose mounting is known; an unplaced agent's from its
// own. Wheel odometry (its odom frame) stands in for an agent without SLAM; ground truth (the simulator's world
// frame, which the fleet is not told) is not drawn.
const UNPLACED_OFFSET_M = 40;
state.frames = {};
const frames = new Map();
const fleetRoot = new THREE.Group();
fleetRoot.matrixAutoUpdate = false;
scene.add(fleetRoot);
function frameOf(agent) {
  if (agent === "fleet") return fleetRoot;
  let frame = frames.get(agent);
  if (frame) return frame;
  frame = new THREE.Group();
  frame.name = agent;
  frame.matrixAutoUpdate = false;
  frames.set(agent, frame);
  scene.add(frame);
  placeFrames();
  return frame;
}
function frameLabel(text, color) {
  const canvas = document.createElement("canvas");
  canvas.width = 512; canvas.height = 64;
  const ctx = canvas.getContext("2d");
  ctx.font = "bold 30px sans-serif";
  ctx.fillStyle = color;
  ctx.textAlign = "center";
  ctx.fillText(text, 256, 42, 500);
  const sprite = new THREE.Sprite(new THREE.SpriteMaterial({ map: new THREE.CanvasTexture(canvas), depthTest: false }));
  sprite.scale.set(6, 0.75, 1);
  sprite.userData.text = text;
  return sprite;
}
const rowMajor = (m) => new THREE.Matrix4().set(...m);
function placeFrames() {
  const known = [...new Set([...state.agents, ...frames.keys()])].sort();
  const placement = (a) => state.frames[a]?.placement, mounting = (a) => state.frames[a]?.mounting;
  const upright = known.find((a) => placement(a) && mounting(a));
  fleetRoot.matrix.identity();
  if (upright) fleetRoot.matrix.copy(rowMajor(mounting(upright))).multiply(rowMajor(placement(upright)).invert());
  fleetRoot.matrixWorldNeedsUpdate = true;
  const unplaced = known.filter((a) => !placement(a));
  const shift = unplaced.length < known.length ? 1 : 0; // beside the fleet frame once anyone is in it
  for (const [agent, frame] of frames) {
    if (placement(agent)) {
      if (frame.parent !== fleetRoot) fleetRoot.add(frame);
      frame.matrix.copy(rowMajor(placement(agent)));
    } else {
      if (frame.parent !== scene) scene.add(frame);
      frame.matrix.makeTranslation(0, -UNPLACED_OFFSET_M * (unplaced.indexOf(agent) + shift), 0);
      if (mounting(agent)) frame.matrix.multiply(rowMajor(mounting(agent)));
    }
    frame.matrixWorldNeedsUpdate = true;
    const text = placement(agent) ? agent : `${agent} (own frame, not merged)`;
    let label = frame.userData.label;
    if (label?.userData.text !== text) {
      if (label) { label.removeFromParent(); label.material.map.dispose(); label.material.dispose(); }
      label = frame.userData.label = frameLabel(text, agentColor(agent));
      scene.add(label);
    }
    frame.updateMatrixWorld(true);
    label.position.setFromMatrixPosition(frame.matrixWorld).add(new THREE.Vector3(0, 0, 2.5));
  }
  state.sceneChanged = true;
}
function onFrame(msg) {
  if (msg.agent === "fleet") return;
  const matrix = (m) => (Array.isArray(m) && m.length === 16 ? m : null);
  const before = state.frames[msg.agent] || {};
  state.frames[msg.agent] = { placement: matrix(msg.placement), mounting: matrix(msg.mounting) };
  frameOf(msg.agent);
  placeFrames();
  const now = state.frames[msg.agent];
  if (!before.placement !== !now.placement || !before.mounting !== !now.mounting) { // "up" changed: recolour
    for (const v of agentViews.values()) { v.recolour = v.count > 0; v.dirty = v.count > 0; }
  }
}
// SLAM's pose and path where there is SLAM, else the wheel odometry's; never the ground truth (another frame).
function drawnSource(agent, source) {
  const v = view(agent);
  if (source === "slam" && !v.hasSlam) {
    v.hasSlam = true;
    removeLine(v, "odom"); removeLine(v, "trail-odom"); v.trailsChanged?.delete("odom");
    if (v.poses.odom) { v.poses.odom.removeFromParent(); delete v.poses.odom; }
  }
  return source === "slam" || (source === "odom" && !v.hasSlam);
}
// Where a point of an agent's map frame is drawn (tests): its frame's label, placement and world position.
state.frameOf = (agent, point = [0, 0, 0]) => {
  const frame = frames.get(agent);
  if (!frame) return null;
  scene.updateMatrixWorld(true);
  const v = view(agent);
  const p = new THREE.Vector3(...point).applyMatrix4(frame.matrixWorld);
  const marker = Object.values(v.poses)[0];
  return {
    label: frame.userData.label?.userData.text, placed: !!state.frames[agent]?.placement, world: [p.x, p.y, p.z],
    cloudInFrame: !!v.cloud && v.cloud.parent === frame,
    marker: marker && marker.parent === frame ? marker.getWorldPosition(new THREE.Vector3()).toArray() : null,
    markerUp: marker ? new THREE.Vector3(0, 0, 1).applyQuaternion(marker.getWorldQuaternion(new THREE.Quaternion())).toArray() : null,
  };
};

// Voxels are drawn as square point sprites one voxel wide (sizeAttenuation: world units), not as instanced cubes:
// a fleet's maps hold a few hundred thousand occupied voxels, and on a machine without a GPU (software GL) twelve
// lit triangles each took most of a core at ten frames a second; a sprite is one quad.
// Voxels arrive as indices (i, j, k) in binary messages (centre: (index + 1/2) · size); kept as one number each, in
// a slot of the agent's point buffers. An update writes only the voxels it adds and removes (a removed voxel's slot
// takes the last one), and only those slots are uploaded: rebuilding a map of 200 000 voxels on every update blocked
// the page for seconds on a loaded two-core machine (its pongs then arrived late: "link lost").
const KEY_OFFSET = 65536, KEY_BASE = 131072; // 17 bits per axis: ±3.2 km at 5 cm, well within a double's 53 bits
const voxelKey = (i, j, k) => ((i + KEY_OFFSET) * KEY_BASE + (j + KEY_OFFSET)) * KEY_BASE + (k + KEY_OFFSET);
const voxelColor = new THREE.Color();
function voxelBuffers(agent, v, capacity) {
  const positions = new Float32Array(3 * capacity), colors = new Float32Array(3 * capacity), keys = new Float64Array(capacity);
  if (v.positions) { positions.set(v.positions.subarray(0, 3 * v.count)); colors.set(v.colors.subarray(0, 3 * v.count)); keys.set(v.keys.subarray(0, v.count)); }
  v.positions = positions; v.colors = colors; v.keys = keys;
  if (v.cloud) { v.cloud.removeFromParent(); v.cloud.geometry.dispose(); v.cloud.material.dispose(); }
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.BufferAttribute(positions, 3).setUsage(THREE.DynamicDrawUsage));
  geometry.setAttribute("color", new THREE.BufferAttribute(colors, 3).setUsage(THREE.DynamicDrawUsage));
  geometry.setDrawRange(0, v.count);
  const fleet = agent === "fleet";
  const material = new THREE.PointsMaterial({
    size: v.size, sizeAttenuation: true, vertexColors: true,
    transparent: fleet, opacity: fleet ? 0.35 : 1, depthWrite: !fleet,
  });
  v.cloud = new THREE.Points(geometry, material);
  v.cloud.frustumCulled = false; // its bounding sphere is not recomputed as it grows
  frameOf(agent).add(v.cloud);
  v.dirtyFrom = Infinity; v.dirtyTo = -1; v.dirty = false;
}
function setVoxel(v, slot, key) {
  const k = (key % KEY_BASE) - KEY_OFFSET, rest = Math.floor(key / KEY_BASE);
  const y = ((rest % KEY_BASE) - KEY_OFFSET + 0.5) * v.size, x = (Math.floor(rest / KEY_BASE) - KEY_OFFSET + 0.5) * v.size;
  const z = (k + 0.5) * v.size, o = 3 * slot, e = v.up;
  v.positions[o] = x; v.positions[o + 1] = y; v.positions[o + 2] = z;
  heightColor(e[2] * x + e[6] * y + e[10] * z + e[14], voxelColor); // by height as drawn (a map frame's z may be ahead)
  v.colors[o] = voxelColor.r; v.colors[o + 1] = voxelColor.g; v.colors[o + 2] = voxelColor.b;
  v.keys[slot] = key;
  v.voxels.set(key, slot);
  v.dirtyFrom = Math.min(v.dirtyFrom, slot); v.dirtyTo = Math.max(v.dirtyTo, slot);
}
function frameUp(agent) {
  const frame = frameOf(agent);
  frame.updateWorldMatrix(true, false);
  return frame.matrixWorld.elements.slice();
}
// Draws what changed since the last frame: new buffers when they grew or the frame turned (recoloured), else the slots.
function rebuildVoxels(agent, v) {
  if (!v.cloud || v.recolour) {
    v.up = frameUp(agent);
    v.recolour = false;
    const keys = v.keys ? Array.from(v.keys.subarray(0, v.count)) : [];
    voxelBuffers(agent, v, Math.max(1024, 2 * v.count));
    keys.forEach((key, slot) => setVoxel(v, slot, key));
  }
  const geometry = v.cloud.geometry;
  geometry.setDrawRange(0, v.count);
  geometry.boundingSphere = null; // recomputed when a pick's ray needs it
  if (v.dirtyTo >= v.dirtyFrom) {
    for (const name of ["position", "color"]) {
      const attribute = geometry.attributes[name];
      attribute.clearUpdateRanges();
      attribute.addUpdateRange(3 * v.dirtyFrom, 3 * (v.dirtyTo - v.dirtyFrom + 1));
      attribute.needsUpdate = true;
    }
  }
  v.dirtyFrom = Infinity; v.dirtyTo = -1; v.dirty = false;
}
// The centres drawn of an agent's voxels (tests and the curious).
state.voxelCentres = (agent) => {
  const v = agentViews.get(agent);
  return v && v.positions ? Array.from(v.cloud.geometry.attributes.position.array.subarray(0, 3 * v.count)) : [];
};
// A binary voxel message (fleetslam.station.protocol.VoxelUpdate.encode): u32 header length, JSON header, int32
// indices of the added voxels, then of the removed ones.
function onVoxels(buffer) {
  const length = new DataView(buffer).getUint32(0, true);
  const msg = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, length)));
  const indices = new Int32Array(buffer, 4 + length);
  const v = view(msg.agent);
  if (msg.reset || v.size !== msg.size) { v.voxels.clear(); v.count = 0; v.recolour = true; }
  v.size = msg.size;
  if (!v.up) v.up = frameUp(msg.agent);
  for (let n = 3 * msg.add, end = 3 * (msg.add + msg.remove); n < end; n += 3) {
    const key = voxelKey(indices[n], indices[n + 1], indices[n + 2]), slot = v.voxels.get(key);
    if (slot === undefined) continue;
    v.voxels.delete(key);
    const last = --v.count;
    if (slot !== last) { // the last voxel moves into the freed slot
      const moved = v.keys[last];
      v.keys[slot] = moved; v.voxels.set(moved, slot);
      if (!v.recolour) { // else every slot is written when the buffers are made
        v.positions.copyWithin(3 * slot, 3 * last, 3 * last + 3); v.colors.copyWithin(3 * slot, 3 * last, 3 * last + 3);
        v.dirtyFrom = Math.min(v.dirtyFrom, slot); v.dirtyTo = Math.max(v.dirtyTo, slot);
      }
    }
  }
  const needed = v.count + msg.add;
  if (!v.keys || needed > v.keys.length) { // grow (doubling): new buffers, uploaded whole once
    v.recolour = true;
    if (v.keys) { const keys = v.keys; v.keys = new Float64Array(2 * needed); v.keys.set(keys.subarray(0, v.count)); }
    else v.keys = new Float64Array(Math.max(1024, 2 * needed));
    v.positions = v.colors = null;
  }
  for (let n = 0, end = 3 * msg.add; n < end; n += 3) {
    const key = voxelKey(indices[n], indices[n + 1], indices[n + 2]);
    if (v.voxels.has(key)) continue;
    if (v.recolour) { v.keys[v.count] = key; v.voxels.set(key, v.count); v.count += 1; } // written when rebuilt
    else { setVoxel(v, v.count, key); v.count += 1; }
  }
  v.dirty = true;
  state.voxelMessages += 1;
}
function lineFor(points, color, dashed) {
  const geometry = new THREE.BufferGeometry().setFromPoints(points.map((p) => new THREE.Vector3(p[0], p[1], p[2] + 0.02)));
  const material = dashed
    ? new THREE.LineDashedMaterial({ color, dashSize: 0.15, gapSize: 0.1 })
    : new THREE.LineBasicMaterial({ color });
  const line = new THREE.Line(geometry, material);
  if (dashed) line.computeLineDistances();
  return line;
}
function removeLine(v, name) {
  const line = v.paths[name];
  if (!line) return;
  line.removeFromParent();
  line.geometry.dispose();
  line.material.dispose();
  delete v.paths[name];
}
function onPath(msg) {
  const v = view(msg.agent);
  if (!drawnSource(msg.agent, msg.source)) return;
  removeLine(v, msg.source);
  const color = new THREE.Color(agentColor(msg.agent));
  if (msg.source === "truth") color.multiplyScalar(0.55);
  v.paths[msg.source] = lineFor(msg.points, color, msg.source === "truth");
  frameOf(msg.agent).add(v.paths[msg.source]);
}
function robotMarker(color) {
  const group = new THREE.Group();
  const body = new THREE.Mesh(new THREE.CylinderGeometry(0.22, 0.22, 0.18, 24), new THREE.MeshLambertMaterial({ color }));
  body.rotation.x = Math.PI / 2;
  body.position.z = 0.09;
  const nose = new THREE.Mesh(new THREE.ConeGeometry(0.09, 0.25, 12), new THREE.MeshLambertMaterial({ color: 0xffffff }));
  nose.rotation.z = -Math.PI / 2;
  nose.position.set(0.3, 0, 0.12);
  group.add(body, nose);
  return group;
}
function onPose(msg) {
  const v = view(msg.agent);
  const source = msg.source;
  if (!drawnSource(msg.agent, source)) return;
  if (!v.poses[source]) {
    v.poses[source] = robotMarker(agentColor(msg.agent));
    if (source === "truth") v.poses[source].children.forEach((c) => { c.material.transparent = true; c.material.opacity = 0.35; });
    frameOf(msg.agent).add(v.poses[source]);
    v.trail = v.trail || {};
  }
  v.poses[source].position.set(msg.x, msg.y, msg.z);
  if (msg.q) v.poses[source].quaternion.set(...msg.q);
  else v.poses[source].rotation.set(0, 0, msg.yaw);
  v.trail = v.trail || {};
  const trail = (v.trail[source] = v.trail[source] || []);
  const last = trail[trail.length - 1];
  if (!last || Math.hypot(last[0] - msg.x, last[1] - msg.y) > 0.05) {
    trail.push([msg.x, msg.y, msg.z]);
    if (!v.pathsFromTopic || !v.pathsFromTopic[source]) {
      v.trailsChanged = v.trailsChanged || new Set();
      v.trailsChanged.add(source);
    }
  }
}
// Trails are redrawn at most once a second: poses arrive at 50 Hz from three sources per robot, and a trail of
// thousands of points rebuilt on every one of them kept a core busy.
const TRAIL_INTERVAL_MS = 1000;
function redrawTrails(now) {
  for (const [agent, v] of agentViews) {
    if (!v.trailsChanged || !v.trailsChanged.size || now - (v.trailsDrawn || -Infinity) < TRAIL_INTERVAL_MS) continue;
    for (const source of v.trailsChanged) {
      removeLine(v, "trail-" + source);
      const color = new THREE.Color(agentColor(agent));
      if (source === "truth") color.multiplyScalar(0.55);
      v.paths["trail-" + source] = lineFor(v.trail[source], color, source === "truth");
      frameOf(agent).add(v.paths["trail-" + source]);
    }
    v.trailsChanged.clear();
    v.trailsDrawn = now;
    state.sceneChanged = true;
  }
}
// One camera frustum in the keyframe's frame: apex at the origin, looking along +z (16 points, 8 segments).
const FRUSTUM = (() => {
  const w = 0.18, h = 0.18 * 0.75, d = 0.25;
  return [[0, 0, 0], [w, h, d], [0, 0, 0], [-w, h, d], [0, 0, 0], [w, -h, d], [0, 0, 0], [-w, -h, d],
    [w, h, d], [-w, h, d], [-w, h, d], [-w, -h, d], [-w, -h, d], [w, -h, d], [w, -h, d], [w, h, d]];
})();
// All keyframes of an agent in one set of line segments (one draw call and one buffer, replaced when the graph
// is): a graph of hundreds of keyframes arrives every second.
function onKeyframes(msg) {
  const v = view(msg.agent);
  if (v.keyframes) { v.keyframes.removeFromParent(); v.keyframes.geometry.dispose(); v.keyframes.material.dispose(); }
  const positions = new Float32Array(msg.poses.length * FRUSTUM.length * 3);
  const q = new THREE.Quaternion(), p = new THREE.Vector3();
  let i = 0;
  for (const [x, y, z, qx, qy, qz, qw] of msg.poses) {
    q.set(qx, qy, qz, qw);
    for (const corner of FRUSTUM) {
      p.set(corner[0], corner[1], corner[2]).applyQuaternion(q);
      positions[i++] = p.x + x; positions[i++] = p.y + y; positions[i++] = p.z + z;
    }
  }
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.BufferAttribute(positions, 3));
  const material = new THREE.LineBasicMaterial({ color: agentColor(msg.agent), transparent: true, opacity: 0.7 });
  v.keyframes = new THREE.LineSegments(geometry, material);
  frameOf(msg.agent).add(v.keyframes);
}
// The 3D view is drawn when something in it changed (map, poses, paths, keyframes, the viewpoint), at most five
// times a second: the data arrives about once a second (poses ten times), and on a machine without a GPU (software
// GL) every frame costs tens of milliseconds of CPU that the robots' SLAM needs. Measured in headless Chromium on
// two cores with the demo's maps: the whole browser took 88 % of a core drawing ten times a second, 53 % once a
// second; at the display's 60 Hz it took 80 % for the 3D view alone.
const RENDER_INTERVAL_MS = 200;
let lastRender = -Infinity;
state.sceneChanged = true;
controls.addEventListener("change", () => { state.sceneChanged = true; });
window.addEventListener("resize", () => { state.sceneChanged = true; });
function animate(now) {
  requestAnimationFrame(animate);
  if (now - lastRender < RENDER_INTERVAL_MS) return;
  redrawTrails(now);
  let total = 0;
  for (const [agent, v] of agentViews) {
    if (v.dirty) { rebuildVoxels(agent, v); state.sceneChanged = true; }
    total += v.voxels.size;
  }
  state.voxelCount = total;
  document.getElementById("counts").textContent = `voxels: ${total.toLocaleString()}  ·  agents: ${state.agents.length}`;
  controls.update();
  if (!state.sceneChanged) return;
  state.sceneChanged = false;
  lastRender = now;
  renderer.render(scene, camera3d);
  state.renders += 1;
}
requestAnimationFrame(animate);

// ---------------------------------------------------------------- agents, camera, statistics
// Names come from the network (any node may name itself): they are inserted as text, never as HTML.
function el(tag, props = {}, ...children) {
  const node = document.createElement(tag);
  Object.assign(node, props);
  for (const child of children) node.append(child);
  return node;
}
function renderAgents() {
  const box = document.getElementById("agents");
  box.replaceChildren();
  for (const name of state.agents) {
    const swatch = el("span", { className: "swatch" });
    swatch.style.background = agentColor(name);
    const b = el("button", {}, swatch, name);
    if (name === state.selected) b.classList.add("selected");
    b.onclick = () => select(name);
    box.appendChild(b);
  }
  const legend = document.getElementById("legend");
  legend.replaceChildren();
  for (const a of [...state.agents, "fleet"]) {
    const mark = el("span", { textContent: "■" });
    mark.style.color = agentColor(a);
    legend.append(mark, ` ${a === "fleet" ? "fleet map" : a}\u00a0\u00a0`);
  }
  legend.append("in the fleet frame; an agent not merged yet in its own, beside it");
}
function select(name) {
  state.selected = name;
  send({ type: "select", agent: name });
  document.getElementById("camera-title").textContent = `camera · ${name}`;
  renderAgents();
  if (typeof renderEstop === "function") renderEstop();
}
function onImage(msg) {
  if (msg.agent !== state.selected) return;
  document.getElementById("camera").src = `data:${msg.mime};base64,${msg.data}`;
  state.frameCount += 1;
  state.lastFrameSeq = msg.seq;
  document.getElementById("camera-meta").textContent = `${msg.kind} frame ${msg.seq} · ${new Date().toLocaleTimeString()}`;
}
// The statistics table, grouped by publishing agent, then by topic: a topic's row sums its subscribers, and one
// row per subscriber below it names the publishing and subscribing nodes (each subscription reports its own).
function onStats(msg) {
  const body = document.querySelector("#stats tbody");
  const figures = (r) => [
    (r.bandwidth_bps / 1000).toFixed(1), r.rate_hz.toFixed(1), String(r.dropped),
    `${r.age_mean_ms.toFixed(1)}±${r.age_std_ms.toFixed(1)}`, `${r.period_mean_ms.toFixed(0)}±${r.period_std_ms.toFixed(0)}`,
  ];
  const row = (className, label, cells, title, dropped) => {
    const tr = el("tr", { className });
    tr.append(el("td", { textContent: label, title: title || "" }));
    cells.forEach((text, i) => {
      const td = el("td", { textContent: text });
      if (i === 2 && dropped) td.className = "drop";
      tr.append(td);
    });
    return tr;
  };
  const rows = [];
  let bw = 0, drops = 0;
  const byAgent = new Map();
  for (const r of msg.rows) {
    bw += r.bandwidth_bps; drops += r.dropped;
    const topics = byAgent.get(r.agent) || new Map();
    byAgent.set(r.agent, topics);
    topics.set(r.topic, [...(topics.get(r.topic) || []), r]);
  }
  for (const [agent, topics] of byAgent) {
    const header = el("tr", { className: "agent" }, el("td", { colSpan: 6, textContent: agent || "(root)" }));
    rows.push(header);
    for (const [topic, subs] of topics) {
      const sum = subs.reduce((a, r) => ({ bw: a.bw + r.bandwidth_bps, dropped: a.dropped + r.dropped }), { bw: 0, dropped: 0 });
      const publishers = [...new Set(subs.map((r) => r.node_pub || "?"))].join(", ");
      rows.push(row("topic", topic, [(sum.bw / 1000).toFixed(1), "", String(sum.dropped), "", ""],
        `published by ${publishers}; ${subs.length} subscriber(s)`, sum.dropped));
      for (const r of subs) {
        rows.push(row("subscriber", `${r.node_pub || "?"} → ${r.node_sub}`, figures(r), `${topic}`, r.dropped));
      }
    }
  }
  body.replaceChildren(...rows);
  document.getElementById("stats-summary").textContent = `${(bw / 1e6).toFixed(2)} MB/s · ${drops} dropped`;
}
document.getElementById("depth-toggle").onchange = (e) => {
  state.camera = e.target.checked ? "depth" : "rgb";
  send({ type: "camera", kind: state.camera });
};

// ---------------------------------------------------------------- teleoperation
const deadmanButton = document.getElementById("deadman");
function deadmanHeld() { return state.deadman.key || state.deadman.button || state.deadman.pad; }
function command() {
  const maxV = parseFloat(document.getElementById("max-v").value);
  const maxW = parseFloat(document.getElementById("max-w").value);
  let v = 0, w = 0;
  if (state.keys.has("w") || state.keys.has("arrowup")) v += 1;
  if (state.keys.has("s") || state.keys.has("arrowdown")) v -= 1;
  if (state.keys.has("a") || state.keys.has("arrowleft")) w += 1;
  if (state.keys.has("d") || state.keys.has("arrowright")) w -= 1;
  v += state.stick.v; w += state.stick.w;
  const pad = navigator.getGamepads ? [...navigator.getGamepads()].find((g) => g) : null;
  state.deadman.pad = !!(pad && pad.buttons[4] && pad.buttons[4].pressed);
  if (pad) {
    const dz = (x) => (Math.abs(x) < 0.12 ? 0 : x);
    v += -dz(pad.axes[1] || 0); w += -dz(pad.axes[0] || 0);
  }
  v = Math.max(-1, Math.min(1, v)); w = Math.max(-1, Math.min(1, w));
  return { v: v * maxV, w: w * maxW };
}
let wasDriving = false;
// The stream's tick, also run at once on a release (key up, button up, blur): a stop must not wait for the next
// tick, which a main thread busy drawing (software GL under load) can hold back for hundreds of milliseconds.
function streamDrive() {
  if (!state.selected || !state.socket || state.socket.readyState !== 1) return;
  const held = deadmanHeld() && !state.estop;
  const { v, w } = command();
  deadmanButton.classList.toggle("active", held);
  const badge = document.getElementById("drive-state");
  badge.textContent = state.estop ? "E-STOP" : held ? `driving ${v.toFixed(2)} m/s ${w.toFixed(2)} rad/s` : "idle";
  badge.className = "badge" + (state.estop ? " stopped" : held ? " driving" : "");
  if (held || wasDriving) {
    send({ type: "drive", agent: state.selected, v: held ? v : 0, w: held ? w : 0, deadman: held });
    state.driveSent += 1;
  }
  wasDriving = held;
}
setInterval(streamDrive, 50); // 20 Hz: the server's stream stops within its timeout if these stop arriving
function releaseNow() { if (wasDriving) streamDrive(); }

window.addEventListener("keydown", (e) => {
  const k = e.key.toLowerCase();
  if (k === " ") { state.deadman.key = true; e.preventDefault(); return; }
  if (["w", "a", "s", "d", "arrowup", "arrowdown", "arrowleft", "arrowright"].includes(k)) { state.keys.add(k); e.preventDefault(); }
});
window.addEventListener("keyup", (e) => {
  const k = e.key.toLowerCase();
  if (k === " ") state.deadman.key = false;
  state.keys.delete(k);
  releaseNow();
});
window.addEventListener("blur", () => { state.keys.clear(); state.deadman.key = false; state.deadman.button = false; releaseNow(); });
deadmanButton.addEventListener("pointerdown", () => { state.deadman.button = true; });
for (const ev of ["pointerup", "pointerleave", "pointercancel"]) deadmanButton.addEventListener(ev, () => { state.deadman.button = false; releaseNow(); });

const stick = document.getElementById("joystick"), knob = document.getElementById("knob");
function stickMove(e) {
  const r = stick.getBoundingClientRect();
  let dx = (e.clientX - r.left - r.width / 2) / (r.width / 2), dy = (e.clientY - r.top - r.height / 2) / (r.height / 2);
  const n = Math.hypot(dx, dy); if (n > 1) { dx /= n; dy /= n; }
  state.stick = { v: -dy, w: -dx };
  knob.style.left = `${42 + dx * 42}px`; knob.style.top = `${42 + dy * 42}px`;
}
stick.addEventListener("pointerdown", (e) => { stick.setPointerCapture(e.pointerId); state.deadman.button = true; stickMove(e); });
stick.addEventListener("pointermove", (e) => { if (stick.hasPointerCapture(e.pointerId)) stickMove(e); });
stick.addEventListener("pointerup", () => { state.stick = { v: 0, w: 0 }; state.deadman.button = false; knob.style.left = "42px"; knob.style.top = "42px"; releaseNow(); });

// ---------------------------------------------------------------- e-stop
// The button shows what the robot answered, never what was asked: "engaged" only once the robot's `e_stop` service
// confirmed it. While a request is out it says so; a refusal, or no answer within ESTOP_TIMEOUT_MS, is shown to the
// operator and the button stays as the robot last confirmed. Driving is blocked from the click on (safe side).
const ESTOP_TIMEOUT_MS = 5000;
state.estopBy = {}; // agent -> engaged, as the robot last confirmed
state.estopPending = null; // { agent, engage, timer }
function renderEstop(text, error) {
  state.estop = !!state.estopBy[state.selected] || !!state.estopPending;
  const button = document.getElementById("estop"), line = document.getElementById("estop-message");
  const pending = state.estopPending && state.estopPending.agent === state.selected ? state.estopPending : null;
  const engaged = !!state.estopBy[state.selected];
  button.classList.toggle("engaged", engaged);
  button.classList.toggle("pending", !!pending);
  button.textContent = pending ? `${pending.engage ? "engaging" : "releasing"} e-stop… (waiting for ${pending.agent})`
    : engaged ? "E-STOP ENGAGED (click to release)" : "E-STOP";
  if (text !== undefined) { line.textContent = text; line.classList.toggle("error", !!error); }
}
function onEstop(msg) {
  const pending = state.estopPending;
  if (!pending || pending.agent !== msg.agent || pending.engage !== msg.engaged) return; // not the request out
  clearTimeout(pending.timer);
  state.estopPending = null;
  if (msg.ok) {
    state.estopBy[msg.agent] = msg.engaged;
    renderEstop(`${msg.agent}: e-stop ${msg.engaged ? "engaged" : "released"} (${msg.message || "confirmed"})`, false);
  } else {
    renderEstop(`${msg.agent} refused: ${msg.message || "no reason given"}`, true);
  }
}
document.getElementById("estop").onclick = () => {
  if (!state.selected || state.estopPending) return;
  const agent = state.selected, engage = !state.estopBy[agent];
  const timer = setTimeout(() => {
    if (state.estopPending && state.estopPending.timer === timer) {
      state.estopPending = null;
      renderEstop(`${agent} did not answer the e-stop request within ${ESTOP_TIMEOUT_MS / 1000} s`, true);
    }
  }, ESTOP_TIMEOUT_MS);
  state.estopPending = { agent, engage, timer };
  renderEstop("", false);
  send({ type: "estop", agent, engage });
};
for (const [id, out] of [["max-v", "max-v-out"], ["max-w", "max-w-out"]]) {
  document.getElementById(id).oninput = (e) => { document.getElementById(out).textContent = parseFloat(e.target.value).toFixed(2); };
}

// ---------------------------------------------------------------- findings
// The operator clicks on the live camera image: the server freezes that frame (photo, depth at the pixel) and
// answers with a crop; the form's title, severity and note make the finding, recorded by the fleet's findings
// service. Findings come back from the fleet (every console sees them) with the point in their keyframe's camera
// frame: their markers are placed from the keyframe's current pose, so they move with it. Text is inserted as text.
const findings = { list: [], keyframes: new Map(), markers: new Map(), pick: null, selected: null, frame: null };
state.findings = findings.list;
const SEVERITY_COLORS = { info: "#8fb8de", low: "#3ddc84", medium: "#ffd166", high: "#ff7a45", critical: "#ff4d4f" };
// Where an agent's findings are drawn: the group its keyframes are drawn in (its map frame, placed in the fleet frame).
function findingParent(agent) { return frameOf(agent); }
function findingPosition(f) {
  const poses = findings.keyframes.get(f.agent);
  if (!poses) return f.position || null; // no keyframes (a finished run's review): where it was last known
  if (f.keyframe_id >= poses.length) return null;
  const [x, y, z, qx, qy, qz, qw] = poses[f.keyframe_id];
  const p = new THREE.Vector3(f.point[0], f.point[1], f.point[2]).applyQuaternion(new THREE.Quaternion(qx, qy, qz, qw));
  return [p.x + x, p.y + y, p.z + z];
}
function findingMessage(text, error) {
  const line = document.getElementById("finding-message");
  line.textContent = text;
  line.classList.toggle("error", !!error);
}
function placeFindings() {
  for (const f of findings.list) {
    f.position = findingPosition(f);
    let marker = findings.markers.get(f.id);
    if (!marker) {
      // Drawn over the map (no depth test): a finding inside a wall of voxels stays visible.
      marker = new THREE.Mesh(new THREE.SphereGeometry(0.13, 16, 12), new THREE.MeshBasicMaterial({ color: 0xffffff, depthTest: false }));
      marker.renderOrder = 10;
      marker.userData.findingId = f.id;
      findingParent(f.agent).add(marker);
      findings.markers.set(f.id, marker);
    }
    marker.material.color.set(f.status === "closed" ? "#6b7785" : SEVERITY_COLORS[f.severity] || "#ffffff");
    marker.visible = f.position !== null;
    if (f.position) marker.position.set(f.position[0], f.position[1], f.position[2]);
  }
  for (const [id, marker] of findings.markers) {
    if (findings.list.some((f) => f.id === id)) continue;
    marker.parent && marker.parent.remove(marker);
    marker.geometry.dispose(); marker.material.dispose();
    findings.markers.delete(id);
  }
  state.sceneChanged = true;
}
// World positions of the markers as drawn (for tests and the curious).
state.findingMarkers = () => Object.fromEntries([...findings.markers].map(([id, m]) => {
  const p = new THREE.Vector3(); m.getWorldPosition(p); return [id, m.visible ? [p.x, p.y, p.z] : null];
}));
function renderFindings() {
  const list = document.getElementById("findings-list");
  list.replaceChildren();
  findings.list.forEach((f) => {
    const item = document.createElement("li");
    const sev = document.createElement("span");
    sev.className = `sev sev-${f.severity}`;
    sev.textContent = f.severity;
    item.append(sev, document.createTextNode(`${f.title} · ${f.agent} · ${f.status}`));
    item.dataset.id = f.id;
    item.title = f.id;
    if (f.status === "closed") item.classList.add("closed");
    if (f.id === findings.selected) item.classList.add("selected");
    item.onclick = () => showFinding(f.id);
    list.appendChild(item);
  });
  const open = findings.list.filter((f) => f.status === "open").length;
  document.getElementById("findings-summary").textContent = findings.list.length ? `${open} open · ${findings.list.length}` : "none";
  if (findings.selected) showFindingText(findings.list.find((f) => f.id === findings.selected));
}
function showFindingText(f) {
  const detail = document.getElementById("finding-detail");
  detail.hidden = !f;
  if (!f) return;
  const where = f.position ? f.position.map((c) => c.toFixed(2)).join(", ") : "(keyframe not known yet)";
  const time = findingTime(f.stamp_ns);
  document.getElementById("finding-text").textContent =
    `${f.id} · ${f.title}\n${f.severity} · ${f.status} · ${f.agent}, keyframe ${f.keyframe_id} · ${time}\n` +
    `at (${where}) m in ${f.agent}'s map\n${f.note}`;
  document.getElementById("finding-toggle").textContent = f.status === "open" ? "close finding" : "reopen";
}
// A stamp before 2001 is a simulated clock's (seconds since the simulation started), not a date.
function findingTime(stampNs) {
  return stampNs < 1e18 ? `t = ${(stampNs / 1e9).toFixed(1)} s (simulated clock)` : new Date(stampNs / 1e6).toLocaleString();
}
function flyTo(position) {
  const target = new THREE.Vector3(position[0], position[1], position[2]);
  const offset = camera3d.position.clone().sub(controls.target).setLength(3.0);
  controls.target.copy(target);
  camera3d.position.copy(target).add(offset);
  controls.update();
  state.sceneChanged = true;
}
function showFinding(id) {
  findings.selected = id;
  const f = findings.list.find((x) => x.id === id);
  renderFindings();
  if (!f) return;
  document.getElementById("finding-photo").removeAttribute("src");
  document.getElementById("finding-photo-crop").removeAttribute("src");
  if (f.has_photo) send({ type: "finding_photo", id });
  if (f.position) flyTo(f.position);
}
function onFindingPhoto(msg) {
  if (msg.id !== findings.selected) return;
  if (msg.photo) document.getElementById("finding-photo").src = `data:image/jpeg;base64,${msg.photo}`;
  if (msg.crop) document.getElementById("finding-photo-crop").src = `data:image/jpeg;base64,${msg.crop}`;
}
// The pixel (centres at integers) of the camera image under a click, or null outside the picture (object-fit: contain).
function imagePixel(img, event) {
  const rect = img.getBoundingClientRect();
  if (!img.naturalWidth || !img.naturalHeight) return null;
  const scale = Math.min(rect.width / img.naturalWidth, rect.height / img.naturalHeight);
  const left = rect.left + (rect.width - img.naturalWidth * scale) / 2, top = rect.top + (rect.height - img.naturalHeight * scale) / 2;
  const u = (event.clientX - left) / scale - 0.5, v = (event.clientY - top) / scale - 0.5;
  if (u < -0.5 || v < -0.5 || u > img.naturalWidth - 0.5 || v > img.naturalHeight - 0.5) return null;
  return { u, v };
}
document.getElementById("camera").addEventListener("click", (event) => {
  const frame = findings.frame;
  const pixel = imagePixel(event.currentTarget, event);
  if (!frame || !pixel) return;
  if (measure.on) {
    send({ type: "measure_pick", agent: frame.agent, stamp: frame.stamp, u: pixel.u, v: pixel.v });
    return;
  }
  findingMessage(`picking (${pixel.u.toFixed(0)}, ${pixel.v.toFixed(0)})…`);
  state.lastFindingPick = { agent: frame.agent, stamp: frame.stamp, u: pixel.u, v: pixel.v };
  send({ type: "finding_pick", ...state.lastFindingPick });
});
function onFindingPick(msg) {
  if (!msg.ok) { findingMessage(msg.message, true); return; }
  findings.pick = msg.pick;
  document.getElementById("finding-crop").src = `data:image/jpeg;base64,${msg.crop}`;
  document.getElementById("finding-point").textContent =
    `${msg.agent}: ${msg.point.map((c) => c.toFixed(2)).join(", ")} m (camera frame), ${msg.point[2].toFixed(2)} m away`;
  document.getElementById("finding-form").hidden = false;
  findingMessage("");
  document.getElementById("finding-title").focus();
}
document.getElementById("finding-form").addEventListener("submit", (event) => {
  event.preventDefault();
  if (!findings.pick) return;
  send({
    type: "finding_create", pick: findings.pick, title: document.getElementById("finding-title").value,
    severity: document.getElementById("finding-severity").value, note: document.getElementById("finding-note").value,
  });
  findingMessage("recording…");
});
document.getElementById("finding-cancel").onclick = () => { findings.pick = null; document.getElementById("finding-form").hidden = true; findingMessage(""); };
// Typing in the form must not drive the robot (W/A/S/D, Space are teleoperation keys).
for (const id of ["finding-title", "finding-note"]) {
  document.getElementById(id).addEventListener("keydown", (e) => e.stopPropagation());
  document.getElementById(id).addEventListener("keyup", (e) => e.stopPropagation());
}
function onFindingCreated(msg) {
  if (!msg.ok) { findingMessage(msg.message, true); return; }
  findings.pick = null;
  document.getElementById("finding-form").hidden = true;
  document.getElementById("finding-title").value = "";
  document.getElementById("finding-note").value = "";
  findingMessage(msg.message);
}
document.getElementById("finding-toggle").onclick = () => {
  const f = findings.list.find((x) => x.id === findings.selected);
  if (f) send({ type: "finding_update", id: f.id, status: f.status === "open" ? "closed" : "open" });
};
document.getElementById("finding-fly").onclick = () => {
  const f = findings.list.find((x) => x.id === findings.selected);
  if (f && f.position) flyTo(f.position);
};
// Every server message passes here first; true: it was a findings message and is handled.
function findingsOnMessage(msg) {
  switch (msg.type) {
    case "image": if (msg.agent === state.selected) findings.frame = { agent: msg.agent, stamp: msg.stamp }; return false;
    case "keyframes": findings.keyframes.set(msg.agent, msg.poses); placeFindings(); renderFindings(); return false;
    case "findings":
      findings.list.splice(0, findings.list.length, ...msg.findings);
      placeFindings(); renderFindings();
      return true;
    case "finding_pick": onFindingPick(msg); return true;
    case "finding_created": onFindingCreated(msg); return true;
    case "finding_updated": findingMessage(msg.message, !msg.ok); return true;
    case "finding_photo": onFindingPhoto(msg); return true;
    case "measure_point": onMeasurePoint(msg); return true;
  }
  return false;
}

// ---------------------------------------------------------------- measure
// With "measure" on, two points picked on the camera image (the depth there, placed by SLAM's pose of that frame) or
// in the 3D view (the nearest voxel under the pointer) give their distance, drawn as a line.
const measure = { on: false, points: [], objects: [], distance: null };
state.measure = measure;
function measureText() {
  const box = document.getElementById("measure-result");
  box.hidden = !measure.on;
  if (measure.distance !== null) box.textContent = `distance ${measure.distance.toFixed(3)} m`;
  else box.textContent = measure.points.length ? "measure: pick the second point" : "measure: pick two points on the camera image or the map";
}
function resetMeasure() {
  for (const o of measure.objects) { scene.remove(o); o.geometry.dispose(); o.material.dispose(); }
  measure.objects = []; measure.points = []; measure.distance = null;
  state.sceneChanged = true;
  measureText();
}
function addMeasurePoint(point) {
  if (measure.points.length >= 2) resetMeasure();
  measure.points.push(point);
  const world = new THREE.Vector3(...point.world);
  const dot = new THREE.Mesh(new THREE.SphereGeometry(0.05, 12, 8), new THREE.MeshBasicMaterial({ color: 0xffe066 }));
  dot.position.copy(world);
  scene.add(dot);
  measure.objects.push(dot);
  if (measure.points.length === 2) {
    const [a, b] = measure.points.map((p) => new THREE.Vector3(...p.world));
    const line = new THREE.Line(new THREE.BufferGeometry().setFromPoints([a, b]), new THREE.LineBasicMaterial({ color: 0xffe066 }));
    scene.add(line);
    measure.objects.push(line);
    measure.distance = a.distanceTo(b);
  }
  state.sceneChanged = true;
  measureText();
}
document.getElementById("measure-toggle").onchange = (e) => { measure.on = e.target.checked; resetMeasure(); };
// A point of the image arrives in the agent's map frame: drawn where that agent's findings are.
function onMeasurePoint(msg) {
  if (!msg.ok) { findingMessage(msg.message, true); return; }
  findingMessage("");
  const world = findingParent(msg.agent).localToWorld(new THREE.Vector3(...msg.point));
  addMeasurePoint({ source: "image", agent: msg.agent, stamp: msg.stamp, world: [world.x, world.y, world.z] });
}
// Where a point of the scene is on the screen (client pixels; for tests and the curious).
state.screenOf = (x, y, z) => {
  const p = new THREE.Vector3(x, y, z).project(camera3d), rect = renderer.domElement.getBoundingClientRect();
  return [rect.left + ((p.x + 1) / 2) * rect.width, rect.top + ((1 - p.y) / 2) * rect.height];
};
// The 3D view: a click (not a drag of the view) picks the nearest voxel under the pointer.
const measureRay = new THREE.Raycaster();
let measureDown = null;
renderer.domElement.addEventListener("pointerdown", (e) => { measureDown = [e.clientX, e.clientY]; });
renderer.domElement.addEventListener("pointerup", (e) => {
  if (!measure.on || !measureDown || Math.hypot(e.clientX - measureDown[0], e.clientY - measureDown[1]) > 4) return;
  const rect = renderer.domElement.getBoundingClientRect();
  const ndc = new THREE.Vector2(((e.clientX - rect.left) / rect.width) * 2 - 1, -((e.clientY - rect.top) / rect.height) * 2 + 1);
  measureRay.setFromCamera(ndc, camera3d);
  const clouds = [...agentViews.values()].map((v) => v.cloud).filter(Boolean);
  measureRay.params.Points.threshold = 0.5 * Math.max(...[...agentViews.values()].map((v) => v.size), 0.05);
  const hit = measureRay.intersectObjects(clouds, false)[0];
  if (!hit) { findingMessage("measure: no map under the pointer", true); return; }
  const voxel = new THREE.Vector3().fromBufferAttribute(hit.object.geometry.attributes.position, hit.index).applyMatrix4(hit.object.matrixWorld);
  findingMessage("");
  addMeasurePoint({ source: "map", world: [voxel.x, voxel.y, voxel.z] });
});

// ---------------------------------------------------------------- reviewing a finished run
// `fleetslam station --session DIR`: the run's maps and findings as they ended, and a time slider that replays each
// robot's SLAM trajectory (marker and path up to the slider's time) and, when the run recorded its cameras, the
// camera frame nearest that time (asked from the server).
const session = { data: null, t: 0, timer: null, asked: 0, pending: null };
state.session = session;
function onSession(msg) {
  session.data = msg;
  const slider = document.getElementById("session-time");
  slider.min = msg.start; slider.max = msg.end;
  document.getElementById("session").hidden = false;
  document.getElementById("session-title").textContent = `review of ${msg.run}`;
  for (const agent of Object.keys(msg.agents)) view(agent).pathsFromTopic = { slam: true }; // the replay draws the path
  setSessionTime(msg.end);
}
function sessionIndex(stamps, t) { // the last stamp at or before t, or -1
  let lo = 0, hi = stamps.length;
  while (lo < hi) { const mid = (lo + hi) >> 1; if (stamps[mid] <= t) lo = mid + 1; else hi = mid; }
  return lo - 1;
}
function setSessionTime(t) {
  const data = session.data;
  session.t = t;
  document.getElementById("session-time").value = t;
  document.getElementById("session-time-out").textContent = `t = ${t.toFixed(1)} s`;
  for (const [agent, track] of Object.entries(data.agents)) {
    const i = Math.max(0, sessionIndex(track.stamps, t));
    if (!track.poses.length) continue;
    const [x, y, z, qx, qy, qz, qw] = track.poses[i];
    onPose({ agent, source: "slam", x, y, z, q: [qx, qy, qz, qw] });
    onPath({ agent, source: "slam", points: track.poses.slice(0, i + 1).map((p) => p.slice(0, 3)) });
  }
  state.sceneChanged = true;
  const meta = document.getElementById("camera-meta");
  if (!data.camera.includes(state.selected)) {
    meta.textContent = "no camera in this run's recording: the trajectories are replayed";
  } else {
    askSessionFrame();
  }
}
// At most five frames a second while scrubbing, and always the frame of where the slider stopped: a move within
// 200 ms of the last request is asked for when that interval ends (the newest time then, not each one on the way).
function askSessionFrame() {
  const wait = session.asked + 200 - performance.now();
  if (wait > 0) {
    if (session.pending === null) session.pending = setTimeout(() => { session.pending = null; askSessionFrame(); }, wait);
    return;
  }
  session.asked = performance.now();
  send({ type: "session_frame", agent: state.selected, t: session.t });
}
document.getElementById("session-time").oninput = (e) => setSessionTime(parseFloat(e.target.value));
document.getElementById("session-play").onclick = () => {
  const button = document.getElementById("session-play");
  if (session.timer) { clearInterval(session.timer); session.timer = null; button.textContent = "play"; return; }
  if (session.t >= session.data.end) setSessionTime(session.data.start);
  button.textContent = "pause";
  session.timer = setInterval(() => {
    const t = Math.min(session.data.end, session.t + 0.2);
    setSessionTime(t);
    if (t >= session.data.end) document.getElementById("session-play").click();
  }, 200);
};

// ---------------------------------------------------------------- connection
function send(msg) { if (state.socket && state.socket.readyState === 1) state.socket.send(JSON.stringify(msg)); }
// The server sends the bulk streams only while this page keeps up: it keeps at most a window of them unacknowledged
// (newest only meanwhile), so a pong never waits behind a backlog of images and maps in a busy page.
const BULK_TYPES = new Set(["image", "pose", "path", "keyframes", "stats", "voxels"]);
const ACK_EVERY = 32 * 1024;
function handled(size, bulk) {
  if (!bulk) return;
  state.received += size;
  if (state.received - state.acked >= ACK_EVERY) ack();
}
function ack() {
  if (state.received === state.acked) return;
  state.acked = state.received;
  send({ type: "ack", bytes: state.received });
}
setInterval(ack, 100);
function connect() {
  // The console's token comes with the URL it printed; kept for reloads of this tab, passed on to the WebSocket.
  const token = new URLSearchParams(location.search).get("token") || sessionStorage.getItem("fleetslam-token") || "";
  sessionStorage.setItem("fleetslam-token", token);
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const socket = new WebSocket(`${scheme}://${location.host}/ws?token=${encodeURIComponent(token)}`);
  state.socket = socket;
  socket.binaryType = "arraybuffer";
  socket.onmessage = (event) => {
    if (typeof event.data !== "string") { // binary: voxels, a bulk stream
      onVoxels(event.data); state.sceneChanged = true; handled(event.data.byteLength, true);
      return;
    }
    const msg = JSON.parse(event.data);
    handled(event.data.length, BULK_TYPES.has(msg.type));
    if (findingsOnMessage(msg)) return;
    switch (msg.type) {
      case "hello":
        state.limits = msg.limits;
        document.getElementById("max-v").max = msg.limits.max_linear;
        document.getElementById("max-w").max = msg.limits.max_angular;
      // falls through
      case "agents":
        state.agents = msg.agents;
        if (!state.selected && state.agents.length) select(state.agents[0]);
        renderAgents();
        placeFrames();
        break;
      case "pose": onPose(msg); state.sceneChanged = true; break;
      case "path": onPath(msg); state.sceneChanged = true; break;
      case "keyframes": onKeyframes(msg); state.sceneChanged = true; break;
      case "frame": onFrame(msg); break;
      case "image": onImage(msg); break;
      case "stats": onStats(msg); break;
      case "session": onSession(msg); break;
      case "session_frame": if (!msg.ok) document.getElementById("camera-meta").textContent = msg.message; break;
      case "estop": onEstop(msg); break;
    }
  };
  socket.onopen = () => {
    state.received = state.acked = 0; // counted per connection
    showLink();
    if (state.selected) send({ type: "select", agent: state.selected });
    send({ type: "camera", kind: state.camera });
  };
  socket.onclose = () => { state.rtt = null; showLink(); setTimeout(connect, 1000); };
}
// The link indicator shows what its worker (link.js) judges from pongs on a connection of its own; "lost" too while
// this page's connection is not open.
state.link = { state: "connecting", rtt: null };
function showLink() {
  const link = document.getElementById("link"), text = document.getElementById("link-text");
  const open = state.socket && state.socket.readyState === 1;
  const { state: judged, rtt } = state.link;
  const fresh = open && judged === "ok";
  state.rtt = fresh ? rtt : null;
  link.className = "link" + (fresh ? (rtt > 150 ? " slow" : " ok") : "");
  text.textContent = fresh ? `link ok · RTT ${rtt.toFixed(1)} ms` : open && judged === "connecting" ? "connecting…" : "link lost";
}
const linkWorker = new Worker("/static/link.js");
linkWorker.onmessage = (event) => { state.link = event.data; showLink(); };
{
  const token = new URLSearchParams(location.search).get("token") || sessionStorage.getItem("fleetslam-token") || "";
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  linkWorker.postMessage({ url: `${scheme}://${location.host}/ws?role=link&token=${encodeURIComponent(token)}` });
}
connect();
