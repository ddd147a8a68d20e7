// The spec form, made from the spec's JSON schema (GET /schemas/reconstruction-spec): one field
// per property, its default filled in, its limits shown. The API validates; its messages
// ("spec.grid: ... (fix: ...)") are shown beside the field they name.

const el = (tag, attrs = {}, ...kids) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) if (v !== undefined && v !== null) e.setAttribute(k, v);
  e.append(...kids);
  return e;
};

/** The non-null branch of an ``anyOf: [X, {type: null}]`` property, and whether null is allowed. */
function unwrap(prop) {
  if (!prop.anyOf) return [prop, false];
  const some = prop.anyOf.find((p) => p.type !== "null") || {};
  return [{ ...some, ...prop, anyOf: undefined }, prop.anyOf.some((p) => p.type === "null")];
}

function limits(p, nullable) {
  const parts = [];
  if (p.minimum !== undefined) parts.push(`≥ ${p.minimum}`);
  if (p.exclusiveMinimum !== undefined) parts.push(`> ${p.exclusiveMinimum}`);
  if (p.maximum !== undefined) parts.push(`≤ ${p.maximum}`);
  if (p.exclusiveMaximum !== undefined) parts.push(`< ${p.exclusiveMaximum}`);
  if (p.pattern) parts.push(`pattern ${p.pattern}`);
  if (nullable) parts.push("empty = automatic");
  return parts.join(", ");
}

export class SpecForm {
  constructor(container, schema) {
    this.container = container;
    this.schema = schema;
    this.fields = {}; // name -> { read(): value, prop, nullable, box }
    container.replaceChildren();
    for (const [name, raw] of Object.entries(schema.properties)) this.add(name, raw);
  }

  add(name, raw) {
    const [p, nullable] = unwrap(raw);
    const id = `spec-${name}`;
    const box = el("div", { class: "field", id: `field-${name}` });
    const err = el("p", { class: "field-error", id: `err-spec-${name}`, role: "alert" });
    // long descriptions are cut to their first clause; the whole text stays in the title
    const desc = p.description || "";
    const short = desc.length > 80 ? `${desc.slice(0, 80).replace(/[\s,;:]+\S*$/, "")}…` : desc;
    const hintText = [short, limits(p, nullable)].filter(Boolean).join(" — ");
    const hint = el("span", { class: "hint", id: `hint-${name}`, title: desc || undefined }, hintText);
    let read;
    let write;
    let check = () => null;
    if (p.type === "array" && p.items && p.items.enum) {
      const group = el("div", { class: "checks", role: "group", "aria-labelledby": `lbl-${name}`, "aria-describedby": hint.id });
      const boxes = p.items.enum.map((v) => {
        const cb = el("input", { type: "checkbox", id: `${id}-${v}`, value: v, name });
        cb.checked = (p.default || []).includes(v);
        group.append(el("label", { for: cb.id }, cb, ` ${v}`));
        return cb;
      });
      box.append(el("span", { class: "label", id: `lbl-${name}` }, name), group);
      read = () => boxes.filter((b) => b.checked).map((b) => b.value);
      write = (v) => boxes.forEach((b) => (b.checked = (v || []).includes(b.value)));
    } else if (p.enum) {
      const sel = el("select", { id, name, "aria-describedby": `${hint.id} ${err.id}` },
        ...p.enum.map((v) => el("option", { value: v }, String(v))));
      sel.value = p.default;
      box.append(el("label", { for: id }, name), sel);
      read = () => sel.value;
      write = (v) => (sel.value = v);
    } else if (p.type === "boolean") {
      const cb = el("input", { type: "checkbox", id, name, "aria-describedby": `${hint.id} ${err.id}` });
      cb.checked = !!p.default;
      box.append(el("label", { for: id }, name), cb);
      read = () => cb.checked;
      write = (v) => (cb.checked = !!v);
    } else {
      const numeric = p.type === "integer" || p.type === "number";
      const input = el("input", {
        id, name, type: numeric ? "number" : "text", "aria-describedby": `${hint.id} ${err.id}`,
        step: p.type === "integer" ? 1 : "any",
        placeholder: nullable ? "auto" : undefined,
      });
      input.value = p.default ?? "";
      box.append(el("label", { for: id }, name), input);
      // an emptied field is an error, not the default: "iters" left empty must not mean 2000
      if (numeric && !nullable) {
        check = () => (input.value.trim() === "" ? `${name}: ${input.validity.badInput ? "not a number" : "empty"} ` +
          `(fix: give a value${p.default !== undefined ? `; the default is ${p.default}` : ""})` : null);
      }
      write = (v) => (input.value = v ?? "");
      read = () => {
        const v = input.value.trim();
        if (v === "") return nullable ? null : undefined;
        if (!numeric) return v;
        const n = Number(v);
        return Number.isFinite(n) ? n : v; // the API names a non-number
      };
    }
    box.append(err, hint); // the error right under the control, where the focus lands
    this.container.append(box);
    this.fields[name] = { read, write, check, default: p.default ?? null, box, err };
  }

  /** The problems found before sending (each also shown beside its field): [{name, text}]. */
  check() {
    const out = [];
    for (const [name, f] of Object.entries(this.fields)) {
      const text = f.check();
      if (!text) continue;
      f.err.textContent = text;
      f.box.classList.add("invalid");
      out.push({ name, text });
    }
    return out;
  }

  /** The problems found before sending, without showing them: [{name, text}]. */
  problems() {
    return Object.entries(this.fields).map(([name, f]) => ({ name, text: f.check() })).filter((p) => p.text);
  }

  /** Every field back to its default, then ``values`` (a preset's fields) over them. */
  reset(values = {}) {
    this.clearErrors();
    for (const [name, f] of Object.entries(this.fields)) f.write(name in values ? values[name] : f.default);
  }

  /** The spec to send: only the fields that differ from their defaults. */
  value() {
    const spec = {};
    for (const [name, f] of Object.entries(this.fields)) {
      const v = f.read();
      if (v === undefined) continue;
      if (JSON.stringify(v) !== JSON.stringify(f.default)) spec[name] = v;
    }
    return spec;
  }

  set(name, value) {
    const input = this.fields[name].box.querySelector("input,select");
    input.value = value;
  }

  clearErrors() {
    for (const f of Object.values(this.fields)) {
      f.err.textContent = "";
      f.box.classList.remove("invalid");
    }
  }

  /** Put each "spec.<field>…: message" part of an API error beside its field; the rest is returned. */
  showErrors(detail) {
    const rest = [];
    for (const part of detail.split(/; (?=spec[.:])/)) {
      const m = part.match(/^spec\.([A-Za-z_]\w*)/);
      const f = m && this.fields[m[1]];
      if (f) {
        f.err.textContent = part;
        f.box.classList.add("invalid");
        f.box.querySelector("input,select")?.focus();
        f.err.scrollIntoView({ block: "nearest" });
      } else rest.push(part);
    }
    return rest.join("; ");
  }
}
