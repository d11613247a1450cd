// The Download dialog: one clip (or a span of it: a moment) as BVH, FBX or GLB — on a stored
// rig, with its root kept, in place or extracted, in cm, m or inches, at a frame rate — or
// many clips as one ZIP (POST /exports) with the same options. The choice is kept for the
// session (sessionStorage), so the next download is one click.

import { download, postForm, rigs as fetchRigs } from "./api.js";
import { withKey } from "./keys.js";
import { clear, el, formatSeconds, nextId, plural } from "./util.js";

const OPTIONS_KEY = "mocap-index.download-options";
const DEFAULTS = Object.freeze({ format: "bvh", rig: "", root: "keep", units: "", fps: "" });
/** The files a rig may be read from (POST /rigs). */
// A .gltf rig comes with the files it refers to (its .bin, textures): several may be chosen.
export const RIG_ACCEPT = ".bvh,.asf,.fbx,.glb,.gltf,.vrm,.vrma,.bin,.png,.jpg,.jpeg,.webp,.ktx2";

/** The form of a rig upload: every chosen file as 'file'; its name, the rig file's. */
export function rigForm(files) {
  const body = new FormData();
  for (const file of files) body.append("file", file, file.name);
  const main = [...files].find((file) => !/\.(bin|png|jpe?g|webp|ktx2)$/i.test(file.name)) || files[0];
  return { body, name: main.name };
}
const UPLOAD_RIG = "upload"; // the rig select's "Upload a rig…" entry

const FORMATS = [
  ["bvh", "BVH", "A text hierarchy and its frames: Blender, MotionBuilder and most tools read it."],
  ["fbx", "FBX", "Binary FBX 7.4 written by Blender's exporter: Unity, Unreal, Maya, MotionBuilder."],
  ["glb", "GLB (glTF 2.0)", "glTF binary in metres, +Y up: Godot, three.js, Unity (glTFast), Unreal, Blender."],
  ["original", "As uploaded", "The stored file itself (cut to the span for a moment): no option below applies."],
];
const ROOTS = [
  ["keep", "Keep", "The root travels as it did in the capture."],
  ["in-place", "In place", "The horizontal travel is removed: a walk stays on the spot (height and turns kept)."],
  ["extract", "Root motion", "A new top joint “root” on the floor carries the travel and the facing, as Unity's and Unreal's root motion expect."],
];
const UNITS = [
  ["", "The source's own"],
  ["cm", "Centimetres"],
  ["m", "Metres"],
  ["in", "Inches"],
];

/** The options chosen last in this tab (or the defaults). */
export function savedOptions() {
  try {
    const saved = JSON.parse(sessionStorage.getItem(OPTIONS_KEY) || "{}");
    return { ...DEFAULTS, ...(saved && typeof saved === "object" ? saved : {}) };
  } catch {
    return { ...DEFAULTS };
  }
}

function saveOptions(options) {
  try {
    sessionStorage.setItem(OPTIONS_KEY, JSON.stringify(options));
  } catch {
    // storage disabled: the choice is simply not remembered
  }
}

/** The query of GET /clips/{id}/file for `options` and a span ([start, end] or null). */
export function fileParams(options, span = null) {
  const params = {};
  if (options.format !== "original") {
    params.format = options.format;
    if (options.rig) params.rig = options.rig;
    if (options.root !== "keep") params.root = options.root;
    if (options.units && options.format !== "glb") params.units = options.units;
    if (options.fps) params.fps = options.fps;
  }
  if (span) [params.start, params.end] = span;
  return params;
}

/** The body of POST /exports: `items` [{id, start?, end?}] with `options`. */
export function exportBody(options, items) {
  const body = {
    clips: items.map((item) => (item.start === undefined || item.start === null ? item.id : { id: item.id, start: item.start, end: item.end })),
    format: options.format === "original" ? "bvh" : options.format,
    root: options.root,
  };
  if (options.rig) body.rig = Number(options.rig);
  if (options.units && body.format !== "glb") body.units = options.units;
  if (options.fps) body.fps = Number(options.fps);
  return body;
}

function select(id, choices, value) {
  const node = el("select", { id }, choices.map(([v, text]) => el("option", { value: v }, text)));
  node.value = choices.some(([v]) => v === value) ? value : choices[0][0];
  return node;
}

/**
 * Open the Download dialog. `target` is one clip — `{clip: {id, name}, span: [start, end] or
 * null}` (a span: a moment) — or many: `{items: [{id, name, start?, end?}], title}`, saved as
 * one ZIP. Resolves when it closes: to the name of the file saved, or null.
 */
