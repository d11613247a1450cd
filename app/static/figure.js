// Animated stick figures drawn on a 2-D canvas from GET /clips/{id}/skeleton.
//
// The service gives joint positions in a display frame: body heights, y up, the subject
// facing +z at its first frame. A figure is seen by an orthographic camera turned by
// CAMERA.yaw about the vertical and looking down by CAMERA.pitch. The camera follows the
// pelvis over the floor exactly, and follows the body's height smoothly: each figure is framed
// from its own frames (frameMotion) so that every pose of what it plays stays in the canvas
// (climbs, jumps, stairs), with the floor where it always is when nothing needs it to move.
// projectFrame() is the whole projection, so what is drawn can be checked against the API's
// numbers (window.__mocap).

import { getJson } from "./api.js";

export const CAMERA = Object.freeze({
  yaw: -0.55, // radians about the vertical: a three-quarter view
  pitch: 0.2, // radians looking down
  viewHeight: 1.4, // body heights visible from the bottom to the top of the canvas, at least
  floor: 0.1, // fraction of the canvas height below the floor line, when the body allows
  margin: 0.07, // body heights kept free around the figure (the head's disc, the lines)
  smoothing: 0.35, // seconds: the spread of the vertical follow's smoothing
  steady: 0.5, // seconds each side over which the follow ignores a step's bob
  hold: 1.5, // seconds: what the body does within this fits the view without moving it
});

const GRID_STEP = 0.25; // body heights between floor lines
const GRID_REACH = 1.0; // floor drawn this far around the pelvis
const HEAD_RADIUS = 0.045; // body heights
const SIDE_MARGIN_PX = 3;

// -- a skeleton response, decoded ---------------------------------------------------------

/**
 * One skeleton response as typed arrays. `positions` holds frames × joints × 3 floats;
 * `t0` is the preview time (seconds after the lead-in) of its first frame.
 */
export class Track {
  constructor(body) {
    this.body = body;
    this.fps = body.fps;
    this.frameCount = body.frame_count;
    this.joints = body.joints;
    this.bones = body.bones;
    this.extent = body.extent || null;
    const count = this.joints.length;
    this.jointCount = count;
    const positions = new Float32Array(this.frameCount * count * 3);
    if (body.encoding === "compact") {
      const root = new Float32Array(bytesOf(body.root).buffer);
      const offsets = new Int16Array(bytesOf(body.offsets).buffer);
      const unit = body.offset_unit;
      for (let f = 0; f < this.frameCount; f += 1) {
        for (let j = 0; j < count; j += 1) {
          for (let a = 0; a < 3; a += 1) {
            const i = (f * count + j) * 3 + a;
            positions[i] = root[f * 3 + a] + offsets[i] * unit;
          }
        }
      }
    } else {
      body.frames.forEach((frame, f) => frame.forEach((p, j) => positions.set(p, (f * count + j) * 3)));
    }
    this.positions = positions;
    const sourceFps = body.source_fps || body.fps;
    const leadIn = (body.lead_in_frames || 0) / sourceFps;
    this.t0 = Math.max(0, (body.start || 0) - leadIn);
    this.duration = this.frameCount > 0 ? this.frameCount / this.fps : 0;
  }

  /** Frame `f` as [[x, y, z], ...] (one array per joint). */
  frame(f) {
    const count = this.jointCount;
    const out = new Array(count);
    for (let j = 0; j < count; j += 1) {
      const i = (f * count + j) * 3;
      out[j] = [this.positions[i], this.positions[i + 1], this.positions[i + 2]];
    }
    return out;
  }

  /** The frame shown at preview time `time` (clamped to the track). */
  indexAt(time) {
    const i = Math.floor((time - this.t0) * this.fps + 1e-6);
    return Math.min(this.frameCount - 1, Math.max(0, i));
  }

  /** Whether preview time `time` lies within this track's frames. */
  covers(time) {
    return time >= this.t0 - 1e-6 && time < this.t0 + this.frameCount / this.fps;
  }
}

function bytesOf(base64) {
  const text = atob(base64);
  const bytes = new Uint8Array(text.length);
  for (let i = 0; i < text.length; i += 1) bytes[i] = text.charCodeAt(i);
  return bytes;
}

// -- the camera ----------------------------------------------------------------------------

