// FuseFlow live viewer on three.js (shipped in ./three, MIT): points sized in metres, camera
// frusta with ids and toggles, grid and axes, colour by rgb / weight / camera, WebXR ("Enter VR"
// / "Start AR" where navigator.xr offers them), snapshot. Frames come from /ws?ack=1: one frame
// at a time, acknowledged once shown, so the server always sends the newest one next (protocol
// in fuseflow/live/server.py and docs/live.md; frame formats in decode.js). The page draws only
// when something changed (a frame, the view, a setting), or every frame while in XR.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { VRButton } from "three/addons/webxr/VRButton.js";
import { ARButton } from "three/addons/webxr/ARButton.js";

const $ = (id) => document.getElementById(id);
const params = new URLSearchParams(location.search);
const token = params.get("token");
const stats = { frames: 0, split: 0, bytes: 0, version: 0, decodeMs: [], ages: [], renders: 0, xrFrames: 0, dropped: 0, state: "connecting" };
window.fuseflowStats = stats;

// ---- renderer, scene, camera
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio || 1); // sharp on high-DPI screens
renderer.setSize(window.innerWidth, window.innerHeight);
renderer.setClearColor(0x14161a);
renderer.xr.enabled = true;
renderer.xr.setReferenceSpaceType("local-floor");
document.body.prepend(renderer.domElement);
const scene = new THREE.Scene();
const world = new THREE.Group(); // the rig's world, turned so that its "up" is +y and its floor y = 0
scene.add(world);
const camera = new THREE.PerspectiveCamera(55, window.innerWidth / window.innerHeight, 0.02, 200);
camera.position.set(0, 1.6, 3);
const controls = new OrbitControls(camera, renderer.domElement);
controls.addEventListener("change", () => requestRender());

// points: gl_PointSize is the size in pixels of a disc `size` metres across at the point's depth
const pointMaterial = new THREE.ShaderMaterial({
  uniforms: { size: { value: 0.004 }, scale: { value: 1.0 } },
  vertexColors: true,
  vertexShader: `uniform float size; uniform float scale; varying vec3 vColor;
    void main() {
      vec4 mv = modelViewMatrix * vec4(position, 1.0);
      gl_Position = projectionMatrix * mv;
      gl_PointSize = max(size * scale * projectionMatrix[1][1] / max(-mv.z, 1e-3), 1.0);
      vColor = color;
    }`,
  fragmentShader: `varying vec3 vColor;
    void main() {
      vec2 d = gl_PointCoord - 0.5;
      if (dot(d, d) > 0.25) discard;
      gl_FragColor = vec4(vColor, 1.0);
    }`,
});
const viewport = new THREE.Vector4();
const geometry = new THREE.BufferGeometry();
const points = new THREE.Points(geometry, pointMaterial);
points.frustumCulled = false;
points.onBeforeRender = (r) => { r.getCurrentViewport(viewport); pointMaterial.uniforms.scale.value = viewport.w / 2; };
world.add(points);
const helpers = new THREE.Group();
helpers.add(new THREE.GridHelper(10, 20, 0x666666, 0x333333));
helpers.add(new THREE.AxesHelper(0.5));
scene.add(helpers);
const rigGroup = new THREE.Group();
world.add(rigGroup);

let pending = false;
function requestRender() {
  if (pending || renderer.xr.isPresenting) return;
  pending = true;
  requestAnimationFrame(() => { pending = false; render(); });
}
function render() {
  stats.renders += 1;
  if (renderer.xr.isPresenting) stats.xrFrames += 1;
  renderer.render(scene, camera);
  if (shown) acknowledge();
}
window.addEventListener("resize", () => {
  camera.aspect = window.innerWidth / window.innerHeight;
  camera.updateProjectionMatrix();
  renderer.setSize(window.innerWidth, window.innerHeight);
  requestRender();
});
renderer.xr.addEventListener("sessionstart", () => {
  // stand in front of the scene: its centre 2 m ahead of the viewer, floor at the real floor
  world.position.set(-box.center.x, world.position.y, -box.center.z - 2.0);
  renderer.setAnimationLoop(render);
});
renderer.xr.addEventListener("sessionend", () => {
  renderer.setAnimationLoop(null);
  world.position.set(0, world.position.y, 0);
  requestRender();
});

// ---- the rig: up direction, frusta with ids, toggles
const palette = [0xe6194b, 0x3cb44b, 0xffe119, 0x4363d8, 0xf58231, 0x911eb4, 0x46f0f0, 0xf032e6, 0xbcf60c, 0xfabebe,
  0x008080, 0xe6beff, 0x9a6324, 0xfffac8, 0x800000, 0xaaffc3];
