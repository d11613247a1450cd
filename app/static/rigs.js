// Rigs, #/rigs: the characters' skeletons downloads can be retargeted onto (GET/POST/DELETE
// /rigs). Upload one (or take a stored clip's skeleton), see each drawn in its rest pose with
// the joints the mapper found, read its mapping, delete it.

import { getJson, postForm, sendJson } from "./api.js";
import { formatBadge } from "./clip.js";
import { RIG_ACCEPT, rigForm } from "./download.js";
import { withKey } from "./keys.js";
import { drawRig, jointAt } from "./rigfigure.js";
import { clear, deleteDialog, el, nextId, plural } from "./util.js";

export async function renderRigs(main) {
  const ids = { file: nextId("rig-file"), name: nextId("rig-name"), clip: nextId("rig-clip") };
  const fileInput = el("input", { id: ids.file, type: "file", multiple: true, accept: RIG_ACCEPT, required: true });
  const nameInput = el("input", { id: ids.name, type: "text", maxlength: "255", autocomplete: "off", placeholder: "default: the file's name" });
  const clipInput = el("input", { id: ids.clip, type: "number", min: "1", inputmode: "numeric", placeholder: "e.g. 7" });
  const keyArea = el("div", { class: "key-area" });
  const status = el("p", { class: "status", role: "status", "aria-live": "polite" });
  const list = el("ul", { class: "cards rigs", "aria-label": "Rigs" });
  const uploadForm = el(
    "form",
    { class: "filters rig-form", "aria-label": "Store a rig from a file" },
    el("div", { class: "field" }, el("label", { for: ids.file }, "Rig file (BVH, ASF, FBX, GLB/glTF, VRM, VRMA)"), fileInput),
    el("div", { class: "field" }, el("label", { for: ids.name }, "Name"), nameInput),
    el("div", { class: "field" }, el("button", { type: "submit" }, "Store rig")),
  );
  const clipForm = el(
    "form",
    { class: "filters rig-form", "aria-label": "Store a rig from a stored clip" },
    el("div", { class: "field narrow" }, el("label", { for: ids.clip }, "…or clip #"), clipInput),
    el("div", { class: "field" }, el("button", { type: "submit", class: "secondary" }, "Use its skeleton")),
  );
  const storePanel = el(
    "section",
    { class: "rig-store", "aria-labelledby": ids.file + "-head" },
    el("h2", { id: ids.file + "-head" }, "Store a rig"),
    uploadForm,
    clipForm,
    keyArea,
  );
  const confirm = confirmDelete();
  main.append(
    el("div", { class: "view-head" }, el("h1", {}, "Rigs")),
    el(
      "p",
      { class: "hint" },
      "A rig is your character's skeleton. A download on a rig has exactly its joints, hierarchy and rest offsets; every joint the mapper found (dots below) turns as the clip's does, the others (fingers, face, twist bones) stay at rest. A character file with a mesh and no animation is fine.",
    ),
    storePanel,
    status,
    list,
    confirm.node,
  );

  function say(text, { error = false } = {}) {
    status.textContent = text;
    status.classList.toggle("error", error);
    status.setAttribute("role", error ? "alert" : "status");
  }

  const resizes = new ResizeObserver((entries) => {
    for (const entry of entries) entry.target.__redraw?.();
  });

  async function load() {
    let page;
    try {
      page = await getJson("/rigs", { limit: 200 });
    } catch (error) {
      say(`Cannot list the rigs: ${error.detail || error.message}`, { error: true });
      return;
    }
    clear(list);
    if (!page.items.length) {
      if (!status.textContent || !status.classList.contains("error")) say("No rig yet: store one above, then choose it in any Download dialog.");
      return;
    }
    for (const rig of page.items) list.append(rigCard(rig));
  }

  function rigCard(rig) {
    const headingId = nextId("rig");
    const canvas = el("canvas", { class: "rig-figure", role: "img", "aria-label": `${rig.name} in its rest pose`, dataset: { rigId: String(rig.id) } });
    const caption = el("p", { class: "meta rig-caption" }, "Point at a joint to see its name.");
    const mapping = el("div", { class: "rig-mapping" });
    const remove = el("button", { type: "button", class: "danger small" }, "Delete…");
    const node = el(
      "li",
      { class: "card rig-card", dataset: { rigId: String(rig.id) } },
      el(
        "article",
        { "aria-labelledby": headingId },
        canvas,
        caption,
        el("h2", { id: headingId, class: "clip-name", title: rig.filename }, rig.name),
        el("p", { class: "meta format-line" }, formatBadge(rig.format), ` ${plural(rig.joint_count, "joint")} · ${unitsText(rig.units)} · #${rig.id}`),
        el("p", { class: "meta filenames" }, rig.filename),
        mapping,
        remove,
      ),
    );
    getJson(`/rigs/${rig.id}`).then(
      (full) => {
        let state = null;
        canvas.__redraw = () => {
          state = drawRig(canvas, full.skeleton, full.mapping, { rigId: rig.id });
        };
        canvas.__redraw();
        resizes.observe(canvas);
        canvas.addEventListener("pointermove", (event) => {
          if (!state) return;
          const box = canvas.getBoundingClientRect();
          const i = jointAt(state, event.clientX - box.left, event.clientY - box.top);
          if (i < 0) return;
          const as = Object.entries(state.canonical).filter(([, j]) => j === i).map(([name]) => name);
          caption.textContent = `${state.names[i]} — ${as.length ? `mapped as ${as.join(", ")}` : "not mapped: stays at rest"}`;
        });
        mapping.append(mappingTable(full.mapping));
      },
      (error) => {
        caption.textContent = `Cannot draw it: ${error.detail || error.message}`;
      },
    );
    remove.addEventListener("click", async () => {
      if (!(await confirm.ask(rig))) return;
      try {
        const done = await withKey(keyArea, () => sendJson("DELETE", `/rigs/${rig.id}`, undefined, { quietAuth: true }), "delete a rig");
        if (done === undefined) {
          say("Not deleted.");
          return;
        }
        say(`Deleted rig #${rig.id} “${rig.name}”.`);
        load();
      } catch (error) {
        say(`Not deleted: ${error.detail || error.message}`, { error: true });
      }
    });
    return node;
  }

  /** Store a rig; ``stored()`` clears its form as soon as the service has it, before the
   * list is fetched again: a next file chosen meanwhile must not be cleared with it. */
  async function store(send, what, stored) {
    say(`Reading ${what}…`);
    try {
      const rig = await withKey(keyArea, send, "store a rig");
      if (rig === undefined) {
        say("Not stored.");
        return;
      }
      stored();
      const found = Object.keys((rig.mapping && rig.mapping.joints) || {}).length;
      say(`Stored rig #${rig.id} “${rig.name}”: ${plural(rig.joint_count, "joint")}, ${found} of them mapped.`);
      await load();
    } catch (error) {
      say(`Not stored: ${error.code && error.code !== "http_error" ? `${error.code.replace(/_/g, " ")}: ` : ""}${error.detail || error.message}`, { error: true });
    }
  }

  uploadForm.addEventListener("submit", async (event) => {
    event.preventDefault();
    if (!fileInput.files.length) return;
    const { body, name } = rigForm(fileInput.files);
    if (nameInput.value.trim()) body.append("name", nameInput.value.trim());
    const send = () => postForm("/rigs", null, body, { quietAuth: true }).then((answer) => answer.body);
    await store(send, name, () => uploadForm.reset());
  });
  clipForm.addEventListener("submit", async (event) => {
    event.preventDefault();
    const id = Number.parseInt(clipInput.value, 10);
    if (!(id > 0)) {
      say("Give the id of a stored clip (its page's address ends with it).", { error: true });
      return;
    }
    const send = () => sendJson("POST", "/rigs", undefined, { params: { from_clip: id }, quietAuth: true });
    await store(send, `clip #${id}`, () => clipForm.reset());
  });

  await load();
  return () => {
    resizes.disconnect();
    if (confirm.node.open) confirm.node.close();
  };
}

