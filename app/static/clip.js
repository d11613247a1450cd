// The clip page, #/clips/{id}: a large moving preview with its timeline, every stored fact,
// download, rename/relabel/source/licence, delete (with confirmation) and "find similar".
//
// Changing a clip may need the API key: on 401/403 the page asks for it next to the button
// that needed it and tries again, keeping what was typed.

import { ApiError, apiKey, download, getJson, sendJson, setApiKey } from "./api.js";
import { Figure, Player, loadSkeleton } from "./figure.js";
import { Timeline, formatTime } from "./timeline.js";
import { clear, el, labelChips, nextId, plural } from "./util.js";

const MAX_FRAMES = 600; // per skeleton request (the API's cap)
const OVERVIEW_FPS = 30;
const MAX_DETAIL_FPS = 120;

/**
 * The frames of a take of any length for the clip page's figure: an overview of the whole
 * take (at most MAX_FRAMES frames: 30 fps up to 20 s, a frame every 6 s for an hour) that
 * frames the figure and fills in, and windows of MAX_FRAMES frames at the file's own rate
 * (up to 120 fps) around the playhead, fetched as it gets near them. So the page never holds
 * more than a few windows, whatever the take's length, and every frame can be stepped to.
 */
class TakeLoader {
  constructor(clip, figure) {
    this.clip = clip;
    this.figure = figure;
    this.fileFps = clip.frame_time > 0 ? 1 / clip.frame_time : 30;
    this.duration = Math.max(0, clip.frame_count - clip.lead_in_frames) * clip.frame_time;
    this.detailFps = Math.round(Math.min(this.fileFps, MAX_DETAIL_FPS) * 1e6) / 1e6;
    this.windowSeconds = MAX_FRAMES / this.detailFps;
    this.windows = new Map(); // window number -> Track, or null while it loads
  }

  /** Load the overview; then the figure plays it, with detail windows where they are loaded. */
  async load() {
    const fps = Math.min(OVERVIEW_FPS, Math.floor(((MAX_FRAMES - 1) / Math.max(this.duration, 1e-6)) * 1e4) / 1e4);
    await this.figure.load({ fps: Math.max(0.01, fps), maxFrames: MAX_FRAMES });
    if (this.figure.track && this.figure.track.fps < this.detailFps - 1e-6) {
      this.figure.detailAt = (time) => this.detailAt(time);
    }
  }

  /** The loaded window for preview time `time` (else null, and it is fetched). */
  detailAt(time) {
    const k = Math.max(0, Math.floor(time / this.windowSeconds));
    const found = this.windows.get(k);
    if (found === undefined) this.fetch(k);
    // Playing on: the next window comes before it is needed.
    if (time - k * this.windowSeconds > this.windowSeconds / 2) this.fetch(k + 1);
    return found || null;
  }

  fetch(k) {
    if (this.windows.has(k) || k * this.windowSeconds >= this.duration) return;
    this.windows.set(k, null);
    const lead = this.clip.lead_in_frames * this.clip.frame_time;
    const first = this.clip.lead_in_frames + Math.round(k * MAX_FRAMES * (this.fileFps / this.detailFps));
    const start = first * this.clip.frame_time;
    const end = Math.min(lead + this.duration, start + this.windowSeconds);
    loadSkeleton(this.clip.id, { fps: this.detailFps, maxFrames: MAX_FRAMES, start: start.toFixed(6), end: end.toFixed(6), priority: () => 2 }).then(
      (track) => {
        this.windows.set(k, track);
        // Only the windows near the playhead are kept.
        for (const key of this.windows.keys()) if (Math.abs(key - k) > 3) this.windows.delete(key);
        this.figure.lastKey = "";
      },
      () => this.windows.set(k, false), // not asked again: the overview stands in
    );
  }
}

/** A format as a short badge text ("bvh" -> "BVH", "asf/amc" -> "ASF/AMC"). */
export function formatBadge(format) {
  return el("span", { class: `badge format-${String(format).replace(/[^a-z0-9]+/gi, "-")}` }, String(format).toUpperCase());
}

