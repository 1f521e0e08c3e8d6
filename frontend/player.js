// ClipPlayer: draws a clip from its data (GET /api/clips/{domain}/{rollout_id}.json and the domain's scene.json)
// instead of playing its MP4: three.js for the MuJoCo domains, a 2-D canvas for lane change, the MP4 in a <video>
// where WebGL is missing or the data cannot be had. Plain ES module, no build step; three.js is vendored.
// Coordinates stay MuJoCo's (z up, metres): the camera's up is +z, so nothing is converted.

import * as THREE from "./vendor/three-0.187.0/three.module.min.js";

THREE.ColorManagement.enabled = false;  // MuJoCo writes its colours as they are: no sRGB conversion either way

const RATES = [0.25, 0.5, 0.75, 1];
const VIDEO_FPS = 30;  // frame step in the MP4 fallback, where the clip data (and its rate) did not arrive
const COMPARE = { off: "No compare", beside: "Previous beside", ghost: "Previous ghosted" };
const KEYS = [["Space", "play / pause"], ["← →", "one frame back / on"], ["Home End", "first / last frame"],
  ["[ ]", "slower / faster"], ["L", "loop on / off"], ["C", "compare with the previous clip"],
  ["0", "reset the camera"], ["D", "show the description"]];
const ICONS = {  // drawn, not characters: not every font has a pause sign
  play: '<svg viewBox="0 0 16 16" width="14" height="14" aria-hidden="true"><path d="M4 2l10 6-10 6z" fill="currentColor"/></svg>',
  pause: '<svg viewBox="0 0 16 16" width="14" height="14" aria-hidden="true"><path d="M3 2h4v12H3zM9 2h4v12H9z" fill="currentColor"/></svg>',
};
const scenes = new Map();  // scene_url -> Promise of the scene JSON: fetched once a page

/** Whether this browser can draw the 3-D clips (else the player shows the MP4). */
export function webglAvailable() {
  try {
    const c = document.createElement("canvas");
    return Boolean(window.WebGLRenderingContext && (c.getContext("webgl2") || c.getContext("webgl")));
  } catch { return false; }
}

const floats = (s) => new Float32Array(Uint8Array.from(atob(s), (c) => c.charCodeAt(0)).buffer);
const ints = (s) => new Int32Array(Uint8Array.from(atob(s), (c) => c.charCodeAt(0)).buffer);
const rgb = (a) => new THREE.Color(a[0], a[1], a[2]);
const css = (a, alpha = 1) => `rgba(${a.map((v) => Math.round(v * 255)).slice(0, 3).join(",")},${alpha})`;

function base64(bytes) {
  let s = "";
  for (let i = 0; i < bytes.length; i += 8192) s += String.fromCharCode(...bytes.subarray(i, i + 8192));
  return btoa(s);
}

async function getJson(url) {
  const res = await fetch(url);
  if (!res.ok) throw new Error(`${url}: HTTP ${res.status}`);
  return res.json();
}

function node(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === null || v === undefined || v === false) continue;
    if (k === "text") e.textContent = v; else e.setAttribute(k, v === true ? "" : v);
  }
  e.append(...children.filter((c) => c !== null));
  return e;
}

/** A clip's data decoded once: per-frame typed arrays and its scene. */
async function loadClip(dataUrl) {
  const data = await getJson(dataUrl);
  if (!scenes.has(data.scene_url)) scenes.set(data.scene_url, getJson(data.scene_url));
  let scene;
  try { scene = await scenes.get(data.scene_url); } catch (err) { scenes.delete(data.scene_url); throw err; }
  const clip = { data, scene, frames: data.frames, rate: data.frame_rate || scene.frame_rate };
  if (scene.kind === "mujoco") {
    clip.pos = floats(data.pos);
    clip.quat = floats(data.quat);
    clip.lookat = floats(data.lookat);
    clip.lightPos = data.light_pos ? floats(data.light_pos) : null;
    clip.geoms = data.geoms;
  } else {
    clip.vehicles = floats(data.vehicles);
  }
  return clip;
}

// ---------------------------------------------------------------- 3-D: MuJoCo's visual geoms in three.js
function checkerTexture(t, size) {
  if (t.kind !== "checker") return null;
  const c = document.createElement("canvas");
  c.width = c.height = 64;
  const g = c.getContext("2d");
  g.fillStyle = css(t.rgb1); g.fillRect(0, 0, 64, 64);
  g.fillStyle = css(t.rgb2); g.fillRect(32, 0, 32, 32); g.fillRect(0, 32, 32, 32);
  const tex = new THREE.CanvasTexture(c);
  tex.wrapS = tex.wrapT = THREE.RepeatWrapping;
  tex.magFilter = THREE.NearestFilter;
  tex.anisotropy = 4;
  const [u, v] = t.repeat || [1, 1];  // uniform: repeats per metre (MuJoCo's texuniform), else over the plane
  tex.repeat.set(t.uniform ? u * 2 * size[0] : u, t.uniform ? v * 2 * size[1] : v);
  return tex;
}

function geometry(g, meshes, far) {
  const [a, b, c] = g.size;
  switch (g.type) {
    case "plane": {
      const w = a > 0 ? 2 * a : 2 * far, h = b > 0 ? 2 * b : 2 * far;
      return new THREE.PlaneGeometry(w, h);
    }
    case "sphere": return new THREE.SphereGeometry(a, 24, 16);
    case "ellipsoid": return new THREE.SphereGeometry(1, 24, 16).scale(a, b, c);
    case "capsule": return new THREE.CapsuleGeometry(a, 2 * c, 8, 16).rotateX(Math.PI / 2);
    case "cylinder": return new THREE.CylinderGeometry(a, a, 2 * c, 24).rotateX(Math.PI / 2);
    case "box": return new THREE.BoxGeometry(2 * a, 2 * b, 2 * c);
    case "mesh": {
      const m = meshes[g.mesh];
      const geo = new THREE.BufferGeometry();
      geo.setAttribute("position", new THREE.BufferAttribute(m.vertices, 3));
      geo.setIndex(new THREE.BufferAttribute(new Uint32Array(m.faces), 1));
      geo.computeVertexNormals();
      return geo;
    }
    default: return null;
  }
}

