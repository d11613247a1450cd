// Filter controls the Library and Search pages share.

import { licences as fetchLicences } from "./api.js";
import { el, nextId } from "./util.js";

/**
 * A licence filter: a select of the licences in use and a "leave it out" box. `initial` is
 * the `licence=` value ("CC0", or "!CC BY-NC 4.0" to exclude). Returns {node, value(),
 * onChange(fn)}: value() is what `licence=` takes ("" for no filter).
 */
export function licenceFilter(initial = "") {
  const exclude = initial.startsWith("!");
  const wanted = exclude ? initial.slice(1) : initial;
  const ids = { select: nextId("licence"), exclude: nextId("licence-exclude") };
  const select = el("select", { id: ids.select }, el("option", { value: "" }, "Any licence"));
  const box = el("input", { id: ids.exclude, type: "checkbox", checked: exclude, disabled: !wanted });
  const node = el(
    "div",
    { class: "field licence-field" },
    el("label", { for: ids.select }, "Licence"),
    el("div", { class: "licence-row" }, select, el("span", { class: "check-line" }, box, el("label", { for: ids.exclude }, "all but this"))),
  );
  const listeners = [];
  const changed = () => {
    box.disabled = !select.value;
    for (const fn of listeners) fn();
  };
  select.addEventListener("change", changed);
  box.addEventListener("change", changed);
  if (wanted) select.append(el("option", { value: wanted }, wanted));
  select.value = wanted;
  fetchLicences()
    .then((rows) => {
      for (const option of [...select.options].slice(1)) option.remove();
      for (const { licence, count } of rows) select.append(el("option", { value: licence }, `${licence} (${count})`));
      const known = rows.find((r) => r.licence.toLowerCase() === wanted.toLowerCase());
      if (wanted && !known) select.append(el("option", { value: wanted }, wanted));
      select.value = known ? known.licence : wanted;
    })
    .catch(() => {});
  return {
    node,
    value: () => (select.value ? `${box.checked ? "!" : ""}${select.value}` : ""),
    onChange: (fn) => listeners.push(fn),
  };
}
