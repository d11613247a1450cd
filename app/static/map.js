// Map: every clip as a point — FMDistance's 3-MAN features (Onuma et al. 2008, Figure 1) or
// a PCA of a descriptor — coloured by label, outliers ringed; hover or arrow keys to
// preview, click or Enter to search from a clip. Wheel zooms, dragging pans.

import { descriptors, getJson } from "./api.js";
import { Figure, libraryPlayer } from "./figure.js";
import { MAX_LABEL_STYLES, OTHER_COLOUR, UNLABELLED_COLOUR, clear, el, formatNumber, labelStyle, nextId, plural } from "./util.js";

// Axes in plain words; the paper's names (Onuma et al. 2008, FMDistance's 3-MAN features) are
// in each axis's tooltip (`paper`).
const ENERGY = {
  name: "How much the body moves",
  short: "movement",
  paper: "e_all: the total kinetic energy of the body's joints (3-MAN, Onuma et al. 2008)",
};
const PROJECTIONS = {
  "3man-ul": {
    title: "How much the body moves × upper body against legs",
    paper: "3-MAN features e_all × r_u/l (Onuma et al. 2008)",
    axes: [
      ENERGY,
      { name: "Upper body against legs", short: "upper/legs", paper: "r_u/l: the energy of the upper body over that of the lower body (3-MAN)" },
    ],
    pick: (c) => (c.three_man ? [c.three_man[0], c.three_man[1]] : null),
  },
  "3man-lt": {
    title: "How much the body moves × arms and legs against the trunk",
    paper: "3-MAN features e_all × r_l/t (Onuma et al. 2008)",
    axes: [
      ENERGY,
      { name: "Arms and legs against the trunk", short: "limbs/trunk", paper: "r_l/t: the energy of the limbs over that of the trunk (3-MAN)" },
    ],
    pick: (c) => (c.three_man ? [c.three_man[0], c.three_man[2]] : null),
  },
  pca: {
    title: "The two main ways clips differ (under the descriptor)",
    paper: "PCA: the first two principal components of the descriptor's vectors",
    axes: [
      { name: "Main way clips differ", short: "PC 1", paper: "PC 1: the first principal component of the descriptor's vectors" },
      { name: "Second way clips differ", short: "PC 2", paper: "PC 2: the second principal component" },
    ],
    pick: (c) => c.pca,
  },
};
const MARGIN = { left: 56, right: 16, top: 16, bottom: 44 };
const RADIUS = 4;
const mapCache = new Map(); // descriptor -> Promise<map>

function loadMap(descriptor, { fresh = false } = {}) {
  if (fresh || !mapCache.has(descriptor)) {
    const promise = getJson("/map", { descriptor });
    promise.catch(() => mapCache.delete(descriptor));
    mapCache.set(descriptor, promise);
  }
  return mapCache.get(descriptor);
}

/** "Nice" tick values covering [lo, hi]. */
function ticks(lo, hi, count = 6) {
  const span = hi - lo || 1;
  const raw = span / count;
  const power = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((m) => m * power).find((s) => span / s <= count) || power * 10;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(Number(v.toFixed(10)));
  return out;
}

