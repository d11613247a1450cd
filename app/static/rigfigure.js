// A rig in its rest pose as a stick figure, showing its mapping (GET /rigs/{id}: `skeleton`
// and `mapping`). The rig's own axes can be anything (Z up, centimetres, lying along X), so the
// view is set by the body itself: pelvis → head is up, right hip → left hip the subject's
// left; it is seen from the front, turned a little for depth. Joints the mapper found are dots
// (left blue, right orange, trunk dark); the bones between them are thick; joints it left
// alone (fingers, face, twist bones, end sites, a static root above the pelvis) are joined by
// thin grey lines.

const SIDE_COLOURS = { l: "#1f6feb", r: "#e8590c", mid: "#2b2f36" }; // as figure.js
const LOOSE_COLOUR = "#9aa3af";
const YAW = -0.35; // radians: a little turned, so depth shows
const MARGIN_PX = 14;

const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const scaled = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
function unit(a) {
  const n = Math.hypot(...a);
  return n > 1e-12 ? scaled(a, 1 / n) : null;
}

/**
 * The rig's joints in the body's own frame: [[left, up, forward], ...] (rig units, origin at
 * the pelvis), the index of each canonical joint, each joint's side, and which bones (by
 * child joint) join two mapped joints: those whose child is or leads to a mapped joint and
 * whose parent is or lies under one.
 */
export function bodyFrame(skeleton, mapping) {
  const { names, parents, positions } = skeleton;
  const index = new Map(names.map((name, i) => [name, i]));
  const canonical = {};
  for (const [name, found] of Object.entries((mapping && mapping.joints) || {})) {
    const i = found && index.get(found.joint);
    if (i !== undefined && i !== null) canonical[name] = i;
  }
  const at = (...choices) => {
    const name = choices.find((c) => c in canonical);
    return name === undefined ? null : positions[canonical[name]];
  };
  const pelvis = at("pelvis") || positions[0];
  const top = at("head", "neck", "chest");
  // Without a mapping to say where up is: the axis along which the joints spread most.
  const spread = [0, 1, 2].map((a) => Math.max(...positions.map((p) => p[a])) - Math.min(...positions.map((p) => p[a])));
  const fallbackUp = [0, 0, 0];
  fallbackUp[spread.indexOf(Math.max(...spread))] = 1;
  const up = (top && unit(sub(top, pelvis))) || fallbackUp;
  const pair = ["hip", "shoulder"].map((part) => [at(`l_${part}`), at(`r_${part}`)]).find(([l, r]) => l && r);
  let left = pair ? sub(pair[0], pair[1]) : null;
  if (left) left = unit(sub(left, scaled(up, dot(left, up))));
  if (!left) left = unit(cross(up, [0, 0, 1])) || unit(cross(up, [1, 0, 0]));
  const forward = cross(left, up);
  const body = positions.map((p) => {
    const d = sub(p, pelvis);
    return [dot(d, left), dot(d, up), dot(d, forward)];
  });
  const mapped = new Set(Object.values(canonical));
  const sides = new Array(names.length).fill("mid");
  const sideOf = new Map(Object.entries(canonical).map(([name, i]) => [i, name.startsWith("l_") ? "l" : name.startsWith("r_") ? "r" : "mid"]));
  const leads = new Array(names.length).fill(false); // a mapped joint at or below it
  const inside = new Array(names.length).fill(false); // a mapped joint at or above it
  // Parents come first (the service stores skeletons depth first: parents[j] < j).
  parents.forEach((parent, i) => {
    sides[i] = sideOf.has(i) ? sideOf.get(i) : parent >= 0 ? sides[parent] : "mid";
    inside[i] = mapped.has(i) || (parent >= 0 && inside[parent]);
  });
  for (let i = names.length - 1; i >= 0; i -= 1) {
    if (mapped.has(i)) leads[i] = true;
    if (leads[i] && parents[i] >= 0) leads[parents[i]] = true;
  }
  const driven = parents.map((parent, i) => parent >= 0 && leads[i] && inside[parent]);
  return { body, canonical, mapped, sides, driven };
}

