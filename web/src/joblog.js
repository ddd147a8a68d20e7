// A job's own log lines (GET /reconstructions/{id}/log): shown under its result or status,
// followed every two seconds while the job is queued or running and the log is open.

import { api } from "./api.js";

const POLL_MS = 2000;
const TAIL = 300;

export class LogView {
  constructor(box, pre, count) {
    Object.assign(this, { box, pre, count });
    this.id = null;
    this.losses = []; // the loss values the log holds (every 15 s of training), oldest first
    this.active = false;
    this.timer = null;
    box.addEventListener("toggle", () => this.box.open && this.load());
  }

  /** Show job ``id``'s log, open and followed when ``active`` (queued or running). */
  show(id, active) {
    const same = this.id === id;
    this.id = id;
    this.active = active;
    this.box.hidden = false;
    if (!same) {
      this.losses = [];
      this.box.open = active;
      this.pre.textContent = "";
      this.count.textContent = "";
    }
    this.load();
  }

  close() {
    this.id = null;
    clearTimeout(this.timer);
    this.box.hidden = true;
  }

  async load() {
    clearTimeout(this.timer);
    const id = this.id;
    if (!id || !this.box.open) return;
    let log;
    try {
      log = await api(`/reconstructions/${id}/log?tail=${TAIL}`);
    } catch (e) {
      this.pre.textContent = `the log could not be read: ${e.message}`;
      return;
    }
    if (id !== this.id) return;
    // follow the end unless the reader scrolled up to read
    const atEnd = this.pre.scrollTop + this.pre.clientHeight >= this.pre.scrollHeight - 4;
    const lines = log.lines.length ? log.lines : ["(no lines yet: a worker has not started this job)"];
    this.pre.textContent = (log.truncated ? `… earlier lines left out (the last ${log.lines.length} shown)\n` : "") + lines.join("\n");
    this.pre.dataset.lines = String(log.lines.length);
    this.losses = log.lines.map((l) => Number(l.match(/, loss ([-+0-9.eE]+)/)?.[1])).filter((v) => Number.isFinite(v) && v > 0);
    this.count.textContent = `(${log.lines.length} line${log.lines.length === 1 ? "" : "s"})`;
    if (atEnd) this.pre.scrollTop = this.pre.scrollHeight;
    if (this.active && ["queued", "running"].includes(log.status)) this.timer = setTimeout(() => this.load(), POLL_MS);
  }
}
