// The admin page: jobs of every team by state (stalled ones too) with their age and last
// error; per job: re-run from a stage with parameter overrides (each parameter's
// description shown), replace an input file (uploaded like the upload page does), cancel.
"use strict";

const ADMIN_KEY = "firefly3d.admin-token";
const $ = (id) => document.getElementById(id);
const token = () => $("admin-token").value.trim();
let parameters = [];

function say(text) { $("admin-status").textContent = text; }

function age(iso) {
  const minutes = (Date.now() - new Date(iso).getTime()) / 60000;
  if (minutes < 60) return `${Math.max(0, Math.round(minutes))} min`;
  if (minutes < 48 * 60) return `${Math.round(minutes / 60)} h`;
  return `${Math.round(minutes / 1440)} days`;
}

async function load() {
  sessionStorage.setItem(ADMIN_KEY, token());
  try {
    if (!parameters.length) parameters = await api("GET", "/api/v1/admin/params", token());
    const state = $("state").value;
    const jobs = await api("GET", `/api/v1/admin/jobs${state ? `?status=${state}` : ""}`, token());
    say(`${jobs.length} ${state || "recent"} job(s)`);
    $("jobs").querySelector("tbody").replaceChildren(...jobs.map(jobRow));
  } catch (error) {
    say(`error: ${error.message}`);
  }
}

function statusText(job) {
  return job.stalled_at ? `${job.status}: stalled since ${new Date(job.stalled_at).toLocaleString()}` : job.status;
}

function jobRow(job) {
  const actions = $("job-actions").content.cloneNode(true);
  const row = el("tr", { "data-job": job.id },
    el("td", {}, el("a", { href: `/jobs/${job.id}` }, job.id.slice(0, 8))),
    el("td", {}, job.team), el("td", {}, `${job.site}, ${job.date}`),
    el("td", { class: `status-${job.status}` }, statusText(job)),
    el("td", { title: job.created_at }, age(job.created_at)),
    el("td", { class: "error" }, job.error || ""), el("td", {}, actions));
  rerunForm(job, row.querySelector(".rerun-form"));
  replaceForm(job, row.querySelector(".replace-form"));
  row.querySelector(".cancel").addEventListener("click", () => act(
    () => api("POST", `/api/v1/jobs/${job.id}/cancel`, token()), `job ${job.id} cancelled`));
  return row;
}

// Runs an action, reloads the list, then says what happened (or what went wrong).
async function act(action, done) {
  try {
    const result = await action();
    await load();
    say(typeof done === "function" ? done(result) : done);
  } catch (error) {
    say(`error: ${error.message}`);
  }
}

function setPath(target, path, value) {
  const keys = path.split(".");
  const last = keys.pop();
  for (const key of keys) target = target[key] ??= {};
  target[last] = value;
}

function rerunForm(job, form) {
  const stage = form.querySelector(".rerun-stage");
  stage.append($("stage-options").content.cloneNode(true));
  const name = form.querySelector(".param-name");
  name.append(...parameters.map((p) => el("option", { value: p.path }, p.path)));
  const help = form.querySelector(".param-help");
  name.addEventListener("change", () => {
    const p = parameters.find((q) => q.path === name.value);
    help.textContent = p ? `${p.description} (${p.type}, default ${JSON.stringify(p.default)})` : "";
  });
  const overrides = {};
  const list = form.querySelector(".overrides");
  form.querySelector(".add-override").addEventListener("click", () => {
    if (!name.value) return;
    const raw = form.querySelector(".param-value").value.trim();
    let value;
    try { value = JSON.parse(raw); } catch { value = raw; }
    overrides[name.value] = value;
    list.replaceChildren(...Object.entries(overrides).map(([k, v]) => el("li", {}, `${k} = ${JSON.stringify(v)}`)));
  });
  form.querySelector(".rerun").addEventListener("click", () => {
    const body = {};
    if (stage.value) body.from_stage = stage.value;
    if (Object.keys(overrides).length) {
      body.params = {};
      for (const [path, value] of Object.entries(overrides)) setPath(body.params, path, value);
    }
    act(() => api("POST", `/api/v1/admin/jobs/${job.id}/rerun`, token(), body),
      (result) => `job ${job.id} re-queued from ${result.from_stage}`);
  });
}

function replaceForm(job, form) {
  const bar = form.querySelector(".replace-progress");
  const speed = form.querySelector(".replace-speed");
  form.querySelector(".replace").addEventListener("click", async () => {
    const file = form.querySelector(".replace-file").files[0];
    if (!file) return say("choose the replacement file first");
    const camera = Number(form.querySelector(".replace-camera").value);
    const chapter = Number(form.querySelector(".replace-chapter").value);
    const url = `/api/v1/jobs/${job.id}/files/${camera}/${chapter}`;
    try {
      await api("POST", `${url}/replace`, token(), { camera, chapter, filename: file.name, size: file.size });
      await uploadFile(token(), url, file, (state, fraction, rate = "") => {
        if (fraction !== undefined) bar.value = fraction;
        speed.textContent = rate;
      }, say);
      say(`camera ${camera} chapter ${chapter} of job ${job.id} replaced by ${file.name}`);
    } catch (error) {
      say(`error: ${error.message}`);
    }
  });
}

$("admin-token").value = sessionStorage.getItem(ADMIN_KEY) || "";
$("load").addEventListener("click", load);
$("state").addEventListener("change", load);
if ($("admin-token").value) load();
