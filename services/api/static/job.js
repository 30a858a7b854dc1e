// The job page's core: polls the job (ETag: an unchanged job costs a 304) and hands
// each state to the registered sections. Another script adds a section with
// jobPage.register({ update(job) {…}, finished(job, token) {…} }) (both optional):
// this file shows the header, the status and the stages; job-summary.js the summary;
// job-downloads.js the downloads and plots.
"use strict";

const FINISHED = ["succeeded", "failed", "cancelled"];
const JOB_ID = document.getElementById("job-id").dataset.jobId;
const $ = (id) => document.getElementById(id);

const jobPage = {
  sections: [],
  register(section) { this.sections.push(section); },
};

// "sync", "merge camera 1", "track camera 1, frames 0–1800" (chunks have frame ranges).
function stageLabel(stage) {
  const camera = stage.camera ? `${stage.name} camera ${stage.camera}` : stage.name;
  return stage.frame_start === null ? camera : `${camera}, frames ${stage.frame_start}–${stage.frame_stop}`;
}

const localTime = (iso) => new Date(iso).toLocaleString();

function stageMessage(stage) {
  if (stage.status === "queued" && stage.stalled_at) {
    return `stalled, re-queued at ${localTime(stage.stalled_at)}`;
  }
  return stage.error || stage.warnings.join("; ");
}

jobPage.register({
  update(job) {
    $("job-title").textContent = `${job.site}, ${job.date} — ${job.team}`;
    document.title = `${job.site}, ${job.date} · firefly3d`;
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
      el("td", {}, stageMessage(stage)))));
  },
});

async function poll(token) {
  for (;;) {
    try {
      // The browser revalidates with If-None-Match (Cache-Control: no-cache): a 304
      // comes back here as the cached 200.
      const job = await api("GET", `/api/v1/jobs/${JOB_ID}`, token);
      for (const section of jobPage.sections) section.update?.(job);
      if (FINISHED.includes(job.status)) {
        for (const section of jobPage.sections) await section.finished?.(job, token);
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
// Sections register in the scripts after this one; start once they all have.
document.addEventListener("DOMContentLoaded", () => {
  if (savedToken()) poll(savedToken()); else askToken();
});
