// Library: clips a page at a time, each with a moving preview; one search box over names, file
// names, labels, source and licence (GET /clips?q=), label and licence filters, an order, a
// page jump. Cards can be selected (click, shift-click a range, the whole page, everything that
// matches) to add or remove labels (POST /clips/labels) or delete them (DELETE /clips).

import { getJson, labels as fetchLabels, sendJson } from "./api.js";
import { formatBadge } from "./clip.js";
import { Figure, libraryPlayer } from "./figure.js";
import { licenceFilter } from "./filters.js";
import { withKey } from "./keys.js";
import { clear, debounce, deleteDialog, el, formatSeconds, labelChips, nextId, plural } from "./util.js";

const PAGE_SIZE = 24;
export const PREVIEW = { fps: 15, maxFrames: 300 }; // small previews: 20 s at 15 fps

const SORTS = [
  ["id", "Order stored"],
  ["-created_at", "Newest first"],
  ["created_at", "Oldest first"],
  ["name", "Name A–Z"],
  ["-name", "Name Z–A"],
  ["-duration", "Longest first"],
  ["duration", "Shortest first"],
  ["-frame_count", "Most frames first"],
  ["frame_count", "Fewest frames first"],
];

const splitLabels = (text) => text.split(",").map((s) => s.trim()).filter(Boolean);

