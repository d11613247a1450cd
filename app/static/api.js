// Talking to the service: JSON GETs, uploads with progress, one error type.

/** An error answered by the service ({"error", "detail"}) or the network. */
export class ApiError extends Error {
  constructor(status, code, detail) {
    super(detail);
    this.status = status;
    this.code = code;
    this.detail = detail;
  }
}

// -- API key ---------------------------------------------------------------------------
// A library may need a key to be changed (MOCAP_API_KEY) or read (MOCAP_REQUIRE_KEY_FOR_READS).
// The key a user types is kept for this browser tab only and sent as X-API-Key.

const KEY_STORAGE = "mocap-index.api-key";
const authListeners = new Set();

export function apiKey() {
  try {
    return sessionStorage.getItem(KEY_STORAGE) || "";
  } catch {
    return "";
  }
}

export function setApiKey(key) {
  try {
    if (key) sessionStorage.setItem(KEY_STORAGE, key);
    else sessionStorage.removeItem(KEY_STORAGE);
  } catch {
    // storage disabled: the key is simply not remembered
  }
}

/** listener(error) is called when the service answers 401 or 403. */
export function onAuthError(listener) {
  authListeners.add(listener);
}

function authHeaders() {
  const key = apiKey();
  return key ? { "X-API-Key": key } : {};
}

function reportAuth(error) {
  if (error.status === 401 || error.status === 403) {
    for (const listener of authListeners) listener(error);
  }
  return error;
}

async function errorOf(response) {
  let code = "http_error";
  let detail = `${response.status} ${response.statusText}`;
  try {
    const body = await response.json();
    if (body && typeof body.detail === "string") detail = body.detail;
    if (body && typeof body.error === "string") code = body.error;
  } catch {
    // not JSON: keep the status line
  }
  return new ApiError(response.status, code, detail);
}

/** path?params: empty values left out; an array value repeats its key (id=1&id=2). */
function url(path, params) {
  const query = new URLSearchParams();
  for (const [key, value] of Object.entries(params || {})) {
    for (const one of Array.isArray(value) ? value : [value]) {
      if (one === null || one === undefined || one === "") continue;
      query.append(key, String(one));
    }
  }
  const text = query.toString();
  return text ? `${path}?${text}` : path;
}

/** GET a JSON document; throws ApiError. */
export async function getJson(path, params, { signal } = {}) {
  let response;
  try {
    response = await fetch(url(path, params), {
      signal,
      headers: { Accept: "application/json", ...authHeaders() },
    });
  } catch (error) {
    if (error.name === "AbortError") throw error;
    throw new ApiError(0, "network_error", `the service cannot be reached (${error.message})`);
  }
  if (!response.ok) throw reportAuth(await errorOf(response));
  return response.json();
}

/**
 * PATCH/DELETE/POST a JSON body (or none); resolves to the JSON answer (null for 204).
 * With quietAuth a 401/403 is only thrown, not reported to onAuthError: the caller asks for
 * the key itself (and keeps what the user typed).
 */
export async function sendJson(method, path, body, { params, quietAuth = false } = {}) {
  let response;
  try {
    response = await fetch(url(path, params), {
      method,
      headers: {
        Accept: "application/json",
        ...(body === undefined ? {} : { "Content-Type": "application/json" }),
        ...authHeaders(),
      },
      body: body === undefined ? undefined : JSON.stringify(body),
    });
  } catch (error) {
    throw new ApiError(0, "network_error", `the service cannot be reached (${error.message})`);
  }
  if (!response.ok) {
    const error = await errorOf(response);
    throw quietAuth ? error : reportAuth(error);
  }
  return response.status === 204 ? null : response.json();
}

/** The file name a Content-Disposition header gives (filename* first). */
function dispositionName(header, fallback) {
  const exact = /filename\*=UTF-8''([^;]+)/i.exec(header || "");
  if (exact) {
    try {
      return decodeURIComponent(exact[1]);
    } catch {
      // fall through to the plain name
    }
  }
  const plain = /filename="([^"]*)"/i.exec(header || "");
  return plain ? plain[1] : fallback;
}

/**
 * Download a file the API serves, with the API key if one is set (a plain link could not
 * send it): the browser saves it under the name the service gives. With `body` it is a POST
 * of that JSON (POST /exports). With quietAuth a 401/403 is only thrown (see sendJson).
 */