/** The clip, with its joint mapping when the service offers it (older services: without). */
async function loadClip(id) {
  try {
    return await getJson(`/clips/${id}`, { include: "mapping" });
  } catch (error) {
    if (error.status === 422) return getJson(`/clips/${id}`);
    throw error;
  }
}

export async function renderClip(main, params, { navigate, notify }) {
  const id = Number.parseInt(params.get("id") || "", 10);
  if (!Number.isSafeInteger(id) || id < 1) {
    main.append(el("h1", {}, "No such clip"), el("p", {}, "The address names no clip. ", el("a", { href: "#/library" }, "Back to the library")));
    return null;
  }
  let clip;
  try {
    clip = await loadClip(id);
  } catch (error) {
    if (error.status === 404) {
      main.append(
        el("h1", {}, `No clip #${id}`),
        el("p", {}, "It was deleted, or never existed. ", el("a", { href: "#/library" }, "Back to the library")),
      );
      return null;
    }
    throw error;
  }
  document.title = `${clip.name} · mocap-index`;

  // -- preview: the whole take, at a resolution that fits what is shown ----------------------------
  // The clock starts once the take's length is known (it would run off the end before).
  const player = new Player({ playing: false });
  const timeline = new Timeline(player, { label: `Playback of ${clip.name}`, zoomable: true });
  const canvas = el("canvas", {
    class: "figure large",
    role: "img",
    "aria-label": `Animated stick figure of ${clip.name}`,
    dataset: { role: "clip", clipId: String(clip.id) },
  });
  const figure = new Figure(canvas, { player, clipId: clip.id, name: clip.name });
  const take = new TakeLoader(clip, figure);
  const previewNote = el("p", { class: "hint preview-note" });
  const keysHint = el(
    "p",
    { class: "hint keys-hint" },
    "Keys: Space plays or pauses, ←/→ step a frame, Shift+←/→ a second, Home/End, +/− zoom, [ and ] set the span's start and end at the playhead.",
  );
  take.load().then(() => {
    if (!figure.track) {
      timeline.node.hidden = true;
      keysHint.hidden = true;
      previewNote.textContent =
        figure.error && figure.error.code === "no_stored_file"
          ? "Synthetic clip: no preview (it has no stored file)."
          : `No preview: ${figure.error ? figure.error.message || figure.error : "unknown error"}`;
      return;
    }
    // The readout counts the file's own frames; the preview leaves out the lead-in frames.
    timeline.setLength(take.duration, {
      fps: take.fileFps,
      frameCount: clip.frame_count,
      firstFrame: clip.lead_in_frames,
    });
    previewNote.textContent = clip.lead_in_frames ? `Preview: the first ${plural(clip.lead_in_frames, "rest-pose frame")} left out.` : "";
    showSpan();
    if (!player.range) timeline.setPlaying(true);
  });

  // -- a span of the clip: drag on the band under the timeline, type it, or press [ and ] -------
  // Times in the form are seconds of the file as uploaded (lead-in included), like the API's;
  // the preview leaves the lead-in out, so its time is shifted by it.
  const leadIn = clip.lead_in_frames * clip.frame_time;
  const spanBox = el("div", { class: "span-box", hidden: true });
  const spanBand = el("div", { class: "span-band", title: "Drag across to pick a span of the clip" }, spanBox);
  timeline.track.append(spanBand);
  const spanIds = { start: nextId("span-start"), end: nextId("span-end"), loop: nextId("span-loop") };
  const step = "any"; // a frame-time step would make most typed times "invalid"
  const spanStart = el("input", { id: spanIds.start, type: "number", min: "0", step, required: true, inputmode: "decimal" });
  const spanEnd = el("input", { id: spanIds.end, type: "number", min: "0", step, required: true, inputmode: "decimal" });
  const loopSpan = el("input", { id: spanIds.loop, type: "checkbox" });
  const spanForm = el(
    "form",
    { class: "span-form", "aria-label": "Find moments like a span of this clip" },
    el("p", { class: "hint" }, "Drag across the band under the timeline to pick a span (or type it, or press [ and ] at the playhead), then find where in the library the same motion happens."),
    el("div", { class: "field" }, el("label", { for: spanIds.start }, "From (s)"), spanStart),
    el("div", { class: "field" }, el("label", { for: spanIds.end }, "To (s)"), spanEnd),
    el("div", { class: "field check" }, loopSpan, el("label", { for: spanIds.loop }, "Play only the span")),
    el("div", { class: "field" }, el("button", { type: "submit" }, "Find moments like this span")),
  );
  const spanValues = () => [Number.parseFloat(spanStart.value), Number.parseFloat(spanEnd.value)];
  function showSpan() {
    const [from, to] = spanValues();
    const valid = Number.isFinite(from) && Number.isFinite(to) && to > from;
    const width = timeline.rail.clientWidth;
    const left = Math.max(0, timeline.xAt(from - leadIn));
    const right = Math.min(width, timeline.xAt(to - leadIn));
    spanBox.hidden = !valid || right < 0 || left > width || right <= left;
    spanBox.style.left = `${left}px`;
    spanBox.style.width = `${Math.max(2, right - left)}px`;
    spanBox.dataset.start = valid ? String(from) : "";
    spanBox.dataset.end = valid ? String(to) : "";
  }
  timeline.onView(showSpan);
  /** Play only the span when asked (and it is one), else the whole take. */
  function previewSpan() {
    const [from, to] = spanValues();
    const valid = Number.isFinite(from) && Number.isFinite(to) && to > from;
    player.setRange(loopSpan.checked && valid ? [Math.max(0, from - leadIn), Math.max(0, to - leadIn)] : null);
  }
  player.onChange(() => {
    if (!player.range && loopSpan.checked) loopSpan.checked = false; // the user went elsewhere
  });
  const round = (t) => Math.round(t * 1000) / 1000;
  /** A span picked (the times of the file): shown, and played in a loop to check it. */
  function pick(from, to) {
    spanStart.value = Number.isFinite(from) ? String(round(from)) : "";
    spanEnd.value = Number.isFinite(to) ? String(round(to)) : "";
    showSpan();
    if (Number.isFinite(from) && Number.isFinite(to) && to > from) {
      loopSpan.checked = true;
      previewSpan();
      player.setPlaying(true);
    }
  }
  let dragFrom = null;
  spanBand.addEventListener("pointerdown", (event) => {
    if (!timeline.duration || event.button !== 0) return;
    dragFrom = timeline.timeAt(event.clientX);
    spanBand.setPointerCapture(event.pointerId);
    event.preventDefault();
  });
  spanBand.addEventListener("pointermove", (event) => {
    if (dragFrom === null) return;
    const at = timeline.timeAt(event.clientX);
    const [a, b] = [Math.min(dragFrom, at), Math.max(dragFrom, at)];
    spanStart.value = String(round(a + leadIn));
    spanEnd.value = String(round(b + leadIn));
    showSpan();
  });
  const endDrag = () => {
    if (dragFrom === null) return;
    dragFrom = null;
    const [from, to] = spanValues();
    pick(from, to); // the figure plays the span picked, so it can be checked before searching
  };
  spanBand.addEventListener("pointerup", endDrag);
  spanBand.addEventListener("pointercancel", endDrag);
  for (const input of [spanStart, spanEnd]) {
    input.addEventListener("input", () => {
      showSpan();
      if (loopSpan.checked) previewSpan();
    });
  }
  loopSpan.addEventListener("change", previewSpan);
  const here = () => round(player.time + leadIn);
  const unbindKeys = timeline.bindKeys(document, {
    "[": () => {
      const [, to] = spanValues();
      pick(here(), Number.isFinite(to) && to > here() ? to : NaN);
    },
    "]": () => {
      const [from] = spanValues();
      pick(Number.isFinite(from) && from < here() ? from : NaN, here());
    },
  });
  spanForm.addEventListener("submit", (event) => {
    event.preventDefault();
    const [start, end] = spanValues();
    if (!(end > start)) {
      actionStatus.textContent = "Pick a span: its end must come after its start.";
      spanEnd.focus();
      return;
    }
    navigate("search", { clip: clip.id, mode: "moments", start: String(start), end: String(end) });
  });

  // -- facts -----------------------------------------------------------------------------------
  const fps = clip.frame_time > 0 ? 1 / clip.frame_time : NaN;
  const facts = [
    ["Format", formatBadge(clip.format)],
    ["Files", el("ul", { class: "plain" }, clip.filenames.map((name) => el("li", { class: "filename" }, name)))],
    ["Frames", clip.frame_count.toLocaleString("en")],
    ["Frame rate", Number.isFinite(fps) ? `${fps.toFixed(fps % 1 < 0.01 || fps % 1 > 0.99 ? 0 : 2)} fps` : "–"],
    ["Duration", formatTime(clip.duration)],
    ["Joints", String(clip.joint_count)],
    ["Skeleton family", clip.skeleton_family],
    ["Lead-in frames", `${clip.lead_in_frames}${clip.lead_in_frames ? " (rest pose, left out of the descriptors)" : ""}`],
    ["Labels", labelChips(clip.labels)],
    ["Source", clip.source || el("span", { class: "muted" }, "not given")],
    ["Licence", clip.licence || el("span", { class: "muted" }, "not given")],
    ["Stored", `${clip.created_at.replace("T", " ").replace(/(:\d\d)(\.\d+)?(Z|[+-]00:00)$/, "$1")} UTC`],
    ["Content hash", el("code", { class: "hash", title: clip.content_hash }, clip.content_hash)],
  ];
  const factList = el(
    "dl",
    { class: "facts" },
    facts.map(([term, value]) => [el("dt", {}, term), el("dd", { dataset: { fact: term.toLowerCase().replace(/\s+/g, "-") } }, value)]),
  );
  const warnings = Array.isArray(clip.warnings) && clip.warnings.length
    ? el(
        "section",
        { class: "clip-warnings", "aria-labelledby": "warnings-head" },
        el("h2", { id: "warnings-head" }, "Reading warnings"),
        el("ul", {}, clip.warnings.map((text) => el("li", {}, text))),
      )
    : null;
  const mapping = mappingSection(clip.mapping);

  // -- actions ---------------------------------------------------------------------------------
  const actionStatus = el("p", { class: "status", role: "status", "aria-live": "polite" });
  const keyArea = el("div", { class: "key-area" });
  const downloads = el("div", { class: "downloads" });
  const addDownload = (text, params, hint) => {
    const button = el("button", { type: "button", class: "secondary", title: hint }, text);
    button.addEventListener("click", async () => {
      try {
        const name = await download(`/clips/${clip.id}/file`, params);
        actionStatus.textContent = `Downloaded ${name}.`;
      } catch (error) {
        if (error.status !== 401 && error.status !== 403) actionStatus.textContent = `Download failed: ${error.detail || error.message}`;
      }
    });
    downloads.append(button);
  };
  if (!clip.filenames.length) {
    downloads.append(el("p", { class: "muted" }, "Synthetic clip: no stored file to download."));
  } else if (clip.filenames.length === 1) {
    addDownload(`Download ${clip.filenames[0]}`, null, "The uploaded file, byte for byte");
    if (clip.format !== "bvh") addDownload("Download as BVH", { format: "bvh" }, "The clip as a BVH file of its own skeleton");
  } else {
    addDownload("Download all (ZIP)", null, "Both uploaded files in one ZIP");
    for (const role of ["skeleton", "motion"]) {
      const name = clip.filenames[role === "skeleton" ? 0 : 1];
      if (name) addDownload(`Download ${name}`, { part: role }, `The ${role} file, byte for byte`);
    }
    addDownload("Download as BVH", { format: "bvh" }, "The clip as a BVH file of its own skeleton");
  }

  const form = editForm(clip);
  const deleteButton = el("button", { type: "button", class: "danger" }, "Delete clip…");
  const dialog = confirmDialog(clip);

  const asking = (error) => error instanceof ApiError && (error.status === 401 || error.status === 403);

  /** Run `action`; on 401/403 ask for the key next to the buttons and run it again. */
  async function withKey(action, what) {
    try {
      return await action();
    } catch (error) {
      if (!asking(error)) throw error;
      const key = await askForKey(keyArea, error, what);
      if (key === null) return undefined;
      return withKey(action, what);
    }
  }

  form.node.addEventListener("submit", async (event) => {
    event.preventDefault();
    actionStatus.textContent = "Saving…";
    try {
      const saved = await withKey(
        () => sendJson("PATCH", `/clips/${clip.id}`, form.changes(), { quietAuth: true }),
        "save the changes",
      );
      if (saved === undefined) {
        actionStatus.textContent = "Not saved.";
        return;
      }
      notify(`Saved the changes to clip #${clip.id}.`);
      navigate("clip", { id: clip.id }, { replace: true });
    } catch (error) {
      actionStatus.textContent = `Not saved: ${error.detail || error.message}`;
    }
  });

  deleteButton.addEventListener("click", () => dialog.node.showModal());
  dialog.onConfirm(async () => {
    actionStatus.textContent = "Deleting…";
    try {
      const done = await withKey(
        () => sendJson("DELETE", `/clips/${clip.id}`, undefined, { quietAuth: true }),
        "delete the clip",
      );
      if (done === undefined) {
        actionStatus.textContent = "Not deleted.";
        return;
      }
      notify(`Deleted clip #${clip.id} “${clip.name}”.`);
      navigate("library", {});
    } catch (error) {
      actionStatus.textContent = `Not deleted: ${error.detail || error.message}`;
    }
  });

  main.append(
    ...[
    el(
      "div",
      { class: "view-head clip-head" },
      el("h1", { class: "clip-title" }, clip.name, " ", formatBadge(clip.format)),
      el("a", { class: "button", href: `#/search?clip=${clip.id}`, "aria-label": `Find clips similar to ${clip.name}` }, "Find similar"),
    ),
    el(
      "div",
      { class: "clip-layout" },
      el("section", { class: "clip-preview", "aria-label": "Preview" }, canvas, timeline.node, previewNote, keysHint, clip.filenames.length ? spanForm : null),
      el("section", { class: "clip-facts", "aria-labelledby": "facts-head" }, el("h2", { id: "facts-head" }, "About this clip"), factList),
    ),
    warnings,
    mapping,
    el(
      "section",
      { class: "clip-actions", "aria-labelledby": "actions-head" },
      el("h2", { id: "actions-head" }, "Download, change or delete"),
      downloads,
      form.node,
      el("div", { class: "danger-zone" }, deleteButton),
      keyArea,
      actionStatus,
    ),
    dialog.node,
    ].filter(Boolean), // no section for facts the clip does not have
  );

  return () => {
    unbindKeys();
    timeline.dispose();
    figure.dispose();
    player.dispose();
    if (dialog.node.open) dialog.node.close();
  };
}

