// The admin page: failed jobs of every team, each with a re-run button.
"use strict";

const ADMIN_KEY = "firefly3d.admin-token";
const $ = (id) => document.getElementById(id);

async function load() {
  const token = $("admin-token").value.trim();
  sessionStorage.setItem(ADMIN_KEY, token);
  try {
    const jobs = await api("GET", "/api/v1/admin/jobs?status=failed", token);
    $("admin-status").textContent = `${jobs.length} failed job(s)`;
    $("failed").querySelector("tbody").replaceChildren(...jobs.map((job) => jobRow(job, token)));
  } catch (error) {
    $("admin-status").textContent = `error: ${error.message}`;
  }
}

function jobRow(job, token) {
  const select = el("select", {});
  select.append($("stage-options").content.cloneNode(true));
  const button = el("button", { type: "button" }, "Re-run");
  button.addEventListener("click", async () => {
    button.disabled = true;
    try {
      const body = select.value ? { from_stage: select.value } : {};
      const result = await api("POST", `/api/v1/admin/jobs/${job.id}/rerun`, token, body);
      await load();
      $("admin-status").textContent = `job ${job.id} re-queued from ${result.from_stage}`;
    } catch (error) {
      $("admin-status").textContent = `error: ${error.message}`;
      button.disabled = false;
    }
  });
  return el("tr", { "data-job": job.id },
    el("td", {}, el("a", { href: `/jobs/${job.id}` }, job.id.slice(0, 8))),
    el("td", {}, job.team), el("td", {}, `${job.site}, ${job.date}`),
    el("td", { class: "error" }, job.error || ""), el("td", {}, select), el("td", {}, button));
}

$("admin-token").value = sessionStorage.getItem(ADMIN_KEY) || "";
$("load").addEventListener("click", load);
if ($("admin-token").value) load();