export async function renderMap(main, params, { navigate }) {
  const known = await descriptors();
  const ids = { descriptor: nextId("descriptor"), projection: nextId("projection"), help: nextId("map-help") };
  const state = {
    descriptor: known.descriptors.some((d) => d.name === params.get("descriptor")) ? params.get("descriptor") : known.default,
    projection: params.get("projection") in PROJECTIONS ? params.get("projection") : "3man-ul",
  };
  if (!known.descriptors.some((d) => d.name === state.descriptor)) state.descriptor = known.default;

  const descriptorSelect = el("select", { id: ids.descriptor }, known.descriptors.map((d) => el("option", { value: d.name }, d.name)));
  descriptorSelect.value = state.descriptor;
  const projectionSelect = el(
    "select",
    { id: ids.projection },
    Object.entries(PROJECTIONS).map(([value, p]) => el("option", { value, title: p.paper }, p.title)),
  );
  projectionSelect.value = state.projection;
  const resetButton = el("button", { type: "button" }, "Reset zoom");
  const status = el("p", { class: "status", role: "status", "aria-live": "polite" }, "Loading the map…");
  const announce = el("p", { class: "visually-hidden", "aria-live": "polite" });
  const canvas = el("canvas", {
    class: "map-canvas",
    tabindex: "0",
    role: "img",
    "aria-describedby": ids.help,
    "aria-label": "Map of the library",
  });
  const tooltip = el("div", { class: "map-tooltip", hidden: true });
  // Axis names as text over the canvas, so each has a tooltip with the paper's name.
  const xName = el("span", { class: "axis-name axis-x", tabindex: "0" });
  const yName = el("span", { class: "axis-name axis-y", tabindex: "0" });
  const legend = el("ul", { class: "legend", "aria-label": "Colours" });
  const help = el(
    "p",
    { id: ids.help, class: "hint" },
    "Each point is a clip. Hover a point (or focus the map and use the arrow keys) to preview it; click it (or press Enter) to search from it. Scroll to zoom, drag to pan. Ringed points are outliers.",
  );

  main.append(
    el("div", { class: "view-head" }, el("h1", {}, "Map")),
    el(
      "form",
      { class: "filters", "aria-label": "Map settings", onsubmit: (e) => e.preventDefault() },
      el("div", { class: "field wide" }, el("label", { for: ids.projection }, "Axes"), projectionSelect),
      el("div", { class: "field" }, el("label", { for: ids.descriptor }, "Descriptor (PCA and outliers)"), descriptorSelect),
      el("div", { class: "field" }, resetButton),
    ),
    status,
    el("div", { class: "map-wrap" }, canvas, xName, yName, tooltip),
    legend,
    help,
    announce,
  );

  let data = null; // {clips, xs, ys, colours, outliers, shown: [indices]}
  let view = { scale: 1, tx: 0, ty: 0 }; // zoom/pan in screen space
  let selected = -1;
  let hoverFigure = null;
  let grid = new Map();
  let screen = null; // Float32Array of screen x, y per shown point

  function remember() {
    history.replaceState(null, "", `#/map?${new URLSearchParams({ descriptor: state.descriptor, projection: state.projection })}`);
  }

  async function load() {
    remember();
    status.textContent = "Loading the map…";
    let map;
    try {
      map = await loadMap(state.descriptor);
    } catch (error) {
      status.textContent = `Cannot load the map: ${error.detail || error.message}`;
      return;
    }
    for (const option of projectionSelect.options) {
      option.disabled = option.value.startsWith("3man") && !map.three_man_available;
    }
    if (state.projection.startsWith("3man") && !map.three_man_available) {
      state.projection = "pca";
      projectionSelect.value = "pca";
    }
    build(map);
  }

  function build(map) {
    const projection = PROJECTIONS[state.projection];
    const counts = new Map();
    for (const clip of map.clips) {
      const first = clip.labels[0];
      if (first !== undefined) counts.set(first, (counts.get(first) || 0) + 1);
    }
    const ranked = [...counts.entries()].sort((a, b) => b[1] - a[1] || a[0].localeCompare(b[0]));
    const styleOf = new Map(ranked.slice(0, MAX_LABEL_STYLES).map(([label], i) => [label, labelStyle(i)]));
    const otherStyle = { colour: OTHER_COLOUR, marker: "circle" };
    const noLabelStyle = { colour: UNLABELLED_COLOUR, marker: "circle" };
    const n = map.clips.length;
    const xs = new Float64Array(n);
    const ys = new Float64Array(n);
    const shown = [];
    const colours = new Array(n); // a style per clip: "colour marker"
    map.clips.forEach((clip, i) => {
      const point = projection.pick(clip);
      const first = clip.labels[0];
      const style = first === undefined ? noLabelStyle : styleOf.get(first) || otherStyle;
      colours[i] = `${style.colour} ${style.marker}`;
      if (point && Number.isFinite(point[0]) && Number.isFinite(point[1])) {
        xs[i] = point[0];
        ys[i] = point[1];
        shown.push(i);
      }
    });
    // Outliers last, so they are drawn on top.
    shown.sort((a, b) => Number(map.clips[a].outlier) - Number(map.clips[b].outlier));
    data = { map, projection, xs, ys, colours, shown, styleOf, counts, version: (data ? data.version : 0) + 1 };
    selected = -1;
    view = { scale: 1, tx: 0, ty: 0 };
    hideTooltip();

    clear(legend);
    for (const [label, style] of styleOf) {
      legend.append(el("li", { dataset: { colour: style.colour, marker: style.marker } }, el("span", { class: `swatch ${style.marker}`, style: `background:${style.colour}` }), `${label} (${counts.get(label)})`));
    }
    if (ranked.length > MAX_LABEL_STYLES) {
      legend.append(el("li", {}, el("span", { class: "swatch", style: `background:${OTHER_COLOUR}` }), "other labels"));
    }
    if (map.clips.some((c) => c.labels.length === 0)) {
      legend.append(el("li", {}, el("span", { class: "swatch", style: `background:${UNLABELLED_COLOUR}` }), "no label"));
    }
    legend.append(el("li", {}, el("span", { class: "swatch ring" }), "outlier"));

    const outliers = map.clips.filter((c) => c.outlier).length;
    const missing = n - shown.length;
    status.textContent =
      `${plural(shown.length, "clip")} on the map` +
      (missing ? `, ${missing} without the vectors this view needs` : "") +
      `; ${plural(outliers, "outlier")} under ${map.descriptor}.` +
      (state.projection === "pca" ? ` The two axes explain ${Math.round(100 * (map.pca_explained_variance[0] + map.pca_explained_variance[1]))} % of the variance.` : "");
    canvas.setAttribute("aria-label", `Map of ${plural(shown.length, "clip")}: ${projection.title}`);
    const [xAxis, yAxis] = projection.axes;
    xName.textContent = xAxis.name;
    xName.title = xAxis.paper;
    xName.setAttribute("aria-label", `Horizontal axis: ${xAxis.name} (${xAxis.paper})`);
    yName.textContent = yAxis.name;
    yName.title = yAxis.paper;
    yName.setAttribute("aria-label", `Vertical axis: ${yAxis.name} (${yAxis.paper})`);
    canvas.dataset.points = String(shown.length);
    draw();
  }

  // -- geometry ------------------------------------------------------------------------------

  function plotBox() {
    const rect = canvas.getBoundingClientRect();
    return { width: Math.max(1, rect.width), height: Math.max(1, rect.height) };
  }

  function layout() {
    const { width, height } = plotBox();
    const { xs, ys, shown } = data;
    let [x0, x1, y0, y1] = [Infinity, -Infinity, Infinity, -Infinity];
    for (const i of shown) {
      x0 = Math.min(x0, xs[i]);
      x1 = Math.max(x1, xs[i]);
      y0 = Math.min(y0, ys[i]);
      y1 = Math.max(y1, ys[i]);
    }
    if (!shown.length) [x0, x1, y0, y1] = [0, 1, 0, 1];
    const padX = (x1 - x0 || 1) * 0.04;
    const padY = (y1 - y0 || 1) * 0.04;
    x0 -= padX;
    x1 += padX;
    y0 -= padY;
    y1 += padY;
    const innerW = width - MARGIN.left - MARGIN.right;
    const innerH = height - MARGIN.top - MARGIN.bottom;
    const base = {
      toX: (x) => MARGIN.left + ((x - x0) / (x1 - x0)) * innerW,
      toY: (y) => MARGIN.top + (1 - (y - y0) / (y1 - y0)) * innerH,
    };
    const toX = (x) => base.toX(x) * view.scale + view.tx;
    const toY = (y) => base.toY(y) * view.scale + view.ty;
    const fromX = (px) => x0 + (((px - view.tx) / view.scale - MARGIN.left) / innerW) * (x1 - x0);
    const fromY = (py) => y0 + (1 - ((py - view.ty) / view.scale - MARGIN.top) / innerH) * (y1 - y0);
    return { width, height, toX, toY, fromX, fromY, innerW, innerH };
  }

  // Axes and points are drawn into an off-screen layer when the data, zoom or size change;
  // hovering only copies that layer and rings the selected point.
  const base = document.createElement("canvas");
  let baseKey = "";

  function draw() {
    if (!data) return;
    const geo = layout();
    const ratio = window.devicePixelRatio || 1;
    const width = Math.round(geo.width * ratio);
    const height = Math.round(geo.height * ratio);
    const key = `${width}:${height}:${view.scale}:${view.tx}:${view.ty}:${data.version}`;
    if (key !== baseKey) {
      baseKey = key;
      if (base.width !== width || base.height !== height) {
        base.width = width;
        base.height = height;
      }
      drawBase(base.getContext("2d"), geo, ratio);
    }
    if (canvas.width !== width || canvas.height !== height) {
      canvas.width = width;
      canvas.height = height;
    }
    const g = canvas.getContext("2d");
    g.setTransform(1, 0, 0, 1, 0, 0);
    g.clearRect(0, 0, width, height);
    g.drawImage(base, 0, 0);
    if (selected >= 0 && Number.isFinite(screen[2 * selected])) {
      g.setTransform(ratio, 0, 0, ratio, 0, 0);
      g.strokeStyle = "#111827";
      g.lineWidth = 2;
      g.beginPath();
      g.arc(screen[2 * selected], screen[2 * selected + 1], 8, 0, 2 * Math.PI);
      g.stroke();
    }
  }

  function drawBase(g, geo, ratio) {
    g.setTransform(ratio, 0, 0, ratio, 0, 0);
    g.clearRect(0, 0, geo.width, geo.height);
    const { xs, ys, shown, colours, map, projection } = data;

    // Axes and ticks.
    const left = MARGIN.left;
    const right = geo.width - MARGIN.right;
    const top = MARGIN.top;
    const bottom = geo.height - MARGIN.bottom;
    g.strokeStyle = "#d0d4da";
    g.fillStyle = "#4b5563";
    g.lineWidth = 1;
    g.font = "11px system-ui, sans-serif";
    g.textAlign = "center";
    g.textBaseline = "top";
    for (const t of ticks(geo.fromX(left), geo.fromX(right))) {
      const px = geo.toX(t);
      g.beginPath();
      g.moveTo(px, top);
      g.lineTo(px, bottom);
      g.stroke();
      g.fillText(String(t), px, bottom + 4);
    }
    g.textAlign = "right";
    g.textBaseline = "middle";
    for (const t of ticks(geo.fromY(bottom), geo.fromY(top))) {
      const py = geo.toY(t);
      g.beginPath();
      g.moveTo(left, py);
      g.lineTo(right, py);
      g.stroke();
      g.fillText(String(t), left - 6, py);
    }
    // The axes' names are HTML over the canvas (xName, yName): they carry tooltips.

    // Points: one path per colour; screen positions kept for hit tests.
    screen = new Float32Array(xs.length * 2).fill(Number.NaN);
    grid = new Map();
    const byColour = new Map();
    g.save();
    g.beginPath();
    g.rect(left, top, right - left, bottom - top);
    g.clip();
    for (const i of shown) {
      const px = geo.toX(xs[i]);
      const py = geo.toY(ys[i]);
      screen[2 * i] = px;
      screen[2 * i + 1] = py;
      if (px < left - 8 || px > right + 8 || py < top - 8 || py > bottom + 8) continue;
      const key = `${Math.floor(px / 16)}:${Math.floor(py / 16)}`;
      if (!grid.has(key)) grid.set(key, []);
      grid.get(key).push(i);
      if (!byColour.has(colours[i])) byColour.set(colours[i], []);
      byColour.get(colours[i]).push(i);
    }
    for (const [style, members] of byColour) {
      const [colour, marker] = style.split(" ");
      g.fillStyle = colour;
      g.strokeStyle = "rgba(17, 24, 39, 0.55)"; // outlined: light colours stay visible on white
      g.lineWidth = 0.75;
      g.beginPath();
      for (const i of members) {
        const [px, py] = [screen[2 * i], screen[2 * i + 1]];
        if (marker === "square") {
          g.rect(px - RADIUS, py - RADIUS, 2 * RADIUS, 2 * RADIUS);
        } else {
          g.moveTo(px + RADIUS, py);
          g.arc(px, py, RADIUS, 0, 2 * Math.PI);
        }
      }
      g.fill();
      g.stroke();
    }
    g.strokeStyle = "#d00000";
    g.lineWidth = 1.5;
    g.beginPath();
    for (const i of shown) {
      if (!map.clips[i].outlier) continue;
      g.moveTo(screen[2 * i] + 6.5, screen[2 * i + 1]);
      g.arc(screen[2 * i], screen[2 * i + 1], 6.5, 0, 2 * Math.PI);
    }
    g.stroke();
    g.restore();
  }

  function nearest(px, py, reach = 10) {
    let best = -1;
    let bestDistance = reach * reach;
    const cx = Math.floor(px / 16);
    const cy = Math.floor(py / 16);
    for (let dx = -1; dx <= 1; dx += 1) {
      for (let dy = -1; dy <= 1; dy += 1) {
        for (const i of grid.get(`${cx + dx}:${cy + dy}`) || []) {
          const d = (screen[2 * i] - px) ** 2 + (screen[2 * i + 1] - py) ** 2;
          if (d <= bestDistance) {
            best = i;
            bestDistance = d;
          }
        }
      }
    }
    return best;
  }

  // -- tooltip with a moving preview -----------------------------------------------------------

  function hideTooltip() {
    tooltip.hidden = true;
    if (hoverFigure) hoverFigure.dispose();
    hoverFigure = null;
    canvas.style.cursor = "";
  }

  function select(index, { announceIt = false } = {}) {
    if (index === selected && (index < 0 || !tooltip.hidden)) return;
    selected = index;
    draw();
    if (index < 0) {
      hideTooltip();
      return;
    }
    const clip = data.map.clips[index];
    const [u, v] = [screen[2 * index], screen[2 * index + 1]];
    const point = data.projection.pick(clip);
    clear(tooltip);
    const previewCanvas = el("canvas", { class: "figure small", role: "img", "aria-label": `Stick figure of ${clip.name}`, dataset: { role: "map", clipId: String(clip.id) } });
    if (hoverFigure) hoverFigure.dispose();
    hoverFigure = new Figure(previewCanvas, { player: libraryPlayer, clipId: clip.id, name: clip.name });
    hoverFigure.load({ fps: 15, maxFrames: 300 });
    tooltip.append(
      ...[
      previewCanvas,
      el("p", { class: "clip-name" }, clip.name),
      el("p", { class: "meta" }, clip.labels.length ? clip.labels.join(", ") : "no labels"),
      el("p", { class: "meta" }, `${data.projection.axes[0].short} ${formatNumber(point[0])} · ${data.projection.axes[1].short} ${formatNumber(point[1])}`),
      clip.outlier
        ? el("p", { class: "meta outlier-note" }, `outlier under ${data.map.descriptor} (isolation z ${formatNumber(clip.outlier_score, 1)})`)
        : null,
      el("p", { class: "hint" }, "Click or press Enter to search from it"),
      ].filter(Boolean),
    );
    tooltip.hidden = false;
    const { width } = plotBox();
    const left = u + 14 + 190 > width ? u - 14 - 190 : u + 14;
    tooltip.style.left = `${Math.max(0, left)}px`;
    tooltip.style.top = `${Math.max(0, v - 60)}px`;
    tooltip.dataset.clipId = String(clip.id);
    canvas.style.cursor = "pointer";
    if (announceIt) {
      announce.textContent = `${clip.name}${clip.labels.length ? `, ${clip.labels.join(", ")}` : ""}${clip.outlier ? ", outlier" : ""}.`;
    }
  }

  function openSelected() {
    if (selected < 0) return;
    navigate("search", { clip: data.map.clips[selected].id, descriptor: state.descriptor });
  }

  // -- interaction -------------------------------------------------------------------------

  let drag = null;
  canvas.addEventListener("mousemove", (event) => {
    if (!data) return;
    const rect = canvas.getBoundingClientRect();
    const px = event.clientX - rect.left;
    const py = event.clientY - rect.top;
    if (drag) {
      view.tx = drag.tx + (px - drag.x);
      view.ty = drag.ty + (py - drag.y);
      drag.moved = drag.moved || Math.abs(px - drag.x) + Math.abs(py - drag.y) > 3;
      draw();
      return;
    }
    select(nearest(px, py));
  });
  canvas.addEventListener("mouseleave", () => {
    drag = null;
    if (document.activeElement !== canvas) select(-1);
  });
  canvas.addEventListener("mousedown", (event) => {
    const rect = canvas.getBoundingClientRect();
    drag = { x: event.clientX - rect.left, y: event.clientY - rect.top, tx: view.tx, ty: view.ty, moved: false };
  });
  canvas.addEventListener("mouseup", (event) => {
    const moved = drag && drag.moved;
    drag = null;
    if (moved || !data) return;
    const rect = canvas.getBoundingClientRect();
    const hit = nearest(event.clientX - rect.left, event.clientY - rect.top);
    if (hit >= 0) {
      selected = hit;
      openSelected();
    }
  });
  canvas.addEventListener(
    "wheel",
    (event) => {
      if (!data) return;
      event.preventDefault();
      const rect = canvas.getBoundingClientRect();
      zoomAt(event.clientX - rect.left, event.clientY - rect.top, event.deltaY < 0 ? 1.25 : 0.8);
    },
    { passive: false },
  );
  function zoomAt(px, py, factor) {
    const scale = Math.min(200, Math.max(1, view.scale * factor));
    const applied = scale / view.scale;
    view.tx = px - (px - view.tx) * applied;
    view.ty = py - (py - view.ty) * applied;
    view.scale = scale;
    if (scale === 1) view = { scale: 1, tx: 0, ty: 0 };
    draw();
    if (selected >= 0) {
      const keep = selected;
      selected = -1;
      select(keep);
    }
  }
  canvas.addEventListener("keydown", (event) => {
    if (!data || !data.shown.length) return;
    const { width, height } = plotBox();
    if (event.key === "+" || event.key === "=") {
      zoomAt(width / 2, height / 2, 1.25);
    } else if (event.key === "-") {
      zoomAt(width / 2, height / 2, 0.8);
    } else if (event.key === "Enter" || event.key === " ") {
      if (selected >= 0) openSelected();
    } else if (event.key === "Escape") {
      select(-1);
    } else if (event.key.startsWith("Arrow")) {
      const direction = { ArrowRight: [1, 0], ArrowLeft: [-1, 0], ArrowUp: [0, -1], ArrowDown: [0, 1] }[event.key];
      select(step(direction), { announceIt: true });
    } else {
      return;
    }
    event.preventDefault();
  });
  canvas.addEventListener("focus", () => {
    if (selected < 0 && data && data.shown.length) select(step([1, 0]), { announceIt: true });
  });
  canvas.addEventListener("blur", () => {
    if (!canvas.matches(":hover")) select(-1);
  });

  /** The point nearest the selection in a direction (the leftmost point to start). */
  function step([dx, dy]) {
    const { shown } = data;
    if (selected < 0) {
      return shown.reduce((best, i) => (best < 0 || screen[2 * i] < screen[2 * best] ? i : best), -1);
    }
    const sx = screen[2 * selected];
    const sy = screen[2 * selected + 1];
    let best = selected;
    let bestScore = Infinity;
    for (const i of shown) {
      if (i === selected) continue;
      const ox = screen[2 * i] - sx;
      const oy = screen[2 * i + 1] - sy;
      const along = ox * dx + oy * dy;
      if (along <= 0) continue;
      const across = Math.abs(ox * dy - oy * dx);
      const score = along + 2 * across;
      if (score < bestScore) {
        best = i;
        bestScore = score;
      }
    }
    return best;
  }

  descriptorSelect.addEventListener("change", () => {
    state.descriptor = descriptorSelect.value;
    load();
  });
  projectionSelect.addEventListener("change", () => {
    state.projection = projectionSelect.value;
    remember();
    if (data) build(data.map);
  });
  resetButton.addEventListener("click", () => {
    view = { scale: 1, tx: 0, ty: 0 };
    draw();
  });
  const resize = new ResizeObserver(() => draw());
  resize.observe(canvas);

  // The library may have changed since the last visit: fetch the map again.
  mapCache.delete(state.descriptor);
  await load();
  return () => {
    resize.disconnect();
    hideTooltip();
  };
}
