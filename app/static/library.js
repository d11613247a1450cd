// Library: clips a page at a time, filtered by name and label, each with a moving preview.

import { getJson, labels as fetchLabels } from "./api.js";
import { formatBadge } from "./clip.js";
import { Figure, libraryPlayer } from "./figure.js";
import { clear, debounce, el, formatSeconds, labelChips, nextId, plural } from "./util.js";

const PAGE_SIZE = 24;
export const PREVIEW = { fps: 15, maxFrames: 300 }; // small previews: 20 s at 15 fps

export async function renderLibrary(main, params) {
  const state = {
    q: params.get("q") || "",
    label: params.get("label") || "",
    page: Math.max(1, Number.parseInt(params.get("page") || "1", 10) || 1),
  };
  let request = 0;

  const nameId = nextId("q");
  const labelId = nextId("label");
  const nameInput = el("input", {
    id: nameId,
    type: "search",
    value: state.q,
    placeholder: "e.g. walk",
    autocomplete: "off",
  });
  const labelSelect = el("select", { id: labelId }, el("option", { value: "" }, "All labels"));
  const status = el("p", { class: "status", role: "status", "aria-live": "polite" }, "Loading…");
  const list = el("ul", { class: "cards", "aria-label": "Clips" });
  const pager = el("nav", { class: "pager", "aria-label": "Pages" });
  const form = el(
    "form",
    { class: "filters", role: "search", "aria-label": "Filter clips", onsubmit: (e) => e.preventDefault() },
    el("div", { class: "field" }, el("label", { for: nameId }, "Name contains"), nameInput),
    el("div", { class: "field" }, el("label", { for: labelId }, "Label"), labelSelect),
  );
  main.append(
    el("div", { class: "view-head" }, el("h1", {}, "Library"), el("a", { class: "button", href: "#/upload" }, "Upload clips")),
    form,
    status,
    list,
    pager,
  );

  fetchLabels()
    .then((rows) => {
      for (const { label, count } of rows) {
        labelSelect.append(el("option", { value: label }, `${label} (${count})`));
      }
      if (state.label && !rows.some((r) => r.label === state.label)) {
        labelSelect.append(el("option", { value: state.label }, state.label));
      }
      labelSelect.value = state.label;
    })
    .catch(() => {});

  function remember() {
    const query = new URLSearchParams();
    if (state.q) query.set("q", state.q);
    if (state.label) query.set("label", state.label);
    if (state.page > 1) query.set("page", String(state.page));
    const text = query.toString();
    history.replaceState(null, "", `#/library${text ? `?${text}` : ""}`);
  }

  async function load() {
    const mine = ++request;
    remember();
    status.textContent = "Loading…";
    let page;
    try {
      page = await getJson("/library/clips", {
        q: state.q,
        label: state.label,
        limit: PAGE_SIZE,
        offset: (state.page - 1) * PAGE_SIZE,
      });
    } catch (error) {
      if (mine === request) status.textContent = `Cannot list the clips: ${error.detail || error.message}`;
      return;
    }
    if (mine !== request) return;
    const pages = Math.max(1, Math.ceil(page.total / PAGE_SIZE));
    if (state.page > pages && page.total > 0) {
      state.page = pages;
      load();
      return;
    }
    clear(list);
    for (const clip of page.items) list.append(card(clip));
    const first = page.total ? page.offset + 1 : 0;
    const lastShown = page.offset + page.items.length;
    const filtered = state.q || state.label;
    status.textContent = page.total
      ? `Showing ${first}–${lastShown} of ${plural(page.total, filtered ? "matching clip" : "clip")}.`
      : filtered
        ? "No clip matches these filters."
        : "The library is empty: upload some clips.";
    renderPager(pages);
  }

  function renderPager(pages) {
    clear(pager);
    if (pages <= 1) return;
    const go = (page) => {
      state.page = page;
      load();
      list.scrollIntoView?.({ block: "start" });
    };
    pager.append(
      el("button", { type: "button", disabled: state.page <= 1, onclick: () => go(state.page - 1) }, "← Previous"),
      el("span", { class: "page-of", "aria-current": "page" }, `Page ${state.page} of ${pages}`),
      el("button", { type: "button", disabled: state.page >= pages, onclick: () => go(state.page + 1) }, "Next →"),
    );
  }

  const refilter = debounce(() => {
    state.q = nameInput.value.trim();
    state.page = 1;
    load();
  }, 250);
  nameInput.addEventListener("input", refilter);
  labelSelect.addEventListener("change", () => {
    state.label = labelSelect.value;
    state.page = 1;
    load();
  });
  libraryPlayer.setPlaying(true);
  await load();
}

/** One clip as a card with an animated preview. */
export function card(clip) {
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
  return el(
    "li",
    { class: "card", dataset: { clipId: String(clip.id) } },
    el(
      "article",
      { "aria-labelledby": headingId },
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
      labelChips(clip.labels),
      el(
        "a",
        { class: "button small", href: `#/search?clip=${clip.id}`, "aria-label": `Find clips similar to ${clip.name}` },
        "Find similar",
      ),
    ),
  );
}
