// The job list: one page of GET /reconstructions?order=active (running jobs, then queued, then
// finished), filtered by status and text on the server, paged with its cursors, polled every
// second. Rows are updated in place (so keyboard focus stays on its button). Delete asks first.

import { api, ApiError } from "./api.js";
import { plainStage } from "./stages.js";

const POLL_MS = 1000;
export const PAGE_SIZE = 20;
const ACTIVE = new Set(["queued", "running"]);

export function fmtDuration(s) {
  if (!Number.isFinite(s) || s < 0) return "";
  if (s < 90) return `${Math.round(s)} s`;
  if (s < 5400) return `${Math.floor(s / 60)} min ${String(Math.round(s % 60)).padStart(2, "0")} s`;
  return `${(s / 3600).toFixed(1)} h`;
}

/** What the job is called in the list: its label, else the uploaded file's name, else its id. */
export function jobTitle(job) {
  return job.label || job.input?.filename || job.id.slice(0, 8);
}

/** "running for 3 min 04 s", "ran 2 min 24 s", "waiting for 40 s": from the job's own times. */
export function elapsed(job, now = Date.now()) {
  const t = (iso) => (iso ? Date.parse(iso) : null);
  const [created, started, finished] = [t(job.created_at), t(job.started_at), t(job.finished_at)];
  if (job.status === "queued") return created ? `waiting for ${fmtDuration((now - created) / 1000)}` : "";
  if (job.status === "running") return started ? `running for ${fmtDuration((now - started) / 1000)}` : "";
  if (started && finished) return `ran ${fmtDuration((finished - started) / 1000)}`;
  return "";
}

/** "about 3 min left" from the status's ETA (the pace the current stage measured), or
 *  "estimating time left" while the stage has not measured it. Running jobs only. */
export function timeLeft(job) {
  if (job.status !== "running") return "";
  return Number.isFinite(job.eta_s) ? `about ${fmtDuration(job.eta_s)} left` : "estimating time left";
}

/** ``values`` (positive) as a log-scale line in ``svg`` (its viewBox's size); hidden below two. */
export function drawCurve(svg, values) {
  // an <svg> has no "hidden" property (HTMLElement's only): the attribute itself hides it
  svg.toggleAttribute("hidden", values.length < 2);
  if (values.length < 2) return;
  const [, , w, h] = svg.getAttribute("viewBox").split(" ").map(Number);
  const logs = values.map(Math.log10);
  const lo = Math.min(...logs);
  const span = Math.max(...logs) - lo || 1;
  const pts = logs.map((v, i) => `${((i / (logs.length - 1)) * w).toFixed(1)},${(h - 2 - ((v - lo) / span) * (h - 4)).toFixed(1)}`);
  svg.querySelector("polyline").setAttribute("points", pts.join(" "));
  svg.dataset.samples = String(values.length);
  svg.setAttribute("aria-label", `loss from ${values[0].toPrecision(3)} to ${values[values.length - 1].toPrecision(3)} over ${values.length} readings`);
}

export class JobList {
  constructor({ list, empty, status, search, newer, older, pageLabel, dialog, compareLink, onOpen, onError }) {
    Object.assign(this, { list, empty, status, search, newer, older, pageLabel, dialog, compareLink, onOpen, onError });
    this.picked = []; // ids ticked for the two-job view (kept across pages)
    compareLink.addEventListener("click", () => this.onOpen(compareLink.getAttribute("href")));
    this.rows = new Map();
    this.losses = new Map(); // job id -> the loss values seen while this page polled it
    this.selected = null;
    this.timer = null;
    this.cursors = [null]; // cursors[i] loads page i; the first page has none
    this.page = 0;
    this.next = null;
    this.onJob = () => {}; // called with every job seen (main.js opens a routed job once it finished)
    status.addEventListener("change", () => this.restart());
    let typing = null;
    search.addEventListener("input", () => {
      clearTimeout(typing);
      typing = setTimeout(() => this.restart(), 300); // one request per pause in typing
    });
    newer.addEventListener("click", () => this.go(this.page - 1));
    older.addEventListener("click", () => this.go(this.page + 1));
  }

  start() {
    this.stop();
    const tick = async () => {
      await this.refresh();
      this.timer = setTimeout(tick, POLL_MS);
    };
    tick();
  }

  stop() {
    clearTimeout(this.timer);
    this.timer = null;
  }

  clear() {
    this.rows.clear();
    this.list.replaceChildren();
    this.empty.hidden = false;
  }