/** MuJoCo's gradient skybox: rgb1 straight up, rgb2 straight down, blended by elevation (the horizon halfway). */
function sky(s, radius) {
  const material = new THREE.ShaderMaterial({
    side: THREE.BackSide, depthWrite: false,
    uniforms: { top: { value: rgb(s.rgb1) }, bottom: { value: rgb(s.rgb2) } },
    vertexShader: "varying vec3 d; void main() { d = position; gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0); }",
    fragmentShader: "uniform vec3 top; uniform vec3 bottom; varying vec3 d;"
      + "void main() { float t = asin(clamp(normalize(d).z, -1.0, 1.0)) / 3.14159265 + 0.5;"
      + " gl_FragColor = vec4(mix(bottom, top, t), 1.0); }",
  });
  const mesh = new THREE.Mesh(new THREE.SphereGeometry(radius, 32, 16), material);
  mesh.renderOrder = -1;
  mesh.frustumCulled = false;
  return mesh;
}

class Stage3D {
  constructor(scene) {
    this.spec = scene;
    const cam = scene.camera;
    this.camera = new THREE.PerspectiveCamera(cam.fovy, scene.width / scene.height, cam.znear, cam.zfar);
    this.camera.up.set(0, 0, 1);
    this.world = new THREE.Scene();
    this.world.background = new THREE.Color(0, 0, 0);
    // MuJoCo's ambient term is the headlight's plus each light's; the headlight shines along the camera's view
    const amb = [...(scene.ambient || [0.1, 0.1, 0.1])];
    for (const l of scene.lights || []) (l.ambient || [0, 0, 0]).forEach((v, i) => { amb[i] += v; });
    this.world.add(new THREE.AmbientLight(rgb(amb), 1));
    const head = scene.headlight;
    this.headlight = head && head.active !== false ? new THREE.DirectionalLight(rgb(head.diffuse || head), 1) : null;
    if (this.headlight) this.world.add(this.headlight, this.headlight.target);
    this.lights = (scene.lights || []).map((l) => {
      const light = l.directional ? new THREE.DirectionalLight(rgb(l.diffuse), 1)
        : new THREE.SpotLight(rgb(l.diffuse), 1, 0, THREE.MathUtils.degToRad(l.cutoff || 45), 0, 0);
      this.world.add(light, light.target);
      light.userData.dir = l.dir;
      this.place(light, l.pos);
      return light;
    });
    this.sky = scene.sky ? sky(scene.sky, cam.zfar * 0.9) : null;
    if (this.sky) this.world.add(this.sky);
    const meshes = (scene.meshes || []).map((m) => ({ vertices: floats(m.vertices), faces: ints(m.faces) }));
    this.geometries = scene.geoms.map((g) => geometry(g, meshes, cam.zfar));
    this.white = new THREE.MeshBasicMaterial({ color: 0xffffff });
    this.current = this.bodies(1);
    this.ghost = null;
    this.overlay = new THREE.Group();
    this.world.add(this.overlay);
  }

  place(light, pos) {
    const d = light.userData.dir;
    light.position.set(pos[0], pos[1], pos[2]);
    light.target.position.set(pos[0] + d[0], pos[1] + d[1], pos[2] + d[2]);
  }

  /** One mesh per geom (none where the type is unknown), opaque or see-through (a ghost). */
  bodies(opacity) {
    const group = new THREE.Group();
    const list = this.spec.geoms.map((g, i) => {
      const geo = this.geometries[i];
      if (!geo || (opacity < 1 && !g.agent)) return null;
      const see = opacity < 1 || g.rgba[3] < 1;
      const flat = g.texture && g.texture.kind === "flat" ? g.texture.rgb1 : null;
      const base = flat ? g.rgba.map((v, k) => (k < 3 ? v * flat[k] : v)) : g.rgba;
      const spec = g.specular ?? 0.5;
      const material = new THREE.MeshPhongMaterial({  // MuJoCo's fixed-function terms; shininess is of 128
        color: rgb(base), transparent: see, opacity: opacity * g.rgba[3], depthWrite: !see,
        specular: new THREE.Color(spec, spec, spec), shininess: 128 * (g.shininess ?? 0.5),
        emissive: rgb(base).multiplyScalar(g.emission ?? 0),
        map: g.texture ? checkerTexture(g.texture, g.size) : null,
      });
      const mesh = new THREE.Mesh(geo, material);
      mesh.userData = { agent: g.agent, material };
      mesh.matrixAutoUpdate = true;
      group.add(mesh);
      return mesh;
    });
    this.world.add(group);
    return { group, list };
  }

  pose(bodies, clip, frame) {
    const f = Math.min(frame, clip.frames - 1);
    const G = clip.geoms;
    bodies.list.forEach((mesh, i) => {
      if (!mesh) return;
      const p = (f * G + i) * 3, q = (f * G + i) * 4;
      mesh.position.set(clip.pos[p], clip.pos[p + 1], clip.pos[p + 2]);
      mesh.quaternion.set(clip.quat[q + 1], clip.quat[q + 2], clip.quat[q + 3], clip.quat[q]);
    });
    if (clip.lightPos && bodies === this.current) {  // a light may follow a body
      const L = this.lights.length;
      this.lights.forEach((light, i) => {
        const k = (f * L + i) * 3;
        this.place(light, [clip.lightPos[k], clip.lightPos[k + 1], clip.lightPos[k + 2]]);
      });
    }
  }

