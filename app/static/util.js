// Small DOM and formatting helpers shared by the views.

/**
 * Create an element: el("a", {href: "#/map", class: "x"}, "text", child, ...).
 * Attributes starting with "on" are event listeners; `dataset` takes an object;
 * null/undefined/false attributes are left out.
 */
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs || {})) {
    if (value === null || value === undefined || value === false) continue;
    if (key.startsWith("on") && typeof value === "function") {
      node.addEventListener(key.slice(2).toLowerCase(), value);
    } else if (key === "dataset") {
      Object.assign(node.dataset, value);
    } else if (key === "style") {
      node.style.cssText = value; // CSSOM: allowed by the page's Content-Security-Policy
    } else if (key === "class") {
      node.className = value;
    } else if (key in node && typeof value !== "string") {
      node[key] = value;
    } else {
      node.setAttribute(key, value === true ? "" : String(value));
    }
  }
  append(node, children);
  return node;
}

function append(node, children) {
  for (const child of children.flat(Infinity)) {
    if (child === null || child === undefined || child === false) continue;
    node.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
}

export function clear(node) {
  while (node.firstChild) node.firstChild.remove();
  return node;
}

let uid = 0;
/** A unique id for label/aria wiring. */
export function nextId(prefix = "id") {
  uid += 1;
  return `${prefix}-${uid}`;
}

export function formatSeconds(seconds) {
  if (!Number.isFinite(seconds)) return "–";
  if (seconds < 60) return `${seconds.toFixed(1)} s`;
  const m = Math.floor(seconds / 60);
  const s = Math.round(seconds - m * 60);
  return `${m} min ${String(s).padStart(2, "0")} s`;
}

export function formatNumber(value, digits = 3) {
  return Number.isFinite(value) ? value.toFixed(digits) : "–";
}

export function plural(n, word, many = `${word}s`) {
  return `${n.toLocaleString("en")} ${n === 1 ? word : many}`;
}

/** Debounce: call fn after `ms` without further calls. */
export function debounce(fn, ms) {
  let timer = null;
  return (...args) => {
    clearTimeout(timer);
    timer = setTimeout(() => fn(...args), ms);
  };
}

// Label colours a colour-blind eye tells apart: Okabe and Ito's set (yellow kept: markers are
// outlined) and two of Paul Tol's; twenty hues cannot all be, so labels 11-20 take the same
// ten colours as squares (MARKERS). Then grey for "other" labels.
export const PALETTE = [
  "#0072B2", "#E69F00", "#009E73", "#CC79A7", "#56B4E9",
  "#D55E00", "#000000", "#F0E442", "#882255", "#999933",
];
export const MARKERS = ["circle", "square"];
/** The colour and marker of the label ranked `i` (0-based), for up to 20 labels. */
export function labelStyle(i) {
  return { colour: PALETTE[i % PALETTE.length], marker: MARKERS[Math.floor(i / PALETTE.length) % MARKERS.length] };
}
export const MAX_LABEL_STYLES = PALETTE.length * MARKERS.length;
export const OTHER_COLOUR = "#9aa0a6";
export const UNLABELLED_COLOUR = "#c8ccd0";

/** A label list as small chips. */
export function labelChips(labels) {
  if (!labels || labels.length === 0) return el("span", { class: "muted" }, "no labels");
  return el(
    "ul",
    { class: "chips", "aria-label": "Labels" },
    labels.map((label) => el("li", { class: "chip" }, label)),
  );
}