/**
 * How the skeleton was mapped, when the clip JSON has it (`?include=mapping`):
 * `{joints: {canonical: {joint, how}}, end_sites: [...], pose, mirrored}`.
 */
function mappingSection(mapping) {
  if (!mapping || typeof mapping !== "object" || !mapping.joints) return null;
  const rows = Object.entries(mapping.joints);
  if (!rows.length) return null;
  const notes = [];
  if (mapping.pose) notes.push(`Read from ${mapping.pose}.`);
  if (mapping.mirrored) notes.push("The capture was mirrored and is stored un-mirrored.");
  if (Array.isArray(mapping.end_sites) && mapping.end_sites.length) notes.push(`End effectors: ${mapping.end_sites.join(", ")}.`);
  return el(
    "section",
    { class: "clip-mapping", "aria-labelledby": "mapping-head" },
    el("h2", { id: "mapping-head" }, "How the skeleton's joints were mapped"),
    notes.length ? el("p", { class: "hint" }, notes.join(" ")) : null,
    el(
      "table",
      {},
      el(
        "thead",
        {},
        el("tr", {}, el("th", { scope: "col" }, "Canonical joint"), el("th", { scope: "col" }, "Joint in the file"), el("th", { scope: "col" }, "Found by")),
      ),
      el(
        "tbody",
        {},
        rows.map(([canonical, found]) =>
          el("tr", {}, el("th", { scope: "row" }, canonical), el("td", {}, (found && found.joint) || "—"), el("td", {}, (found && found.how) || "")),
        ),
      ),
    ),
  );
}

