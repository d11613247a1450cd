// Animated stick figures drawn on a 2-D canvas from GET /clips/{id}/skeleton.
//
// The service gives joint positions in a display frame: body heights, y up, the subject
// facing +z at its first frame. A figure is seen by an orthographic camera turned by
// CAMERA.yaw about the vertical and looking down by CAMERA.pitch; the camera follows the
// pelvis over the floor, and a floor grid shows the travel. projectFrame() is the whole
// projection, so what is drawn can be checked against the API's numbers (window.__mocap).

import { getJson } from "./api.js";

export const CAMERA = Object.freeze({
  yaw: -0.55, // radians about the vertical: a three-quarter view
  pitch: 0.2, // radians looking down
  viewHeight: 1.4, // body heights visible from the bottom to the top of the canvas
  floor: 0.1, // fraction of the canvas height below the floor line
});

const GRID_STEP = 0.25; // body heights between floor lines
const GRID_REACH = 1.0; // floor drawn this far around the pelvis

/**
 * 2-D canvas points (CSS pixels) of one frame's joints.
 * joints: [[x, y, z], ...] display-frame positions; centre: index of the joint followed.
 */
export function projectFrame(joints, width, height, camera = CAMERA, centre = 0) {
  const [cx, , cz] = joints[centre];
  return joints.map((p) => projectPoint(p, cx, cz, width, height, camera));
}

function projectPoint([x, y, z], cx, cz, width, height, camera) {
  const cosYaw = Math.cos(camera.yaw);
  const sinYaw = Math.sin(camera.yaw);
  const dx = x - cx;
  const dz = z - cz;
  const across = dx * cosYaw + dz * sinYaw; // to the screen's right
  const depth = -dx * sinYaw + dz * cosYaw; // towards the camera
  const up = y * Math.cos(camera.pitch) - depth * Math.sin(camera.pitch);
  const scale = height / camera.viewHeight;
  return [width / 2 + across * scale, height * (1 - camera.floor) - up * scale];
}

// -- loading ----------------------------------------------------------------------------

const MAX_PARALLEL = 4;
const CACHE_SIZE = 60;
const cache = new Map(); // key -> Promise<skeleton>
const waiting = [];
let running = 0;

function pump() {
  while (running < MAX_PARALLEL && waiting.length) {
    const job = waiting.shift();
    running += 1;
    job().finally(() => {
      running -= 1;
      pump();
    });
  }
}

/** A clip's skeleton at `fps` (at most `maxFrames` frames); cached, 4 requests at a time. */
export function loadSkeleton(clipId, { fps = 30, maxFrames = 600 } = {}) {
  const key = `${clipId}:${fps}:${maxFrames}`;
  if (cache.has(key)) {
    const hit = cache.get(key);
    cache.delete(key); // most recent last
    cache.set(key, hit);
    return hit;
  }
  const promise = new Promise((resolve, reject) => {
    waiting.push(() =>
      getJson(`/clips/${clipId}/skeleton`, { fps, max_frames: maxFrames }).then(resolve, reject),
    );
    pump();
  });
  promise.catch(() => cache.delete(key));
  cache.set(key, promise);
  while (cache.size > CACHE_SIZE) cache.delete(cache.keys().next().value);
  return promise;
}

// -- playing ------------------------------------------------------------------------------

/** A clock shared by the figures that play in sync. */
export class Player {
  constructor({ playing = true, loop = 0 } = {}) {
    this.time = 0;
    this.playing = playing;
    this.loop = loop; // seconds after which time wraps (0: never)
    this.listeners = new Set();
    players.add(this);
  }

  tick(seconds) {
    if (!this.playing) return;
    this.seek(this.time + seconds, { keepPlaying: true });
  }

  seek(time, { keepPlaying = false } = {}) {
    let t = Math.max(0, time);
    if (this.loop > 0) t %= this.loop;
    this.time = t;
    if (!keepPlaying) this.notify();
  }

  setPlaying(playing) {
    this.playing = playing;
    this.notify();
  }

  notify() {
    for (const listener of this.listeners) listener(this);
  }

  onChange(listener) {
    this.listeners.add(listener);
  }

  dispose() {
    players.delete(this);
    this.listeners.clear();
  }
}

const players = new Set();
const figures = new Set();
export const libraryPlayer = new Player();

const SIDE_COLOURS = { l: "#1f6feb", r: "#e8590c", mid: "#2b2f36" };

