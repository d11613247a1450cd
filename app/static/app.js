// The single page: hash routes #/library, #/upload, #/search, #/map, #/rigs and #/clips/{id} -> one
// view at a time. Only hashes starting with "#/" are routes: "#view" (the skip link) is not.

import { apiKey, onAuthError, setApiKey } from "./api.js";
import { clear, el, nextId } from "./util.js";
import { renderLibrary } from "./library.js";
import { renderUpload } from "./upload.js";
import { renderSearch } from "./search.js";
import { renderMap } from "./map.js";
import { renderClip } from "./clip.js";
import { renderRigs } from "./rigs.js";

const VIEWS = {
  library: { title: "Library", render: renderLibrary },
  upload: { title: "Upload", render: renderUpload },
  search: { title: "Search", render: renderSearch },
  map: { title: "Map", render: renderMap },
  rigs: { title: "Rigs", render: renderRigs },
  clip: { title: "Clip", render: renderClip },
};

let current = null; // {name, cleanup}

/** The route in the hash: {view, params}. */
export function parseRoute(hash = location.hash) {
  const text = hash.replace(/^#\/?/, "");
  const [path, query = ""] = text.split("?");
  const params = new URLSearchParams(query);
  const clip = /^clips\/([^/]+)$/.exec(path);
  if (clip) {
    params.set("id", clip[1]);
    return { view: "clip", params };
  }
  const view = path in VIEWS && path !== "clip" ? path : "library";
  return { view, params };
}

/** The hash of a view: #/clips/{id} for a clip, #/{view}?{params} for the others. */
export function routeHash(view, params = {}) {
  const query = new URLSearchParams();
  let path = view;
  for (const [key, value] of Object.entries(params)) {
    if (value === null || value === undefined || value === "") continue;
    if (view === "clip" && key === "id") path = `clips/${encodeURIComponent(value)}`;
    else query.set(key, String(value));
  }
  const text = query.toString();
  return `#/${path}${text ? `?${text}` : ""}`;
}

/** Go to a view; params is an object (empty values dropped). */
export function navigate(view, params = {}, { replace = false } = {}) {
  const hash = routeHash(view, params);
  if (replace) {
    history.replaceState(null, "", hash);
    route({ keepFocus: true });
  } else if (location.hash === hash) {
    route();
  } else {
    location.hash = hash;
  }
}

export function showAlert(message, { kind = "error" } = {}) {
  const alert = document.getElementById("alert");
  alert.classList.toggle("notice", kind === "notice");
  if (!message) {
    alert.hidden = true;
    alert.textContent = "";
    return;
  }
  alert.textContent = message;
  alert.hidden = false;
}

let pendingNotice = null;
/** A message to show (as a notice, not an error) once the next view is drawn. */
export function notify(message) {
  pendingNotice = message;
}

/** The API key form, in the alert area: shown when the service asks for a key. */
export function showKeyForm(message) {
  const alert = document.getElementById("alert");
  const inputId = nextId("api-key");
  const input = el("input", { id: inputId, type: "password", autocomplete: "off", value: apiKey() });
  const form = el(
    "form",
    { class: "key-form" },
    el("p", {}, message),
    el("label", { for: inputId }, "API key"),
    input,
    el("button", { type: "submit" }, "Use this key"),
    apiKey()
      ? el("button", { type: "button", class: "secondary", onclick: () => forget() }, "Forget the key")
      : null,
    el("button", { type: "button", class: "secondary", onclick: () => showAlert(null) }, "Close"),
  );
  const forget = () => {
    setApiKey("");
    showAlert(null);
    route({ keepFocus: true });
  };
  form.addEventListener("submit", (event) => {
    event.preventDefault();
    setApiKey(input.value.trim());
    showAlert(null);
    route({ keepFocus: true });
  });
  clear(alert);
  alert.append(form);
  alert.hidden = false;
  input.focus();
}

onAuthError((error) => {
  const alert = document.getElementById("alert");
  if (!alert.hidden && alert.querySelector(".key-form")) return;
  const reason =
    error.status === 401
      ? `The service needs an API key: ${error.detail}`
      : `The API key was refused: ${error.detail}`;
  showKeyForm(reason);
});

async function route({ keepFocus = false } = {}) {
  const { view, params } = parseRoute();
  const main = document.getElementById("view");
  if (current && current.cleanup) current.cleanup();
  showAlert(null);
  clear(main);
  for (const link of document.querySelectorAll("nav a[data-view]")) {
    if (link.dataset.view === view) link.setAttribute("aria-current", "page");
    else link.removeAttribute("aria-current");
  }
  document.title = `${VIEWS[view].title} · mocap-index`;
  document.body.dataset.view = view;
  current = { name: view, cleanup: null };
  const mine = current;
  try {
    const cleanup = await VIEWS[view].render(main, params, { navigate, showAlert, notify });
    if (mine === current) mine.cleanup = cleanup || null;
    else if (cleanup) cleanup();
  } catch (error) {
    // 401/403 already opened the key form (onAuthError); other errors are shown as they are.
    if (error.status !== 401 && error.status !== 403) {
      showAlert(error.detail || error.message || String(error));
    }
  }
  if (pendingNotice && mine === current) {
    showAlert(pendingNotice, { kind: "notice" });
    pendingNotice = null;
  }
  if (!keepFocus && mine === current && !main.contains(document.activeElement)) {
    main.focus({ preventScroll: true });
  }
  main.dataset.ready = view;
}

document.getElementById("key-button").addEventListener("click", () =>
  showKeyForm(
    apiKey()
      ? "An API key is set for this tab; change or forget it."
      : "If the library needs a key to upload (or to read), enter it here; it is kept for this tab only.",
  ),
);
// "Skip to content" moves the focus; it must not change the route (#view is no view).
document.querySelector(".skip-link").addEventListener("click", (event) => {
  event.preventDefault();
  document.getElementById("view").focus();
});
window.addEventListener("hashchange", () => {
  if (location.hash && !location.hash.startsWith("#/")) return;
  route();
});

// A file dropped anywhere the page does not take it must not make the browser open it (and
// leave the app); the Search and Upload pages take drops on the whole page.
for (const type of ["dragover", "drop"]) {
  window.addEventListener(type, (event) => {
    if (event.dataTransfer && [...event.dataTransfer.types].includes("Files")) event.preventDefault();
  });
}
route({ keepFocus: true });