export async function renderLibrary(main, params) {
  const askedSort = params.get("sort") || "id";
  const state = {
    q: params.get("q") || "",
    label: params.get("label") || "",
    licence: params.get("licence") || "",
    sort: SORTS.some(([v]) => v === askedSort) ? askedSort : "id",
    page: Math.max(1, Number.parseInt(params.get("page") || "1", 10) || 1),
  };
  let request = 0;
  let lastPage = null; // the answer shown: {total, items}

  // -- the selection: ids picked card by card, or every clip the filters match ---------------
  const selection = { ids: new Set(), all: false, anchor: null };

  const ids = { q: nextId("q"), label: nextId("label"), sort: nextId("sort"), add: nextId("add"), remove: nextId("remove"), jump: nextId("page") };
  const textInput = el("input", {
    id: ids.q,
    type: "search",
    value: state.q,
    placeholder: "name, file, label, source or licence",
    autocomplete: "off",
  });
  const labelSelect = el("select", { id: ids.label }, el("option", { value: "" }, "All labels"));
  const licence = licenceFilter(state.licence);
  const sortSelect = el("select", { id: ids.sort }, SORTS.map(([v, text]) => el("option", { value: v }, text)));
  sortSelect.value = state.sort;
  const status = el("p", { class: "status", role: "status", "aria-live": "polite" }, "Loading…");
  const list = el("ul", { class: "cards", "aria-label": "Clips" });
  const pager = el("nav", { class: "pager", "aria-label": "Pages" });
  const form = el(
    "form",
    { class: "filters", role: "search", "aria-label": "Filter clips", onsubmit: (e) => e.preventDefault() },
    el(
      "div",
      { class: "field wide" },
      el("label", { for: ids.q }, "Find"),
      textInput,
    ),
    el("div", { class: "field" }, el("label", { for: ids.label }, "Label"), labelSelect),
    licence.node,
    el("div", { class: "field" }, el("label", { for: ids.sort }, "Order"), sortSelect),
  );

  // The bulk bar: what is selected and what to do with it.
  const selectedText = el("p", { class: "selected-count", role: "status", "aria-live": "polite" });
  const selectPage = el("button", { type: "button", class: "secondary small" }, "Select this page");
  const selectAll = el("button", { type: "button", class: "secondary small" }, "Select all matching");
  const clearSelection = el("button", { type: "button", class: "secondary small" }, "Clear selection");
  const addInput = el("input", { id: ids.add, type: "text", autocomplete: "off", placeholder: "e.g. walk, mine" });
  const removeInput = el("input", { id: ids.remove, type: "text", autocomplete: "off", placeholder: "e.g. todo" });
  const applyLabels = el("button", { type: "submit", class: "small" }, "Change labels");
  const deleteButton = el("button", { type: "button", class: "danger small" }, "Delete…");
  const keyArea = el("div", { class: "key-area" });
  const bulkStatus = el("p", { class: "bulk-status", role: "status", "aria-live": "polite" });
  const labelForm = el(
    "form",
    { class: "bulk-labels", "aria-label": "Change the labels of the selected clips" },
    el("div", { class: "field" }, el("label", { for: ids.add }, "Add labels"), addInput),
    el("div", { class: "field" }, el("label", { for: ids.remove }, "Remove labels"), removeInput),
    el("div", { class: "bulk-actions" }, applyLabels, deleteButton),
  );
  const bulk = el(
    "section",
    { class: "bulk-bar", "aria-label": "Selected clips" },
    el("div", { class: "bulk-select" }, selectedText, selectPage, selectAll, clearSelection),
    labelForm,
    keyArea,
    bulkStatus,
  );
  const confirm = confirmDialog();

  main.append(
    el("div", { class: "view-head" }, el("h1", {}, "Library"), el("a", { class: "button", href: "#/upload" }, "Upload clips")),
    form,
    bulk,
    status,
    list,
    pager,
    confirm.node,
  );

  function fillLabels() {
    return fetchLabels()
      .then((rows) => {
        clear(labelSelect);
        labelSelect.append(el("option", { value: "" }, "All labels"));
        for (const { label, count } of rows) labelSelect.append(el("option", { value: label }, `${label} (${count})`));
        if (state.label && !rows.some((r) => r.label === state.label)) labelSelect.append(el("option", { value: state.label }, state.label));
        labelSelect.value = state.label;
      })
      .catch(() => {});
  }
  fillLabels();

  /** The filters as GET /clips, DELETE /clips and POST /clips/labels take them. */
  function filters() {
    return { q: state.q, label: state.label, licence: state.licence };
  }
  const filtered = () => Boolean(state.q || state.label || state.licence);

  function remember() {
    const query = new URLSearchParams();
    if (state.q) query.set("q", state.q);
    if (state.label) query.set("label", state.label);
    if (state.licence) query.set("licence", state.licence);
    if (state.sort !== "id") query.set("sort", state.sort);
    if (state.page > 1) query.set("page", String(state.page));
    const text = query.toString();
    history.replaceState(null, "", `#/library${text ? `?${text}` : ""}`);
  }

  async function load() {
    const mine = ++request;
    remember();
    status.textContent = "Loading…";
    status.classList.remove("error");
    let page;
    try {
      page = await getJson("/clips", {
        ...filters(),
        sort: state.sort,
        limit: PAGE_SIZE,
        offset: (state.page - 1) * PAGE_SIZE,
      });
    } catch (error) {
      if (mine === request) {
        status.textContent = `Cannot list the clips: ${error.detail || error.message}`;
        status.classList.add("error");
      }
      return;
    }
    if (mine !== request) return;
    const pages = Math.max(1, Math.ceil(page.total / PAGE_SIZE));
    if (state.page > pages && page.total > 0) {
      state.page = pages;
      load();
      return;
    }
    lastPage = page;
    clear(list);
    page.items.forEach((clip, i) => list.append(card(clip, { selectable: true, onSelect: (event) => pick(clip.id, i, event) })));
    const first = page.total ? page.offset + 1 : 0;
    const lastShown = page.offset + page.items.length;
    status.textContent = page.total
      ? `Showing ${first}–${lastShown} of ${plural(page.total, filtered() ? "matching clip" : "clip")}.`
      : filtered()
        ? "No clip matches these filters."
        : "The library is empty: upload some clips.";
    renderPager(pages);
    showSelection();
  }

  // -- selecting -------------------------------------------------------------------------------

  /** A card's box clicked: toggle it; with Shift, the range from the last one clicked. */
  function pick(id, index, event) {
    const box = event.currentTarget;
    const on = box.checked;
    const items = lastPage ? lastPage.items : [];
    if (event.shiftKey && selection.anchor !== null && selection.anchor < items.length) {
      const [a, b] = [Math.min(selection.anchor, index), Math.max(selection.anchor, index)];
      for (const clip of items.slice(a, b + 1)) {
        if (on) selection.ids.add(clip.id);
        else selection.ids.delete(clip.id);
      }
    } else if (on) selection.ids.add(id);
    else selection.ids.delete(id);
    selection.anchor = index;
    showSelection();
  }

  function showSelection() {
    const count = selection.all ? (lastPage ? lastPage.total : 0) : selection.ids.size;
    for (const node of list.querySelectorAll(".card")) {
      const id = Number(node.dataset.clipId);
      const on = selection.all || selection.ids.has(id);
      node.classList.toggle("selected", on);
      const box = node.querySelector(".select-box");
      box.checked = on;
      box.disabled = selection.all;
    }
    selectedText.textContent = selection.all
      ? `All ${plural(count, filtered() ? "matching clip" : "clip")} selected.`
      : count
        ? `${plural(count, "clip")} selected.`
        : "Tick clips to change their labels or delete them (Shift+click ticks a range).";
    bulk.classList.toggle("active", count > 0);
    labelForm.hidden = count === 0;
    for (const control of [addInput, removeInput, applyLabels, deleteButton]) control.disabled = count === 0;
    clearSelection.disabled = count === 0;
    selectAll.disabled = selection.all || !lastPage || lastPage.total === 0;
    selectAll.textContent = lastPage && lastPage.total ? `Select all ${lastPage.total.toLocaleString("en")} matching` : "Select all matching";
    selectPage.disabled = selection.all || !lastPage || !lastPage.items.length;
  }

  selectPage.addEventListener("click", () => {
    for (const clip of lastPage.items) selection.ids.add(clip.id);
    showSelection();
  });
  selectAll.addEventListener("click", () => {
    selection.all = true;
    showSelection();
  });
  function unselect() {
    selection.all = false;
    selection.ids.clear();
    selection.anchor = null;
    showSelection();
  }
  clearSelection.addEventListener("click", unselect);

  /** The selection as POST /clips/labels takes it. */
  function chosen() {
    if (!selection.all) return { ids: [...selection.ids] };
    if (!filtered()) return { all: true };
    const body = {};
    if (state.q) body.q = state.q;
    if (state.label) body.label = [state.label];
    if (state.licence) body.licence = [state.licence];
    return body;
  }

  function report(text, { error = false } = {}) {
    bulkStatus.textContent = text;
    bulkStatus.classList.toggle("error", error);
    bulkStatus.setAttribute("role", error ? "alert" : "status");
  }

  labelForm.addEventListener("submit", async (event) => {
    event.preventDefault();
    const add = splitLabels(addInput.value);
    const remove = splitLabels(removeInput.value);
    if (!add.length && !remove.length) {
      report("Type labels to add or to remove (comma-separated).", { error: true });
      addInput.focus();
      return;
    }
    report("Changing labels…");
    try {
      const done = await withKey(keyArea, () => sendJson("POST", "/clips/labels", { ...chosen(), add, remove }, { quietAuth: true }), "change labels");
      if (done === undefined) {
        report("Labels not changed.");
        return;
      }
      const parts = [];
      if (done.added.length) parts.push(`added ${done.added.join(", ")}`);
      if (done.removed.length) parts.push(`removed ${done.removed.join(", ")}`);
      report(`${parts.join(" and ")}: ${plural(done.changed, "clip")} changed of ${done.matched} selected.`.replace(/^./, (c) => c.toUpperCase()));
      addInput.value = "";
      removeInput.value = "";
      fillLabels();
      load();
    } catch (error) {
      report(`Labels not changed: ${error.detail || error.message}`, { error: true });
    }
  });

  /** DELETE /clips for the selection: its query (confirm added by the caller). */
  function deleteQuery() {
    if (!selection.all) return { id: [...selection.ids] };
    return { q: state.q, label: state.label, licence: state.licence };
  }

  deleteButton.addEventListener("click", async () => {
    if (selection.all && !filtered()) {
      report("Deleting every clip of the library is not done from here: filter the clips first, or tick them.", { error: true });
      return;
    }
    // Without confirm=true the service deletes nothing and says how many would go.
    report("Counting…");
    let count = null;
    try {
      const answer = await withKey(keyArea, () => sendJson("DELETE", "/clips", undefined, { params: deleteQuery(), quietAuth: true }), "delete clips");
      if (answer === undefined) {
        report("Nothing deleted.");
        return;
      }
    } catch (error) {
      const match = /would delete (\d+) clip/.exec(error.detail || "");
      if (!match) {
        report(`Cannot delete: ${error.detail || error.message}`, { error: true });
        return;
      }
      count = Number(match[1]);
    }
    report("");
    const names = selection.all ? [] : (lastPage ? lastPage.items : []).filter((c) => selection.ids.has(c.id)).map((c) => c.name);
    const yes = await confirm.ask(count, names, selection.all ? describeFilters() : "");
    if (!yes) return;
    report("Deleting…");
    try {
      const done = await withKey(
        keyArea,
        () => sendJson("DELETE", "/clips", undefined, { params: { ...deleteQuery(), confirm: "true" }, quietAuth: true }),
        "delete clips",
      );
      if (done === undefined) {
        report("Nothing deleted.");
        return;
      }
      unselect();
      report(`Deleted ${plural(done.deleted, "clip")}.`);
      fillLabels();
      load();
    } catch (error) {
      report(`Not deleted: ${error.detail || error.message}`, { error: true });
    }
  });

  function describeFilters() {
    const parts = [];
    if (state.q) parts.push(`holding “${state.q}”`);
    if (state.label) parts.push(`labelled ${state.label}`);
    if (state.licence) parts.push(state.licence.startsWith("!") ? `not under ${state.licence.slice(1)}` : `under ${state.licence}`);
    return `Every clip ${parts.join(", ")}.`;
  }

  // -- pages -----------------------------------------------------------------------------------

  function renderPager(pages) {
    clear(pager);
    if (pages <= 1) return;
    const go = (page) => {
      state.page = Math.min(pages, Math.max(1, page));
      load();
      list.scrollIntoView?.({ block: "start" });
    };
    const jump = el("input", { id: ids.jump, type: "number", min: "1", max: String(pages), value: String(state.page), inputmode: "numeric", class: "page-input" });
    const jumpForm = el(
      "form",
      { class: "page-jump", "aria-label": "Go to a page" },
      el("label", { for: ids.jump }, "Page"),
      jump,
      el("span", { class: "page-of", "aria-current": "page" }, `of ${pages}`),
      el("button", { type: "submit", class: "secondary small" }, "Go"),
    );
    jumpForm.addEventListener("submit", (event) => {
      event.preventDefault();
      const page = Number.parseInt(jump.value, 10);
      if (Number.isFinite(page)) go(page);
    });
    pager.append(
      el("button", { type: "button", disabled: state.page <= 1, onclick: () => go(state.page - 1) }, "← Previous"),
      jumpForm,
      el("button", { type: "button", disabled: state.page >= pages, onclick: () => go(state.page + 1) }, "Next →"),
    );
  }

  // A new filter is a new set of clips: the selection starts again.
  function refilter() {
    state.page = 1;
    unselect();
    report("");
    load();
  }
  const retext = debounce(() => {
    state.q = textInput.value.trim();
    refilter();
  }, 250);
  textInput.addEventListener("input", retext);
  labelSelect.addEventListener("change", () => {
    state.label = labelSelect.value;
    refilter();
  });
  licence.onChange(() => {
    state.licence = licence.value();
    refilter();
  });
  sortSelect.addEventListener("change", () => {
    state.sort = sortSelect.value;
    state.page = 1;
    load();
  });
  libraryPlayer.setPlaying(true);
  showSelection();
  await load();
  return () => {
    if (confirm.node.open) confirm.node.close();
  };
}