export async function download(path, params, fallbackName = "download", { body, quietAuth = false } = {}) {
  let response;
  const request =
    body === undefined
      ? { headers: authHeaders() }
      : { method: "POST", headers: { "Content-Type": "application/json", ...authHeaders() }, body: JSON.stringify(body) };
  try {
    response = await fetch(url(path, params), request);
  } catch (error) {
    throw new ApiError(0, "network_error", `the service cannot be reached (${error.message})`);
  }
  if (!response.ok) {
    const error = await errorOf(response);
    throw quietAuth ? error : reportAuth(error);
  }
  const name = dispositionName(response.headers.get("Content-Disposition"), fallbackName);
  const link = document.createElement("a");
  link.href = URL.createObjectURL(await response.blob());
  link.download = name;
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(link.href), 10_000);
  return name;
}

/**
 * POST multipart form data with upload progress (fetch has none): resolves to
 * {status, body}; rejects with ApiError. onProgress(fraction) gets 0..1; quietAuth: see
 * sendJson.
 */
export function postForm(path, params, form, { onProgress, signal, quietAuth = false } = {}) {
  return new Promise((resolve, reject) => {
    const request = new XMLHttpRequest();
    request.open("POST", url(path, params));
    request.responseType = "text";
    request.setRequestHeader("Accept", "application/json");
    for (const [name, value] of Object.entries(authHeaders())) request.setRequestHeader(name, value);
    if (onProgress) {
      request.upload.addEventListener("progress", (event) => {
        if (event.lengthComputable) onProgress(event.loaded / event.total);
      });
    }
    request.addEventListener("load", () => {
      let body = null;
      try {
        body = JSON.parse(request.responseText);
      } catch {
        body = null;
      }
      if (request.status >= 200 && request.status < 300) {
        resolve({ status: request.status, body });
      } else {
        const detail =
          body && typeof body.detail === "string"
            ? body.detail
            : `${request.status} ${request.statusText || "error"}`;
        const error = new ApiError(request.status, (body && body.error) || "http_error", detail);
        reject(quietAuth ? error : reportAuth(error));
      }
    });
    request.addEventListener("error", () =>
      reject(new ApiError(0, "network_error", "the upload failed: the service cannot be reached")),
    );
    request.addEventListener("abort", () =>
      reject(new ApiError(0, "aborted", "the upload was cancelled")),
    );
    if (signal) signal.addEventListener("abort", () => request.abort());
    request.send(form);
  });
}

/**
 * The form fields of one clip: {file} (a .gltf's buffers and textures, `clip.resources`, as
 * further 'file' fields) or {skeleton, motion}, plus labels, `fields` (source, licence: empty
 * ones left out) and (FBX/glTF) the animation to read (`clip.animation`).
 */
export function clipForm(clip, labels = [], fields = {}) {
  const form = new FormData();
  if (clip.bvh) {
    form.append("file", clip.bvh, clip.bvh.name);
    for (const resource of clip.resources || []) form.append("file", resource, resource.name);
  } else {
    form.append("skeleton", clip.asf, clip.asf.name);
    form.append("motion", clip.amc, clip.amc.name);
  }
  for (const label of labels) form.append("labels", label);
  for (const [name, value] of Object.entries(fields)) if (value) form.append(name, value);
  if (clip.animation) form.append("animation", clip.animation);
  return form;
}

/** Files that may hold several animations (FBX, glTF, VRM animation). */
export function mayHoldAnimations(clip) {
  return Boolean(clip.bvh) && /\.(fbx|glb|gltf|vrma|vrm)$/i.test(clip.bvh.name);
}

/** The animations of a file (POST /inspect): [{name, frame_count, duration, selected}]. */
export async function fileAnimations(clip) {
  const { body } = await postForm("/inspect", null, clipForm(clip));
  return body.animations;
}

// -- cached look-ups ------------------------------------------------------------------

let descriptorsPromise = null;
/** {default, descriptors: [{name, dimension, version, description}]} (fetched once). */
export function descriptors() {
  if (!descriptorsPromise) {
    descriptorsPromise = getJson("/descriptors").catch((error) => {
      descriptorsPromise = null;
      throw error;
    });
  }
  return descriptorsPromise;
}

/** Labels in use with their counts (not cached: uploads change them). */
export function labels() {
  return getJson("/library/labels");
}

/** Licences in use with their counts, most used first (not cached). */
export function licences() {
  return getJson("/library/licences");
}

/** Stored rigs, in id order (the first 200: a rig picker's worth). */
export async function rigs() {
  const page = await getJson("/rigs", { limit: 200 });
  return page.items;
}