/** Across (to the screen's right) and up (on the screen) of a point, relative to (cx, cz). */
function viewOf([x, y, z], cx, cz, camera) {
  const cosYaw = Math.cos(camera.yaw);
  const sinYaw = Math.sin(camera.yaw);
  const dx = x - cx;
  const dz = z - cz;
  const across = dx * cosYaw + dz * sinYaw;
  const depth = -dx * sinYaw + dz * cosYaw; // towards the camera
  return [across, y * Math.cos(camera.pitch) - depth * Math.sin(camera.pitch)];
}

/**
 * 2-D canvas points (CSS pixels) of one frame's joints.
 * joints: [[x, y, z], ...] display-frame positions; centre: index of the joint followed over
 * the floor; view: {width, height, scale (px per body height), bottom (the screen-up value, in
 * body heights, at the canvas's bottom edge)} (see frameMotion).
 */
export function projectFrame(joints, view, camera = CAMERA, centre = 0) {
  const [cx, , cz] = joints[centre];
  return joints.map((p) => projectPoint(p, cx, cz, view, camera));
}

function projectPoint(p, cx, cz, view, camera) {
  const [across, up] = viewOf(p, cx, cz, camera);
  return [view.width / 2 + across * view.scale, view.height - (up - view.bottom) * view.scale];
}

/** Lowest and highest screen-up value of a frame's joints and its farthest across (body
 * heights), from `positions` (frames × joints × 3) at frame `f`. */
function upRangeAt(positions, count, f, centre, camera) {
  const cosYaw = Math.cos(camera.yaw);
  const sinYaw = Math.sin(camera.yaw);
  const cosPitch = Math.cos(camera.pitch);
  const sinPitch = Math.sin(camera.pitch);
  const base = f * count * 3;
  const cx = positions[base + centre * 3];
  const cz = positions[base + centre * 3 + 2];
  let lo = Infinity;
  let hi = -Infinity;
  let across = 0;
  for (let j = 0; j < count; j += 1) {
    const i = base + j * 3;
    const dx = positions[i] - cx;
    const dz = positions[i + 2] - cz;
    const depth = -dx * sinYaw + dz * cosYaw;
    const up = positions[i + 1] * cosPitch - depth * sinPitch;
    lo = Math.min(lo, up);
    hi = Math.max(hi, up);
    across = Math.max(across, Math.abs(dx * cosYaw + dz * sinYaw));
  }
  return [lo, hi, across];
}

/**
 * How a figure frames `track` (frames `first` to `last`) on a width × height canvas: one scale
 * for the whole clip (every pose fits: no zooming while it plays) and, per frame, the
 * screen-up value at the canvas's bottom edge. That follows the body: the floor stays at
 * CAMERA.floor where every pose allows it, and where a pose needs more room (a climb, a jump)
 * the view moves — smoothed in time, then held to the poses' bounds so that none leaves the
 * canvas (the smoothing never takes a frame out).
 */