/**
 * One clip as a card with an animated preview. `selectable`: a box to tick it, whose click
 * goes to `onSelect(event)`.
 */
export function card(clip, { selectable = false, onSelect = null } = {}) {
  const headingId = nextId("clip");
  const canvas = el("canvas", {
    class: "figure",
    role: "img",
    "aria-label": `Animated stick figure of ${clip.name}`,
    dataset: { clipId: String(clip.id), role: "library" },
  });
  const figure = new Figure(canvas, { player: libraryPlayer, clipId: clip.id, name: clip.name });
  figure.load(PREVIEW);
  const page = `#/clips/${clip.id}`;
  const title = `${clip.name} — ${clip.filenames.join(", ") || clip.format}`;
  const box = selectable ? el("input", { type: "checkbox", class: "select-box", "aria-label": `Select ${clip.name}`, onclick: onSelect }) : null;
  return el(
    "li",
    { class: "card", dataset: { clipId: String(clip.id) } },
    el(
      "article",
      { "aria-labelledby": headingId },
      box,
      // The figure opens the clip's page too (a link around it, skipped by the keyboard: the
      // name is the same link).
      el("a", { href: page, tabindex: "-1", "aria-hidden": "true", class: "figure-link" }, canvas),
      el("h2", { id: headingId, class: "clip-name", title }, el("a", { href: page }, clip.name)),
      el(
        "p",
        { class: "meta" },
        formatBadge(clip.format),
        ` ${formatSeconds(clip.duration)} · ${plural(clip.frame_count, "frame")}`,
      ),
      clip.licence ? el("p", { class: "meta licence", title: clip.source || "" }, clip.licence) : null,
      labelChips(clip.labels),
      el(
        "a",
        { class: "button small", href: `#/search?clip=${clip.id}`, "aria-label": `Find clips similar to ${clip.name}` },
        "Find similar",
      ),
    ),
  );
}

/** "Delete N clips?": resolves to true when confirmed. */
function confirmDialog() {
  const dialog = deleteDialog();
  return {
    node: dialog.node,
    ask(count, list, what) {
      const shown = list.slice(0, 8);
      const more = shown.length && count > shown.length ? el("li", { class: "muted" }, `and ${count - shown.length} more`) : null;
      return dialog.ask(
        `Delete ${plural(count, "clip")}?`,
        el("p", {}, `${what ? `${what} ` : ""}Their descriptor vectors and stored files are removed too. This cannot be undone.`),
        el("ul", { class: "plain confirm-names" }, shown.map((name) => el("li", {}, name)), more),
      );
    },
  };
}
