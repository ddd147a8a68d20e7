// Presets (quick look, standard, paper: GET /schemas/reconstruction-presets) and the run-time
// estimate of the spec in the form (POST /estimates: the cost model's CPU seconds by part, and
// every check a submission would fail), shown while the operator chooses, before any upload.

import { api } from "./api.js";
import { fmtDuration } from "./jobs.js";

const el = (tag, attrs = {}, ...kids) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  e.append(...kids);
  return e;
};

/** "about 4 min on a CPU worker (training 3 min 40 s), plus ..." from an estimate. */
export function estimateWords(est) {
  const p = est.parts;
  const base = `about ${fmtDuration(est.cpu_s)} on a CPU worker`;
  const parts = [`training ${fmtDuration(p.train_s)}`];
  if (est.survey_known) parts.push(`backprojection ${fmtDuration(p.backprojection_s)}`, `signal processing ${fmtDuration(p.signal_s)}`);
  return `${base} (${parts.join(", ")})${est.survey_known ? "" : ", plus the backprojection and signal processing of the survey, which depend on its size"}`;
}

export class Presets {
  /** ``form``: the SpecForm; ``box``: the fieldset for the choices; ``out``: the estimate line. */
  constructor(form, box, out) {
    Object.assign(this, { form, box, out });
    this.seq = 0;
    this.timer = null;
    form.container.addEventListener("input", () => {
      // an edited field: the form is no longer exactly a preset
      for (const r of box.querySelectorAll("input[type=radio]")) r.checked = false;
      this.later();
    });
    form.container.addEventListener("change", () => this.later());
  }

  async load() {
    const list = await api("/schemas/reconstruction-presets");
    const legend = el("legend", {}, "Preset");
    this.box.replaceChildren(legend);
    for (const p of list) {
      const id = `preset-${p.name}`;
      const radio = el("input", { type: "radio", name: "preset", id, value: p.name });
      radio.checked = p.name === "standard"; // the form starts at the spec's defaults
      radio.addEventListener("change", () => {
        if (!radio.checked) return;
        this.form.reset(p.spec);
        this.estimate();
      });
      const cost = el("span", { class: "preset-cost muted", id: `${id}-cost` });
      const label = el("label", { for: id, title: p.description }, radio, ` ${p.title} `, cost);
      this.box.append(el("div", { class: "preset" }, label, el("span", { class: "hint" }, p.description)));
      // each preset's own cost on a CPU, so they can be compared at a glance
      api("/estimates", { method: "POST", headers: { "Content-Type": "application/json" },
        body: JSON.stringify({ spec: { ...p.spec, device: "cpu" } }) })
        .then((est) => {
          cost.textContent = `(about ${fmtDuration(est.cpu_s)} on a CPU${est.survey_known ? "" : " + the survey's imaging"})`;
          cost.dataset.seconds = String(est.cpu_s);
        })
        .catch(() => {});
    }
    this.estimate();
  }

  later() {
    clearTimeout(this.timer);
    this.timer = setTimeout(() => this.estimate(), 300);
  }

  /** The estimate of the spec as the form holds it now. */
  async estimate() {
    const seq = ++this.seq;
    if (this.form.problems().length) {
      this.out.textContent = "Estimate: fill in every field first.";
      delete this.out.dataset.seconds;
      return;
    }
    let est;
    try {
      est = await api("/estimates", { method: "POST", headers: { "Content-Type": "application/json" },
        body: JSON.stringify({ spec: this.form.value() }) });
    } catch (e) {
      if (seq === this.seq) {
        this.out.textContent = `Estimate: ${e.message}`;
        delete this.out.dataset.seconds;
      }
      return;
    }
    if (seq !== this.seq) return; // a later edit's answer is coming
    const where = est.queue === "cpu" ? "" : ` (it runs on the ${est.queue} queue; a GPU takes far less)`;
    this.out.replaceChildren(`Estimated run time: ${estimateWords(est)}${where}.`);
    this.out.dataset.seconds = String(est.cpu_s);
    this.out.classList.toggle("refused", est.refused.length > 0);
    if (est.refused.length) {
      const ul = el("ul");
      for (const m of est.refused) ul.append(el("li", {}, m));
      this.out.append(el("strong", {}, " This spec would be refused:"), ul);
    }
  }
}
