// The job list: polls GET /reconstructions and updates one row per job in place (so keyboard
// focus stays on its button). ETA and queue position are worked out here from what the API
// gives: progress and started_at; created_at of the key's queued jobs.

import { api, ApiError } from "./api.js";

const POLL_MS = 1000;
const ACTIVE = new Set(["queued", "running"]);

function fmtDuration(s) {
  if (!Number.isFinite(s) || s < 0) return "";
  if (s < 90) return `${Math.round(s)} s`;
  if (s < 5400) return `${Math.round(s / 60)} min`;
  return `${(s / 3600).toFixed(1)} h`;
}

export function eta(job, now = Date.now()) {
  if (job.status !== "running" || !job.started_at || !(job.progress > 0.01)) return null;
  const elapsed = (now - Date.parse(job.started_at)) / 1000;
  return (elapsed * (1 - job.progress)) / job.progress;
}

export class JobList {
  constructor({ list, empty, onOpen, onError }) {
    this.list = list;
    this.empty = empty;
    this.onOpen = onOpen;
    this.onError = onError;
    this.rows = new Map();
    this.selected = null;
    this.timer = null;
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

  async refresh() {
    let page;
    try {
      page = await api("/reconstructions?limit=50");
    } catch (e) {
      this.onError(e);
      return;
    }
    this.onError(null);
    const jobs = page.items;
    const queued = jobs.filter((j) => j.status === "queued").sort((a, b) => Date.parse(a.created_at) - Date.parse(b.created_at));
    const seen = new Set();
    jobs.forEach((job, i) => {
      seen.add(job.id);
      let row = this.rows.get(job.id);
      if (!row) {
        row = this.makeRow(job.id);
        this.rows.set(job.id, row);
      }
      if (this.list.children[i] !== row.li) this.list.insertBefore(row.li, this.list.children[i] || null);
      this.update(row, job, queued.findIndex((q) => q.id === job.id));
    });
    for (const [id, row] of this.rows) {
      if (!seen.has(id)) {
        row.li.remove();
        this.rows.delete(id);
      }
    }
    this.empty.hidden = jobs.length > 0;
  }

  makeRow(id) {
    const li = document.createElement("li");
    li.className = "job";
    li.dataset.jobId = id;
    li.innerHTML = `
      <div class="top"><span class="badge"></span><span class="id"></span><span class="stage muted"></span></div>
      <progress max="1" value="0"></progress> <span class="pct"></span>
      <div class="meta muted"></div>
      <div class="error" role="alert"></div>
      <div class="warn"></div>
      <div class="actions">
        <button type="button" class="open">View result</button>
        <button type="button" class="cancel">Cancel</button>
        <button type="button" class="delete">Delete</button>
      </div>`;
    const q = (s) => li.querySelector(s);
    const row = { li, badge: q(".badge"), id: q(".id"), stage: q(".stage"), bar: q("progress"), pct: q(".pct"),
      meta: q(".meta"), error: q(".error"), warn: q(".warn"), open: q(".open"), cancel: q(".cancel"), del: q(".delete") };
    row.id.textContent = id.slice(0, 8);
    row.id.title = id;
    row.bar.setAttribute("aria-label", `progress of job ${id.slice(0, 8)}`);
    row.open.addEventListener("click", () => this.select(id));
    row.cancel.addEventListener("click", () => this.act(id, "cancel"));
    row.del.addEventListener("click", () => this.act(id, "delete"));
    return row;
  }

  update(row, job, queueIndex) {
    row.job = job;
    row.li.dataset.status = job.status;
    row.li.dataset.progress = String(job.progress);
    row.badge.className = `badge ${job.status}`;
    row.badge.textContent = job.status + (job.cancel_requested && ACTIVE.has(job.status) ? " (cancelling)" : "");
    row.stage.textContent = job.stage || "";
    row.bar.value = job.progress;
    row.pct.textContent = `${Math.round(job.progress * 100)} %`;
    const meta = [];
    if (job.status === "queued" && queueIndex >= 0) meta.push(`queue position ${queueIndex + 1} of your queued jobs`);
    const left = eta(job);
    if (left !== null) meta.push(`about ${fmtDuration(left)} left`);
    if (job.iterations_per_s) meta.push(`${job.iterations_per_s.toFixed(1)} it/s`);
    meta.push(`attempts ${job.attempts}`);
    meta.push(`methods ${(job.spec.methods || []).join(", ")}`);
    if (job.created_at) meta.push(`submitted ${new Date(job.created_at).toLocaleString()}`);
    row.meta.textContent = meta.join(" · ");
    row.error.textContent = job.error ? `Error: ${job.error}` : "";
    row.warn.textContent = (job.warnings || []).map((w) => `⚠ ${w.method}: ${w.message}`).join("\n");
    row.open.hidden = job.status !== "succeeded";
    row.cancel.hidden = !ACTIVE.has(job.status) || job.cancel_requested;
    row.del.hidden = ACTIVE.has(job.status);
    row.li.classList.toggle("selected", this.selected === job.id);
  }

  select(id) {
    this.selected = id;
    for (const [rid, row] of this.rows) row.li.classList.toggle("selected", rid === id);
    const row = this.rows.get(id);
    if (row) this.onOpen(row.job);
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