export function frameMotion(track, width, height, { first = 0, last = track.frameCount - 1, centre = 0, camera = CAMERA } = {}) {
  const count = Math.max(0, last - first + 1);
  const lows = new Float64Array(count);
  const highs = new Float64Array(count);
  let tallest = 0;
  let reach = 0;
  for (let k = 0; k < count; k += 1) {
    const [lo, hi, across] = upRangeAt(track.positions, track.jointCount, first + k, centre, camera);
    lows[k] = lo;
    highs[k] = hi;
    tallest = Math.max(tallest, hi - lo);
    reach = Math.max(reach, across);
  }
  // An overview (a frame every few seconds) has not seen every pose: the service's extent,
  // measured on every frame, bounds what the frames between may need.
  if (track.extent && track.fps < 10) {
    const e = track.extent;
    tallest = Math.max(tallest, e.height * Math.cos(camera.pitch) + 2 * e.reach * Math.sin(camera.pitch));
    reach = Math.max(reach, e.reach);
  }
  // The view is tall enough for all the body does within `hold` seconds (a jump, a squat, a
  // quick step up): the camera then never has to move fast, only follow slow changes (a
  // climb) — a figure a little smaller rather than a view that lurches.
  const holdRadius = Math.max(1, Math.round((camera.hold / 2) * track.fps));
  const tops = runningExtreme(highs, holdRadius, Math.max);
  const floors = runningExtreme(lows, holdRadius, Math.min);
  for (let k = 0; k < count; k += 1) tallest = Math.max(tallest, tops[k] - floors[k]);
  const m = camera.margin;
  const needed = Math.max(camera.viewHeight, tallest + 2 * m);
  const sideRoom = Math.max(1, width / 2 - SIDE_MARGIN_PX);
  const scale = Math.min(height / needed, sideRoom / (reach + m));
  const visible = height / scale; // body heights from the bottom to the top edge
  const preferred = -camera.floor * visible;
  // The bottom edge must stay between low[k] (the head in) and high[k] (the feet in).
  const low = new Float64Array(count);
  const high = new Float64Array(count);
  for (let k = 0; k < count; k += 1) {
    high[k] = lows[k] - m;
    low[k] = highs[k] + m - visible;
    if (low[k] > high[k]) low[k] = high[k] = (low[k] + high[k]) / 2;
  }
  // Aim within the bounds' extremes over a second around each frame: the bounds bob with
  // every step (the head rises and falls), and a view held to them would bob too.
  const window = Math.max(1, Math.round(camera.steady * track.fps));
  const steadyLow = runningExtreme(low, window, Math.max);
  const steadyHigh = runningExtreme(high, window, Math.min);
  const path = new Float64Array(count);
  for (let k = 0; k < count; k += 1) {
    const [a, b] = steadyLow[k] <= steadyHigh[k] ? [steadyLow[k], steadyHigh[k]] : [low[k], high[k]];
    // The floor where it always is when the body allows; else the body in the middle (a
    // climber high above the floor is followed as a camera operator would).
    path[k] = preferred >= a && preferred <= b ? preferred : (a + b) / 2;
  }
  const sigma = Math.max(0.5, camera.smoothing * track.fps);
  for (let pass = 0; pass < 3; pass += 1) {
    const smooth = gaussianSmooth(path, sigma);
    for (let k = 0; k < count; k += 1) path[k] = Math.min(high[k], Math.max(low[k], smooth[k]));
  }
  // Bend out what kinks the bounds left: steps that lower the path's curvature (its fourth
  // difference, as an elastic rod rests on what holds it), held to the bounds each time. Where
  // a pose stops the view, the view then turns gently around it rather than at a corner.
  const at = (i) => path[Math.min(count - 1, Math.max(0, i))];
  for (let pass = 0; pass < 300; pass += 1) {
    for (let k = 0; k < count; k += 1) {
      const bend = at(k - 2) - 4 * at(k - 1) + 6 * path[k] - 4 * at(k + 1) + at(k + 2);
      path[k] = Math.min(high[k], Math.max(low[k], path[k] - bend / 16));
    }
  }
  return { scale, visible, first, bottoms: path, width, height };
}

/** The max (or min: `pick`) of `values` over `radius` samples each side of each one. */
function runningExtreme(values, radius, pick) {
  const n = values.length;
  const out = new Float64Array(n);
  for (let i = 0; i < n; i += 1) {
    let best = values[i];
    for (let j = Math.max(0, i - radius); j <= Math.min(n - 1, i + radius); j += 1) best = pick(best, values[j]);
    out[i] = best;
  }
  return out;
}

/** Values smoothed by a Gaussian of `sigma` samples (three box filters in a row: each pass
 * costs the same whatever sigma; the ends are held). */
function gaussianSmooth(values, sigma) {
  const width = Math.max(1, Math.round(Math.sqrt((12 * sigma * sigma) / 3 + 1)));
  let out = Float64Array.from(values);
  for (let pass = 0; pass < 3; pass += 1) out = boxSmooth(out, Math.floor(width / 2));
  return out;
}

function boxSmooth(values, radius) {
  const n = values.length;
  const out = new Float64Array(n);
  if (!n) return out;
  const at = (i) => values[Math.min(n - 1, Math.max(0, i))];
  let sum = 0;
  for (let d = -radius; d <= radius; d += 1) sum += at(d);
  for (let i = 0; i < n; i += 1) {
    out[i] = sum / (2 * radius + 1);
    sum += at(i + radius + 1) - at(i - radius);
  }
  return out;
}

