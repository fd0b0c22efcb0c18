// FuseFlow live viewer: WebGL points + camera frustums, orbit controls, frames from /ws
// (binary format in fuseflow/live/wire.py and docs/live.md). No dependencies.
"use strict";
(function () {
  const canvas = document.getElementById("view");
  const gl = canvas.getContext("webgl", { antialias: false, preserveDrawingBuffer: true });
  const $ = (id) => document.getElementById(id);
  if (!gl) { $("status").textContent = "WebGL is not available"; return; }

  function shader(type, src) {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    return s;
  }
  function program(vs, fs) {
    const p = gl.createProgram();
    gl.attachShader(p, shader(gl.VERTEX_SHADER, vs));
    gl.attachShader(p, shader(gl.FRAGMENT_SHADER, fs));
    gl.linkProgram(p);
    return p;
  }
  // Points: float32 positions (decoded from either frame codec below); uint8 colours.
  const pointProg = program(
    "attribute vec3 q; attribute vec3 c; uniform mat4 mvp; uniform float size;" +
    "varying vec3 vc; void main() {" +
    "gl_Position = mvp * vec4(q, 1.0); gl_PointSize = size / max(gl_Position.w, 0.1); vc = c / 255.0; }",
    "precision mediump float; varying vec3 vc; void main() { gl_FragColor = vec4(vc, 1.0); }");
  const lineProg = program(
    "attribute vec3 p; uniform mat4 mvp; void main() { gl_Position = mvp * vec4(p, 1.0); }",
    "precision mediump float; uniform vec3 col; void main() { gl_FragColor = vec4(col, 1.0); }");
  const posBuf = gl.createBuffer(), colBuf = gl.createBuffer(), lineBuf = gl.createBuffer();
  let count = 0, lineCount = 0, haveView = false;

  // ---- camera: orbit around a target. "Up" is the cameras' mean up direction (minus their
  // y axes: image up), so z-up and y-down worlds both look upright; the first view looks the way
  // the first camera does, from a little above.
  const view = { target: [0, 0, 0], dist: 4, yaw: 0, pitch: 0.35, up: [0, -1, 0], fwd: [0, 0, 1] };
  function resetView(box) {
    if (box) {
      view.target = [0, 1, 2].map((i) => box[0][i] + box[1][i] / 2);
      view.dist = Math.max(0.9 * Math.hypot(box[1][0], box[1][1], box[1][2]), 0.5);
    }
    view.yaw = 0; view.pitch = 0.35;
  }
  function eye() {
    const u = view.up, b = norm(sub(view.fwd, u.map((x) => x * dot(view.fwd, u)))), a = cross(u, b);
    const cp = Math.cos(view.pitch), sp = Math.sin(view.pitch), sy = Math.sin(view.yaw), cy = Math.cos(view.yaw);
    return [0, 1, 2].map((i) => view.target[i] - view.dist * (cp * (cy * b[i] + sy * a[i]) - sp * u[i]));
  }
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const norm = (a) => { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  function mvp() {
    const e = eye(), f = norm(sub(view.target, e)), s = norm(cross(f, view.up)), u = cross(s, f);
    const aspect = canvas.width / Math.max(canvas.height, 1), fov = 1.0, n = 0.02, far = 100;
    const y = 1 / Math.tan(fov / 2), x = y / aspect;
    // projection * lookAt, column-major for WebGL
    const v = [s[0], u[0], -f[0], 0, s[1], u[1], -f[1], 0, s[2], u[2], -f[2], 0, -dot(s, e), -dot(u, e), dot(f, e), 1];
    const p = [x, 0, 0, 0, 0, y, 0, 0, 0, 0, (far + n) / (n - far), -1, 0, 0, (2 * far * n) / (n - far), 0];
    const m = new Float32Array(16);
    for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) {
      let acc = 0;
      for (let k = 0; k < 4; k++) acc += p[k * 4 + r] * v[c * 4 + k];
      m[c * 4 + r] = acc;
    }
    return m;
  }
  let drag = null;
  canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  canvas.addEventListener("mousedown", (e) => { drag = { x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2 }; });
  window.addEventListener("mouseup", () => { drag = null; });
  window.addEventListener("mousemove", (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) {
      const e0 = eye(), f = norm(sub(view.target, e0)), s = norm(cross(f, view.up)), u = cross(s, f);
      const k = view.dist * 0.0015;
      for (let i = 0; i < 3; i++) view.target[i] += -dx * k * s[i] + dy * k * u[i];
    } else {
      view.yaw += dx * 0.005;
      view.pitch = Math.max(-1.5, Math.min(1.5, view.pitch + dy * 0.005));
    }
  });
  canvas.addEventListener("wheel", (e) => { e.preventDefault(); view.dist *= Math.exp(e.deltaY * 0.001); }, { passive: false });
  canvas.addEventListener("dblclick", () => resetView(lastBox));

  // ---- camera frustums from the rig message
  function frustums(cams) {
    const lines = [];
    for (const c of cams) {
      const T = c.T_world_cam, K = c.K, d = 0.15;
      const P = (x, y, z) => [0, 1, 2].map((r) => T[r * 4] * x + T[r * 4 + 1] * y + T[r * 4 + 2] * z + T[r * 4 + 3]);
      const o = P(0, 0, 0);
      const corners = [[0, 0], [c.width, 0], [c.width, c.height], [0, c.height]].map(
        ([u, v]) => P(((u - K[0][2]) / K[0][0]) * d, ((v - K[1][2]) / K[1][1]) * d, d));
      for (let i = 0; i < 4; i++) lines.push(o, corners[i], corners[i], corners[(i + 1) % 4]);
    }
    gl.bindBuffer(gl.ARRAY_BUFFER, lineBuf);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(lines.flat()), gl.STATIC_DRAW);
    lineCount = lines.length;
    $("cameras").textContent = cams.length;
    if (cams.length) {
      const col = (c, k) => [c.T_world_cam[k], c.T_world_cam[4 + k], c.T_world_cam[8 + k]];
      let up = [0, 0, 0];
      for (const c of cams) up = sub(up, col(c, 1));
      if (Math.hypot(up[0], up[1], up[2]) > 1e-6) view.up = norm(up);
      const f0 = col(cams[0], 2);
      if (Math.abs(dot(f0, view.up)) < 0.99) view.fwd = f0;
    }
  }

  // ---- frames: version 1 (raw) and version 2 (compact); docs/live.md has both byte by byte
  let frames = 0, lastBox = null, times = [], busy = false, waiting = null, decodeMs = [];
  window.fuseflowStats = { decodeMs, frames: 0, bytes: 0, version: 0 };
  function boxOf(xyz, m) {
    const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (let i = 0; i < m; i++) for (let a = 0; a < 3; a++) {
      const v = xyz[3 * i + a]; if (v < lo[a]) lo[a] = v; if (v > hi[a]) hi[a] = v;
    }
    return [lo, [0, 1, 2].map((a) => Math.max(hi[a] - lo[a], 1e-6))];
  }
  async function onFrame(buf) {
    // one frame decodes at a time; frames arriving meanwhile replace each other (newest wins)
    if (busy) { waiting = buf; return; }
    busy = true;
    try {
      while (buf) {
        await show(buf);
        buf = waiting; waiting = null;
      }
    } finally { busy = false; }
  }
  async function show(buf) {
    const t0 = performance.now();
    let frame;
    try { frame = await FuseFlowDecode.decodeFrame(buf); } catch (err) {
      $("status").textContent = "bad frame: " + err.message; return;
    }
    const version = frame.version;
    decodeMs.push(performance.now() - t0);
    if (decodeMs.length > 200) decodeMs.shift();
    const m = frame.m;
    gl.bindBuffer(gl.ARRAY_BUFFER, posBuf);
    gl.bufferData(gl.ARRAY_BUFFER, frame.xyz, gl.DYNAMIC_DRAW);
    gl.bindBuffer(gl.ARRAY_BUFFER, colBuf);
    gl.bufferData(gl.ARRAY_BUFFER, frame.rgb, gl.DYNAMIC_DRAW);
    count = m;
    if (!haveView && m > 0) { lastBox = boxOf(frame.xyz, m); resetView(lastBox); haveView = true; }
    frames += 1;
    Object.assign(window.fuseflowStats, { frames, bytes: window.fuseflowStats.bytes + buf.byteLength, version });
    const now = performance.now();
    times.push(now);
    while (times.length && now - times[0] > 2000) times.shift();
    $("frames").textContent = frames;
    $("points").textContent = m.toLocaleString();
    $("latency").textContent = frame.latency.toFixed(0);
    $("fps").textContent = times.length > 1 ? ((times.length - 1) * 1000 / (now - times[0])).toFixed(1) : "0";
    $("codec").textContent = version === 1 ? "raw" : "compact";
  }

  function draw() {
    const w = canvas.clientWidth, h = canvas.clientHeight;
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    gl.viewport(0, 0, w, h);
    gl.clearColor(0.08, 0.086, 0.1, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    const m = mvp();
    if (count > 0) {
      gl.useProgram(pointProg);
      gl.uniformMatrix4fv(gl.getUniformLocation(pointProg, "mvp"), false, m);
      gl.uniform1f(gl.getUniformLocation(pointProg, "size"), 6.0 * window.devicePixelRatio);
      const qa = gl.getAttribLocation(pointProg, "q"), ca = gl.getAttribLocation(pointProg, "c");
      gl.bindBuffer(gl.ARRAY_BUFFER, posBuf);
      gl.enableVertexAttribArray(qa);
      gl.vertexAttribPointer(qa, 3, gl.FLOAT, false, 0, 0);
      gl.bindBuffer(gl.ARRAY_BUFFER, colBuf);
      gl.enableVertexAttribArray(ca);
      gl.vertexAttribPointer(ca, 3, gl.UNSIGNED_BYTE, false, 0, 0);
      gl.drawArrays(gl.POINTS, 0, count);
      gl.disableVertexAttribArray(ca);
    }
    if (lineCount > 0) {
      gl.useProgram(lineProg);
      gl.uniformMatrix4fv(gl.getUniformLocation(lineProg, "mvp"), false, m);
      gl.uniform3fv(gl.getUniformLocation(lineProg, "col"), [1.0, 0.75, 0.2]);
      const pa = gl.getAttribLocation(lineProg, "p");
      gl.bindBuffer(gl.ARRAY_BUFFER, lineBuf);
      gl.enableVertexAttribArray(pa);
      gl.vertexAttribPointer(pa, 3, gl.FLOAT, false, 0, 0);
      gl.drawArrays(gl.LINES, 0, lineCount);
    }
    requestAnimationFrame(draw);
  }
  requestAnimationFrame(draw);

  function connect() {
    // ?codec=raw in the page's address asks the server for that codec (default: the server's)
    const codec = new URLSearchParams(location.search).get("codec");
    const ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws" +
      (codec ? "?codec=" + encodeURIComponent(codec) : ""));
    ws.binaryType = "arraybuffer";
    ws.onopen = () => { $("status").textContent = "live"; };
    ws.onmessage = (e) => {
      if (typeof e.data === "string") {
        const msg = JSON.parse(e.data);
        if (msg.type === "rig") frustums(msg.cameras);
      } else onFrame(e.data);
    };
    ws.onclose = () => { $("status").textContent = "disconnected, retrying"; setTimeout(connect, 1000); };
  }
  connect();
  setInterval(() => {
    fetch("/stats").then((r) => r.json()).then((s) => {
      $("clients").textContent = s.clients;
      $("dropped").textContent = s.dropped;
    }).catch(() => {});
  }, 1000);
})();
