// The upload form: hash each chapter, create the night and the job, upload every file
// (presigned S3 multipart parts, or Content-Range pieces streamed to the API), submit,
// then open the job's page. Progress survives a reload: the job and the files'
// checksums are remembered in localStorage, and the server says what it already has.
"use strict";

const RESUME_KEY = "firefly3d.upload";
const PARALLEL_PARTS = 3;
const SIGN_BATCH = 20;
const RETRIES = 5;
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

function row(entry) {
  const bar = el("progress", { max: "1", value: "0" });
  const state = el("td", {}, "waiting");
  $("files").querySelector("tbody").append(
    el("tr", { "data-camera": entry.camera, "data-chapter": entry.chapter },
      el("td", {}, String(entry.camera)), el("td", {}, String(entry.chapter)),
      el("td", {}, entry.file.name), state, el("td", {}, bar)));
  return (text, fraction) => {
    state.textContent = text;
    if (fraction !== undefined) bar.value = fraction;
  };
}

function nightBody() {
  const number = (id) => ($(id).value === "" ? null : Number($(id).value));
  return {
    site: $("site").value, date: $("date").value, latitude: number("latitude"),
    longitude: number("longitude"), separation_m: number("separation"),
    height_m: number("height"), notes: $("notes").value,
  };
}

async function withRetries(action, what) {
  for (let attempt = 1; ; attempt++) {
    try {
      return await action();
    } catch (error) {
      const permanent = error instanceof ApiError && error.status < 500 && error.status !== 409;
      if (permanent || attempt >= RETRIES) throw error;
      status(`${what}: ${error.message}; retrying (${attempt}/${RETRIES - 1})`);
      await sleep(1000 * 2 ** attempt);
    }
  }
}

// PUT with upload progress (fetch cannot report it).
function put(url, body, headers, onProgress) {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("PUT", url);
    for (const [key, value] of Object.entries(headers)) xhr.setRequestHeader(key, value);
    xhr.upload.onprogress = (e) => onProgress(e.loaded);
    xhr.onload = () => (xhr.status < 300 ? resolve(xhr)
      : reject(new ApiError(xhr.status, xhr.responseText || xhr.statusText)));
    xhr.onerror = () => reject(new Error("network error"));
    xhr.send(body);
  });
}

async function uploadMultipart(token, info, file, show) {
  const done = new Set(info.uploaded_parts);
  const todo = [];
  for (let n = 1; n <= info.part_count; n++) if (!done.has(n)) todo.push(n);
  const sent = {};
  const total = () => (done.size * info.part_size + Object.values(sent).reduce((a, b) => a + b, 0)) / file.size;
  while (todo.length) {
    const batch = todo.splice(0, SIGN_BATCH);
    const signed = await withRetries(
      () => api("POST", `${info.upload_url}/parts`, token, { part_numbers: batch }), "signing");
    const queue = [...signed.parts];
    const worker = async () => {
      for (let part = queue.shift(); part; part = queue.shift()) {
        const start = (part.number - 1) * info.part_size;
        const blob = file.slice(start, Math.min(start + info.part_size, file.size));
        await withRetries(() => put(part.url, blob, {}, (loaded) => {
          sent[part.number] = loaded;
          show("uploading", Math.min(total(), 1));
        }), `part ${part.number}`);
        delete sent[part.number];
        done.add(part.number);
        show("uploading", Math.min(total(), 1));
      }
    };
    await Promise.all(Array.from({ length: PARALLEL_PARTS }, worker));
  }
  return withRetries(() => api("POST", `${info.upload_url}/complete`, token), "completing");
}

async function uploadStream(token, info, file, show) {
  let offset = info.received_bytes;
  while (offset < file.size) {
    const end = Math.min(offset + info.part_size, file.size);
    try {
      const xhr = await put(info.upload_url, file.slice(offset, end), {
        Authorization: `Bearer ${token}`,
        "Content-Type": "application/octet-stream",
        "Content-Range": `bytes ${offset}-${end - 1}/${file.size}`,
      }, (loaded) => show("uploading", (offset + loaded) / file.size));
      offset = JSON.parse(xhr.responseText).received_bytes;
    } catch (error) {
      if (error instanceof ApiError && error.status === 422) throw error;
      status(`${file.name}: ${error.message}; resuming`);
      await sleep(2000);
      offset = (await withRetries(() => api("GET", info.upload_url, token), "status")).received_bytes;
    }
    show("uploading", offset / file.size);
  }
}

async function uploadFile(token, entry, show) {
  const info = await withRetries(() => api("GET", entry.url, token), "status");
  if (info.upload_state === "uploaded") return show("uploaded", 1);
  show("uploading", info.received_bytes / entry.file.size);
  if (info.method === "s3-multipart") await uploadMultipart(token, info, entry.file, show);
  else await uploadStream(token, info, entry.file, show);
  show("uploaded", 1);
}

async function hashAll(entries, saved) {
  const known = new Map((saved?.files || []).map((f) => [f.fingerprint, f.sha256]));
  for (const entry of entries) {
    entry.sha256 = known.get(fingerprint(entry.file))
      || await sha256File(entry.file, (p) => entry.show("checksum", p));
    entry.show("checksum done", 0);
  }
}

function paramOverrides() {
  const text = $("params").value.trim();
  try {
    return text ? JSON.parse(text) : null;
  } catch (error) {
    throw new Error(`parameter overrides are not valid JSON: ${error.message}`);
  }
}

async function createJob(token, entries) {
  const params = paramOverrides();
  const night = await api("POST", "/api/v1/nights", token, nightBody());
  return api("POST", "/api/v1/jobs", token, {
    night_id: night.id,
    params,
    files: entries.map((e) => ({
      camera: e.camera, chapter: e.chapter, filename: e.file.name, size: e.file.size, sha256: e.sha256,
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
    status("computing checksums…");
    await hashAll(entries, saved);
    let job = await resumableJob(token, entries, saved);
    status(job ? "resuming the previous upload…" : "creating the job…");
    job = job || await createJob(token, entries);
    localStorage.setItem(RESUME_KEY, JSON.stringify({
      jobId: job.id,
      night: nightBody(),
      files: entries.map((e) => ({ fingerprint: fingerprint(e.file), sha256: e.sha256 })),
    }));
    for (const entry of entries) {
      entry.url = job.files.find((f) => f.camera === entry.camera && f.chapter === entry.chapter).upload_url;
      status(`uploading ${entry.file.name}…`);
      await uploadFile(token, entry, entry.show);
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
    separation_m: "separation", height_m: "height", notes: "notes" };
  for (const [key, id] of Object.entries(fields)) if (saved.night[key] != null) $(id).value = saved.night[key];
  $("progress").hidden = false;
  status(`An upload of ${saved.files.length} files was interrupted: select the same files and ` +
    "press the button to continue where it stopped.");
}

offerResume();
$("upload-form").addEventListener("submit", start);