/** The bottom edge at preview time `time` on a framing of `track` (linear between frames). */
function bottomAt(framing, track, time) {
  const { bottoms, first } = framing;
  if (!bottoms.length) return -CAMERA.floor * framing.visible;
  const at = (time - track.t0) * track.fps - first;
  const i = Math.min(bottoms.length - 1, Math.max(0, Math.floor(at)));
  const j = Math.min(bottoms.length - 1, i + 1);
  const w = Math.min(1, Math.max(0, at - i));
  return bottoms[i] * (1 - w) + bottoms[j] * w;
}

// -- loading ----------------------------------------------------------------------------

const MAX_PARALLEL = 6; // a browser's connections to one host
const CACHE_SIZE = 80;
const cache = new Map(); // key -> Promise<Track>
const waiting = []; // [{run, priority}]
let running = 0;

function pump() {
  while (running < MAX_PARALLEL && waiting.length) {
    // Figures on screen first: they are what the user waits for.
    let best = 0;
    for (let i = 1; i < waiting.length; i += 1) {
      if (waiting[i].priority() > waiting[best].priority()) best = i;
    }
    const [job] = waiting.splice(best, 1);
    running += 1;
    job.run().finally(() => {
      running -= 1;
      pump();
    });
  }
}

/**
 * A clip's skeleton as a Track: at `fps` (at most `maxFrames` frames), optionally only
 * `start`..`end` seconds of the file. Cached; six requests at a time, visible figures first
 * (`priority`: a function, higher first).
 */