let rig = { cameras: [], run: null, ids: [] };
let reframe = true;
function label(text, color) {
  const c = document.createElement("canvas");
  c.width = 256; c.height = 64;
  const g = c.getContext("2d");
  g.font = "bold 40px sans-serif";
  g.fillStyle = "#" + color.toString(16).padStart(6, "0");
  g.fillText(text, 4, 46);
  const sprite = new THREE.Sprite(new THREE.SpriteMaterial({ map: new THREE.CanvasTexture(c), depthTest: false }));
  sprite.scale.set(0.24, 0.06, 1);
  return sprite;
}
function setRig(msg) {
  if (msg.run !== rig.run) reframe = true; // another server (another scene): frame it anew
  rig = { cameras: msg.cameras || [], run: msg.run, ids: msg.source_ids || (msg.cameras || []).map((c) => c.id) };
  rigGroup.clear();
  $("cams").textContent = "";
  const up = new THREE.Vector3();
  rig.cameras.forEach((c, k) => {
    const T = new THREE.Matrix4().fromArray(c.T_world_cam).transpose(); // row-major -> three's column-major
    up.sub(new THREE.Vector3().setFromMatrixColumn(T, 1)); // image up = minus the camera's y axis
    const K = c.K, d = 0.15;
    const corners = [[0, 0], [c.width, 0], [c.width, c.height], [0, c.height]].map(([u, v]) =>
      new THREE.Vector3(((u - K[0][2]) / K[0][0]) * d, ((v - K[1][2]) / K[1][1]) * d, d));
    const pts = [];
    for (let i = 0; i < 4; i++) pts.push(new THREE.Vector3(), corners[i], corners[i], corners[(i + 1) % 4]);
    const color = palette[rig.ids.indexOf(c.id) % palette.length] ?? palette[k % palette.length];
    const g = new THREE.Group();
    g.add(new THREE.LineSegments(new THREE.BufferGeometry().setFromPoints(pts), new THREE.LineBasicMaterial({ color })));
    const tag = label(c.id, color);
    tag.position.set(0, -0.05, 0);
    g.add(tag);
    g.applyMatrix4(T);
    rigGroup.add(g);
    const box = document.createElement("label");
    box.innerHTML = `<input type="checkbox" checked> camera <span></span>`;
    box.querySelector("span").textContent = c.id;
    box.querySelector("span").style.color = "#" + color.toString(16).padStart(6, "0");
    box.querySelector("input").addEventListener("change", (e) => { g.visible = e.target.checked; requestRender(); });
    $("cams").append(box);
  });
  // turn the world so that the cameras' mean up is +y
  world.quaternion.identity();
  if (up.lengthSq() > 1e-9) world.quaternion.setFromUnitVectors(up.normalize(), new THREE.Vector3(0, 1, 0));
  $("cameras").textContent = rig.cameras.length;
  requestRender();
}
const box = { center: new THREE.Vector3(), size: 1 };
function frameView() {
  geometry.computeBoundingBox();
  const bb = geometry.boundingBox.clone().applyMatrix4(new THREE.Matrix4().makeRotationFromQuaternion(world.quaternion));
  world.position.set(0, -bb.min.y, 0); // the lowest point on the floor grid
  bb.translate(world.position);
  bb.getCenter(box.center);
  box.size = Math.max(bb.getSize(new THREE.Vector3()).length(), 0.5);
  controls.target.copy(box.center);
  const dir = new THREE.Vector3(0, 0.35, 1).normalize();
  if (rig.cameras.length) { // look the way the first camera does, from a little above
    const T = new THREE.Matrix4().fromArray(rig.cameras[0].T_world_cam).transpose();
    const f = new THREE.Vector3().setFromMatrixColumn(T, 2).applyQuaternion(world.quaternion);
    f.y = 0;
    if (f.lengthSq() > 1e-6) dir.copy(f.normalize().negate()).setY(0.35).normalize();
  }
  camera.position.copy(box.center).addScaledVector(dir, 0.9 * box.size);
  controls.update();
}
renderer.domElement.addEventListener("dblclick", () => { frameView(); requestRender(); });