  restart() {
    this.cursors = [null];
    this.page = 0;
    this.refresh();
  }

  go(page) {
    if (page < 0 || (page > this.page && !this.next)) return;
    if (page > this.page) this.cursors[page] = this.next;
    this.page = page;
    this.refresh();
  }

  query() {
    const q = new URLSearchParams({ order: "active", limit: String(PAGE_SIZE) });
    if (this.status.value) q.set("status", this.status.value);
    if (this.search.value.trim()) q.set("q", this.search.value.trim());
    if (this.cursors[this.page]) q.set("cursor", this.cursors[this.page]);
    return q.toString();
  }

  async refresh() {
    const query = this.query();
    let page;
    try {
      page = await api(`/reconstructions?${query}`);
    } catch (e) {
      this.onError(e);
      return;
    }
    if (query !== this.query()) return; // the filter or page changed meanwhile: its answer is coming
    this.onError(null);
    this.next = page.next_cursor;
    const jobs = page.items;
    const seen = new Set();
    jobs.forEach((job, i) => {
      seen.add(job.id);
      let row = this.rows.get(job.id);
      if (!row) {
        row = this.makeRow(job.id);
        this.rows.set(job.id, row);
      }
      if (this.list.children[i] !== row.li) this.list.insertBefore(row.li, this.list.children[i] || null);
      this.update(row, job);
      this.onJob(job);
    });
    for (const [id, row] of this.rows) {
      if (!seen.has(id)) {
        row.li.remove();
        this.rows.delete(id);
      }
    }
    const filtered = this.status.value || this.search.value.trim();
    this.empty.hidden = jobs.length > 0;
    this.empty.textContent = filtered ? "No job matches this filter." : this.page ? "No more jobs." : "No jobs yet.";
    this.newer.disabled = this.page === 0;
    this.older.disabled = !this.next;
    this.pageLabel.textContent = `page ${this.page + 1}`;
  }

  makeRow(id) {
    const li = document.createElement("li");
    li.className = "job";
    li.dataset.jobId = id;
    li.innerHTML = `
      <div class="top"><span class="badge"></span><span class="title"></span></div>
      <div class="sub muted"><span class="file"></span> <span class="id"></span></div>
      <div class="stage"></div>
      <progress max="1" value="0"></progress> <span class="pct"></span>
      <div class="meta muted"></div>
      <svg class="loss" viewBox="0 0 200 30" preserveAspectRatio="none" role="img" hidden><polyline fill="none" stroke="currentColor" stroke-width="1.5"></polyline></svg>
      <div class="error" role="alert"></div>
      <div class="warn"></div>
      <div class="actions">
        <a class="open button" role="button">View result</a>
        <a class="details button" role="button">Details and log</a>
        <a class="compare button" role="button">Compare methods</a>
        <button type="button" class="cancel">Cancel</button>
        <button type="button" class="delete">Delete…</button>
        <label class="pick"><input type="checkbox" class="pick-box"> compare</label>
      </div>`;
    const q = (s) => li.querySelector(s);
    const row = { li, badge: q(".badge"), title: q(".title"), file: q(".file"), id: q(".id"), stage: q(".stage"),
      bar: q("progress"), pct: q(".pct"), meta: q(".meta"), error: q(".error"), warn: q(".warn"),
      open: q(".open"), details: q(".details"), compare: q(".compare"), cancel: q(".cancel"), del: q(".delete"), pick: q(".pick"), pickBox: q(".pick-box"), curve: q("svg.loss") };
    row.id.textContent = id.slice(0, 8);
    row.id.title = id;
    // links, not handlers: each result has its own address (#/jobs/{id}); back and forward work
    row.open.href = `#/jobs/${id}`;
    row.details.href = `#/jobs/${id}`;
    row.compare.href = `#/jobs/${id}/compare`;
    row.open.addEventListener("click", () => this.onOpen(row.open.getAttribute("href")));
    row.details.addEventListener("click", () => this.onOpen(row.details.getAttribute("href")));
    row.compare.addEventListener("click", () => this.onOpen(row.compare.getAttribute("href")));
    row.cancel.addEventListener("click", () => this.act(id, "cancel"));
    row.del.addEventListener("click", () => this.confirmDelete(id));
    row.pickBox.setAttribute("aria-label", `compare job ${id.slice(0, 8)} with another`);
    row.pickBox.addEventListener("change", () => this.pick(id, row.pickBox.checked));
    return row;
  }