export function loadSkeleton(clipId, { fps = 30, maxFrames = 600, start = null, end = null, priority = () => 0 } = {}) {
  const key = `${clipId}:${fps}:${maxFrames}:${start}:${end}`;
  if (cache.has(key)) {
    const hit = cache.get(key);
    cache.delete(key); // most recent last
    cache.set(key, hit);
    return hit;
  }
  const promise = new Promise((resolve, reject) => {
    waiting.push({
      priority,
      run: () =>
        getJson(`/clips/${clipId}/skeleton`, { fps, max_frames: maxFrames, start, end, encoding: "compact" })
          .then((body) => resolve(new Track(body)), reject),
    });
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
    this.range = null; // [start, end): play only this part, looping (a span being checked)
    this.listeners = new Set();
    players.add(this);
  }

  tick(seconds) {
    if (!this.playing) return;
    this.seek(this.time + seconds, { keepPlaying: true });
  }

  seek(time, { keepPlaying = false } = {}) {
    let t = Math.max(0, time);
    if (this.range && !keepPlaying && (t < this.range[0] || t >= this.range[1])) {
      this.range = null; // going elsewhere by hand ends the span's loop
    }
    if (this.range) {
      const [a, b] = this.range;
      if (t >= b || t < a) t = a + ((((t - a) % (b - a)) + (b - a)) % (b - a));
    } else if (this.loop > 0) {
      t %= this.loop;
    }
    this.time = t;
    if (!keepPlaying) this.notify();
  }

  /** Loop only [start, end) (null: the whole clip again). */
  setRange(range) {
    this.range = range && range[1] > range[0] ? range : null;
    if (this.range) this.seek(this.range[0]);
    else this.notify();
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

/**
 * One stick figure on one canvas, following one Player. It plays its `track` (the whole clip,
 * or a span of it), looping; `detailAt(time)` may give a finer Track for the time shown (the
 * clip page's windows of a long take), the track then frames and fills in around it.
 */
export class Figure {
  constructor(canvas, { player = libraryPlayer, clipId = null, name = "" } = {}) {
    this.canvas = canvas;
    this.player = player;
    this.clipId = clipId;
    this.name = name;
    this.track = null;
    this.detailAt = null;
    this.error = null;
    this.visible = true;
    this.framing = null;
    this.lastKey = "";
    this.lastPoints = null;
    this.lastFrame = -1;
    this.lastView = null;
    this.lastSource = null;
    this.cssSize = null; // [width, height], kept up to date by a ResizeObserver
    figures.add(this);
    visibility.observe(canvas);
    sizes.observe(canvas);
    canvas.__figure = this;
  }

  /** The skeleton as loaded: a raw response (POST /skeleton) or a Track. */
  setSkeleton(skeleton) {
    this.setTrack(skeleton instanceof Track ? skeleton : new Track(skeleton));
  }

  setTrack(track) {
    this.track = track;
    this.error = null;
    this.pelvis = Math.max(0, track.joints.indexOf("pelvis"));
    this.head = track.joints.indexOf("head");
    this.sides = track.bones.map(([, child]) => {
      const name = track.joints[child];
      return name.startsWith("l_") ? "l" : name.startsWith("r_") ? "r" : "mid";
    });
    this.canvas.dataset.frameCount = String(track.frameCount);
    this.framing = null;
    this.lastKey = "";
    if (this.visible) this.draw(); // off screen: framed and drawn when it scrolls into view
  }

  /** Kept for callers written for the raw response: the decoded track's response. */
  get skeleton() {
    return this.track ? this.track.body : null;
  }

  setError(error) {
    this.error = error;
    this.canvas.title = `No preview: ${error.message || error}`;
    this.lastKey = "";
    this.draw();
  }

  /** Load the clip's skeleton and show it; errors are drawn on the canvas. */
  load(options = {}) {
    const priority = () => (this.visible && this.canvas.isConnected ? 1 : 0);
    return loadSkeleton(this.clipId, { ...options, priority }).then(
      (track) => this.setTrack(track),
      (error) => this.setError(error),
    );
  }

  /** Seconds the figure plays before it loops. */
  get duration() {
    return this.track && this.track.frameCount > 0 ? this.track.duration : 0;
  }

  /** The track and frame shown at `time` on the player's clock. */
  sourceAt(time) {
    const track = this.track;
    if (this.detailAt) {
      const detail = this.detailAt(time);
      if (detail && detail.covers(time)) return { track: detail, index: detail.indexAt(time), time, detail: true };
      return { track, index: track.indexAt(time), time, detail: false };
    }
    // A track plays from its own start, looping over its length.
    const local = track.t0 + (Math.max(0, time) % Math.max(track.duration, 1e-9));
    return { track, index: track.indexAt(local), time: local, detail: false };
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

  /** The framing for the current size (computed again when the size or the track changes). */
  framingFor(width, height) {
    const f = this.framing;
    if (!f || f.width !== width || f.height !== height || f.track !== this.track) {
      this.framing = { ...frameMotion(this.track, width, height, { centre: this.pelvis }), track: this.track };
    }
    return this.framing;
  }

  /** Redraw if the frame or the size changed (or `force`). */
  draw(force = false) {
    const [width, height] = this.size();
    const ratio = window.devicePixelRatio || 1;
    const shown = this.track && this.track.frameCount > 0 ? this.sourceAt(this.player.time) : null;
    const frameKey = shown ? `${shown.track.t0}:${shown.track.fps}:${shown.index}` : "-";
    const key = `${frameKey}:${width}:${height}:${ratio}:${this.error ? 1 : 0}`;
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
    if (!shown) {
      drawMessage(g, width, height, "loading…");
      return;
    }
    const joints = shown.track.frame(shown.index);
    const framing = this.framingFor(width, height);
    // The framing's bottom edge at this time, held to this very frame's bounds (a detail
    // frame between two frames of an overview may need a little more room).
    const [lo, hi] = upRangeAt(shown.track.positions, shown.track.jointCount, shown.index, this.pelvis, CAMERA);
    const m = CAMERA.margin;
    let bottom = bottomAt(framing, this.track, shown.time);
    bottom = Math.min(lo - m, Math.max(hi + m - framing.visible, bottom));
    const view = { width, height, scale: framing.scale, bottom };
    drawFloor(g, joints[this.pelvis], view);
    const points = projectFrame(joints, view, CAMERA, this.pelvis);
    drawBones(g, points, shown.track.bones, this.sides, view.scale);
    if (this.head >= 0) {
      const [hx, hy] = points[this.head];
      g.beginPath();
      g.arc(hx, hy, Math.max(2, HEAD_RADIUS * view.scale), 0, 2 * Math.PI);
      g.fillStyle = SIDE_COLOURS.mid;
      g.fill();
    }
    this.lastPoints = points;
    this.lastView = view;
    this.lastFrame = Math.floor(shown.time * shown.track.fps + 1e-6);
    this.lastSource = shown.detail ? "detail" : "track";
    this.canvas.dataset.frame = String(this.lastFrame);
  }

  /** What the page drew last, for tests (window.__mocap.figures()). */
  debugState() {
    const [width, height] = this.size();
    const view = this.lastView;
    return {
      clipId: this.clipId,
      name: this.name,
      role: this.canvas.dataset.role || null,
      frame: this.lastFrame,
      frameCount: this.track ? this.track.frameCount : 0,
      fps: this.track ? this.track.fps : null,
      time: this.player.time,
      width,
      height,
      camera: { ...CAMERA },
      view: view ? { scale: view.scale, bottom: view.bottom } : null,
      centreJoint: this.track ? this.track.joints[this.pelvis] : null,
      points: this.lastPoints,
      // The drawn figure's box: its joints, the head's disc and the lines' half width.
      box: this.lastPoints ? drawnBox(this.lastPoints, this.head, view.scale) : null,
      source: this.lastSource,
      error: this.error ? String(this.error.message || this.error) : null,
    };
  }

  dispose() {
    figures.delete(this);
    visibility.unobserve(this.canvas);
    sizes.unobserve(this.canvas);
  }
}

function lineWidth(scale) {
  return Math.max(1.5, 0.018 * scale);
}

function drawnBox(points, head, scale) {
  const half = lineWidth(scale) / 2;
  let [x0, y0, x1, y1] = [Infinity, Infinity, -Infinity, -Infinity];
  for (const [x, y] of points) {
    x0 = Math.min(x0, x - half);
    x1 = Math.max(x1, x + half);
    y0 = Math.min(y0, y - half);
    y1 = Math.max(y1, y + half);
  }
  if (head >= 0) {
    const r = Math.max(2, HEAD_RADIUS * scale);
    const [hx, hy] = points[head];
    x0 = Math.min(x0, hx - r);
    x1 = Math.max(x1, hx + r);
    y0 = Math.min(y0, hy - r);
    y1 = Math.max(y1, hy + r);
  }
  return { left: x0, top: y0, right: x1, bottom: y1 };
}

function drawMessage(g, width, height, text) {
  g.fillStyle = "#6b7280";
  g.font = "12px system-ui, sans-serif";
  g.textAlign = "center";
  g.fillText(text, width / 2, height / 2);
}

function drawFloor(g, pelvis, view) {
  const [cx, , cz] = pelvis;
  const at = (p) => projectPoint(p, cx, cz, view, CAMERA);
  g.lineWidth = 1;
  g.strokeStyle = "rgba(60, 70, 90, 0.16)";
  g.beginPath();
  const first = (v) => Math.ceil((v - GRID_REACH) / GRID_STEP) * GRID_STEP;
  for (let x = first(cx); x <= cx + GRID_REACH; x += GRID_STEP) {
    const a = at([x, 0, cz - GRID_REACH]);
    const b = at([x, 0, cz + GRID_REACH]);
    g.moveTo(a[0], a[1]);
    g.lineTo(b[0], b[1]);
  }
  for (let z = first(cz); z <= cz + GRID_REACH; z += GRID_STEP) {
    const a = at([cx - GRID_REACH, 0, z]);
    const b = at([cx + GRID_REACH, 0, z]);
    g.moveTo(a[0], a[1]);
    g.lineTo(b[0], b[1]);
  }
  g.stroke();
  // The pelvis's shadow.
  const [sx, sy] = at([cx, 0, cz]);
  g.fillStyle = "rgba(40, 50, 70, 0.15)";
  g.beginPath();
  g.ellipse(sx, sy, 0.12 * view.scale, 0.03 * view.scale, 0, 0, 2 * Math.PI);
  g.fill();
}

function drawBones(g, points, bones, sides, scale) {
  g.lineCap = "round";
  g.lineJoin = "round";
  g.lineWidth = lineWidth(scale);
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
  /**
   * Every frame a figure plays, as drawn: [{time, frame, box, points}] for the figure at
   * `index` of figures() (stepping its clock through the track; the clock is left paused).
   */
  sweep(index, step = null) {
    const figure = [...figures].filter((f) => f.canvas.isConnected)[index];
    const track = figure.track;
    const out = [];
    figure.player.setPlaying(false);
    const dt = step || 1 / track.fps;
    const start = figure.detailAt ? track.t0 : 0;
    const end = figure.detailAt ? track.t0 + track.duration : track.duration;
    for (let t = start; t < end - 1e-9; t += dt) {
      figure.player.seek(t);
      figure.draw(true);
      const state = figure.debugState();
      out.push({ time: t, frame: state.frame, box: state.box, head: state.points[figure.head], view: state.view });
    }
    return out;
  },
});
