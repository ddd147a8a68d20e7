// The shsas operator console: key, upload, jobs, result. Only the public REST API is used.
// Each result has its own address, #/jobs/{id} (#/jobs/{id}/compare: its methods side by
// side; #/compare/{a}/{b}: two jobs side by
// side), so reload, back and forward work.

import { api, ApiError, key, upload } from "./api.js";
import { SpecForm } from "./form.js";
import { JobList } from "./jobs.js";
import { Presets } from "./presets.js";
import { ResultView } from "./result.js";
import { sniffSurvey } from "./sniff.js";
import { ViewerTools } from "./tools.js";
import { Viewer } from "./viewer.js";

const $ = (id) => document.getElementById(id);
let sticky = false;

function banner(err, keep = false) {
  const box = $("banner");
  if (!err) {
    if (!sticky) box.hidden = true;
    return;
  }
  sticky = keep;
  box.textContent = err.status === 401 ? `${err.message} — paste an API key above (shsas keys create NAME).` : err.message;
  box.hidden = false;
  if (err.status === 401) {
    $("key-status").textContent = key.get() ? "this key was refused" : "a key is needed";
    $("key-input").focus();
  }
}

function keyStatus() {
  $("key-status").textContent = key.get() ? "key in use for this tab" : "no key (loopback without keys needs none)";
}

let form = null;
let file = null;
let pending = null; // { form: FormData, idem: string } of an upload to retry
let uploading = false;

const jobs = new JobList({
  list: $("job-list"),
  empty: $("jobs-empty"),
  status: $("jobs-status"),
  search: $("jobs-search"),
  newer: $("jobs-newer"),
  older: $("jobs-older"),
  pageLabel: $("jobs-page"),
  dialog: $("confirm-delete"),
  compareLink: $("compare-jobs"),
  onOpen: (href) => {
    // a click on "View result": bring the result into view once routed (at once when it is
    // the address already, which fires no hashchange)
    if (location.hash === href) result.bringIntoView();
    else wantFocus = true;
  },
  onError: (e, keep) => banner(e, keep),
});
const viewer = new Viewer($("viewer"));
const result = new ResultView(viewer, (e, keep) => banner(e, keep));
const tools = new ViewerTools(viewer, {
  scalebar: $("scalebar"), measureBtn: $("measure"), resetBtn: $("reset-view"), out: $("measure-out"), shotBtn: $("screenshot"),
  // named after the uploaded survey, as the other downloads are
  shotName: () => (result.job?.input?.filename || "").replace(/^.*[\\/]/, "").replace(/\.[^.]*$/, "").trim() || result.job?.id.slice(0, 8) || "shsas",
});
let wantFocus = false;

// --- routing: #/jobs/{id}[/compare] -------------------------------------------------------