  /** MuJoCo's free camera: it looks at ``lookat`` from ``distance`` along azimuth / elevation (degrees). */
  aim(clip, frame, orbit) {
    const f = Math.min(frame, clip.frames - 1);
    const c = this.spec.camera;
    const az = THREE.MathUtils.degToRad(c.azimuth + orbit.azimuth);
    const el = THREE.MathUtils.degToRad(Math.max(-89, Math.min(89, c.elevation + orbit.elevation)));
    const d = c.distance * orbit.zoom;
    const [x, y, z] = [clip.lookat[3 * f], clip.lookat[3 * f + 1], clip.lookat[3 * f + 2]];
    this.camera.position.set(x - d * Math.cos(el) * Math.cos(az), y - d * Math.cos(el) * Math.sin(az),
      z - d * Math.sin(el));
    this.camera.lookAt(x, y, z);
    if (this.sky) this.sky.position.copy(this.camera.position);
    if (this.headlight) {
      this.headlight.position.copy(this.camera.position);
      this.headlight.target.position.set(x, y, z);
    }
  }
}

// ---------------------------------------------------------------- the player
/** Plays one clip (and, to compare, the previous one): data drawn by three.js or a canvas, else its MP4. */
export class ClipPlayer extends EventTarget {
  /** ``describe: false`` leaves out the text description (a study must not show a clip's measured values);
   * ``loop: false`` plays each clip once and offers no Loop box (a study counts every replay). */
  constructor(container, { label = "Clip", describe = true, loop = true } = {}) {
    super();
    injectStyle();
    this.label = label;
    this.describe = describe;
    this.loopable = loop;
    this.reduced = window.matchMedia && window.matchMedia("(prefers-reduced-motion: reduce)").matches;
    this.mode = null;
    this.clip = null;
    this.previous = null;  // the clip to compare with (its data)
    this.compareMode = "off";
    this.frame = 0;
    this.time = 0;
    this.playing = false;
    this.loop = loop && !this.reduced;
    this._rate = 1;
    this.orbit = { azimuth: 0, elevation: 0, zoom: 1 };
    this.shownOverlays = new Set();
    this.stats = { drawn: 0, dropped: 0, ms: 0 };
    this._token = 0;
    this.build(container);
  }

  get rate() { return this._rate; }
  set rate(r) {
    if (!(r > 0)) return;
    this._rate = r;
    const v = Math.min(16, r);  // the MP4 fallback plays at the same speed, within what media elements allow
    this.ui.video.defaultPlaybackRate = v;  // (a new src keeps it)
    this.ui.video.playbackRate = v;
    const option = [...this.ui.speed.options].find((o) => Number(o.value) === r);
    if (option) this.ui.speed.value = option.value;
  }

  get paused() { return !this.playing; }

  build(container) {
    const id = `clip${Math.random().toString(36).slice(2, 8)}`;
    this.ui = {};
    const u = this.ui;
    u.canvas = node("canvas", { class: "cp-canvas", role: "img", "aria-label": this.label,
      "aria-describedby": `${id}-desc` });
    u.video = node("video", { class: "cp-video", muted: true, playsinline: true, preload: "auto",
      "aria-label": this.label, hidden: true });
    u.video.muted = true;
    u.labels = node("div", { class: "cp-labels", "aria-hidden": "true" });
    u.play = node("button", { type: "button", class: "cp-play", "aria-label": "Play", "aria-keyshortcuts": "Space" });
    u.big = node("button", { type: "button", class: "cp-big", "aria-label": "Play the clip", hidden: true, text: "▶" });
    u.back = node("button", { type: "button", "aria-label": "One frame back", "aria-keyshortcuts": "ArrowLeft", text: "|◀" });
    u.on = node("button", { type: "button", "aria-label": "One frame on", "aria-keyshortcuts": "ArrowRight", text: "▶|" });
    u.scrub = node("input", { type: "range", class: "cp-scrub", min: "0", max: "0", step: "1", value: "0",
      "aria-label": "Frame" });
    u.time = node("span", { class: "cp-time", "aria-hidden": "true" });
    u.speed = node("select", { "aria-label": "Speed", class: "cp-speed" },
      ...RATES.map((r) => node("option", { value: String(r), text: `${r}×` })));
    u.speed.value = "1";
    u.loop = node("input", { type: "checkbox", id: `${id}-loop` });
    u.loop.checked = this.loop;
    u.compare = node("select", { "aria-label": "Compare with the previous clip", class: "cp-compare", disabled: true },
      ...Object.entries(COMPARE).map(([v, t]) => node("option", { value: v, text: t })));
    u.reset = node("button", { type: "button", "aria-label": "Reset the camera", "aria-keyshortcuts": "0", text: "⟲" });
    u.overlays = node("fieldset", { class: "cp-overlays", hidden: true },
      node("legend", { text: "Show what an attribute measures" }));
    u.descButton = node("button", { type: "button", "aria-expanded": "false", "aria-controls": `${id}-desc`,
      "aria-keyshortcuts": "D", text: "Description" });
    u.desc = node("p", { id: `${id}-desc`, class: "cp-desc", hidden: true });
    u.keys = node("ul", { "aria-label": "The player's keys" },
      ...KEYS.map(([k, t]) => node("li", {}, node("kbd", { text: k }), ` ${t}`)));
    u.more = node("details", { class: "cp-more" }, node("summary", { text: "Options" }),
      node("div", { class: "cp-panel" }, node("div", { class: "cp-row" }, u.compare,
        node("label", { class: "cp-check" }, u.loop, " Loop"), u.reset, u.descButton), u.overlays, u.keys));
    u.stage = node("div", { class: "cp-stage" }, u.canvas, u.video, u.labels, u.big, u.desc);
    // over the clip's bottom edge, as a video's controls: the player takes no more room than the clip
    u.bar = node("div", { class: "cp-bar", role: "group", "aria-label": `${this.label}: player controls` },
      u.play, u.back, u.on, u.scrub, u.time, u.speed, u.more);
    this.element = node("div", { class: "clip-player", "data-mode": "" }, u.stage, u.bar);
    container.append(this.element);
    this.setPlayIcon();

    u.play.addEventListener("click", () => this.toggle());
    u.big.addEventListener("click", () => this.play());
    u.back.addEventListener("click", () => this.step(-1));
    u.on.addEventListener("click", () => this.step(1));
    u.scrub.addEventListener("input", () => { this.pause(); this.seek(Number(u.scrub.value)); });
    u.speed.addEventListener("change", () => { this.rate = Number(u.speed.value); });
    u.loop.addEventListener("change", () => { this.loop = u.loop.checked; });
    u.compare.addEventListener("change", () => this.setCompare(u.compare.value));
    u.reset.addEventListener("click", () => this.resetCamera());
    u.descButton.addEventListener("click", () => this.toggleDescription());
    this.element.addEventListener("keydown", (e) => this.key(e));
    u.loop.parentElement.hidden = !this.loopable;
    u.descButton.hidden = !this.describe;
    if (!this.describe) u.canvas.removeAttribute("aria-describedby");
    this.orbiting();
  }

