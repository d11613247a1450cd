// The single page: hash routes #/library, #/upload, #/search, #/map -> one view at a time.

import { apiKey, onAuthError, setApiKey } from "./api.js";
import { clear, el, nextId } from "./util.js";
import { renderLibrary } from "./library.js";
import { renderUpload } from "./upload.js";
import { renderSearch } from "./search.js";
import { renderMap } from "./map.js";

const VIEWS = {
  library: { title: "Library", render: renderLibrary },
  upload: { title: "Upload", render: renderUpload },
  search: { title: "Search", render: renderSearch },
  map: { title: "Map", render: renderMap },
};

let current = null; // {name, cleanup}

/** The route in the hash: {view, params}. */
export function parseRoute(hash = location.hash) {
  const text = hash.replace(/^#\/?/, "");
  const [path, query = ""] = text.split("?");
  const view = path in VIEWS ? path : "library";
  return { view, params: new URLSearchParams(query) };
}

/** Go to a view; params is an object (empty values dropped). */
export function navigate(view, params = {}, { replace = false } = {}) {
  const query = new URLSearchParams();
  for (const [key, value] of Object.entries(params)) {
    if (value !== null && value !== undefined && value !== "") query.set(key, String(value));
  }
  const text = query.toString();
  const hash = `#/${view}${text ? `?${text}` : ""}`;
  if (replace) {
    history.replaceState(null, "", hash);
    route({ keepFocus: true });
  } else if (location.hash === hash) {
    route();
  } else {
    location.hash = hash;
  }
}

export function showAlert(message) {
  const alert = document.getElementById("alert");
  if (!message) {
    alert.hidden = true;
    alert.textContent = "";
    return;
  }
  alert.textContent = message;
  alert.hidden = false;
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
    const cleanup = await VIEWS[view].render(main, params, { navigate, showAlert });
    if (mine === current) mine.cleanup = cleanup || null;
    else if (cleanup) cleanup();
  } catch (error) {
    // 401/403 already opened the key form (onAuthError); other errors are shown as they are.
    if (error.status !== 401 && error.status !== 403) {
      showAlert(error.detail || error.message || String(error));
    }
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
window.addEventListener("hashchange", () => route());
route({ keepFocus: true });