function parseRoute() {
  const pair = location.hash.match(/^#\/compare\/([0-9a-f]{32})\/([0-9a-f]{32})$/);
  if (pair) return { pair: [pair[1], pair[2]] };
  const m = location.hash.match(/^#\/jobs\/([0-9a-f]{32})(\/compare)?$/);
  return m ? { id: m[1], compare: !!m[2] } : null;
}

async function route() {
  const r = parseRoute();
  jobs.select(r?.id ?? null);
  if (!r) {
    result.close();
    return;
  }
  const focus = wantFocus;
  wantFocus = false;
  try {
    if (r.pair) await result.showPair(r.pair, { focus });
    else await result.show(r.id, { compare: r.compare, focus });
  } catch (e) {
    banner(e, true);
  }
}

jobs.onJob = (job) => {
  if (result.waitingFor !== job.id) return;
  // a routed job that was still running when opened: its live status, then its result (or
  // its end) once it finished
  if (["queued", "running"].includes(job.status)) result.live(job, jobs.losses.get(job.id) || []);
  else route();
};

// --- upload -------------------------------------------------------------------------------

function pickFile(f) {
  file = f;
  $("survey-name").textContent = f ? `${f.name} (${(f.size / 1e6).toFixed(2)} MB)` : "";
  $("err-survey").textContent = "";
}

/** List every problem of a refused submission above the button, each linked to its field. */
function listErrors(problems) {
  const box = $("submit-errors");
  const ul = box.querySelector("ul");
  ul.replaceChildren();
  for (const { text, target } of problems) {
    const li = document.createElement("li");
    if (target) {
      const a = Object.assign(document.createElement("a"), { href: "#", textContent: text });
      a.addEventListener("click", (ev) => {
        ev.preventDefault(); // not a navigation: the hash is the result's address
        $(target)?.focus();
      });
      li.append(a);
    } else li.textContent = text;
    ul.append(li);
  }
  box.hidden = problems.length === 0;
  if (problems.length) box.scrollIntoView({ block: "nearest" });
}

function showUploadError(e) {
  const parts = e.message.split(/; (?=spec[.:])/);
  const rest = form.showErrors(e.message);
  if (rest) {
    if (/^survey|upload|file/i.test(rest) || e.status === 413 || e.status === 415) $("err-survey").textContent = rest;
    else if (e.status === 401) banner(e);
    else if (/^label/.test(rest)) $("err-label").textContent = rest;
    else $("err-spec").textContent = rest;
  }
  listErrors(parts.map((text) => {
    const m = text.match(/^spec\.([A-Za-z_]\w*)/);
    const target = m && form.fields[m[1]] ? `spec-${m[1]}` : /^label/.test(text) ? "label-input" : /^survey|file/i.test(text) ? "survey-input" : null;
    return { text, target };
  }));
}

async function send() {
  const { form: body, idem } = pending;
  const bar = $("upload-progress");
  bar.hidden = false;
  bar.value = 0;
  $("retry-btn").hidden = true;
  $("submit-btn").disabled = true;
  $("upload-status").textContent = "uploading…";
  uploading = true;
  try {
    const job = await upload(body, idem, (f) => {
      bar.value = f;
      $("upload-status").textContent = f < 1 ? `uploading ${Math.round(f * 100)} %` : "checking the survey…";
    });
    pending = null;
    $("upload-status").textContent = `queued as ${job.id.slice(0, 8)}`;
    await jobs.refresh();
  } catch (e) {
    if (e.status === 0) {
      // a dropped connection: the same Idempotency-Key on retry never queues the job twice
      $("upload-status").textContent = `${e.message}.`;
      $("retry-btn").hidden = false;
      $("retry-btn").focus();
    } else {
      pending = null;
      $("upload-status").textContent = "refused by the server";
      showUploadError(e);
    }
  } finally {
    uploading = false;
    $("submit-btn").disabled = false;
  }
}

function clearErrors() {
  form.clearErrors();
  $("err-survey").textContent = "";
  $("err-spec").textContent = "";
  $("err-label").textContent = "";
  listErrors([]);
}

async function submit(ev) {
  ev.preventDefault();
  clearErrors();
  const problems = [];
  if (!file) {
    $("err-survey").textContent = "survey: choose or drop a survey file first";
    problems.push({ text: $("err-survey").textContent, target: "survey-input" });
  } else {
    // the first bytes say whether this can be a survey at all: a wrong file is refused here,
    // before a long upload, with the message the server would give after it
    const wrong = await sniffSurvey(file);
    if (wrong) {
      $("err-survey").textContent = wrong;
      problems.push({ text: wrong, target: "survey-input" });
    }
  }
  for (const p of form.check()) problems.push({ text: p.text, target: `spec-${p.name}` });
  if (problems.length) {
    listErrors(problems);
    $(problems[0].target)?.focus();
    return;
  }
  const body = new FormData();
  body.append("survey", file, file.name);
  body.append("spec", JSON.stringify(form.value()));
  if ($("label-input").value.trim()) body.append("label", $("label-input").value.trim());
  pending = { form: body, idem: crypto.randomUUID() };
  send();
}

// Leaving mid-upload loses it: the browser asks first.
window.addEventListener("beforeunload", (ev) => {
  if (!uploading) return;
  ev.preventDefault();
  ev.returnValue = "";
});

async function start() {
  keyStatus();
  try {
    form = new SpecForm($("spec-fields"), await api("/schemas/reconstruction-spec"));
  } catch (e) {
    banner(e, true);
    return;
  }
  new Presets(form, $("presets"), $("estimate")).load().catch((e) => ($("estimate").textContent = `Presets unavailable: ${e.message}`));
  jobs.start();
  route();
}

$("key-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  key.set($("key-input").value);
  $("key-input").value = "";
  sticky = false;
  keyStatus();
  jobs.clear();
  jobs.refresh();
  route();
});
$("key-forget").addEventListener("click", () => {
  key.set("");
  keyStatus();
  jobs.clear();
  jobs.refresh();
});
$("survey-input").addEventListener("change", () => pickFile($("survey-input").files[0] || null));
const drop = $("drop");
for (const t of ["dragenter", "dragover"]) drop.addEventListener(t, (e) => {
  e.preventDefault();
  drop.classList.add("over");
});
for (const t of ["dragleave", "drop"]) drop.addEventListener(t, () => drop.classList.remove("over"));
drop.addEventListener("drop", (e) => {
  e.preventDefault();
  if (e.dataTransfer.files.length) pickFile(e.dataTransfer.files[0]);
});
$("upload-form").addEventListener("submit", submit);
$("retry-btn").addEventListener("click", () => pending && send());
// the skip link moves the focus without touching the address (the hash names the open result)
document.querySelector(".skip").addEventListener("click", (ev) => {
  ev.preventDefault();
  $("jobs-h").focus();
});
window.addEventListener("hashchange", route);
window.shsasConsole = { jobs, result, viewer, tools, ApiError }; // for the browser tests
start();