// ---- colours
let colourMode = "rgb", last = null;
const colourSelect = $("colour");
function applyColours() {
  if (!last) return;
  let rgb = last.rgb;
  const a = last.attrs, m = last.m;
  if (colourMode !== "rgb" && a && new DataView(a.buffer).getUint32(8, true) === m) {
    const out = new Uint8Array(3 * m); // attributes: "FFLA", number, M (uint32), M camera, M weight (uint8)
    for (let i = 0; i < m; i++) {
      let r, g, b;
      if (colourMode === "weight") { // low weight blue, high red
        const w = a[12 + m + i] / 255;
        r = 255 * w; g = 255 * (1 - Math.abs(2 * w - 1)); b = 255 * (1 - w);
      } else {
        const cam = a[12 + i], p = cam === 255 ? 0x808080 : palette[cam % palette.length];
        r = p >> 16; g = (p >> 8) & 255; b = p & 255;
      }
      out[3 * i] = r; out[3 * i + 1] = g; out[3 * i + 2] = b;
    }
    rgb = out;
  }
  geometry.setAttribute("color", new THREE.BufferAttribute(rgb, 3, true));
}
window.fuseflowColours = () => { // the distinct colours drawn now, "r,g,b" (for tests and checks)
  const c = geometry.getAttribute("color"), seen = new Set();
  if (c) for (let i = 0; i < geometry.drawRange.count * 3 && i < c.array.length; i += 3) seen.add(c.array[i] + "," + c.array[i + 1] + "," + c.array[i + 2]);
  return [...seen];
};
colourSelect.addEventListener("change", () => { colourMode = colourSelect.value; applyColours(); requestRender(); });
$("size").addEventListener("input", (e) => {
  pointMaterial.uniforms.size.value = e.target.value / 1000; $("sizeText").textContent = e.target.value; requestRender();
});
$("grid").addEventListener("change", (e) => { helpers.visible = e.target.checked; requestRender(); });
$("snapshot").addEventListener("click", () => {
  render();
  renderer.domElement.toBlob((blob) => {
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = `fuseflow-live-${last ? last.number : 0}.png`;
    a.click();
    setTimeout(() => URL.revokeObjectURL(a.href), 1000);
  });
});

// ---- WebXR: offer the buttons only where the browser offers the session kind
if (navigator.xr) {
  navigator.xr.isSessionSupported("immersive-vr").then((ok) => { if (ok) $("xr").append(inline(VRButton.createButton(renderer))); }).catch(() => {});
  navigator.xr.isSessionSupported("immersive-ar").then((ok) => { if (ok) $("xr").append(inline(ARButton.createButton(renderer))); }).catch(() => {});
}
function inline(button) { // the addons place their buttons at the bottom centre; keep them in the panel
  Object.assign(button.style, { position: "static", display: "inline-block", padding: "4px 8px", fontSize: "12px", width: "auto" });
  return button;
}