  /** Show a clip: its data drawn where WebGL (or, for 2-D, a canvas) can, else its MP4. Resolves once its first
   * frame is on screen. */
  async show({ data_url: dataUrl, url, rollout_id: rolloutId }) {
    const token = ++this._token;
    this.pause();
    this.element.dataset.rolloutId = rolloutId || "";
    delete this.element.dataset.played;
    this.element.dataset.ready = "false";
    this.playedOnce = false;
    this.watched = 0;  // seconds of the clip played since it was shown: scrubbing and stepping add nothing
    this.videoAt = 0;
    let clip = null;
    if (dataUrl) {
      try { clip = await loadClip(dataUrl); } catch (err) { console.warn("clip data:", err.message); clip = null; }
      if (token !== this._token) return;
    }
    const kind = clip && clip.scene.kind;
    if (clip && (kind === "plane2d" || (kind === "mujoco" && webglAvailable()))) {
      try {
        this.useData(clip);
      } catch (err) {
        console.warn("clip drawing:", err.message);
        clip = null;
      }
    } else {
      clip = null;
    }
    if (!clip) await this.useVideo(url, token);
    if (token !== this._token) return;
    this.element.dataset.ready = "true";
    if (!this.reduced) this.play(); else this.ui.big.hidden = false;
  }

  useData(clip) {
    if (this.previous && this.previous.scene !== clip.scene) this.previous = null;
    this.clip = clip;
    this.ui.video.hidden = true;
    this.ui.video.removeAttribute("src");
    this.ui.canvas.hidden = false;
    this.ui.bar.hidden = false;
    if (clip.scene.kind === "mujoco") {
      if (!this.stage || this.stage.spec !== clip.scene) this.makeStage(clip.scene);
      this.mode = "webgl";
    } else {
      this.stage = null;
      this.mode = "canvas";
    }
    this.element.dataset.mode = this.mode;
    this.ui.reset.hidden = this.mode !== "webgl";
    this.ui.compare.disabled = !this.previous;
    this.ui.scrub.max = String(clip.frames - 1);
    this.element.dataset.duration = String(clip.frames / clip.rate);
    this.ui.desc.textContent = this.describe ? clip.data.description || "" : "";
    this.buildOverlays(clip.data.overlays || []);
    this.frame = 0;
    this.time = 0;
    this.draw();
  }

  makeStage(scene) {
    if (this.renderer) this.renderer.dispose();
    this.renderer = new THREE.WebGLRenderer({ canvas: this.ui.canvas, antialias: false, powerPreference: "low-power" });
    this.renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
    this.stage = new Stage3D(scene);
    this.ghostOf = null;
  }

  async useVideo(url, token) {
    this.mode = "video";
    this.failed = false;
    this.clip = null;
    this.element.dataset.mode = "video";
    const v = this.ui.video;
    this.ui.canvas.hidden = true;
    v.hidden = false;
    this.ui.bar.hidden = true;
    v.controls = true;
    v.loop = this.loop;
    v.src = url;
    if (!this.videoHooked) {
      this.videoHooked = true;
      v.addEventListener("timeupdate", () => {
        const d = v.currentTime - this.videoAt;  // a jump (a seek, a loop's restart) is not watching
        if (d > 0 && d < 0.75 * Math.max(1, v.playbackRate) && !v.seeking) this.watched += d;
        this.videoAt = v.currentTime;
        this.checkPlayed(v.duration);
      });
      v.addEventListener("ended", () => this.checkPlayed(v.duration));
      v.addEventListener("error", () => { if (v.getAttribute("src")) this.failed = true; });
    }
    await new Promise((resolve) => {
      const done = () => { v.removeEventListener("loadeddata", done); v.removeEventListener("error", done); resolve(); };
      v.addEventListener("loadeddata", done);
      v.addEventListener("error", done);
    });
    if (token !== this._token) return;
    this.element.dataset.duration = String(v.duration);
  }

  // ---------------------------------------------------------------- playback
  play() {
    this.ui.big.hidden = true;
    if (this.mode === "video") { this.ui.video.play().catch(() => {}); this.playing = true; this.setPlayIcon(); return; }
    if (!this.clip || this.playing) return;
    if (this.frame >= this.clip.frames - 1) { this.frame = 0; this.time = 0; }
    this.playing = true;
    this.setPlayIcon();
    this.last = null;
    const tick = (now) => {
      if (!this.playing) return;
      this.advance(now);
      this.raf = requestAnimationFrame(tick);
    };
    this.raf = requestAnimationFrame(tick);
  }

  pause() {
    this.playing = false;
    if (this.raf) cancelAnimationFrame(this.raf);
    this.raf = null;
    if (this.mode === "video") this.ui.video.pause();
    this.setPlayIcon();
  }

  toggle() { if (this.playing) this.pause(); else this.play(); }

  advance(now) {
    if (this.last !== null) {
      const dt = ((now - this.last) / 1000) * this._rate;
      this.time += dt;
      this.watched += dt;
    }
    this.last = now;
    const n = this.clip.frames;
    let f = Math.floor(this.time * this.clip.rate);
    if (f >= n) {
      this.checkPlayed((n - 1) / this.clip.rate);
      if (!this.loop) { this.seek(n - 1); this.pause(); return; }
      this.time %= n / this.clip.rate;
      f = Math.floor(this.time * this.clip.rate) % n;
      this.frame = -1;
    }
    if (f === this.frame) return;
    if (this.frame >= 0 && f > this.frame + 1) this.stats.dropped += f - this.frame - 1;
    this.frame = f;
    const t0 = performance.now();
    this.draw();
    this.stats.ms += performance.now() - t0;
    this.stats.drawn += 1;
    if (f === n - 1) this.checkPlayed((n - 1) / this.clip.rate);
  }

