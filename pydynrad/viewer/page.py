"""The page the viewer serves: one HTML document with its script, nothing fetched from elsewhere.

The script draws the scene with WebGL 2 in the browser's own render loop: the geometry (every
patch's three corners) arrives once, then each radiosity update is one half-float texture of
smooth-vertex radiosity (and, with an overlay on, one byte-per-patch texture), which the vertex
shader fetches by index. The camera is the browser's (orbit, pan, dolly, WASD fly) and moves at
the display's frame rate whatever the solver costs; its pose goes to the server at most 30 times
a second, tagged with a sequence number so the page can time a move to its first radiosity.
Exposure (automatic by default), the sRGB transfer and back faces in black (patches radiate
from their front only, as :mod:`pydynrad.renderer` shows them) are applied in the fragment shader.

``window.pydynrad`` exposes the page's state to scripts and tests: ``ready``, ``stats`` (frames
received, updates per second, browser frames per second, move-to-radiosity latencies), the
camera, and ``setCamera(position, look_at)``.
"""

from __future__ import annotations

__all__ = ["PAGE"]

_STYLE = r"""
html, body { margin: 0; height: 100%; overflow: hidden; background: #1b1d22; color: #ddd;
  font: 12px/1.35 system-ui, sans-serif; }
#view { position: absolute; inset: 0; width: 100%; height: 100%; display: block; outline: none; }
#panel { position: absolute; top: 8px; right: 8px; width: 270px; max-height: calc(100% - 16px); overflow-y: auto;
  background: rgba(20, 22, 27, 0.88); border: 1px solid #333; border-radius: 6px; padding: 6px 8px; }
#panel h3 { margin: 8px 0 4px; font-size: 12px; color: #9ac; text-transform: uppercase; letter-spacing: 0.05em; }
#panel label { display: flex; align-items: center; justify-content: space-between; gap: 6px; margin: 2px 0; }
#panel input[type=range] { width: 130px; }
#panel input[type=number] { width: 64px; background: #111; color: #ddd; border: 1px solid #444; }
#panel select, #panel button { background: #2a2e36; color: #ddd; border: 1px solid #555; border-radius: 3px; }
#panel button { margin: 2px 2px 2px 0; padding: 2px 6px; cursor: pointer; }
#stats { font: 11px/1.3 ui-monospace, monospace; white-space: pre; color: #bcd; }
#notice { color: #fc8; white-space: pre-wrap; }
.point { border-top: 1px solid #333; padding-top: 2px; }
#help { position: absolute; left: 8px; bottom: 6px; color: #889; font-size: 11px; }
"""

_BODY = r"""
<canvas id="view" tabindex="0"></canvas>
<div id="panel">
  <div id="title"><b>pydynrad</b> <span id="scene-name"></span></div>
  <div id="notice"></div>
  <h3>Frame</h3><div id="stats">connecting...</div>
  <h3>View</h3>
  <label>auto exposure <input type="checkbox" id="auto-exposure" checked></label>
  <label>exposure <input type="range" id="exposure" min="-10" max="10" step="0.1" value="0">
    <span id="exposure-value">0</span></label>
  <label>overlay <select id="overlay">
    <option value="none">none</option><option value="local">local set / far field</option>
    <option value="clusters">far-field clusters</option><option value="error">error vs full solve</option>
  </select></label>
  <div><button id="full-solve">full solve (error)</button><button id="screenshot">screenshot</button>
    <button id="record">record</button></div>
  <h3>Sun</h3>
  <label>on <input type="checkbox" id="sun-on"></label>
  <label>elevation <input type="range" id="sun-elevation" min="-5" max="90" step="0.5"><span id="sun-elevation-value"></span></label>
  <label>azimuth <input type="range" id="sun-azimuth" min="0" max="360" step="1"><span id="sun-azimuth-value"></span></label>
  <label>irradiance W/m&sup2; <input type="number" id="sun-irradiance" min="0" step="any"></label>
  <h3>Sky</h3>
  <label>model <select id="sky-kind">
    <option value="none">none</option><option value="uniform">uniform</option>
    <option value="cie_overcast">CIE overcast (traditional)</option><option value="overcast">CIE 1 overcast</option>
    <option value="clear">CIE 12 clear (follows the sun)</option></select></label>
  <label>horizontal lux <input type="number" id="sky-illuminance" min="0" step="any"></label>
  <h3>Point lights</h3>
  <div id="points"></div>
  <button id="add-point">add at view centre</button>
  <div id="fixed-lights"></div>
  <div id="path-box" hidden>
    <h3>Path</h3>
    <div><button id="play">play</button> <span id="path-frame"></span></div>
    <label>frame <input type="range" id="path-slider" min="0" max="0" step="1" value="0"></label>
    <label>camera follows the path <input type="checkbox" id="path-follow" checked></label>
  </div>
</div>
<div id="help">drag: orbit &middot; right/shift-drag: pan &middot; wheel: dolly &middot; W A S D Q E: fly</div>
"""

