// The shsas operator console: key, upload, jobs, result. Only the public REST API is used.

import { api, ApiError, key, upload } from "./api.js";
import { SpecForm } from "./form.js";
import { JobList } from "./jobs.js";
import { ResultView } from "./result.js";
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

const jobs = new JobList({
  list: $("job-list"),
  empty: $("jobs-empty"),
  onOpen: (job) => result.open(job).catch((e) => banner(e, true)),
  onError: (e, keep) => banner(e, keep),
});
const viewer = new Viewer($("viewer"));
const result = new ResultView(viewer, (e, keep) => banner(e, keep));

function pickFile(f) {
  file = f;
  $("survey-name").textContent = f ? `${f.name} (${(f.size / 1e6).toFixed(2)} MB)` : "";
  $("err-survey").textContent = "";
}

function showUploadError(e) {
  const detail = e.message;
  const rest = form.showErrors(detail);
  if (!rest) return;
  if (/^survey|upload|file/i.test(rest) || e.status === 413 || e.status === 415) $("err-survey").textContent = rest;
  else if (e.status === 401) banner(e);
  else $("err-spec").textContent = rest;
}

async function send() {
  const { form: body, idem } = pending;
  const bar = $("upload-progress");
  bar.hidden = false;
  bar.value = 0;
  $("retry-btn").hidden = true;
  $("submit-btn").disabled = true;
  $("upload-status").textContent = "uploading…";
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
    $("submit-btn").disabled = false;
  }
}

function submit(ev) {
  ev.preventDefault();
  form.clearErrors();
  $("err-survey").textContent = "";
  $("err-spec").textContent = "";
  if (!file) {
    $("err-survey").textContent = "survey: choose or drop a survey file first";
    $("survey-input").focus();
    return;
  }
  const body = new FormData();
  body.append("survey", file, file.name);
  body.append("spec", JSON.stringify(form.value()));
  pending = { form: body, idem: crypto.randomUUID() };
  send();
}

async function start() {
  keyStatus();
  try {
    form = new SpecForm($("spec-fields"), await api("/schemas/reconstruction-spec"));
  } catch (e) {
    banner(e, true);
    return;
  }
  jobs.start();
}

$("key-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  key.set($("key-input").value);
  $("key-input").value = "";
  sticky = false;
  keyStatus();
  jobs.clear();
  jobs.refresh();
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
window.shsasConsole = { jobs, result, viewer, ApiError }; // for the browser tests
start();