  /** The clip counts as played once a clip's length of it has played (``duration`` seconds, a little slack for
   * the last frame's timing): scrubbing to the end and playing the last frames does not unlock answers. */
  checkPlayed(duration) {
    if (Number.isFinite(duration) && this.watched >= duration - 0.25) this.reachedEnd();
  }

  reachedEnd() {
    if (this.playedOnce) return;
    this.playedOnce = true;
    this.element.dataset.played = this.element.dataset.rolloutId;
    this.dispatchEvent(new Event("playedonce"));
  }

  seek(frame) {
    if (this.mode === "video") {
      const v = this.ui.video;
      const end = Number.isFinite(v.duration) ? v.duration : 0;
      v.currentTime = Math.max(0, Math.min(end, frame / VIDEO_FPS));
      return;
    }
    if (!this.clip) return;
    this.frame = Math.max(0, Math.min(this.clip.frames - 1, Math.round(frame)));
    this.time = this.frame / this.clip.rate;
    this.draw();
  }

  step(n) {
    this.pause();
    this.seek((this.mode === "video" ? Math.round(this.ui.video.currentTime * VIDEO_FPS) : this.frame) + n);
  }

  setPlayIcon() {
    this.ui.play.innerHTML = this.playing ? ICONS.pause : ICONS.play;
    this.ui.play.setAttribute("aria-label", this.playing ? "Pause" : "Play");
  }

  // ---------------------------------------------------------------- drawing
  draw() {
    const clip = this.clip;
    if (!clip) return;
    this.element.dataset.frame = String(this.frame);
    this.ui.scrub.value = String(this.frame);
    this.ui.time.textContent = `${(this.frame / clip.rate).toFixed(2)} s`;
    if (this.mode === "webgl") this.draw3d(); else this.draw2d();
  }

  /** Size the canvas to its box, but at most the MP4's pixels a pane (the browser scales it up as it scales the
   * video): a software rasteriser draws every pixel, and at the laptop size 1.5 times skipped a fifth of the frames
   * on a busy 2-core machine (benchmarks/clip_player.py). */
  fit(canvas) {
    const box = this.ui.stage.getBoundingClientRect();
    const s = this.clip.scene, panes = this.compareMode === "beside" && this.previous ? 2 : 1;
    const ratio = Math.min(window.devicePixelRatio || 1, 2,
      (1.0 * s.width * panes) / Math.max(1, box.width), (1.0 * s.height) / Math.max(1, box.height));
    this.pixelRatio = Math.max(ratio, 0.01);
    const w = Math.max(1, Math.round(box.width * ratio)), h = Math.max(1, Math.round(box.height * ratio));
    if (canvas.width !== w || canvas.height !== h) {
      if (this.renderer) this.renderer.setSize(w, h, false); else { canvas.width = w; canvas.height = h; }
    }
    return [w, h];
  }

  /** The viewports (x, y, w, h, clip) to draw: the clip alone, or the previous one on the left of it. */
  panes(w, h) {
    if (this.compareMode === "beside" && this.previous) {
      return [[0, 0, Math.floor(w / 2), h, this.previous], [Math.floor(w / 2), 0, w - Math.floor(w / 2), h, this.clip]];
    }
    return [[0, 0, w, h, this.clip]];
  }

  draw3d() {
    const [w, h] = this.fit(this.ui.canvas);
    const { stage, renderer } = this;
    const ghost = this.compareMode === "ghost" && this.previous;
    if (ghost && this.ghostOf !== this.previous) this.makeGhost();
    if (stage.ghost) stage.ghost.group.visible = Boolean(ghost);
    if (ghost) stage.pose(stage.ghost, this.previous, this.frame);
    renderer.setScissorTest(true);
    for (const [x, y, pw, ph, clip] of this.panes(w, h)) {
      stage.pose(stage.current, clip, this.frame);
      stage.aim(clip, this.frame, this.orbit);
      this.placeOverlays(clip === this.clip);
      const target = clip.scene.width / clip.scene.height;  // the MP4's frame, letterboxed into the pane
      const [vw, vh] = pw / ph > target ? [ph * target, ph] : [pw, pw / target];
      renderer.setScissor(x, y, pw, ph);
      renderer.setClearColor(0x000000);
      renderer.clear();
      renderer.setViewport(x + (pw - vw) / 2, y + (ph - vh) / 2, vw, vh);
      renderer.setScissor(x + (pw - vw) / 2, y + (ph - vh) / 2, vw, vh);
      stage.camera.aspect = target;
      stage.camera.updateProjectionMatrix();
      renderer.render(stage.world, stage.camera);
    }
    renderer.setScissorTest(false);
    this.placeLabels(w, h);
  }

  makeGhost() {
    const { stage } = this;
    if (stage.ghost) stage.world.remove(stage.ghost.group);
    stage.ghost = stage.bodies(0.35);
    this.ghostOf = this.previous;
  }

  draw2d() {
    const canvas = this.ui.canvas;
    const [w, h] = this.fit(canvas);
    const g = canvas.getContext("2d");
    g.setTransform(1, 0, 0, 1, 0, 0);
    g.fillStyle = "#000";
    g.fillRect(0, 0, w, h);
    for (const [x, y, pw, ph, clip] of this.panes(w, h)) {
      const s = clip.scene;
      const scale = Math.min(pw / s.width, ph / s.height);
      g.save();
      g.translate(x + (pw - s.width * scale) / 2, h - y - ph + (ph - s.height * scale) / 2);
      g.scale(scale, scale);
      g.beginPath(); g.rect(0, 0, s.width, s.height); g.clip();
      drawRoad(g, s, clip, this.frame, this.compareMode === "ghost" && this.previous && clip === this.clip
        ? this.previous : null, this.shownOverlays);
      g.restore();
    }
  }