export function openDownload(target) {
  const many = Array.isArray(target.items);
  const saved = savedOptions();
  if (many && saved.format === "original") saved.format = DEFAULTS.format;
  const ids = {
    head: nextId("download-head"),
    format: nextId("format"),
    formatHelp: nextId("format-help"),
    rig: nextId("rig"),
    root: nextId("root"),
    rootHelp: nextId("root-help"),
    units: nextId("units"),
    unitsHelp: nextId("units-help"),
    fps: nextId("fps"),
    start: nextId("from"),
    end: nextId("to"),
    rigFile: nextId("rig-file"),
  };
  const formats = many ? FORMATS.filter(([v]) => v !== "original") : FORMATS;
  const format = select(ids.format, formats, saved.format);
  const formatHelp = el("p", { id: ids.formatHelp, class: "hint" });
  format.setAttribute("aria-describedby", ids.formatHelp);
  const rig = el("select", { id: ids.rig }, el("option", { value: "" }, "The clip's own skeleton"));
  const root = select(ids.root, ROOTS, saved.root);
  const rootHelp = el("p", { id: ids.rootHelp, class: "hint" });
  root.setAttribute("aria-describedby", ids.rootHelp);
  const units = select(ids.units, UNITS, saved.units);
  const unitsHelp = el("p", { id: ids.unitsHelp, class: "hint" });
  units.setAttribute("aria-describedby", ids.unitsHelp);
  const fps = el("input", { id: ids.fps, type: "number", min: "1", max: "1000", step: "any", value: saved.fps, placeholder: "the clip's own", inputmode: "decimal" });

  // A moment: its span, which the user may widen or narrow.
  const span = !many && target.span ? target.span : null;
  const start = span ? el("input", { id: ids.start, type: "number", min: "0", step: "any", value: String(span[0]), inputmode: "decimal" }) : null;
  const end = span ? el("input", { id: ids.end, type: "number", min: "0", step: "any", value: String(span[1]), inputmode: "decimal" }) : null;

  // "Upload a rig…": a file field in the dialog; the rig stored is then chosen.
  const rigFile = el("input", { id: ids.rigFile, type: "file", multiple: true, accept: RIG_ACCEPT });
  const rigStatus = el("p", { class: "hint", role: "status" });
  const storeRig = el("button", { type: "button", class: "small" }, "Store this rig");
  const rigUpload = el(
    "div",
    { class: "rig-upload", hidden: true },
    el("label", { for: ids.rigFile }, "Rig file (BVH, ASF, FBX, GLB/glTF, VRM)"),
    rigFile,
    el("div", { class: "dialog-buttons start" }, storeRig),
    rigStatus,
  );

  const options = el(
    "fieldset",
    { class: "export-options" },
    el("legend", { class: "visually-hidden" }, "Options"),
    el("div", { class: "field" }, el("label", { for: ids.rig }, "Rig"), rig),
    rigUpload,
    el("div", { class: "field" }, el("label", { for: ids.root }, "Root"), root, rootHelp),
    el("div", { class: "field" }, el("label", { for: ids.units }, "Units"), units, unitsHelp),
    el("div", { class: "field" }, el("label", { for: ids.fps }, "Frame rate (fps)"), fps),
  );
  const status = el("p", { class: "status", role: "status", "aria-live": "polite" });
  const keyArea = el("div", { class: "key-area" });
  const go = el("button", { type: "submit" }, many ? "Download ZIP" : "Download");
  const cancel = el("button", { type: "button", class: "secondary" }, "Cancel");
  const what = many
    ? `${plural(target.items.length, "clip")} as one ZIP`
    : span
      ? `“${target.clip.name}”, ${formatSeconds(span[0])} – ${formatSeconds(span[1])}`
      : `“${target.clip.name}”`;
  const form = el(
    "form",
    { class: "download-form" },
    span
      ? el(
          "div",
          { class: "span-fields" },
          el("div", { class: "field" }, el("label", { for: ids.start }, "From (s)"), start),
          el("div", { class: "field" }, el("label", { for: ids.end }, "To (s)"), end),
        )
      : null,
    el("div", { class: "field" }, el("label", { for: ids.format }, "Format"), format, formatHelp),
    options,
    el("div", { class: "dialog-buttons" }, cancel, go),
  );
  const node = el(
    "dialog",
    { class: "download-dialog", "aria-labelledby": ids.head },
    el("h2", { id: ids.head }, `Download ${what}`),
    many && target.title ? el("p", { class: "hint" }, target.title) : null,
    form,
    keyArea,
    status,
    el("p", { class: "hint" }, el("a", { href: "#/rigs" }, "Manage rigs"), " · the choice is kept for this tab."),
  );

  function say(text, { error = false } = {}) {
    status.textContent = text;
    status.classList.toggle("error", error);
    status.setAttribute("role", error ? "alert" : "status");
  }

  function chosen() {
    return { format: format.value, rig: rig.value === UPLOAD_RIG ? "" : rig.value, root: root.value, units: units.value, fps: fps.value.trim() };
  }

  let lastRig = saved.rig;
  function update() {
    const f = format.value;
    formatHelp.textContent = FORMATS.find(([v]) => v === f)[2];
    options.disabled = f === "original";
    rootHelp.textContent = ROOTS.find(([v]) => v === root.value)[2];
    units.disabled = f === "glb" || f === "original";
    unitsHelp.textContent = f === "glb" ? "GLB is always in metres." : "BVH and FBX; by default centimetres for FBX and glTF sources.";
    rigUpload.hidden = rig.value !== UPLOAD_RIG;
    if (rig.value !== UPLOAD_RIG) lastRig = rig.value;
    if (rig.value !== UPLOAD_RIG) saveOptions(chosen());
  }
  for (const control of [format, root, units, rig]) control.addEventListener("change", update);
  form.addEventListener("input", () => status.classList.contains("error") && say(""));
  fps.addEventListener("change", () => saveOptions(chosen()));

  async function loadRigs(selected) {
    let list = [];
    try {
      list = await fetchRigs();
    } catch (error) {
      rigStatus.textContent = `Cannot list the rigs: ${error.detail || error.message}`;
    }
    clear(rig);
    rig.append(el("option", { value: "" }, "The clip's own skeleton"));
    for (const r of list) rig.append(el("option", { value: String(r.id) }, `${r.name} (#${r.id}, ${plural(r.joint_count, "joint")})`));
    rig.append(el("option", { value: UPLOAD_RIG }, "Upload a rig…"));
    rig.value = list.some((r) => String(r.id) === String(selected)) ? String(selected) : "";
    update();
  }
  loadRigs(saved.rig);

  storeRig.addEventListener("click", async () => {
    if (!rigFile.files.length) {
      rigStatus.textContent = "Choose the rig's file first.";
      return;
    }
    const { body, name } = rigForm(rigFile.files);
    rigStatus.textContent = `Reading ${name}…`;
    storeRig.disabled = true;
    try {
      const answer = await withKey(keyArea, () => postForm("/rigs", null, body, { quietAuth: true }), "store a rig");
      if (answer === undefined) {
        rigStatus.textContent = "Not stored.";
        return;
      }
      // Said once the new rig is listed and chosen, so the form shows what the line says.
      await loadRigs(answer.body.id);
      saveOptions(chosen());
      rigStatus.textContent = `Stored as rig #${answer.body.id} “${answer.body.name}”.`;
    } catch (error) {
      rigStatus.textContent = `Not stored: ${error.detail || error.message}`;
    } finally {
      storeRig.disabled = false;
    }
  });

  return new Promise((resolve) => {
    let result = null;
    cancel.addEventListener("click", () => node.close());
    // Leaving the page (the "Manage rigs" link, Back) closes the dialog too.
    const leave = () => node.open && node.close();
    window.addEventListener("hashchange", leave);
    node.addEventListener("close", () => {
      window.removeEventListener("hashchange", leave);
      node.remove();
      resolve(result);
    });
    form.addEventListener("submit", async (event) => {
      event.preventDefault();
      if (rig.value === UPLOAD_RIG) {
        rig.value = lastRig || "";
        update();
      }
      const options = chosen();
      const rate = Number.parseFloat(options.fps);
      if (options.fps && !(rate > 0)) {
        say("The frame rate must be a positive number (or empty: the clip's own).", { error: true });
        fps.focus();
        return;
      }
      let cut = null;
      if (span) {
        cut = [Number.parseFloat(start.value), Number.parseFloat(end.value)];
        if (!(cut[1] > cut[0])) {
          say("The span's end must come after its start.", { error: true });
          end.focus();
          return;
        }
      }
      saveOptions(options);
      const slow = options.format === "fbx" ? " (FBX is written by Blender: a few seconds)" : "";
      say(`Preparing the file${slow}…`);
      go.disabled = true;
      try {
        const name = await withKey(
          keyArea,
          () =>
            many
              ? download("/exports", null, "mocap-export.zip", { body: exportBody(options, target.items), quietAuth: true })
              : download(`/clips/${target.clip.id}/file`, fileParams(options, cut), `${target.clip.name}.${options.format}`, { quietAuth: true }),
          "download",
        );
        if (name === undefined) {
          say("Not downloaded.");
          return;
        }
        result = name;
        node.close();
      } catch (error) {
        say(`Download failed: ${error.detail || error.message}`, { error: true });
      } finally {
        go.disabled = false;
      }
    });
    document.body.append(node);
    update();
    node.showModal();
    format.focus();
  });
}