  update(row, job) {
    row.job = job;
    row.li.dataset.status = job.status;
    row.li.dataset.progress = String(job.progress);
    row.li.dataset.eta = Number.isFinite(job.eta_s) ? String(job.eta_s) : "";
    row.li.dataset.stage = job.stage || "";
    row.badge.className = `badge ${job.status}`;
    row.badge.textContent = job.status + (job.cancel_requested && ACTIVE.has(job.status) ? " (cancelling)" : "");
    row.title.textContent = jobTitle(job);
    row.file.textContent = job.label && job.input?.filename ? job.input.filename : "";
    row.bar.setAttribute("aria-label", `progress of ${jobTitle(job)}`);
    row.stage.textContent = job.status === "running" ? plainStage(job.stage) : "";
    row.bar.hidden = row.pct.hidden = job.status !== "running";
    row.bar.value = job.progress;
    row.pct.textContent = `${Math.round(job.progress * 100)} %`;
    const meta = [elapsed(job), timeLeft(job)];
    const loss = job.live_metrics?.loss;
    if (job.status === "running" && Number.isFinite(loss)) meta.push(`loss ${loss.toPrecision(3)}`);
    if (job.status === "running" && job.iterations_per_s) meta.push(`${job.iterations_per_s.toFixed(1)} it/s`);
    if (job.attempts > 1) meta.push(`attempt ${job.attempts}`);
    meta.push((job.spec.methods || []).join(", "));
    if (job.created_at) meta.push(`submitted ${new Date(job.created_at).toLocaleString()}`);
    row.meta.textContent = meta.filter(Boolean).join(" · ");
    this.drawLoss(row, job);
    row.error.textContent = job.error ? `Error: ${job.error}` : "";
    row.warn.textContent = (job.warnings || []).map((w) => `⚠ ${w.method}: ${w.message}`).join("\n");
    row.open.hidden = job.status !== "succeeded";
    row.details.hidden = job.status === "succeeded"; // the result's page has its log too
    row.compare.hidden = job.status !== "succeeded" || (job.spec.methods || []).length < 2;
    row.cancel.hidden = !ACTIVE.has(job.status) || job.cancel_requested;
    row.del.hidden = ACTIVE.has(job.status);
    row.pick.hidden = job.status !== "succeeded";
    row.pickBox.checked = this.picked.includes(job.id);
    row.li.classList.toggle("selected", this.selected === job.id);
  }

  /** The live loss as a curve (log scale) of the values seen since this page began to watch. */
  drawLoss(row, job) {
    const loss = job.live_metrics?.loss;
    const seen = this.losses.get(job.id) || [];
    if (job.status === "running" && Number.isFinite(loss) && loss > 0 && loss !== seen[seen.length - 1]) {
      seen.push(loss);
      if (seen.length > 300) seen.splice(0, seen.length - 300);
      this.losses.set(job.id, seen);
    }
    drawCurve(row.curve, job.status === "running" ? seen : []);
  }

  /** Tick or untick a job for the two-job view; a third tick drops the oldest. */
  pick(id, on) {
    this.picked = this.picked.filter((p) => p !== id);
    if (on) this.picked.push(id);
    if (this.picked.length > 2) this.picked.shift();
    for (const [rid, row] of this.rows) row.pickBox.checked = this.picked.includes(rid);
    this.compareLink.hidden = this.picked.length !== 2;
    if (this.picked.length === 2) this.compareLink.href = `#/compare/${this.picked[0]}/${this.picked[1]}`;
  }

  select(id) {
    this.selected = id;
    for (const [rid, row] of this.rows) row.li.classList.toggle("selected", rid === id);
  }

  /** Delete only after the operator said so in a dialog that says it cannot be undone. */
  confirmDelete(id) {
    const row = this.rows.get(id);
    const d = this.dialog;
    d.querySelector(".what").textContent = row ? `“${jobTitle(row.job)}” (${id.slice(0, 8)})` : id.slice(0, 8);
    d.returnValue = "";
    d.onclose = () => {
      if (d.returnValue === "delete") this.act(id, "delete");
      else row?.del.focus();
    };
    d.showModal();
  }

  async act(id, what) {
    try {
      if (what === "cancel") await api(`/reconstructions/${id}/cancel`, { method: "POST" });
      else await api(`/reconstructions/${id}`, { method: "DELETE", as: "text" });
    } catch (e) {
      const msg = what === "delete" && e.status === 405 ? "this server cannot delete jobs (no DELETE /reconstructions/{id})" : e.message;
      this.onError(new ApiError(e.status, msg), true);
    }
    await this.refresh();
  }
}