  /** A silhouette of the agent in ``frame`` at the MP4's size: 1 where an agent geom (or car) is, else 0,
   * as base64 bytes row by row from the top (tests compare it with the MP4's). */
  silhouette(frame) {
    const clip = this.clip;
    if (!clip) return null;
    const f = Math.max(0, Math.min(clip.frames - 1, frame));
    const { width: w, height: h } = clip.scene;
    let pixels;
    if (this.mode === "webgl") {
      const { stage, renderer } = this;
      const target = new THREE.WebGLRenderTarget(w, h);
      const saved = stage.current.list.map((m) => m && m.material);
      stage.current.list.forEach((m) => { if (m) m.material = this.stage.white; });
      const hidden = [stage.sky, stage.ghost && stage.ghost.group, stage.overlay, ...stage.current.list.filter(
        (m) => m && !m.userData.agent)].filter(Boolean);
      hidden.forEach((o) => { o.visible = false; });
      stage.pose(stage.current, clip, f);
      stage.aim(clip, f, { azimuth: 0, elevation: 0, zoom: 1 });
      stage.camera.aspect = w / h;
      stage.camera.updateProjectionMatrix();
      renderer.setRenderTarget(target);
      renderer.setClearColor(0x000000);
      renderer.clear();
      renderer.render(stage.world, stage.camera);
      pixels = new Uint8Array(w * h * 4);
      renderer.readRenderTargetPixels(target, 0, 0, w, h, pixels);
      renderer.setRenderTarget(null);
      target.dispose();
      hidden.forEach((o) => { o.visible = true; });
      stage.current.list.forEach((m, i) => { if (m) m.material = saved[i]; });
      const flipped = new Uint8Array(w * h);  // GL's rows run bottom up
      for (let y = 0; y < h; y++) for (let x = 0; x < w; x++) flipped[y * w + x] = pixels[((h - 1 - y) * w + x) * 4] > 127 ? 1 : 0;
      this.draw();
      return base64(flipped);
    }
    const c = document.createElement("canvas");
    c.width = w; c.height = h;
    const g = c.getContext("2d");
    g.fillStyle = "#000"; g.fillRect(0, 0, w, h);
    drawCars(g, clip.scene, clip, f, true);
    pixels = g.getImageData(0, 0, w, h).data;
    const out = new Uint8Array(w * h);
    for (let i = 0; i < w * h; i++) out[i] = pixels[i * 4] > 127 ? 1 : 0;
    return base64(out);
  }

  // ---------------------------------------------------------------- compare, overlays, camera, description
  /** The clip to compare with (the previous one), or null for none; the mode stays as the person chose it. */
  async compare(clip) {
    if (!clip || !clip.data_url || this.mode === "video") {
      this.previous = null;
    } else {
      try { this.previous = await loadClip(clip.data_url); } catch { this.previous = null; }
      if (this.previous && this.clip && this.previous.scene !== this.clip.scene) this.previous = null;
    }
    this.ui.compare.disabled = !this.previous;
    if (!this.previous) this.ui.compare.value = "off";
    this.setCompare(this.previous ? this.ui.compare.value : "off");
  }

  setCompare(mode) {
    this.compareMode = COMPARE[mode] ? mode : "off";
    this.ui.compare.value = this.compareMode;
    this.element.dataset.compare = this.compareMode;
    this.draw();
  }

  buildOverlays(overlays) {
    const box = this.ui.overlays;
    box.replaceChildren(box.firstElementChild);
    this.overlayList = overlays;
    this.shownOverlays = new Set([...this.shownOverlays].filter((a) => overlays.some((o) => o.attribute === a)));
    for (const o of overlays) {
      const input = node("input", { type: "checkbox", "data-attribute": o.attribute });
      input.checked = this.shownOverlays.has(o.attribute);
      input.addEventListener("change", () => this.showOverlay(o.attribute, input.checked));
      box.append(node("label", { class: "cp-check" }, input, ` ${o.label}`));
    }
    box.hidden = overlays.length === 0;
    if (this.stage) this.buildOverlay3d();
  }

  showOverlay(attribute, on) {
    if (on) this.shownOverlays.add(attribute); else this.shownOverlays.delete(attribute);
    const input = this.ui.overlays.querySelector(`[data-attribute="${attribute}"]`);
    if (input) input.checked = on;
    if (this.stage) this.buildOverlay3d();
    this.draw();
  }

  buildOverlay3d() {
    const group = this.stage.overlay;
    group.clear();
    this.ui.labels.replaceChildren();
    this.labelSpots = [];
    for (const o of this.overlayList || []) {
      if (!this.shownOverlays.has(o.attribute)) continue;
      if (o.path && o.path.length > 1) {
        const geo = new THREE.BufferGeometry().setFromPoints(o.path.map((p) => new THREE.Vector3(...p)));
        group.add(new THREE.Line(geo, new THREE.LineBasicMaterial({ color: 0xffd23f })));
      }
      for (const m of o.markers || []) {
        const dot = new THREE.Mesh(new THREE.SphereGeometry(0.025, 12, 8), new THREE.MeshBasicMaterial({ color: 0xffd23f }));
        dot.position.set(...m.pos);
        dot.userData.from = m.frame;
        group.add(dot);
        const label = node("span", { class: "cp-label", text: m.text });
        this.ui.labels.append(label);
        this.labelSpots.push({ label, dot, from: m.frame });
      }
    }
  }

  placeOverlays(isCurrent) {
    const group = this.stage.overlay;
    group.visible = isCurrent;
    for (const c of group.children) if (c.userData.from !== undefined) c.visible = this.frame >= c.userData.from;
  }

