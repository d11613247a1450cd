// Changes that may need the API key (uploads of rigs, bulk labels, deletes, heavy downloads):
// on 401/403 the page asks for the key next to the control that needed it and tries again,
// keeping what the user typed (the header's key form would redraw the page).

import { ApiError, apiKey, setApiKey } from "./api.js";
import { clear, el, nextId } from "./util.js";

/** Whether an error asks for (another) API key. */
export function needsKey(error) {
  return error instanceof ApiError && (error.status === 401 || error.status === 403);
}

/** Ask for the API key in `area`; resolves to the key, or null when the user gives up. */
export function askForKey(area, error, what) {
  return new Promise((resolve) => {
    const inputId = nextId("inline-key");
    const input = el("input", { id: inputId, type: "password", autocomplete: "off", value: apiKey() });
    const reason =
      error.status === 401
        ? `The service needs an API key to ${what}.`
        : `The API key was refused (${error.detail}); another key is needed to ${what}.`;
    const done = (key) => {
      clear(area);
      resolve(key);
    };
    const form = el(
      "form",
      { class: "key-form inline", "aria-label": "Give the API key" },
      el("p", { role: "alert" }, reason),
      el("label", { for: inputId }, "API key"),
      input,
      el("button", { type: "submit" }, "Use this key"),
      el("button", { type: "button", class: "secondary", onclick: () => done(null) }, "Cancel"),
    );
    form.addEventListener("submit", (event) => {
      event.preventDefault();
      event.stopPropagation(); // a key form inside another form (a dialog's) submits only itself
      setApiKey(input.value.trim());
      done(input.value.trim());
    });
    clear(area);
    area.append(form);
    input.focus();
  });
}

/**
 * Run `action` (which must not report 401/403 itself: quietAuth); on 401/403 ask for the key
 * in `area` and run it again. Resolves to the action's result, or undefined when the user
 * gave up.
 */
export async function withKey(area, action, what) {
  try {
    return await action();
  } catch (error) {
    if (!needsKey(error)) throw error;
    const key = await askForKey(area, error, what);
    if (key === null) return undefined;
    return withKey(area, action, what);
  }
}