/** One stick figure on one canvas, following one Player. */
export class Figure {
  constructor(canvas, { player = libraryPlayer, clipId = null, name = "" } = {}) {
    this.canvas = canvas;
    this.player = player;
    this.clipId = clipId;
    this.name = name;
    this.skeleton = null;
    this.error = null;
    this.visible = true;
    this.lastKey = "";
    this.lastPoints = null;
    this.lastFrame = -1;
    this.cssSize = null; // [width, height], kept up to date by a ResizeObserver
    figures.add(this);
    visibility.observe(canvas);
    sizes.observe(canvas);
    canvas.__figure = this;
  }

  setSkeleton(skeleton) {
    this.skeleton = skeleton;
    this.error = null;
    this.pelvis = Math.max(0, skeleton.joints.indexOf("pelvis"));
    this.head = skeleton.joints.indexOf("head");
    this.sides = skeleton.bones.map(([, child]) => {
      const name = skeleton.joints[child];
      return name.startsWith("l_") ? "l" : name.startsWith("r_") ? "r" : "mid";
    });
    this.canvas.dataset.frameCount = String(skeleton.frame_count);
    this.lastKey = "";
    this.draw();
  }

  setError(error) {
    this.error = error;
    this.canvas.title = `No preview: ${error.message || error}`;
    this.lastKey = "";
    this.draw();
  }

  /** Load the clip's skeleton and show it; errors are drawn on the canvas. */
  load(options) {
    return loadSkeleton(this.clipId, options).then(
      (skeleton) => this.setSkeleton(skeleton),
      (error) => this.setError(error),
    );
  }

  /** Play only [start, end) seconds of the skeleton's timeline (a moment), looping. */
  setSpan(start, end) {
    this.span = end > start ? [start, end] : null;
    this.lastKey = "";
  }

  get duration() {
    const s = this.skeleton;
    if (this.span) return this.span[1] - this.span[0];
    return s && s.frame_count > 0 ? s.frame_count / s.fps : 0;
  }

  frameAt(time) {
    const s = this.skeleton;
    if (!s || s.frame_count === 0) return 0;
    if (this.span) {
      const [start, end] = this.span;
      const at = start + (Math.max(0, time) % (end - start));
      return Math.min(s.frame_count - 1, Math.floor(at * s.fps + 1e-6));
    }
    return Math.floor(time * s.fps + 1e-6) % s.frame_count;
  }

  size() {
    // The observed size: reading the layout in the animation loop would force a reflow per
    // figure per frame.
    if (!this.cssSize) {
      const rect = this.canvas.getBoundingClientRect();
      this.cssSize = [rect.width, rect.height];
    }
    return this.cssSize.map((v) => Math.max(1, Math.round(v)));
  }

  /** Redraw if the frame or the size changed (or `force`). */
  draw(force = false) {
    const [width, height] = this.size();
    const frame = this.frameAt(this.player.time);
    const ratio = window.devicePixelRatio || 1;
    const key = `${frame}:${width}:${height}:${ratio}:${this.skeleton ? 1 : 0}:${this.error ? 1 : 0}`;
    if (!force && key === this.lastKey) return;
    this.lastKey = key;
    const canvas = this.canvas;
    if (canvas.width !== Math.round(width * ratio) || canvas.height !== Math.round(height * ratio)) {
      canvas.width = Math.round(width * ratio);
      canvas.height = Math.round(height * ratio);
    }
    const g = canvas.getContext("2d");
    g.setTransform(ratio, 0, 0, ratio, 0, 0);
    g.clearRect(0, 0, width, height);
    if (this.error) {
      const synthetic = this.error.code === "no_stored_file";
      drawMessage(g, width, height, synthetic ? "synthetic clip: no preview" : "no preview");
      return;
    }
    if (!this.skeleton || this.skeleton.frame_count === 0) {
      drawMessage(g, width, height, "loading…");
      return;
    }
    const joints = this.skeleton.frames[frame];
    drawFloor(g, joints[this.pelvis], width, height);
    const points = projectFrame(joints, width, height, CAMERA, this.pelvis);
    drawBones(g, points, this.skeleton.bones, this.sides, height);
    if (this.head >= 0) {
      const [hx, hy] = points[this.head];
      g.beginPath();
      g.arc(hx, hy, Math.max(2, (0.045 * height) / CAMERA.viewHeight), 0, 2 * Math.PI);
      g.fillStyle = SIDE_COLOURS.mid;
      g.fill();
    }
    this.lastPoints = points;
    this.lastFrame = frame;
    this.canvas.dataset.frame = String(frame);
  }

  /** What the page drew last, for tests (window.__mocap.figures()). */
  debugState() {
    const [width, height] = this.size();
    return {
      clipId: this.clipId,
      name: this.name,
      role: this.canvas.dataset.role || null,
      frame: this.lastFrame,
      frameCount: this.skeleton ? this.skeleton.frame_count : 0,
      fps: this.skeleton ? this.skeleton.fps : null,
      time: this.player.time,
      width,
      height,
      camera: { ...CAMERA },
      centreJoint: this.skeleton ? this.skeleton.joints[this.pelvis] : null,
      points: this.lastPoints,
      error: this.error ? String(this.error.message || this.error) : null,
    };
  }