function editForm(clip) {
  const ids = { name: nextId("name"), labels: nextId("labels"), source: nextId("source"), licence: nextId("licence") };
  const name = el("input", { id: ids.name, type: "text", value: clip.name, required: true, maxlength: "255", autocomplete: "off" });
  const labels = el("input", { id: ids.labels, type: "text", value: clip.labels.join(", "), autocomplete: "off", placeholder: "e.g. walk, happy" });
  const source = el("input", { id: ids.source, type: "text", value: clip.source || "", maxlength: "500", autocomplete: "off", placeholder: "where it comes from" });
  const licence = el("input", { id: ids.licence, type: "text", value: clip.licence || "", maxlength: "500", autocomplete: "off", placeholder: "e.g. CC BY 4.0" });
  const node = el(
    "form",
    { class: "filters edit-form", "aria-label": "Change the clip" },
    el("div", { class: "field wide" }, el("label", { for: ids.name }, "Name"), name),
    el("div", { class: "field wide" }, el("label", { for: ids.labels }, "Labels (comma-separated)"), labels),
    el("div", { class: "field wide" }, el("label", { for: ids.source }, "Source"), source),
    el("div", { class: "field wide" }, el("label", { for: ids.licence }, "Licence"), licence),
    el("div", { class: "field" }, el("button", { type: "submit" }, "Save changes")),
  );
  return {
    node,
    changes: () => ({
      name: name.value.trim() || clip.name,
      labels: labels.value.split(","),
      source: source.value.trim() || null,
      licence: licence.value.trim() || null,
    }),
  };
}