/** A rig's length unit: "cm", "in"…, or a scale the service gives as metres ("0.0564444 m"). */
function unitsText(units) {
  const scale = /^(\d*\.?\d+(?:e-?\d+)?) m$/.exec(units || "");
  if (!scale || Number(scale[1]) === 1) return units;
  return `1 unit = ${Number((Number(scale[1]) * 100).toPrecision(3))} cm`;
}

/** Which of the rig's joints is each canonical joint, and how it was found. */
function mappingTable(mapping) {
  const rows = Object.entries((mapping && mapping.joints) || {});
  return el(
    "details",
    { class: "mapping" },
    el("summary", {}, `Mapping: ${plural(rows.length, "canonical joint")}${mapping && mapping.pose ? ` (${mapping.pose})` : ""}`),
    el(
      "table",
      {},
      el("thead", {}, el("tr", {}, el("th", { scope: "col" }, "Canonical"), el("th", { scope: "col" }, "Rig joint, found by"))),
      el(
        "tbody",
        {},
        rows.map(([canonical, found]) =>
          el(
            "tr",
            {},
            el("th", { scope: "row" }, canonical),
            el("td", {}, el("span", { class: "joint" }, (found && found.joint) || "—"), found && found.how ? el("span", { class: "how" }, found.how) : null),
          ),
        ),
      ),
    ),
  );
}

function confirmDelete() {
  const dialog = deleteDialog();
  return {
    node: dialog.node,
    ask: (rig) => dialog.ask(`Delete rig “${rig.name}”?`, el("p", {}, "Clips are not touched; downloads can no longer use this rig.")),
  };
}