  dispose() {
    figures.delete(this);
    visibility.unobserve(this.canvas);
    sizes.unobserve(this.canvas);
  }
}

function drawMessage(g, width, height, text) {
  g.fillStyle = "#6b7280";
  g.font = "12px system-ui, sans-serif";
  g.textAlign = "center";
  g.fillText(text, width / 2, height / 2);
}

function drawFloor(g, pelvis, width, height) {
  const [cx, , cz] = pelvis;
  g.lineWidth = 1;
  g.strokeStyle = "rgba(60, 70, 90, 0.16)";
  g.beginPath();
  const first = (v) => Math.ceil((v - GRID_REACH) / GRID_STEP) * GRID_STEP;
  for (let x = first(cx); x <= cx + GRID_REACH; x += GRID_STEP) {
    const a = projectPoint([x, 0, cz - GRID_REACH], cx, cz, width, height, CAMERA);
    const b = projectPoint([x, 0, cz + GRID_REACH], cx, cz, width, height, CAMERA);
    g.moveTo(a[0], a[1]);
    g.lineTo(b[0], b[1]);
  }
  for (let z = first(cz); z <= cz + GRID_REACH; z += GRID_STEP) {
    const a = projectPoint([cx - GRID_REACH, 0, z], cx, cz, width, height, CAMERA);
    const b = projectPoint([cx + GRID_REACH, 0, z], cx, cz, width, height, CAMERA);
    g.moveTo(a[0], a[1]);
    g.lineTo(b[0], b[1]);
  }
  g.stroke();
  // The pelvis's shadow.
  const [sx, sy] = projectPoint([cx, 0, cz], cx, cz, width, height, CAMERA);
  g.fillStyle = "rgba(40, 50, 70, 0.15)";
  g.beginPath();
  g.ellipse(sx, sy, (0.12 * height) / CAMERA.viewHeight, (0.03 * height) / CAMERA.viewHeight, 0, 0, 2 * Math.PI);
  g.fill();
}

function drawBones(g, points, bones, sides, height) {
  g.lineCap = "round";
  g.lineJoin = "round";
  g.lineWidth = Math.max(1.5, (0.018 * height) / CAMERA.viewHeight);
  // Far side first would need depth; draw right, then trunk, then left for a stable look.
  for (const side of ["r", "mid", "l"]) {
    g.strokeStyle = SIDE_COLOURS[side];
    g.beginPath();
    bones.forEach(([a, b], i) => {
      if (sides[i] !== side) return;
      g.moveTo(points[a][0], points[a][1]);
      g.lineTo(points[b][0], points[b][1]);
    });
    g.stroke();
  }
}

// -- one animation loop for every figure ------------------------------------------------------

const visibility = new IntersectionObserver((entries) => {
  for (const entry of entries) {
    const figure = entry.target.__figure;
    if (figure) figure.visible = entry.isIntersecting;
  }
});

const sizes = new ResizeObserver((entries) => {
  for (const entry of entries) {
    const figure = entry.target.__figure;
    if (figure) figure.cssSize = [entry.contentRect.width, entry.contentRect.height];
  }
});

let last = null;
function animate(now) {
  const seconds = last === null ? 0 : Math.min(0.25, (now - last) / 1000);
  last = now;
  for (const player of players) player.tick(seconds);
  for (const figure of figures) {
    if (!figure.canvas.isConnected) {
      figure.dispose();
      continue;
    }
    if (figure.visible) figure.draw();
  }
  for (const resolve of afterDraw.splice(0)) resolve();
  requestAnimationFrame(animate);
}
requestAnimationFrame(animate);

const afterDraw = [];
/** Resolves once every figure has been drawn again. */
export function nextDraw() {
  return new Promise((resolve) => afterDraw.push(resolve));
}

// Test and debugging hook: what each figure drew, and control of the clocks.
window.__mocap = Object.assign(window.__mocap || {}, {
  camera: CAMERA,
  projectFrame,
  figures: () => [...figures].filter((f) => f.canvas.isConnected).map((f) => f.debugState()),
  /** Pause every clock at `seconds` and resolve after the figures are redrawn. */
  seek(seconds) {
    for (const player of players) {
      player.setPlaying(false);
      player.seek(seconds);
    }
    for (const figure of figures) figure.lastKey = "";
    return nextDraw().then(() => nextDraw());
  },
});