function confirmDialog(clip) {
  const headingId = nextId("confirm");
  let confirmed = null;
  const yes = el("button", { type: "button", class: "danger" }, "Delete");
  const no = el("button", { type: "button", class: "secondary", autofocus: true }, "Cancel");
  const node = el(
    "dialog",
    { class: "confirm", "aria-labelledby": headingId },
    el("h2", { id: headingId }, `Delete “${clip.name}”?`),
    el("p", {}, `Clip #${clip.id} (${clip.filenames.join(", ") || clip.format}), its descriptor vectors and its stored files are removed. This cannot be undone.`),
    el("div", { class: "dialog-buttons" }, no, yes),
  );
  no.addEventListener("click", () => node.close());
  yes.addEventListener("click", () => {
    node.close();
    if (confirmed) confirmed();
  });
  return { node, onConfirm: (fn) => (confirmed = fn) };
}

/** Ask for the API key in `area`; resolves to the key, or null when the user gives up. */
function askForKey(area, error, what) {
  return new Promise((resolve) => {
    const inputId = nextId("clip-key");
    const input = el("input", { id: inputId, type: "password", autocomplete: "off", value: apiKey() });
    const reason = error.status === 401 ? `The service needs an API key to ${what}.` : `The API key was refused (${error.detail}); another key is needed to ${what}.`;
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
      setApiKey(input.value.trim());
      done(input.value.trim());
    });
    clear(area);
    area.append(form);
    input.focus();
  });
}
