// Upload: drop (or choose) BVH files, ASF+AMC pairs and the like (a .gltf with its .bin and
// textures); each clip uploads with its own progress bar, and the service's error is shown
// next to the file that caused it.

import { clipForm, fileAnimations, licences as fetchLicences, mayHoldAnimations, postForm } from "./api.js";
import { el, formatSeconds, nextId, plural } from "./util.js";

const PARALLEL_UPLOADS = 2;

// Skeletons (.asf) dropped earlier in this page's life, for motions dropped later.
const rememberedSkeletons = new Map(); // stem (lower case) -> File

function stem(name) {
  return name.replace(/\.[^.]*$/, "");
}

function extension(name) {
  const match = /\.([^.]+)$/.exec(name);
  return match ? match[1].toLowerCase() : "";
}

/**
 * Group dropped files into clips: one per .bvh, one per .amc with its .asf (same stem, the
 * stem before the first "_" — CMU's 02.asf for 02_01.amc — or the only skeleton around).
 * Returns [{name, bvh} | {name, asf, amc} | {name, error} | {name, note}].
 */
// Files uploaded alone as the 'file' field (kept under the item's `bvh` key, which api.js sends).
export const SINGLE_FILE_EXTENSIONS = ["bvh", "fbx", "glb", "gltf", "vrma", "vrm"];
// Files a .gltf may refer to (its buffers and textures): sent with every .gltf dropped with them.
export const RESOURCE_EXTENSIONS = ["bin", "png", "jpg", "jpeg", "webp", "ktx2"];
export const ACCEPT = ".bvh,.fbx,.glb,.gltf,.vrma,.vrm,.asf,.amc,.bin,.png,.jpg,.jpeg,.webp,.ktx2";

export function groupFiles(files, remembered = rememberedSkeletons) {
  const items = [];
  const skeletons = new Map();
  for (const file of files) {
    if (extension(file.name) === "asf") skeletons.set(stem(file.name).toLowerCase(), file);
  }
  const used = new Set();
  const allSkeletons = new Map([...remembered, ...skeletons]);
  const dropped = Array.from(files);
  const resources = dropped.filter((file) => RESOURCE_EXTENSIONS.includes(extension(file.name)));
  const gltfDropped = dropped.some((file) => extension(file.name) === "gltf");
  for (const file of files) {
    const ext = extension(file.name);
    if (ext === "gltf" && resources.length) {
      items.push({ name: file.name, bvh: file, resources });
    } else if (SINGLE_FILE_EXTENSIONS.includes(ext)) {
      items.push({ name: file.name, bvh: file });
    } else if (RESOURCE_EXTENSIONS.includes(ext)) {
      if (!gltfDropped) {
        items.push({
          name: file.name,
          error: "a .gltf's buffer or texture: drop it together with its .gltf file",
        });
      }
    } else if (ext === "amc") {
      const key = stem(file.name).toLowerCase();
      const candidates = [key, key.split("_")[0], key.split(/[_-]/)[0]];
      let asf = candidates.map((c) => allSkeletons.get(c)).find(Boolean);
      if (!asf && skeletons.size === 1) asf = [...skeletons.values()][0];
      if (!asf && skeletons.size === 0 && remembered.size === 1) asf = [...remembered.values()][0];
      if (asf) {
        used.add(asf);
        items.push({ name: `${file.name} + ${asf.name}`, asf, amc: file });
      } else {
        items.push({
          name: file.name,
          error:
            skeletons.size > 1
              ? "several .asf skeletons were dropped and none is named like this motion; drop the motion with its own skeleton"
              : "no .asf skeleton for this motion: drop its .asf file together with it",
        });
      }
    } else if (ext !== "asf") {
      items.push({
        name: file.name,
        error:
          "not a motion file: drop .bvh, .fbx, .glb, .gltf, .vrma or .vrm files, or .asf skeletons with their .amc motions",
      });
    }
  }
  for (const [key, file] of skeletons) {
    remembered.set(key, file);
    if (!used.has(file)) {
      items.push({
        name: file.name,
        note: "skeleton kept: drop its .amc motions next and they will use it",
      });
    }
  }
  return items;
}

/**
 * Take files dropped anywhere on the page while this view is shown: an overlay says what a
 * drop does; `onFiles(files)` gets them. Returns the function that stops it.
 */
