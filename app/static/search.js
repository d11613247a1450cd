// Search: a stored clip (or a dropped file) as the query, its k nearest clips under a
// descriptor, all animated side by side on one clock; click a result to search from it.
// In "moments" mode the results are spans of clips (GET/POST /search/moments): each plays
// only its span, with a thin timeline showing where in its clip it lies.

import { clipForm, descriptors, download as downloadFile, fileAnimations, getJson, labels as fetchLabels, mayHoldAnimations, postForm } from "./api.js";
import { formatBadge } from "./clip.js";
import { Figure, Player } from "./figure.js";
import { Timeline } from "./timeline.js";
import { ACCEPT, dropTarget, groupFiles } from "./upload.js";
import { clear, debounce, el, formatNumber, formatSeconds, labelChips, nextId, plural } from "./util.js";

const PREVIEW = { fps: 30, maxFrames: 600 };
const MOMENT_DESCRIPTOR = "motion";

function nearestPhrase(count) {
  return count === 1 ? "The clip nearest to" : `The ${count} clips nearest to`;
}
const DEFAULT_K = 8;
// Each result is an animated figure: more than this makes the page crawl. The API itself
// answers up to MOCAP_MAX_K (GET /search?k=...).
const MAX_K = 50;

export async function renderSearch(main, params, { navigate }) {
  const clipParam = Number.parseInt(params.get("clip") || "", 10);
  const askedK = Number.parseInt(params.get("k") || "", 10) || DEFAULT_K;
  const state = {
    clip: Number.isFinite(clipParam) ? clipParam : null,
    descriptor: params.get("descriptor") || "",
    k: Math.min(MAX_K, Math.max(1, askedK)),
    label: params.get("label") || "",
    mode: params.get("mode") === "moments" ? "moments" : "clips",
    start: params.get("start") ?? "",
    end: params.get("end") ?? "",
  };
  let capped = askedK > MAX_K; // say so rather than silently showing fewer

  const ids = {
    query: nextId("query"),
    options: nextId("clip-options"),
    file: nextId("query-file"),
    descriptor: nextId("descriptor"),
    descriptorHelp: nextId("descriptor-help"),
    k: nextId("k"),
    kHelp: nextId("k-help"),
    label: nextId("label"),
    mode: nextId("mode"),
    animation: nextId("animation"),
  };
  const modeButtons = ["clips", "moments"].map((value) =>
    el("input", { type: "radio", name: ids.mode, value, id: `${ids.mode}-${value}`, checked: state.mode === value }),
  );
  const modeSwitch = el(
    "fieldset",
    { class: "field mode-switch" },
    el("legend", {}, "Find"),
    ...modeButtons.flatMap((input) => [
      input,
      el("label", { for: input.id }, input.value === "clips" ? "whole clips" : "moments"),
    ]),
  );
  const queryInput = el("input", {
    id: ids.query,
    type: "search",
    list: ids.options,
    autocomplete: "off",
    placeholder: "type a clip name",
  });
  const options = el("datalist", { id: ids.options });
  const fileInput = el("input", { id: ids.file, type: "file", multiple: true, accept: ACCEPT });
  const descriptorSelect = el("select", { id: ids.descriptor, "aria-describedby": ids.descriptorHelp });
  const descriptorHelp = el("p", { id: ids.descriptorHelp, class: "hint" });
  const kInput = el("input", { id: ids.k, type: "number", min: "1", value: String(state.k), "aria-describedby": ids.kHelp });
  const kHelp = el("p", { id: ids.kHelp, class: "hint" }, `Results: 1–${MAX_K} on this page, as each one is animated; the API (GET /search?k=) gives more.`);
  const labelSelect = el("select", { id: ids.label }, el("option", { value: "" }, "Any"));
  const status = el("p", { class: "status", role: "status", "aria-live": "polite" });
  const progress = el("p", { class: "hint progress-note", "aria-live": "off" });
  // A dropped FBX/glTF file of several animations: which one to search with.
  const animationSelect = el("select", { id: ids.animation });
  const animationField = el(
    "div",
    { class: "field animation-field", hidden: true },
    el("label", { for: ids.animation }, "Animation of the file"),
    animationSelect,
  );
  const results = el("ol", { class: "cards results", "aria-label": "Query and nearest clips" });

  // Nothing plays until there are results to play.
  const player = new Player({ playing: false });
  const timeline = new Timeline(player, { label: "Playback" });
  const controls = timeline.node;
  controls.hidden = true;

  const form = el(
    "form",
    { class: "filters search-form", role: "search", "aria-label": "Search clips" },
    modeSwitch,
    el("div", { class: "field wide" }, el("label", { for: ids.query }, "Query clip"), queryInput, options),
    el("div", { class: "field" }, el("label", { for: ids.file }, "…or search with a file"), fileInput),
    animationField,
    el("div", { class: "field" }, el("label", { for: ids.descriptor }, "Descriptor"), descriptorSelect),
    el("div", { class: "field narrow" }, el("label", { for: ids.k }, "Results"), kInput),
    el("div", { class: "field" }, el("label", { for: ids.label }, "Only label"), labelSelect),
    el("div", { class: "field" }, el("button", { type: "submit" }, "Search")),
  );
  const dropHint = el(
    "p",
    { class: "hint drop-hint" },
    "Drop a motion file — BVH, FBX, glTF/GLB or VRMA, or an ASF skeleton with its AMC motion — anywhere on this page to search with it.",
  );
  main.append(el("div", { class: "view-head" }, el("h1", {}, "Search")), form, descriptorHelp, kHelp, dropHint, status, progress, controls, results);

  /** A status line; failures look like errors (red, announced at once). */
  function say(message) {
    status.textContent = message;
    status.classList.remove("error");
    status.setAttribute("role", "status");
  }
  function fail(message) {
    status.textContent = message;
    status.classList.add("error");
    status.setAttribute("role", "alert");
  }

  // -- form data ---------------------------------------------------------------------------
  const known = await descriptors();
  for (const d of known.descriptors) {
    descriptorSelect.append(el("option", { value: d.name }, `${d.name} (${d.dimension} numbers)`));
  }
  if (!known.descriptors.some((d) => d.name === state.descriptor)) state.descriptor = known.default;
  descriptorSelect.value = state.descriptor;
  // Moments are found with the motion descriptor only (its windows are what is stored):
  // in that mode the control says so and cannot be changed.
  const describe = () => {
    const moments = modeButtons.some((b) => b.checked && b.value === "moments");
    if (moments) {
      if (!descriptorSelect.disabled) descriptorSelect.dataset.chosen = descriptorSelect.value;
      descriptorSelect.value = MOMENT_DESCRIPTOR;
      descriptorSelect.disabled = true;
      descriptorHelp.textContent = `Moments are always found with the ${MOMENT_DESCRIPTOR} descriptor: its windows are what the library stores for moments.`;
      return;
    }
    if (descriptorSelect.disabled) {
      descriptorSelect.disabled = false;
      descriptorSelect.value = descriptorSelect.dataset.chosen || state.descriptor;
    }
    const d = known.descriptors.find((x) => x.name === descriptorSelect.value);
    descriptorHelp.textContent = d ? d.description : "";
  };
  describe();
  descriptorSelect.addEventListener("change", describe);
  for (const button of modeButtons) button.addEventListener("change", describe);

  fetchLabels()
    .then((rows) => {
      for (const { label, count } of rows) labelSelect.append(el("option", { value: label }, `${label} (${count})`));
      labelSelect.value = state.label;
    })
    .catch(() => {});

  const byOption = new Map(); // datalist text -> clip id
  const optionText = (clip) => `${clip.name} (#${clip.id})`;
  const suggest = debounce(async () => {
    const text = queryInput.value.trim();
    if (byOption.has(text)) return;
    try {
      const page = await getJson("/library/clips", { q: text.replace(/\s*\(#\d+\)$/, ""), limit: 20 });
      clear(options);
      for (const clip of page.items) {
        byOption.set(optionText(clip), clip.id);
        options.append(el("option", { value: optionText(clip) }));
      }
    } catch {
      // suggestions are a convenience
    }
  }, 200);
  queryInput.addEventListener("input", suggest);

  // -- playback ------------------------------------------------------------------------------
  const figures = [];
  const syncLoop = () => timeline.setLength(Math.max(0, ...figures.map((f) => f.duration)));
  const unbindKeys = timeline.bindKeys(document);

  /** Results are shown at once and each figure as its frames arrive (those on screen first):
   * say how many are still coming. */
  function track(loads) {
    let done = 0;
    const total = loads.length;
    const show = () => {
      progress.textContent = done < total ? `Loading previews: ${done} of ${plural(total, "figure")}…` : "";
    };
    show();
    for (const load of loads) {
      Promise.resolve(load).finally(() => {
        done += 1;
        show();
      });
    }
    return Promise.allSettled(loads).then(syncLoop);
  }

  function searchParams() {
    // The URL keeps the k asked for: the page shows at most MAX_K, and says so.
    const k = Math.max(1, Number.parseInt(kInput.value, 10) || DEFAULT_K);
    const params = { descriptor: state.descriptor, k, label: state.label };
    return state.mode === "moments" ? { ...params, mode: "moments" } : params;
  }

  function figureCard({ clipId, name, labels, detail, role, rank, format, filenames = [], family = "", span = null }) {
    const headingId = nextId("result");
    const canvas = el("canvas", {
      class: "figure",
      role: "img",
      "aria-label": `Animated stick figure of ${name}`,
      dataset: { role, clipId: clipId === null ? "" : String(clipId) },
    });
    const figure = new Figure(canvas, { player, clipId, name });
    figures.push(figure);
    // Same-named clips (one capture in several formats) differ by format and file names.
    const title = [name, filenames.join(", "), family && `skeleton ${family}`, clipId !== null && `clip #${clipId}`].filter(Boolean).join(" — ");
    const link =
      clipId === null
        ? el("span", {}, name)
        : el(
            "a",
            {
              href: `#/clips/${clipId}`,
              "aria-label": role === "query" ? `${name} (the query): details` : `${name}: details`,
            },
            name,
          );
    const node = el(
      "li",
      {
        class: `card ${role}`,
        dataset: { clipId: clipId === null ? "" : String(clipId), role },
      },
      el(
        "article",
        { "aria-labelledby": headingId },
        el("p", { class: "rank" }, role === "query" ? "Query" : `#${rank}`),
        canvas,
        el("h2", { id: headingId, class: "clip-name", title }, link),
        el(
          "p",
          { class: "meta format-line" },
          format ? formatBadge(format) : null,
          el("span", { class: "filenames" }, filenames.join(", ")),
          family ? el("span", { class: "family" }, `· ${family}`) : null,
          clipId !== null ? el("span", { class: "clip-id" }, `· #${clipId}`) : null,
        ),
        detail,
        labelChips(labels),
      ),
    );
    if (clipId !== null && role !== "query") {
      node.classList.add("clickable");
      node.addEventListener("click", (event) => {
        if (event.target.closest("a, button")) return;
        navigate("search", { clip: clipId, ...searchParams(), ...(span ? { start: span[0], end: span[1] } : {}) });
      });
    }
    return { node, figure };
  }

  function showResults(query, hits, queryFigureLoad) {
    for (const f of figures.splice(0)) f.dispose();
    clear(results);
    const q = figureCard({
      clipId: query.id ?? null,
      name: query.name,
      labels: query.labels,
      role: "query",
      format: query.format,
      filenames: query.filenames,
      family: query.skeleton_family,
      detail: el("p", { class: "meta" }, formatSeconds(query.duration)),
    });
    results.append(q.node);
    const loads = [queryFigureLoad(q.figure)];
    hits.forEach((hit, i) => {
      const card = figureCard({
        clipId: hit.id,
        name: hit.name,
        labels: hit.labels,
        role: "result",
        rank: i + 1,
        format: hit.format,
        filenames: hit.filenames,
        family: hit.skeleton_family,
        detail: el("p", { class: "meta distance" }, "distance ", el("strong", { class: "distance-value" }, formatNumber(hit.distance, 4))),
      });
      results.append(card.node);
      loads.push(card.figure.load(PREVIEW));
    });
    player.seek(0);
    controls.hidden = false;
    timeline.setPlaying(true);
    track(loads);
  }

  // -- moments ---------------------------------------------------------------------------------

  function spanBar(start, end, duration) {
    const whole = Math.max(duration, end, 1e-6);
    const bar = el("span", { class: "timeline-span" });
    bar.style.left = `${(100 * start) / whole}%`;
    bar.style.width = `${Math.max(0.5, (100 * (end - start)) / whole)}%`;
    return el(
      "div",
      { class: "moment-time" },
      el("div", { class: "moment-timeline", role: "img", "aria-label": `${formatSeconds(start)} to ${formatSeconds(end)} of ${formatSeconds(duration)}` }, bar),
      el("p", { class: "meta span-text" }, `${formatSeconds(start)} – ${formatSeconds(end)} of ${formatSeconds(duration)}`),
    );
  }

  /** A figure playing [start, end) seconds of its file: only those frames are fetched. */
  async function loadSpan(figure, start, end) {
    const length = Math.max(0.05, end - start);
    const fps = Math.max(0.5, Math.min(PREVIEW.fps, Math.floor((PREVIEW.maxFrames - 1) / length)));
    await figure.load({ fps, maxFrames: PREVIEW.maxFrames, start, end });
  }

  function showMoments(body, queryClip, queryLoad) {
    for (const f of figures.splice(0)) f.dispose();
    clear(results);
    const { start, end } = body.query;
    const q = figureCard({
      clipId: queryClip.id ?? null,
      name: queryClip.name,
      labels: queryClip.labels || [],
      role: "query",
      format: queryClip.format,
      filenames: queryClip.filenames || [],
      family: queryClip.skeleton_family || "",
      detail: spanBar(start, end, queryClip.duration),
    });
    results.append(q.node);
    const loads = [queryLoad(q.figure)];
    body.results.forEach((moment, i) => {
      const download = el(
        "a",
        {
          class: "button download",
          href: `/clips/${moment.id}/file?start=${moment.start}&end=${moment.end}`,
          download: "",
          "aria-label": `Download ${moment.name} from ${formatSeconds(moment.start)} to ${formatSeconds(moment.end)}`,
        },
        "Download",
      );
      // The link alone could not send the API key (a cut is heavy work, which may need it):
      // fetch the file with the key, as the clip page's buttons do.
      download.addEventListener("click", async (event) => {
        event.preventDefault();
        try {
          const name = await downloadFile(`/clips/${moment.id}/file`, { start: moment.start, end: moment.end });
          status.textContent = `Downloaded ${name}.`;
        } catch (error) {
          if (error.status !== 401 && error.status !== 403) status.textContent = `Download failed: ${error.detail || error.message}`;
        }
      });
      const holder = el("div", { class: "moment-detail" });
      const card = figureCard({
        clipId: moment.id,
        name: moment.name,
        labels: moment.labels,
        role: "result",
        rank: i + 1,
        format: moment.format,
        filenames: moment.filenames || [],
        family: moment.skeleton_family || "",
        span: [moment.start, moment.end],
        detail: el(
          "div",
          {},
          holder,
          el("p", { class: "meta distance" }, "distance ", el("strong", { class: "distance-value" }, formatNumber(moment.distance, 4))),
          download,
        ),
      });
      card.node.classList.add("moment");
      results.append(card.node);
      loads.push(
        getJson(`/clips/${moment.id}`).then((clip) => {
          holder.append(spanBar(moment.start, moment.end, clip.duration));
          return loadSpan(card.figure, moment.start, moment.end);
        }),
      );
    });
    player.seek(0);
    controls.hidden = false;
    timeline.setPlaying(true);
    track(loads);
  }

  async function searchMoments(clipId) {
    say("Searching moments…");
    try {
      const body = await getJson("/search/moments", {
        clip: clipId,
        k: state.k,
        label: state.label,
        start: state.start,
        end: state.end,
        descriptor: MOMENT_DESCRIPTOR,
      });
      const clip = body.query.clip;
      queryInput.value = optionText(clip);
      byOption.set(queryInput.value, clip.id);
      showMoments(body, clip, (figure) => loadSpan(figure, body.query.start, body.query.end));
      say(
        body.results.length
          ? `Moments like ${formatSeconds(body.query.start)} – ${formatSeconds(body.query.end)} of ${clip.name}, nearest first.`
          : `No moment like this one${state.label ? ` under the label ${state.label}` : ""}.`,
      );
    } catch (error) {
      clear(results);
      fail(`Search failed: ${error.detail || error.message}`);
    }
  }

  async function searchClip(clipId) {
    if (state.mode === "moments") return searchMoments(clipId);
    say("Searching…");
    try {
      const body = await getJson("/search", {
        clip: clipId,
        descriptor: state.descriptor,
        k: state.k,
        label: state.label,
      });
      queryInput.value = optionText(body.query);
      byOption.set(queryInput.value, body.query.id);
      showResults(body.query, body.results, (figure) => figure.load(PREVIEW));
      say(
        body.results.length
          ? `${nearestPhrase(body.results.length)} ${body.query.name} under ${body.descriptor}, nearest first.${cappedNote()}`
          : `No other clip to compare ${body.query.name} with${state.label ? ` under the label ${state.label}` : ""}.`,
      );
    } catch (error) {
      clear(results);
      fail(`Search failed: ${error.detail || error.message}`);
    }
  }

  let droppedItem = null; // the file searched with, searched again with another animation

  async function searchFile(files) {
    const items = groupFiles(files, new Map()).filter((item) => !item.note);
    if (items.length !== 1 || items[0].error) {
      fail(items.length === 1 ? items[0].error : "Drop one clip: one motion file, or one .asf with one .amc.");
      return;
    }
    const item = items[0];
    animationField.hidden = true;
    if (mayHoldAnimations(item)) {
      say(`Reading the animations of ${item.name}…`);
      let animations;
      try {
        animations = await fileAnimations(item);
      } catch (error) {
        clear(results);
        fail(`Cannot search with ${item.name}: ${error.detail || error.message}`);
        return;
      }
      if (animations.length > 1) {
        clear(animationSelect);
        for (const a of animations) {
          animationSelect.append(el("option", { value: a.name, selected: a.selected }, `${a.name} (${formatSeconds(a.duration)})`));
        }
        animationField.hidden = false;
        item.animation = animationSelect.value;
      }
    }
    droppedItem = item;
    await searchItem(item);
  }

  animationSelect.addEventListener("change", () => {
    if (!droppedItem) return;
    droppedItem.animation = animationSelect.value;
    readForm();
    searchItem(droppedItem);
  });

  async function searchItem(item) {
    const what = item.animation ? `${item.name} · ${item.animation}` : item.name;
    say(`Searching with ${what}…`);
    const query = { descriptor: state.descriptor, k: state.k, label: state.label };
    const preview = () =>
      postForm("/skeleton", { fps: PREVIEW.fps, max_frames: PREVIEW.maxFrames, encoding: "compact" }, clipForm(item));
    if (state.mode === "moments") {
      try {
        const { body } = await postForm("/search/moments", { ...query, descriptor: MOMENT_DESCRIPTOR }, clipForm(item));
        const skeleton = preview();
        const uploaded = { id: null, name: what, labels: [], duration: body.query.end };
        showMoments(body, uploaded, (figure) =>
          skeleton.then(({ body: answer }) => figure.setSkeleton(answer), (error) => figure.setError(error)),
        );
        say(`Moments like the file ${what}, nearest first.`);
      } catch (error) {
        clear(results);
        fail(`Search with ${what} failed: ${error.detail || error.message}`);
      }
      return;
    }
    try {
      const { body } = await postForm("/search", query, clipForm(item));
      const skeleton = preview();
      showResults({ ...body.query, id: null }, body.results, (figure) =>
        skeleton.then(({ body: answer }) => figure.setSkeleton(answer), (error) => figure.setError(error)),
      );
      say(`${nearestPhrase(body.results.length)} the file ${what} under ${body.descriptor}, nearest first.${cappedNote()}`);
    } catch (error) {
      clear(results);
      fail(`Search with ${what} failed: ${error.detail || error.message}`);
    }
  }

  function cappedNote() {
    return capped ? ` (At most ${MAX_K} here, each animated: GET /search?k= gives more.)` : "";
  }

  function readForm() {
    if (!descriptorSelect.disabled) state.descriptor = descriptorSelect.value;
    const asked = Number.parseInt(kInput.value, 10) || DEFAULT_K;
    capped = asked > MAX_K;
    state.k = Math.min(MAX_K, Math.max(1, asked));
    state.label = labelSelect.value;
    const mode = modeButtons.find((b) => b.checked);
    if (mode && mode.value !== state.mode) {
      state.mode = mode.value;
      state.start = "";
      state.end = "";
    }
  }

  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    readForm();
    if (fileInput.files.length) {
      const files = [...fileInput.files];
      fileInput.value = "";
      await searchFile(files);
      return;
    }
    const text = queryInput.value.trim();
    let clipId = byOption.get(text);
    const typed = /#(\d+)\)?$/.exec(text);
    if (clipId === undefined && typed) clipId = Number(typed[1]);
    if (clipId === undefined && text) {
      const page = await getJson("/library/clips", { q: text, limit: 2 }).catch(() => null);
      if (page && page.total === 1) clipId = page.items[0].id;
      else {
        fail(page && page.total > 1 ? `Several clips match “${text}”: pick one from the list.` : `No clip is named like “${text}”.`);
        return;
      }
    }
    if (clipId === undefined) {
      fail("Pick a query clip, or choose a file.");
      queryInput.focus();
      return;
    }
    const span = state.mode === "moments" && state.start !== "" ? { start: state.start, end: state.end } : {};
    navigate("search", { clip: clipId, ...searchParams(), ...span });
  });
  fileInput.addEventListener("change", () => {
    if (fileInput.files.length) form.requestSubmit();
  });
  const stopDrops = dropTarget(main, (files) => {
    readForm();
    searchFile(files);
  }, "Drop to search with this file");

  if (state.clip !== null) {
    await searchClip(state.clip);
  } else {
    say("Pick a clip (type part of its name) or choose a file, then search.");
  }

  return () => {
    stopDrops();
    unbindKeys();
    timeline.dispose();
    for (const f of figures) f.dispose();
    player.dispose();
  };
}