const drawn = new Map(); // canvas -> the state drawn last (window.__mocap.rigs())

/**
 * Draw `skeleton` (names, parents, positions) on `canvas` with its `mapping`; returns what was
 * drawn: {width, height, points: [[x, y], ...] (CSS pixels), canonical: {name: index}, box}.
 */
export function drawRig(canvas, skeleton, mapping, { rigId = null } = {}) {
  const width = canvas.clientWidth || 200;
  const height = canvas.clientHeight || 200;
  const ratio = window.devicePixelRatio || 1;
  canvas.width = Math.round(width * ratio);
  canvas.height = Math.round(height * ratio);
  const g = canvas.getContext("2d");
  g.setTransform(ratio, 0, 0, ratio, 0, 0);
  g.clearRect(0, 0, width, height);
  const frame = bodyFrame(skeleton, mapping);
  const flat = frame.body.map(([l, u, f]) => [l * Math.cos(YAW) + f * Math.sin(YAW), u]);
  const xs = flat.map((p) => p[0]);
  const ys = flat.map((p) => p[1]);
  const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const scale = Math.min((width - 2 * MARGIN_PX) / Math.max(x1 - x0, 1e-9), (height - 2 * MARGIN_PX) / Math.max(y1 - y0, 1e-9));
  const points = flat.map(([x, y]) => [width / 2 + (x - (x0 + x1) / 2) * scale, height / 2 - (y - (y0 + y1) / 2) * scale]);

  // The floor under the lowest joint.
  g.strokeStyle = "rgba(60, 70, 90, 0.25)";
  g.lineWidth = 1;
  g.beginPath();
  const floor = Math.max(...points.map((p) => p[1]));
  g.moveTo(MARGIN_PX / 2, floor + 0.5);
  g.lineTo(width - MARGIN_PX / 2, floor + 0.5);
  g.stroke();

  g.lineCap = "round";
  const { parents } = skeleton;
  // Loose joints first (under), then the mapped chains: right, trunk, left.
  for (const pass of ["loose", "r", "mid", "l"]) {
    g.beginPath();
    g.strokeStyle = pass === "loose" ? LOOSE_COLOUR : SIDE_COLOURS[pass];
    g.lineWidth = pass === "loose" ? 1.2 : 3;
    parents.forEach((parent, i) => {
      if (parent < 0) return;
      const kind = frame.driven[i] ? frame.sides[i] : "loose";
      if (kind !== pass) return;
      g.moveTo(...points[parent]);
      g.lineTo(...points[i]);
    });
    g.stroke();
  }
  for (const i of frame.mapped) {
    g.fillStyle = SIDE_COLOURS[frame.sides[i]];
    g.beginPath();
    g.arc(points[i][0], points[i][1], 3.5, 0, 2 * Math.PI);
    g.fill();
  }
  const head = frame.canonical.head;
  if (head !== undefined) {
    g.strokeStyle = SIDE_COLOURS.mid;
    g.lineWidth = 2;
    g.beginPath();
    g.arc(points[head][0], points[head][1], 7, 0, 2 * Math.PI);
    g.stroke();
  }
  const state = {
    rigId,
    width,
    height,
    names: skeleton.names,
    points,
    canonical: frame.canonical,
    box: { left: Math.min(...points.map((p) => p[0])), right: Math.max(...points.map((p) => p[0])), top: Math.min(...points.map((p) => p[1])), bottom: floor },
  };
  drawn.set(canvas, state);
  canvas.dataset.drawn = "true";
  return state;
}

/** The joint drawn nearest (x, y) (CSS pixels) within `reach`: its index, or -1. */
export function jointAt(state, x, y, reach = 12) {
  let best = -1;
  let bestDistance = reach;
  state.points.forEach(([px, py], i) => {
    const d = Math.hypot(px - x, py - y);
    if (d < bestDistance) {
      best = i;
      bestDistance = d;
    }
  });
  return best;
}

window.__mocap = Object.assign(window.__mocap || {}, {
  rigs: () => [...drawn].filter(([canvas]) => canvas.isConnected).map(([, state]) => state),
});