_SCRIPT = r"""
"use strict";
const $ = (id) => document.getElementById(id);
const canvas = $("view");
const gl = canvas.getContext("webgl2", { antialias: true, preserveDrawingBuffer: true });
const S = {                       // what window.pydynrad shows
  ready: false, framesReceived: 0, lastFrame: -1, updatesPerSecond: 0, fps: 0, latencies: [],
  lastLatency: null, bytesReceived: 0, frameHeader: null, drawn: 0,
};
window.pydynrad = { stats: S };
let socket = null, scene = null, state = null;
const cam = { eye: [0, 0, 1], target: [0, 0, 0], up: [0, 1, 0], fovY: 45 };
let camSeq = 0, camDirty = true, camSentAt = 0;
const pending = [];               // [seq, time sent] of camera poses not yet answered by a frame
let displayStops = 0, autoStops = 0, haveAuto = false;

// ---------- vectors and matrices (column-major, as WebGL reads them) ----------
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const len = (a) => Math.hypot(a[0], a[1], a[2]);
const norm = (a) => mul(a, 1 / (len(a) || 1));
function rotate(v, axis, angle) {  // Rodrigues
  const k = norm(axis), c = Math.cos(angle), s = Math.sin(angle);
  return add(add(mul(v, c), mul(cross(k, v), s)), mul(k, dot(k, v) * (1 - c)));
}
function viewProj(aspect) {
  const f = norm(sub(cam.target, cam.eye)), r = norm(cross(f, cam.up)), u = cross(r, f);
  const e = cam.eye, span = scene ? scene.scale : 1;
  const dist = len(sub(cam.target, cam.eye));
  const near = Math.max(span * 1e-4, Math.min(dist * 0.01, span * 0.01)), far = span * 20 + dist * 2;
  const t = 1 / Math.tan((cam.fovY * Math.PI) / 360);
  const P = [t / aspect, 0, 0, 0, 0, t, 0, 0, 0, 0, -(far + near) / (far - near), -1, 0, 0, -2 * far * near / (far - near), 0];
  const V = [r[0], u[0], -f[0], 0, r[1], u[1], -f[1], 0, r[2], u[2], -f[2], 0, -dot(r, e), -dot(u, e), dot(f, e), 1];
  const M = new Float32Array(16);
  for (let c = 0; c < 4; c++) for (let rr = 0; rr < 4; rr++) {
    let s = 0;
    for (let k = 0; k < 4; k++) s += P[k * 4 + rr] * V[c * 4 + k];
    M[c * 4 + rr] = s;
  }
  return M;
}

// ---------- WebGL ----------
const VS = `#version 300 es
precision highp float; precision highp int;
in vec3 position; in uint vid;
uniform mat4 viewProj; uniform highp sampler2D rad; uniform highp sampler2D ov; uniform int radW; uniform int ovW;
out vec3 vRad; out vec4 vOv;
void main() {
  int v = int(vid), p = gl_VertexID / 3;
  vRad = texelFetch(rad, ivec2(v % radW, v / radW), 0).rgb;
  vOv = texelFetch(ov, ivec2(p % ovW, p / ovW), 0);
  gl_Position = viewProj * vec4(position, 1.0);
}`;
const FS = `#version 300 es
precision highp float;
in vec3 vRad; in vec4 vOv; uniform float scale; uniform float ovOn; out vec4 color;
vec3 srgb(vec3 c) { c = clamp(c, 0.0, 1.0);
  return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, c)); }
void main() {
  vec3 c = gl_FrontFacing ? srgb(vRad * scale) : vec3(0.0);
  color = vec4(mix(c, vOv.rgb, vOv.a * ovOn), 1.0);
}`;
function compile(type, src) {
  const s = gl.createShader(type);
  gl.shaderSource(s, src); gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
  return s;
}
let prog = null, vao = null, radTex = null, ovTex = null, posBuf = null, loc = {};
function setupGL() {
  prog = gl.createProgram();
  gl.attachShader(prog, compile(gl.VERTEX_SHADER, VS));
  gl.attachShader(prog, compile(gl.FRAGMENT_SHADER, FS));
  gl.linkProgram(prog);
  if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(prog));
  for (const n of ["viewProj", "rad", "ov", "radW", "ovW", "scale", "ovOn"]) loc[n] = gl.getUniformLocation(prog, n);
  gl.enable(gl.DEPTH_TEST);
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
}
function texture(internal, format, type, w, h, data) {
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, t);
  gl.texImage2D(gl.TEXTURE_2D, 0, internal, w, h, 0, format, type, data);
  for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);
  return t;
}
function loadScene(head, arrays) {
  scene = head;
  $("scene-name").textContent = `${head.name}: ${head.n_patches.toLocaleString()} patches`;
  vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
  posBuf = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, posBuf);
  gl.bufferData(gl.ARRAY_BUFFER, arrays.positions, gl.DYNAMIC_DRAW);
  const pl = gl.getAttribLocation(prog, "position");
  gl.enableVertexAttribArray(pl); gl.vertexAttribPointer(pl, 3, gl.FLOAT, false, 0, 0);
  const vb = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, vb);
  gl.bufferData(gl.ARRAY_BUFFER, arrays.vid, gl.STATIC_DRAW);
  const vl = gl.getAttribLocation(prog, "vid");
  gl.enableVertexAttribArray(vl); gl.vertexAttribIPointer(vl, 1, gl.UNSIGNED_INT, 0, 0);
  radTex = texture(gl.RGB16F, gl.RGB, gl.HALF_FLOAT, head.rad_w, head.rad_h, new Uint16Array(head.rad_w * head.rad_h * 3));
  ovTex = texture(gl.RGBA8, gl.RGBA, gl.UNSIGNED_BYTE, head.ov_w, head.ov_h, new Uint8Array(head.ov_w * head.ov_h * 4));
  if (!haveCamera) setCamera(head.camera.position, head.camera.look_at, head.camera.fov_y, false);
  cam.up = head.up;
}
function draw() {
  const w = canvas.clientWidth, h = canvas.clientHeight, dpr = window.devicePixelRatio || 1;
  if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
    canvas.width = Math.round(w * dpr); canvas.height = Math.round(h * dpr); camDirty = true;
  }
  gl.viewport(0, 0, canvas.width, canvas.height);
  gl.clearColor(0.105, 0.115, 0.135, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  if (!scene) return;
  gl.useProgram(prog); gl.bindVertexArray(vao);
  gl.uniformMatrix4fv(loc.viewProj, false, viewProj(canvas.width / canvas.height));
  gl.activeTexture(gl.TEXTURE0); gl.bindTexture(gl.TEXTURE_2D, radTex); gl.uniform1i(loc.rad, 0);
  gl.activeTexture(gl.TEXTURE1); gl.bindTexture(gl.TEXTURE_2D, ovTex); gl.uniform1i(loc.ov, 1);
  gl.uniform1i(loc.radW, scene.rad_w); gl.uniform1i(loc.ovW, scene.ov_w);
  gl.uniform1f(loc.scale, Math.pow(2, displayStops));
  gl.uniform1f(loc.ovOn, $("overlay").value === "none" ? 0 : 1);
  gl.drawArrays(gl.TRIANGLES, 0, scene.n_patches * 3);
  S.drawn++;
}

// ---------- messages ----------
function decode(buf) {
  const n = new DataView(buf).getUint32(0, true);
  const head = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  const base = 4 + n + ((8 - ((4 + n) % 8)) % 8), arrays = {};
  const T = { f4: Float32Array, f2: Uint16Array, u4: Uint32Array, u1: Uint8Array };
  for (const [name, [code, off, count]] of Object.entries(head.arrays)) arrays[name] = new T[code](buf, base + off, count);
  return [head, arrays];
}
const send = (msg) => { if (socket && socket.readyState === 1) socket.send(JSON.stringify(msg)); };
let arrivals = [];
function onFrame(head, arrays) {
  gl.bindTexture(gl.TEXTURE_2D, radTex);
  gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, scene.rad_w, scene.rad_h, gl.RGB, gl.HALF_FLOAT, arrays.rad);
  if (arrays.overlay) {
    gl.bindTexture(gl.TEXTURE_2D, ovTex);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, scene.ov_w, scene.ov_h, gl.RGBA, gl.UNSIGNED_BYTE, arrays.overlay);
  }
  const now = performance.now();
  while (pending.length && pending[0][0] <= head.seq) {
    const [, t] = pending.shift();
    S.lastLatency = now - t;
    S.latencies.push(S.lastLatency);
    if (S.latencies.length > 500) S.latencies.shift();
  }
  arrivals.push(now);
  S.framesReceived++; S.lastFrame = head.frame; S.frameHeader = head;
  if (head.auto_stops !== null && head.auto_stops !== undefined) {
    autoStops = head.auto_stops;
    if (!haveAuto) { displayStops = autoStops; haveAuto = true; }
  }
  showStats();
}
function onPositions(head, arrays) {
  gl.bindBuffer(gl.ARRAY_BUFFER, posBuf);
  gl.bufferSubData(gl.ARRAY_BUFFER, head.offset * 4, arrays.positions);
}
const ms = (s) => (s === null || s === undefined ? "-" : (1e3 * s).toFixed(1).padStart(6));
function showStats() {
  const h = S.frameHeader;
  if (!h) return;
  const st = h.stats, lat = S.latencies.slice(-50).sort((a, b) => a - b);
  const med = lat.length ? lat[Math.floor(lat.length / 2)].toFixed(0) : "-";
  $("stats").textContent = [
    `frame ${h.frame}   M ${st.M} of N ${st.N}`,
    `swaps ${st.swaps}   local ${st.local}   clusters ${st.clusters ?? "-"}`,
    `select   ${ms(st.t_select)} ms   rows ${ms(st.t_form_factors)} ms`,
    `update K ${ms(st.t_update)} ms   moves ${ms(st.t_move)} ms`,
    `lighting ${ms(st.t_lighting)} ms   colours ${ms(st.t_colours)} ms`,
    `solver frame ${ms(st.t_frame)} ms`,
    `K residual ${st.residual === null ? "-" : st.residual.toExponential(2)}   far-field error est. ${
      st.far_error === null || st.far_error === undefined ? "-" : (100 * st.far_error).toFixed(2) + " %"}`,
    `error vs full ${st.error === null ? "(full solve: button)" : (100 * st.error).toFixed(2) + " % rel. RMS"}`,
    `updates/s ${S.updatesPerSecond.toFixed(1)}   browser fps ${S.fps.toFixed(0)}`,
    `move -> radiosity ${med} ms (median)`,
    `exposure ${displayStops.toFixed(2)} stops${h.recording ? "   REC " + h.recorded : ""}`,
  ].join("\n");
}
function onText(msg) {
  if (msg.kind === "state") applyState(msg);
  else if (msg.kind === "camera") setCamera(msg.position, msg.look_at, msg.fov_y, true);
  else if (msg.kind === "notice") $("notice").textContent = msg.text;
  else if (msg.kind === "screenshot") {
    draw();
    send({ type: "screenshot", id: msg.id, png: canvas.toDataURL("image/png") });
  }
}
function connect() {
  socket = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
  socket.binaryType = "arraybuffer";
  socket.onmessage = (ev) => {
    if (typeof ev.data === "string") { onText(JSON.parse(ev.data)); return; }
    S.bytesReceived += ev.data.byteLength;
    const [head, arrays] = decode(ev.data);
    if (head.kind === "scene") loadScene(head, arrays);
    else if (head.kind === "frame") onFrame(head, arrays);
    else if (head.kind === "positions") onPositions(head, arrays);
    else if (head.kind === "overlay") {
      gl.bindTexture(gl.TEXTURE_2D, ovTex);
      gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, scene.ov_w, scene.ov_h, gl.RGBA, gl.UNSIGNED_BYTE, arrays.overlay);
    }
  };
  socket.onopen = () => { S.ready = true; camDirty = true; };
  socket.onclose = () => { S.ready = false; $("stats").textContent = "disconnected: the viewer was closed"; };
}

// ---------- camera ----------
let haveCamera = false;
function setCamera(position, lookAt, fovY, fromServer) {
  const o = scene ? scene.origin : [0, 0, 0];
  cam.eye = sub(position, o); cam.target = sub(lookAt, o);
  if (fovY) cam.fovY = fovY;
  haveCamera = true; camDirty = true;
}
window.pydynrad.setCamera = (p, l, f) => setCamera(p, l, f, false);
window.pydynrad.camera = () => ({ position: add(cam.eye, scene ? scene.origin : [0, 0, 0]),
  look_at: add(cam.target, scene ? scene.origin : [0, 0, 0]), fov_y: cam.fovY });
function sendCamera(now) {
  if (!scene || !socket || socket.readyState !== 1) return;
  camSeq++;
  const c = window.pydynrad.camera();
  send({ type: "camera", seq: camSeq, position: c.position, look_at: c.look_at, fov_y: c.fov_y,
         aspect: canvas.width / Math.max(1, canvas.height) });
  pending.push([camSeq, now]);
  if (pending.length > 200) pending.shift();
  camSentAt = now; camDirty = false;
}
function orbit(dx, dy) {
  let off = sub(cam.eye, cam.target);
  off = rotate(off, cam.up, -dx * 0.005);
  const right = norm(cross(off, cam.up));
  const turned = rotate(off, right, dy * 0.005);
  if (Math.abs(dot(norm(turned), cam.up)) < 0.995) off = turned;
  cam.eye = add(cam.target, off); camDirty = true;
}
function pan(dx, dy) {
  const f = norm(sub(cam.target, cam.eye)), r = norm(cross(f, cam.up)), u = cross(r, f);
  const s = len(sub(cam.eye, cam.target)) * Math.tan((cam.fovY * Math.PI) / 360) * 2 / canvas.clientHeight;
  const d = add(mul(r, -dx * s), mul(u, dy * s));
  cam.eye = add(cam.eye, d); cam.target = add(cam.target, d); camDirty = true;
}
let drag = null;
canvas.addEventListener("pointerdown", (e) => { drag = { x: e.clientX, y: e.clientY, pan: e.button !== 0 || e.shiftKey };
  canvas.setPointerCapture(e.pointerId); canvas.focus(); });
canvas.addEventListener("pointermove", (e) => {
  if (!drag) return;
  const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
  drag.x = e.clientX; drag.y = e.clientY;
  if (drag.pan) pan(dx, dy); else orbit(dx, dy);
});
canvas.addEventListener("pointerup", () => { drag = null; });
canvas.addEventListener("contextmenu", (e) => e.preventDefault());
canvas.addEventListener("wheel", (e) => {
  e.preventDefault();
  const off = sub(cam.eye, cam.target), k = Math.exp(Math.sign(e.deltaY) * Math.min(Math.abs(e.deltaY), 200) * 0.002);
  cam.eye = add(cam.target, mul(off, k)); camDirty = true;
}, { passive: false });
const keys = new Set();
canvas.addEventListener("keydown", (e) => keys.add(e.key.toLowerCase()));
canvas.addEventListener("keyup", (e) => keys.delete(e.key.toLowerCase()));
window.addEventListener("blur", () => keys.clear());
function fly(dt) {
  if (!keys.size || !scene) return;
  const f = norm(sub(cam.target, cam.eye)), r = norm(cross(f, cam.up));
  const h = norm(sub(f, mul(cam.up, dot(f, cam.up))));
  const v = scene.scale * 0.25 * dt * (keys.has("shift") ? 4 : 1);
  let d = [0, 0, 0];
  if (keys.has("w") || keys.has("arrowup")) d = add(d, h);
  if (keys.has("s") || keys.has("arrowdown")) d = sub(d, h);
  if (keys.has("d") || keys.has("arrowright")) d = add(d, r);
  if (keys.has("a") || keys.has("arrowleft")) d = sub(d, r);
  if (keys.has("e")) d = add(d, cam.up);
  if (keys.has("q")) d = sub(d, cam.up);
  if (len(d) === 0) return;
  d = mul(d, v);
  cam.eye = add(cam.eye, d); cam.target = add(cam.target, d); camDirty = true;
}

// ---------- the loop: the browser's own frame rate, never waiting for the server ----------
let last = performance.now(), fpsCount = 0, fpsT = last;
function loop(now) {
  fly(Math.min(0.1, (now - last) / 1e3));
  if (camDirty && now - camSentAt >= 33) sendCamera(now);
  const target = $("auto-exposure").checked ? autoStops + Number($("exposure").value) : Number($("exposure").value);
  displayStops += (target - displayStops) * (1 - Math.exp(-Math.min(1, (now - last) / 1e3) / 0.15));
  last = now;
  draw();
  fpsCount++;
  if (now - fpsT >= 1000) {
    S.fps = (fpsCount * 1000) / (now - fpsT); fpsCount = 0; fpsT = now;
    arrivals = arrivals.filter((t) => now - t <= 2000);
    S.updatesPerSecond = arrivals.length / 2;
    const lat = S.latencies.slice(-100).sort((a, b) => a - b);
    send({ type: "client_stats", fps: S.fps, updates_per_second: S.updatesPerSecond, frames_received: S.framesReceived,
           latency_ms_median: lat.length ? lat[Math.floor(lat.length / 2)] : null, bytes_received: S.bytesReceived });
    showStats();
  }
  requestAnimationFrame(loop);
}

// ---------- the panel ----------
function lightsMessage() {
  const points = [...document.querySelectorAll(".point")].map((el) => ({
    position: ["x", "y", "z"].map((a) => Number(el.querySelector(`.p${a}`).value)),
    intensity: Number(el.querySelector(".pi").value),
  }));
  return { type: "lights",
    sun: { on: $("sun-on").checked, elevation: Number($("sun-elevation").value), azimuth: Number($("sun-azimuth").value),
           irradiance: Number($("sun-irradiance").value) },
    sky: { kind: $("sky-kind").value, illuminance: Number($("sky-illuminance").value) },
    points };
}
let lightsTimer = null;
function lightsChanged() {
  $("sun-elevation-value").textContent = $("sun-elevation").value + "\u00b0";
  $("sun-azimuth-value").textContent = $("sun-azimuth").value + "\u00b0";
  if (lightsTimer) return;
  lightsTimer = setTimeout(() => { lightsTimer = null; send(lightsMessage()); }, 60);
}
function addPoint(p) {
  const el = document.createElement("div");
  el.className = "point";
  el.innerHTML = `<label>x <input type="number" class="px" step="any"> y <input type="number" class="py" step="any"></label>
    <label>z <input type="number" class="pz" step="any"> W/sr <input type="number" class="pi" step="any" min="0"></label>
    <button class="remove">remove</button>`;
  el.querySelector(".px").value = p.position[0]; el.querySelector(".py").value = p.position[1];
  el.querySelector(".pz").value = p.position[2]; el.querySelector(".pi").value = p.intensity;
  for (const i of el.querySelectorAll("input")) i.addEventListener("input", lightsChanged);
  el.querySelector(".remove").addEventListener("click", () => { el.remove(); lightsChanged(); });
  $("points").appendChild(el);
}
function applyState(st) {
  state = st;
  const L = st.lights;
  $("sun-on").checked = L.sun.on; $("sun-elevation").value = L.sun.elevation; $("sun-azimuth").value = L.sun.azimuth;
  $("sun-irradiance").value = L.sun.irradiance;
  $("sky-kind").value = L.sky.kind; $("sky-illuminance").value = L.sky.illuminance;
  $("points").innerHTML = "";
  for (const p of L.points) addPoint(p);
  $("fixed-lights").textContent = L.fixed ? `${L.fixed} more light(s) from the path or command line` : "";
  $("sun-elevation-value").textContent = L.sun.elevation + "\u00b0";
  $("sun-azimuth-value").textContent = L.sun.azimuth + "\u00b0";
  if (st.path) {
    $("path-box").hidden = false;
    $("path-slider").max = st.path.frames - 1; $("path-slider").value = st.path.frame;
    $("play").textContent = st.path.playing ? "pause" : "play";
    $("path-frame").textContent = `frame ${st.path.frame} of ${st.path.frames}`;
    $("path-follow").checked = st.path.follow;
  }
  $("overlay").value = st.overlay;
  $("record").textContent = st.recording ? "stop recording" : "record";
}
for (const id of ["sun-on", "sun-elevation", "sun-azimuth", "sun-irradiance", "sky-kind", "sky-illuminance"]) {
  $(id).addEventListener("input", lightsChanged);
}
$("add-point").addEventListener("click", () => {
  const o = scene ? scene.origin : [0, 0, 0];
  addPoint({ position: add(cam.target, o).map((v) => +v.toPrecision(6)), intensity: scene ? scene.point_intensity : 1 });
  lightsChanged();
});
$("exposure").addEventListener("input", () => { $("exposure-value").textContent = $("exposure").value; });
$("overlay").addEventListener("change", () => send({ type: "overlay", mode: $("overlay").value }));
$("full-solve").addEventListener("click", () => send({ type: "full_solve" }));
$("record").addEventListener("click", () => send({ type: "record", on: !(state && state.recording) }));
$("screenshot").addEventListener("click", () => {
  draw();
  const a = document.createElement("a");
  a.href = canvas.toDataURL("image/png"); a.download = `pydynrad-${S.lastFrame}.png`; a.click();
});
const pathMsg = (extra) => send({ type: "path", frame: Number($("path-slider").value), follow: $("path-follow").checked, ...extra });
$("play").addEventListener("click", () => pathMsg({ playing: !(state && state.path && state.path.playing) }));
$("path-slider").addEventListener("input", () => pathMsg({ playing: false }));
$("path-follow").addEventListener("change", () => pathMsg({}));

if (!gl) {
  $("notice").textContent = "This browser has no WebGL 2: the viewer cannot draw.";
} else {
  setupGL();
  connect();
  requestAnimationFrame(loop);
}
"""

#: The whole page, served at ``/``.
PAGE = (
    '<!doctype html>\n<html lang="en"><head><meta charset="utf-8">'
    '<meta name="viewport" content="width=device-width, initial-scale=1">'
    '<link rel="icon" href="data:,"><title>pydynrad viewer</title>'
    f"<style>{_STYLE}</style></head><body>{_BODY}<script>{_SCRIPT}</script></body></html>\n"
)