// ---- frames: meta (text), frame (binary), attributes (binary, raw codec only); ack once shown
let meta = null, queued = null, decoding = false, shown = null, ws = null, times = [], ended = false;
// a key frame's geometry decodes in a worker while this thread decodes its colours (decode.js);
// ?worker=0, or a browser without module workers: all on this thread
const decodeWorker = (() => {
  if (params.get("worker") === "0" || typeof Worker === "undefined") return null;
  try { return new Worker(new URL("decode-worker.js", import.meta.url), { type: "module" }); } catch { return null; }
})();
const newDecoder = () => FuseFlowDecode.createDecoder(decodeWorker ? { worker: decodeWorker } : undefined);
let decoder = newDecoder();  // one per connection: it holds the frame a delta refers to
function setStatus(text, kind) {
  $("status").textContent = text;
  $("status").className = kind || "";
  stats.state = text;
}
function onBinary(buf) {
  if (buf.byteLength >= 4 && new TextDecoder().decode(new Uint8Array(buf, 0, 4)) === "FFLA") {
    if (queued && queued.wantAttrs && !queued.attrs) {
      queued.attrs = new Uint8Array(buf);
      if (!decoding) setTimeout(decodeNext, 0);
    }
    return;
  }
  if (queued && !decoding) stats.dropped += 1; // replaced before it was decoded
  const wantAttrs = !!(meta && meta.attrs); // the frame's attributes follow: decode with them
  queued = { buf, meta, received: performance.now(), attrs: null, wantAttrs };
  meta = null;
  if (!decoding && !wantAttrs) setTimeout(decodeNext, 0);
}
async function decodeNext() {
  decoding = true;
  try {
    while (queued) {
      const item = queued; queued = null;
      const t0 = performance.now();
      let f;
      try { f = await decoder.decodeFrame(item.buf); } catch (err) {
        setStatus("bad frame: " + err.message, "error");
        // say so (its decoder holds no frame now), so that the server goes on with a key frame
        if (ws && ws.readyState === 1 && item.meta) ws.send(JSON.stringify({ type: "ack", number: item.meta.number, held: null }));
        continue;
      }
      const decodeMs = performance.now() - t0;
      stats.decodeMs.push(decodeMs); if (stats.decodeMs.length > 200) stats.decodeMs.shift();
      last = { ...f, attrs: item.attrs };
      geometry.setAttribute("position", new THREE.BufferAttribute(f.xyz, 3));
      applyColours();
      geometry.setDrawRange(0, f.m);
      if (reframe && f.m > 0) { frameView(); reframe = false; }
      if (f.split) stats.split += 1;
      stats.frames += 1; stats.lastFrameAt = performance.now(); stats.bytes += item.buf.byteLength; stats.version = f.version;
      shown = { number: f.number, meta: item.meta, received: item.received, decodeMs };
      updateHud(f);
      if (renderer.xr.isPresenting) continue; // the XR loop draws it (and acknowledges)
      render();
    }
  } finally { decoding = false; }
}
function acknowledge() {
  const s = shown; shown = null;
  const now = performance.now(), m = s.meta;
  // age = (capture -> sent, by the server's clock) + half the round trip + (received -> shown, ours)
  const age = m && m.age_ms != null ? m.age_ms + (m.rtt_ms || 0) / 2 + (now - s.received) : null;
  if (age != null) { stats.ages.push(age); if (stats.ages.length > 500) stats.ages.shift(); $("age").textContent = age.toFixed(0); }
  const dropped = (m ? m.dropped : 0) + stats.dropped;
  $("dropped").textContent = dropped;
  if (ws && ws.readyState === 1 && m) {
    ws.send(JSON.stringify({ type: "ack", number: s.number, age_ms: age == null ? null : +age.toFixed(1),
      decode_ms: +s.decodeMs.toFixed(1), dropped: stats.dropped, held_ms: +(now - s.received).toFixed(1), held: decoder.held() }));
  }
}
function updateHud(f) {
  const now = performance.now();
  times.push(now);
  while (times.length && now - times[0] > 2000) times.shift();
  $("frames").textContent = stats.frames;
  $("points").textContent = f.m.toLocaleString();
  $("fps").textContent = times.length > 1 ? ((times.length - 1) * 1000 / (now - times[0])).toFixed(1) : "0";
  $("codec").textContent = f.version === 1 ? "raw" : "compact";
}

function connect() {
  const q = new URLSearchParams({ ack: "1", attrs: "1", inter: "1" });  // inter: compact deltas, decoded in order
  decoder = newDecoder();
  if (params.get("codec")) q.set("codec", params.get("codec"));
  if (token) q.set("token", token);
  ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws?" + q);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => { ended = false; setStatus("live"); };
  ws.onmessage = (e) => {
    if (typeof e.data !== "string") { onBinary(e.data); return; }
    const msg = JSON.parse(e.data);
    if (msg.type === "rig") {
      setRig(msg);
      const raw = msg.codec === "raw";
      for (const o of colourSelect.options) if (o.value !== "rgb") { o.disabled = !raw; o.title = raw ? "" : "open the page with ?codec=raw"; }
    } else if (msg.type === "frame") meta = msg;
    else if (msg.type === "end") { ended = true; stats.endedAt = performance.now(); setStatus(msg.reason === "end of source" ? "replay ended" : "ended: " + msg.reason, "ended"); }
    else if (msg.type === "error") { ended = true; setStatus("error: " + msg.message, "error"); }
  };
  let opened = false;
  ws.addEventListener("open", () => { opened = true; });
  ws.onclose = (e) => {
    if (!ended) setStatus(e.code === 1006 ? "disconnected, retrying" : `closed (${e.code}${e.reason ? ": " + e.reason : ""}), retrying`, "error");
    if (!opened && !ended) { // refused (token, origin, too many viewers)? the server says why on /stats
      fetch("/stats" + (token ? "?token=" + encodeURIComponent(token) : "")).then(async (r) => {
        if (!r.ok) setStatus(`${r.status}: ${(await r.text()).trim()}`, "error");
      }).catch(() => {});
    }
    setTimeout(connect, ended ? 5000 : 1000); // a new run on this address is picked up (and framed anew)
  };
}
connect();
setInterval(() => {
  if (document.hidden) return;
  fetch("/stats" + (token ? "?token=" + encodeURIComponent(token) : "")).then((r) => r.json()).then((s) => {
    if ($("clients").textContent !== String(s.clients)) $("clients").textContent = s.clients;
  }).catch(() => {});
}, 2000);
requestRender();
