// The job page: poll the job every 2 s, show its stages, then its downloads and plots.
"use strict";

const FINISHED = ["succeeded", "failed", "cancelled"];
const JOB_ID = document.getElementById("job-id").dataset.jobId;
const $ = (id) => document.getElementById(id);

function stageLabel(stage) {
  if (stage.name === "track") return `track camera ${stage.camera}, frames ${stage.frame_start}–${stage.frame_stop}`;
  return stage.camera ? `${stage.name} camera ${stage.camera}` : stage.name;
}

// The run summary as "section.key" rows; the parameters are on the job already.
const NOT_SHOWN = ["parameters", "warnings"];

function flatten(value, prefix = "") {
  if (value === null || typeof value !== "object" || Array.isArray(value)) return [[prefix, value]];
  return Object.entries(value)
    .filter(([key]) => !(prefix === "" && NOT_SHOWN.includes(key)))
    .flatMap(([key, inner]) => flatten(inner, prefix ? `${prefix}.${key}` : key));
}

function showJob(job) {
  const statusNode = $("job-status");
  statusNode.textContent = job.status;
  statusNode.className = `status-${job.status}`;
  $("job-progress").value = job.progress;
  $("job-percent").textContent = `${Math.round(job.progress * 100)} %`;
  $("job-error").hidden = !job.error;
  $("job-error").textContent = job.error || "";
  $("cancel").hidden = FINISHED.includes(job.status);
  $("stages").querySelector("tbody").replaceChildren(...job.stages.map((stage) => el("tr",
    { "data-stage": stage.key, class: `status-${stage.status}` },
    el("td", {}, stageLabel(stage)),
    el("td", {}, stage.status),
    el("td", {}, String(stage.attempt)),
    el("td", {}, el("progress", { max: "1", value: String(stage.progress) })),
    el("td", {}, stage.error || stage.warnings.join("; ")))));
  const summary = flatten(job.summary).filter(([, value]) => value !== null);
  $("summary").hidden = !summary.length;
  $("summary-list").replaceChildren(...summary.flatMap(([key, value]) => [
    el("dt", {}, key), el("dd", {}, typeof value === "number" ? String(+value.toFixed(4)) : JSON.stringify(value))]));
}

async function showDownloads(token) {
  const artifacts = await api("GET", `/api/v1/jobs/${JOB_ID}/artifacts`, token);
  const link = (a) => el("li", {}, el("a", { href: a.url, download: a.name.split("/").pop() }, a.name),
    ` (${a.size.toLocaleString()} bytes)`);
  const results = artifacts.filter((a) => a.category === "result");
  $("results").replaceChildren(...results.filter((a) => !a.content_type.startsWith("image/")).map(link));
  $("intermediates").replaceChildren(...artifacts.filter((a) => a.category !== "result").map(link));
  $("plots").replaceChildren(...results.filter((a) => a.content_type.startsWith("image/"))
    .map((a) => el("figure", {}, el("img", { src: a.url, alt: a.name }), el("figcaption", {}, a.name))));
  $("downloads").hidden = false;
}

async function poll(token) {
  for (;;) {
    try {
      const job = await api("GET", `/api/v1/jobs/${JOB_ID}`, token);
      showJob(job);
      if (FINISHED.includes(job.status)) {
        if (job.status === "succeeded") await showDownloads(token);
        return;
      }
    } catch (error) {
      $("job-error").hidden = false;
      $("job-error").textContent = error.message;
      if (error.status === 401 || error.status === 404) return askToken();
    }
    await sleep(2000);
  }
}

function askToken() {
  $("token-line").hidden = false;
  $("token").value = savedToken();
}

$("token-save").addEventListener("click", () => {
  saveToken($("token").value.trim());
  $("token-line").hidden = true;
  poll(savedToken());
});
$("cancel").addEventListener("click", async () => {
  if (confirm("Cancel this job?")) await api("POST", `/api/v1/jobs/${JOB_ID}/cancel`, savedToken());
});

if (savedToken()) poll(savedToken()); else askToken();