  placeLabels(w, h) {
    if (!this.labelSpots || !this.labelSpots.length) return;
    const ratio = this.pixelRatio;
    const [x0, , pw, ph] = this.panes(w, h).at(-1);
    const target = this.clip.scene.width / this.clip.scene.height;
    const [vw, vh] = pw / ph > target ? [ph * target, ph] : [pw, pw / target];
    const v = new THREE.Vector3();
    for (const s of this.labelSpots) {
      v.copy(s.dot.position).project(this.stage.camera);
      const show = this.frame >= s.from && v.z < 1 && Math.abs(v.x) <= 1 && Math.abs(v.y) <= 1;
      s.label.hidden = !show;
      if (!show) continue;
      const px = x0 + (pw - vw) / 2 + ((v.x + 1) / 2) * vw, py = (ph - vh) / 2 + ((1 - v.y) / 2) * vh;
      s.label.style.transform = `translate(${px / ratio}px, ${py / ratio}px)`;
    }
  }

  resetCamera() {
    this.orbit = { azimuth: 0, elevation: 0, zoom: 1 };
    this.draw();
  }

  /** Drag to turn the camera around what it looks at (3-D clips), the wheel to come closer. */
  orbiting() {
    const c = this.ui.canvas;
    let from = null;
    c.addEventListener("pointerdown", (e) => {
      if (this.mode !== "webgl") return;
      from = [e.clientX, e.clientY];
      c.setPointerCapture(e.pointerId);
    });
    c.addEventListener("pointermove", (e) => {
      if (!from) return;
      this.orbit.azimuth -= (e.clientX - from[0]) * 0.4;
      this.orbit.elevation = Math.max(-80, Math.min(80, this.orbit.elevation - (e.clientY - from[1]) * 0.3));
      from = [e.clientX, e.clientY];
      if (!this.playing) this.draw();
    });
    const end = () => { from = null; };
    c.addEventListener("pointerup", end);
    c.addEventListener("pointercancel", end);
    c.addEventListener("wheel", (e) => {
      if (this.mode !== "webgl") return;
      e.preventDefault();
      this.orbit.zoom = Math.max(0.3, Math.min(3, this.orbit.zoom * Math.exp(e.deltaY * 0.001)));
      if (!this.playing) this.draw();
    }, { passive: false });
  }

  toggleDescription(show) {
    const on = show ?? this.ui.desc.hidden;
    this.ui.desc.hidden = !on;
    this.ui.descButton.setAttribute("aria-expanded", String(on));
  }

  /** The player's keys (focus inside it); the page may call it for keys pressed elsewhere. */
  key(e) {
    if (e.target instanceof HTMLInputElement && e.target.type === "range" && e.key.startsWith("Arrow")) return;
    if (e.target instanceof HTMLSelectElement || e.metaKey || e.ctrlKey || e.altKey) return;
    const k = e.key;
    const actions = {
      " ": () => this.toggle(), ArrowLeft: () => this.step(-1), ArrowRight: () => this.step(1),
      Home: () => { this.pause(); this.seek(0); }, End: () => { this.pause(); this.seek(Infinity); },
      "[": () => { this.rate = RATES[Math.max(0, RATES.findIndex((r) => r >= this._rate) - 1)]; },
      "]": () => { this.rate = RATES[Math.min(RATES.length - 1, RATES.findIndex((r) => r >= this._rate) + 1)]; },
      l: () => { if (this.loopable) { this.loop = !this.loop; this.ui.loop.checked = this.loop; } },
      c: () => { if (this.previous) this.setCompare({ off: "beside", beside: "ghost", ghost: "off" }[this.compareMode]); },
      0: () => this.resetCamera(), d: () => { if (this.describe) this.toggleDescription(); },
    };
    const act = actions[k.length === 1 ? k.toLowerCase() : k];
    if (!act || (k === " " && e.target instanceof HTMLButtonElement)) return;
    e.preventDefault();
    e.stopPropagation();
    act();
  }

  destroy() {
    this.pause();
    this._token += 1;
    if (this.renderer) { this.renderer.dispose(); this.renderer.forceContextLoss(); }
    this.element.remove();
  }
}

// ---------------------------------------------------------------- 2-D: the road and its cars, as highway-env draws them
function carAt(clip, frame, v) {
  const V = clip.scene.vehicles.length;
  const i = (Math.min(frame, clip.frames - 1) * V + v) * 3;
  return [clip.vehicles[i], clip.vehicles[i + 1], clip.vehicles[i + 2]];
}

/** highway-env's window: the centred vehicle ``offset`` metres from the window's top-left corner. */
function origin(s, clip, frame) {
  const [x, y] = carAt(clip, frame, s.view.centre_on || 0);
  return [x - s.view.offset[0], y - s.view.offset[1]];
}

const rgb255 = (a, alpha = 1) => `rgba(${a.slice(0, 3).map(Math.round).join(",")},${alpha})`;

/** The road's painted lines as highway-env draws them: continuous, or stripes ``length`` long every ``spacing``
 * metres from x = 0, 0.3 m wide. */
function drawRoad(g, s, clip, frame, ghost, overlays) {
  const ppm = s.view.pixels_per_metre;
  const [ox, oy] = origin(s, clip, frame);
  const px = (x) => (x - ox) * ppm, py = (y) => (y - oy) * ppm;
  const L = s.lanes;
  g.fillStyle = rgb255(s.background_rgb || L.road_rgb);
  g.fillRect(0, 0, s.width, s.height);
  const lines = L.lines || Array.from({ length: L.count + 1 }, (_, i) => ({
    y: L.y0 - L.width / 2 + i * L.width, kind: i === 0 || i === L.count ? "continuous" : "striped" }));
  const stripe = L.stripe || { length: 3, spacing: 9 };
  const thick = Math.max(1, Math.round(0.3 * ppm));
  g.fillStyle = rgb255(L.line_rgb);
  const x0 = ox, x1 = ox + s.width / ppm;
  for (const line of lines) {
    const y = Math.round(py(line.y) - thick / 2);
    if (line.kind === "continuous") { g.fillRect(0, y, s.width, thick); continue; }
    for (let k = Math.floor(x0 / stripe.spacing) - 1; k * stripe.spacing <= x1; k++) {
      g.fillRect(px(k * stripe.spacing), y, stripe.length * ppm, thick);
    }
  }
  if (ghost) { g.globalAlpha = 0.35; drawCars(g, s, ghost, frame, false, [ox, oy]); g.globalAlpha = 1; }
  drawCars(g, s, clip, frame, false, [ox, oy]);
  for (const o of clip.data.overlays || []) {
    if (!overlays.has(o.attribute)) continue;
    g.strokeStyle = g.fillStyle = "#ffd23f";
    g.lineWidth = 2;
    if (o.path && o.path.length > 1) {
      g.beginPath();
      o.path.forEach((p, i) => (i ? g.lineTo(px(p[0]), py(p[1])) : g.moveTo(px(p[0]), py(p[1]))));
      g.stroke();
    }
    g.font = "11px system-ui, sans-serif";
    for (const m of o.markers || []) {
      if (frame < m.frame) continue;
      g.beginPath(); g.arc(px(m.pos[0]), py(m.pos[1]), 3, 0, 2 * Math.PI); g.fill();
      g.fillText(m.text, px(m.pos[0]) + 5, py(m.pos[1]) - 5);
    }
  }
}