export function dropTarget(main, onFiles, message) {
  const overlay = el("div", { class: "drop-overlay", hidden: true, "aria-hidden": "true" }, el("p", {}, message));
  document.body.append(overlay);
  let depth = 0; // dragenter/dragleave pairs over nested elements
  const hasFiles = (event) => event.dataTransfer && [...event.dataTransfer.types].includes("Files");
  const show = (on) => {
    overlay.hidden = !on;
    main.classList.toggle("dragging", on);
  };
  const handlers = {
    dragenter(event) {
      if (!hasFiles(event)) return;
      event.preventDefault();
      depth += 1;
      show(true);
    },
    dragover(event) {
      if (!hasFiles(event)) return;
      event.preventDefault();
      event.dataTransfer.dropEffect = "copy";
    },
    dragleave() {
      depth = Math.max(0, depth - 1);
      if (depth === 0) show(false);
    },
    drop(event) {
      if (!hasFiles(event)) return;
      event.preventDefault();
      depth = 0;
      show(false);
      if (event.dataTransfer.files.length) onFiles([...event.dataTransfer.files]);
    },
  };
  for (const [type, handler] of Object.entries(handlers)) document.addEventListener(type, handler);
  return () => {
    for (const [type, handler] of Object.entries(handlers)) document.removeEventListener(type, handler);
    overlay.remove();
  };
}

/**
 * A regular expression from a Python or JavaScript spelling: Python's named groups
 * (?P<name>...) and back-references (?P=name) become JavaScript's (?<name>...), \k<name>
 * (the CLI's --labels-regex takes both spellings too).
 */
