// The upload form: create the night and the job (one request: a wrong token or a bad
// parameter is refused before any byte is read), upload every file (upload-parts.js:
// hashed per part while sending, several parts in flight, speed and time left),
// submit, then open the job's page. A reload or a lost connection resumes: the job is
// remembered in localStorage, the server says which parts it already has, and only
// the others are sent.
"use strict";

const RESUME_KEY = "firefly3d.upload";
const files = { 1: [], 2: [] };
const $ = (id) => document.getElementById(id);
const fingerprint = (f) => `${f.name}|${f.size}|${f.lastModified}`;

function setFiles(camera, list) {
  files[camera] = Array.from(list).sort((a, b) => a.name.localeCompare(b.name, undefined, { numeric: true }));
  $(`cam${camera}-list`).replaceChildren(
    ...files[camera].map((f) => el("li", {}, `${f.name} (${(f.size / 2 ** 20).toFixed(1)} MiB)`)));
}

for (const camera of [1, 2]) {
  $(`cam${camera}-files`).addEventListener("change", (e) => setFiles(camera, e.target.files));
  const zone = document.querySelector(`.dropzone[data-camera="${camera}"]`);
  zone.addEventListener("dragover", (e) => { e.preventDefault(); zone.classList.add("over"); });
  zone.addEventListener("dragleave", () => zone.classList.remove("over"));
  zone.addEventListener("drop", (e) => {
    e.preventDefault();
    zone.classList.remove("over");
    setFiles(camera, e.dataTransfer.files);
  });
}
$("token").value = savedToken();

function status(text) { $("status").textContent = text; }

// A row of the progress table; returns show(state, fraction, speed).
function row(entry) {
  const bar = el("progress", { max: "1", value: "0" });
  const state = el("td", {}, "waiting");
  const speed = el("td", { class: "speed" }, "");
  $("files").querySelector("tbody").append(
    el("tr", { "data-camera": entry.camera, "data-chapter": entry.chapter },
      el("td", {}, String(entry.camera)), el("td", {}, String(entry.chapter)),
      el("td", {}, entry.file.name), state, el("td", {}, bar), speed));
  return (text, fraction, rate = "") => {
    state.textContent = text;
    if (fraction !== undefined) bar.value = fraction;
    speed.textContent = rate;
  };
}

function nightBody() {
  const number = (id) => ($(id).value === "" ? null : Number($(id).value));
  const text = (id) => ($(id).value.trim() === "" ? null : $(id).value.trim());
  return {
    site: $("site").value, date: $("date").value, latitude: number("latitude"),
    longitude: number("longitude"), separation_m: number("separation"),
    height_m: number("height"), notes: $("notes").value,
    time_zone: text("time-zone"), camera_clock: $("camera-clock").value,
    start_time: text("start-time"), camera_model: text("camera-model"),
  };
}

// Time zone names for the site's field (the browser's own is only a hint, not a default:
// the site's zone is what matters, and an unknown zone is better than a wrong one).
function offerTimeZones() {
  const zones = Intl.supportedValuesOf ? Intl.supportedValuesOf("timeZone") : [];
  $("time-zones").replaceChildren(...zones.map((zone) => el("option", { value: zone })));
  const here = Intl.DateTimeFormat().resolvedOptions().timeZone;
  if (here) $("time-zone").placeholder = `e.g. ${here} (this computer's)`;
}

function paramOverrides() {
  const text = $("params").value.trim();
  try {
    return text ? JSON.parse(text) : null;
  } catch (error) {
    throw new Error(`parameter overrides are not valid JSON: ${error.message}`);
  }
}

// One request creates the night and the job, or neither.
function createJob(token, entries) {
  return api("POST", "/api/v1/jobs", token, {
    night: nightBody(),
    params: paramOverrides(),
    files: entries.map((e) => ({
      camera: e.camera, chapter: e.chapter, filename: e.file.name, size: e.file.size,
    })),
  });
}

// A saved job is resumed only if the same files are selected again and it still awaits uploads.
async function resumableJob(token, entries, saved) {
  if (!saved || saved.files.length !== entries.length) return null;
  if (!entries.every((e, i) => saved.files[i].fingerprint === fingerprint(e.file))) return null;
  try {
    const job = await api("GET", `/api/v1/jobs/${saved.jobId}`, token);
    return ["created", "uploading"].includes(job.status) ? job : null;
  } catch {
    return null;
  }
}

async function start(event) {
  event.preventDefault();
  const token = $("token").value.trim();
  saveToken(token);
  if (!files[1].length || !files[2].length) return alert("Select the chapter files of both cameras.");
  $("start").disabled = true;
  $("progress").hidden = false;
  $("files").querySelector("tbody").replaceChildren();
  const entries = [1, 2].flatMap((camera) => files[camera].map((file, chapter) => ({ camera, chapter, file })));
  for (const entry of entries) entry.show = row(entry);
  try {
    const saved = JSON.parse(localStorage.getItem(RESUME_KEY) || "null");
    let job = await resumableJob(token, entries, saved);
    status(job ? "resuming the previous upload…" : "creating the job…");
    job = job || await createJob(token, entries);
    localStorage.setItem(RESUME_KEY, JSON.stringify({
      jobId: job.id,
      night: nightBody(),
      files: entries.map((e) => ({ fingerprint: fingerprint(e.file) })),
    }));
    for (const entry of entries) {
      entry.url = job.files.find((f) => f.camera === entry.camera && f.chapter === entry.chapter).upload_url;
      status(`uploading ${entry.file.name}…`);
      await uploadFile(token, entry.url, entry.file, entry.show, status);
    }
    status("submitting…");
    await api("POST", `/api/v1/jobs/${job.id}/submit`, token);
    localStorage.removeItem(RESUME_KEY);
    const link = $("job-link");
    link.hidden = false;
    link.querySelector("a").href = `/jobs/${job.id}`;
    link.querySelector("a").textContent = job.id;
    status("submitted: opening the job page…");
    window.location.assign(`/jobs/${job.id}`);
  } catch (error) {
    status(`error: ${error.message}`);
    $("start").disabled = false;
  }
}

// After a reload: refill the night and ask for the same files to continue.
function offerResume() {
  const saved = JSON.parse(localStorage.getItem(RESUME_KEY) || "null");
  if (!saved?.night) return;
  const fields = { site: "site", date: "date", latitude: "latitude", longitude: "longitude",
    separation_m: "separation", height_m: "height", notes: "notes", time_zone: "time-zone",
    camera_clock: "camera-clock", start_time: "start-time", camera_model: "camera-model" };
  for (const [key, id] of Object.entries(fields)) if (saved.night[key] != null) $(id).value = saved.night[key];
  $("progress").hidden = false;
  status(`An upload of ${saved.files.length} files was interrupted: select the same files and ` +
    "press the button to continue where it stopped.");
}

offerTimeZones();
offerResume();
$("upload-form").addEventListener("submit", start);