function drawCars(g, s, clip, frame, agentOnly, at = null) {
  const ppm = s.view.pixels_per_metre;
  const [ox, oy] = at || origin(s, clip, frame);
  s.vehicles.forEach((v, i) => {
    if (agentOnly && !v.agent) return;
    const [x, y, heading] = carAt(clip, frame, i);
    g.save();
    g.translate((x - ox) * ppm, (y - oy) * ppm);
    g.rotate(heading);
    const [w, h] = [v.length * ppm, v.width * ppm];
    if (agentOnly) {  // its body inside highway-env's one-pixel black outline
      g.fillStyle = "#fff";
      g.fillRect(-w / 2 + 1, -h / 2 + 1, w - 2, h - 2);
    } else {
      g.fillStyle = rgb255(v.rgb);
      g.fillRect(-w / 2, -h / 2, w, h);
      g.strokeStyle = "#000";
      g.lineWidth = 1;
      g.strokeRect(-w / 2 + 0.5, -h / 2 + 0.5, w - 1, h - 1);
    }
    g.restore();
  });
}

let styled = false;
function injectStyle() {
  if (styled) return;
  styled = true;
  document.head.append(node("style", { "data-from": "player.js" }, `
.clip-player { position: relative; display: flex; flex-direction: column; width: 100%; height: 100%; min-height: 0; }
.clip-player .cp-stage { position: relative; flex: 1; min-height: 0; background: #000; overflow: hidden; }
.clip-player .cp-canvas, .clip-player .cp-video { position: absolute; inset: 0; width: 100%; height: 100%;
  display: block; object-fit: contain; touch-action: none; }
.clip-player [hidden] { display: none !important; }
.clip-player .cp-labels { position: absolute; inset: 0; pointer-events: none; }
.clip-player .cp-label { position: absolute; left: 0; top: 0; font: 600 11px system-ui, sans-serif; color: #111;
  background: #ffd23f; border-radius: 4px; padding: 0 3px; white-space: nowrap; }
.clip-player .cp-big { position: absolute; left: 50%; top: 45%; transform: translate(-50%, -50%); width: 64px;
  height: 64px; border-radius: 50%; border: 2px solid #fff; background: rgba(0,0,0,0.65); color: #fff; font-size: 28px;
  cursor: pointer; }
.clip-player .cp-desc { position: absolute; left: 0; right: 0; top: 0; margin: 0; padding: 6px 8px;
  background: rgba(244,245,250,0.94); color: #1b1f33; font: 14px system-ui, sans-serif; }
.clip-player .cp-bar { position: absolute; left: 0; right: 0; bottom: 0; display: flex; align-items: center; gap: 4px;
  padding: 3px 6px; background: rgba(10,15,32,0.78); color: #f1f3ff; font: 13px system-ui, sans-serif; }
.clip-player .cp-bar button, .clip-player .cp-bar select { min-height: 26px; min-width: 26px; width: auto;
  border-radius: 6px; border: 1px solid #56608a; background: #1e2848; color: #f1f3ff; font: inherit; cursor: pointer;
  padding: 1px 5px; appearance: auto; background-image: none; }
.clip-player .cp-bar svg { display: block; margin: auto; }
.clip-player .cp-bar button:focus-visible, .clip-player .cp-bar select:focus-visible, .clip-player summary:focus-visible,
.clip-player input:focus-visible, .clip-player .cp-big:focus-visible { outline: 3px solid #ffd23f; outline-offset: 1px; }
.clip-player .cp-scrub { flex: 1; min-width: 60px; accent-color: #ffd23f; }
.clip-player .cp-time { min-width: 3.4em; text-align: right; font-variant-numeric: tabular-nums; }
.clip-player .cp-check { display: inline-flex; align-items: center; gap: 3px; }
.clip-player .cp-more summary { cursor: pointer; padding: 2px 6px; border: 1px solid #56608a; border-radius: 6px;
  background: #1e2848; list-style: none; }
.clip-player .cp-more summary::-webkit-details-marker { display: none; }
.clip-player .cp-panel { position: absolute; right: 0; bottom: 100%; left: 0; max-height: 60vh; overflow: auto;
  padding: 6px 8px; background: rgba(10,15,32,0.94); }
.clip-player .cp-row { display: flex; flex-wrap: wrap; align-items: center; gap: 6px; }
.clip-player .cp-overlays { display: flex; flex-wrap: wrap; gap: 2px 12px; margin: 4px 0 0; padding: 0; border: 0; }
.clip-player .cp-overlays legend { float: left; margin-right: 8px; padding: 0; color: #c7cdf0; }
.clip-player .cp-panel ul { margin: 4px 0 0; padding-left: 1.2em; columns: 2; font-size: 12px; }
.clip-player .cp-panel kbd { font: 600 12px ui-monospace, monospace; }
@media (max-width: 480px) { .clip-player .cp-time { display: none; } .clip-player .cp-panel ul { columns: 1; } }
`));
}