export function jsRegex(pattern) {
  return new RegExp(
    pattern
      .replace(/(?<!\\)((?:\\\\)*)\(\?P<(?=\w+>)/g, "$1(?<")
      .replace(/(?<!\\)((?:\\\\)*)\(\?P=(\w+)\)/g, "$1\\k<$2>"),
  );
}

/** Labels for a file name from a regular expression: its named groups, else its groups. */
export function labelsFromName(pattern, fileName) {
  if (!pattern) return [];
  const match = jsRegex(pattern).exec(stem(fileName));
  if (!match) return [];
  const values = match.groups ? Object.values(match.groups) : match.slice(1);
  return values.filter((v) => v !== undefined && v !== "");
}

export async function renderUpload(main) {
  const inputId = nextId("files");
  const labelsId = nextId("labels");
  const patternId = nextId("pattern");
  const patternHelpId = nextId("pattern-help");
  const sourceId = nextId("source");
  const licenceId = nextId("licence");
  const licenceOptions = nextId("licence-options");
  const fileInput = el("input", {
    id: inputId,
    type: "file",
    multiple: true,
    accept: ACCEPT,
    class: "file-input",
  });
  const labelsInput = el("input", { id: labelsId, type: "text", placeholder: "e.g. walk, happy", autocomplete: "off" });
  // Where the clips come from and their licence: stored with each clip (the Library and the
  // searches filter by licence).
  const sourceInput = el("input", { id: sourceId, type: "text", maxlength: "500", autocomplete: "off", placeholder: "e.g. CMU Graphics Lab Motion Capture Database" });
  const licenceInput = el("input", { id: licenceId, type: "text", maxlength: "500", autocomplete: "off", placeholder: "e.g. CC BY 4.0", list: licenceOptions });
  const licenceList = el("datalist", { id: licenceOptions });
  fetchLicences()
    .then((rows) => licenceList.append(...rows.map((r) => el("option", { value: r.licence }))))
    .catch(() => {});
  const patternInput = el("input", {
    id: patternId,
    type: "text",
    placeholder: "e.g. dataset-1_(?<content>[^_]+)_(?<style>[^_]+)",
    autocomplete: "off",
    spellcheck: false,
    "aria-describedby": patternHelpId,
  });
  const patternHelp = el(
    "p",
    { id: patternHelpId, class: "hint" },
    "Optional regular expression over each file name: what its groups match become labels too. Named groups may be written (?<name>…) or (?P<name>…).",
  );
  const summary = el("p", { class: "status", role: "status", "aria-live": "polite" });
  const list = el("ol", { class: "uploads", "aria-label": "Uploads" });
  const zone = el(
    "div",
    { class: "dropzone", "data-testid": "dropzone" },
    el("p", { class: "dropzone-title" }, "Drop BVH, FBX, glTF (a .gltf with its .bin) or VRMA files, or ASF skeletons with their AMC motions, anywhere on this page"),
    el("p", {}, fileInput, el("label", { for: inputId, class: "button" }, "Choose files…")),
    el("p", { class: "hint" }, "Several files at once are fine; each clip is uploaded and checked on its own."),
  );

  main.append(
    el("div", { class: "view-head" }, el("h1", {}, "Upload")),
    el(
      "div",
      { class: "filters align-top" },
      el("div", { class: "field" }, el("label", { for: labelsId }, "Labels for these clips (comma-separated)"), labelsInput),
      el("div", { class: "field wide" }, el("label", { for: patternId }, "Labels from file names"), patternInput, patternHelp),
    ),
    el(
      "div",
      { class: "filters align-top" },
      el("div", { class: "field wide" }, el("label", { for: sourceId }, "Source of these clips"), sourceInput),
      el("div", { class: "field" }, el("label", { for: licenceId }, "Licence of these clips"), licenceInput, licenceList),
    ),
    zone,
    summary,
    list,
  );

  const queue = [];
  // stored: new clips; known: already in the library (nothing new stored); waiting: files of
  // several animations waiting for the user's choice.
  const totals = { stored: 0, known: 0, failed: 0, all: 0, waiting: 0 };
  let active = 0;

  function updateSummary() {
    const left = totals.all - totals.stored - totals.known - totals.failed - totals.waiting;
    const parts = [`${plural(totals.stored, "clip")} stored`];
    if (totals.known) parts.push(`${totals.known} already in the library`);
    parts.push(`${totals.failed} failed`);
    if (totals.waiting) parts.push(`${plural(totals.waiting, "file")} waiting for a choice of animations`);
    if (left) parts.push(`${left} to go`);
    summary.textContent = totals.all ? `${parts.join(", ")}.` : "";
  }

  function addFiles(files) {
    const pattern = patternInput.value.trim();
    if (pattern) {
      try {
        jsRegex(pattern);
        patternInput.removeAttribute("aria-invalid");
        patternHelp.classList.remove("error-text");
      } catch (error) {
        patternInput.setAttribute("aria-invalid", "true");
        patternHelp.textContent = `Not a valid regular expression: ${error.message}`;
        patternHelp.classList.add("error-text");
        return;
      }
    }
    const common = labelsInput.value.split(",").map((s) => s.trim()).filter(Boolean);
    const fields = { source: sourceInput.value.trim(), licence: licenceInput.value.trim() };
    for (const item of groupFiles([...files])) {
      const row = uploadRow(item);
      list.append(row.node);
      if (item.error) {
        row.fail(item.error);
        totals.all += 1;
        totals.failed += 1;
      } else if (item.note) {
        row.note(item.note);
      } else {
        const motionName = (item.bvh || item.amc).name;
        const labels = [...common, ...labelsFromName(pattern, motionName)];
        totals.all += 1;
        if (mayHoldAnimations(item)) chooseAnimations({ item, row, labels, fields });
        else queue.push({ item, row, labels, fields });
      }
    }
    updateSummary();
    pump();
  }

  /**
   * An FBX/glTF file: its animations are listed first (POST /inspect). One animation is
   * uploaded at once; of several, the user ticks those to store (the longest is ticked), each
   * becoming its own clip.
   */
  async function chooseAnimations(job) {
    const { item, row } = job;
    row.note("reading its animations…");
    totals.waiting += 1;
    let animations;
    try {
      animations = await fileAnimations(item);
    } catch (error) {
      totals.waiting -= 1;
      row.fail(error.detail || error.message, error.code);
      totals.failed += 1;
      updateSummary();
      return;
    }
    if (animations.length <= 1) {
      totals.waiting -= 1;
      row.reset();
      queue.push(job);
      updateSummary();
      pump();
      return;
    }
    updateSummary();
    row.choose(animations, (names) => {
      totals.waiting -= 1;
      totals.all += names.length - 1; // each animation is a clip of its own
      const rows = names.map((name, i) => (i === 0 ? row : uploadRow({ name: `${item.name} · ${name}` }, row.node)));
      names.forEach((name, i) => {
        rows[i].reset(`${item.name} · ${name}`);
        queue.push({ ...job, item: { ...item, animation: name }, row: rows[i] });
      });
      updateSummary();
      pump();
    });
  }

  function pump() {
    while (active < PARALLEL_UPLOADS && queue.length) {
      const job = queue.shift();
      active += 1;
      upload(job).finally(() => {
        active -= 1;
        updateSummary();
        pump();
      });
    }
  }

  async function upload({ item, row, labels, fields }) {
    row.start();
    try {
      const { status, body } = await postForm("/clips", null, clipForm(item, labels, fields), {
        onProgress: (fraction) => row.progress(fraction),
      });
      row.succeed(body, status === 201, labels.length > 0);
      if (status === 201) totals.stored += 1;
      else totals.known += 1;
    } catch (error) {
      row.fail(error.detail || error.message, error.code);
      totals.failed += 1;
    }
  }

  fileInput.addEventListener("change", () => {
    addFiles(fileInput.files);
    fileInput.value = "";
  });
  // Files dropped anywhere on the page are uploaded (the zone is only the obvious place).
  return dropTarget(main, addFiles, "Drop to upload these files");
}

/** One row of the upload list (placed after `after` when given). */
function uploadRow(item, after = null) {
  const bar = el("progress", { max: "1", value: "0", "aria-label": `Upload of ${item.name}` });
  const message = el("span", { class: "upload-message" }, "waiting");
  const nameNode = el("span", { class: "upload-name" }, item.name);
  const node = el("li", { class: "upload", dataset: { name: item.name, state: "waiting" } }, nameNode, bar, message);
  if (after) after.after(node);
  const set = (state, text) => {
    node.dataset.state = state;
    message.textContent = text;
  };
  return {
    node,
    start: () => set("uploading", "uploading…"),
    progress(fraction) {
      bar.value = fraction;
      set("uploading", fraction < 1 ? `uploading… ${Math.round(fraction * 100)} %` : "reading and describing…");
    },
    /** Back to waiting in the queue (under a new name: one animation of a file). */
    reset(name = null) {
      if (name) {
        nameNode.textContent = name;
        node.dataset.name = name;
        bar.setAttribute("aria-label", `Upload of ${name}`);
      }
      if (!bar.isConnected) nameNode.after(bar);
      node.querySelector(".animation-choice")?.remove();
      set("waiting", "waiting");
    },
    /** The animations of the file, to tick those to store; `onChosen(names)`. */
    choose(animations, onChosen) {
      bar.remove();
      set("choose", "");
      const groupId = nextId("animations");
      const boxes = animations.map((a) => {
        const id = nextId("animation");
        return {
          name: a.name,
          box: el("input", { type: "checkbox", id, value: a.name, checked: a.selected }),
          label: el("label", { for: id }, `${a.name} `, el("span", { class: "muted" }, formatSeconds(a.duration))),
        };
      });
      const button = el("button", { type: "submit", class: "small" }, "Upload the animations ticked");
      const form = el(
        "form",
        { class: "animation-choice", "aria-labelledby": groupId },
        el("p", { id: groupId }, `${animations.length} animations in this file; each one ticked becomes a clip:`),
        el("ul", { class: "plain" }, boxes.map(({ box, label }) => el("li", {}, box, label))),
        button,
      );
      form.addEventListener("submit", (event) => {
        event.preventDefault();
        const names = boxes.filter((b) => b.box.checked).map((b) => b.name);
        if (!names.length) {
          form.querySelector("p").textContent = "Tick at least one animation.";
          return;
        }
        onChosen(names);
      });
      node.append(form);
    },
    succeed(clip, created, labelled) {
      bar.value = 1;
      set("done", "");
      message.append(
        created
          ? `stored as clip #${clip.id} `
          : `already in the library as clip #${clip.id}${labelled ? ", labels added" : ""} `,
        el("a", { href: `#/clips/${clip.id}` }, "open"),
        " · ",
        el("a", { href: `#/search?clip=${clip.id}` }, "find similar"),
      );
      node.dataset.clipId = String(clip.id);
    },
    fail(text, code) {
      bar.remove();
      set("error", "");
      message.append(el("strong", {}, code ? `${code.replace(/_/g, " ")}: ` : "error: "), text);
      message.setAttribute("role", "alert");
    },
    note(text) {
      bar.remove();
      set("note", text);
    },
  };
}
