// Uploading one file to a job (used by the upload page and the admin page): each part
// hashed in a Web Worker (hash-wasm) and its SHA-256 checked by S3 (signed into its
// presigned URL) or by the API (stream path); several S3 parts in flight; retries with
// backoff; speed and time left; resuming from the parts the server already has.
"use strict";

// SHA-256 of blobs in the hash worker (started on first use).
class PartHasher {
  constructor() { this.worker = null; this.pending = new Map(); this.next = 0; }
  hash(blob) {
    if (!this.worker) {
      this.worker = new Worker("/static/hash-worker.js");
      this.worker.onmessage = ({ data }) => {
        const { resolve, reject } = this.pending.get(data.id);
        this.pending.delete(data.id);
        if (data.error) reject(new Error(`hashing failed: ${data.error}`)); else resolve(data);
      };
    }
    const id = this.next++;
    return new Promise((resolve, reject) => {
      this.pending.set(id, { resolve, reject });
      this.worker.postMessage({ id, blob });
    });
  }
}

// PUT with upload progress (fetch cannot report it). Rejects with ApiError on HTTP errors.
function put(url, body, headers, onProgress) {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("PUT", url);
    for (const [key, value] of Object.entries(headers)) xhr.setRequestHeader(key, value);
    xhr.upload.onprogress = (e) => onProgress(e.loaded);
    xhr.onload = () => {
      if (xhr.status < 300) return resolve(xhr);
      let detail = xhr.responseText || xhr.statusText;
      try { detail = JSON.parse(xhr.responseText).detail; } catch { /* S3's XML, or text */ }
      const error = new ApiError(xhr.status, detail);
      error.offset = xhr.getResponseHeader("Upload-Offset");
      reject(error);
    };
    xhr.onerror = () => reject(new Error("network error"));
    xhr.send(body);
  });
}

const RETRIES = 6;

// Runs action() until it succeeds; network errors, 5xx and 409 are retried with backoff.
async function withRetries(action, what, report) {
  for (let attempt = 1; ; attempt++) {
    try {
      return await action();
    } catch (error) {
      const permanent = error instanceof ApiError && error.status < 500 && error.status !== 409;
      if (permanent || attempt >= RETRIES) throw error;
      report(`${what}: ${error.message}; retrying (${attempt}/${RETRIES - 1})`);
      await sleep(1000 * 2 ** attempt);
    }
  }
}

// Bytes done over the last seconds → rate and time left, for one file.
class SpeedMeter {
  constructor(total, done) { this.total = total; this.samples = [[performance.now(), done]]; }
  update(done) {
    const now = performance.now();
    this.samples.push([now, done]);
    while (this.samples.length > 2 && now - this.samples[0][0] > 10_000) this.samples.shift();
  }
  text(done) {
    const [t0, d0] = this.samples[0];
    const seconds = (performance.now() - t0) / 1000;
    if (seconds < 0.5 || done <= d0) return "";
    const rate = (done - d0) / seconds;
    return `${(rate / 1e6).toFixed(1)} MB/s · ${duration((this.total - done) / rate)} left`;
  }
}

function duration(seconds) {
  if (seconds < 60) return `${Math.ceil(seconds)} s`;
  if (seconds < 3600) return `${Math.round(seconds / 60)} min`;
  return `${Math.floor(seconds / 3600)} h ${Math.round((seconds % 3600) / 60)} min`;
}

const PARALLEL_PARTS = 4;
const hasher = new PartHasher();
const partBlob = (file, size, n) => file.slice((n - 1) * size, Math.min(n * size, file.size));

// S3: PARALLEL_PARTS lanes, each hashing a part, signing it with its checksum, PUTting it.
async function uploadMultipart(token, info, file, show, report) {
  const size = info.part_size;
  const done = new Set(info.uploaded_parts);
  const todo = [];
  for (let n = 1; n <= info.part_count; n++) if (!done.has(n)) todo.push(n);
  const sending = {};
  const bytesDone = () => Math.min(file.size,
    done.size * size + Object.values(sending).reduce((a, b) => a + b, 0));
  const meter = new SpeedMeter(file.size, bytesDone());
  const showProgress = () => {
    const bytes = bytesDone();
    meter.update(bytes);
    show("uploading", bytes / file.size, meter.text(bytes));
  };
  const lane = async () => {
    for (let n = todo.shift(); n !== undefined; n = todo.shift()) {
      const blob = partBlob(file, size, n);
      const digest = await hasher.hash(blob);
      await withRetries(async () => {
        const signed = await api("POST", `${info.upload_url}/parts`, token,
          { part_numbers: [n], checksums_sha256: [digest.base64] });
        await put(signed.parts[0].url, blob, { "x-amz-checksum-sha256": digest.base64 }, (loaded) => {
          sending[n] = loaded;
          showProgress();
        });
      }, `${file.name} part ${n}`, report);
      delete sending[n];
      done.add(n);
      showProgress();
    }
  };
  await Promise.all(Array.from({ length: PARALLEL_PARTS }, lane));
  return withRetries(() => api("POST", `${info.upload_url}/complete`, token), "completing", report);
}

// Local storage: parts PUT in order with Content-Range; the next part is hashed while
// the current one is sent. After an error the server says where to continue.
async function uploadStream(token, info, file, show, report) {
  const size = info.part_size;
  const hashFrom = (start) => (start < file.size ? hasher.hash(file.slice(start, start + size)) : null);
  let offset = info.received_bytes;
  let failures = 0;
  let next = hashFrom(offset);
  const meter = new SpeedMeter(file.size, offset);
  while (offset < file.size) {
    const end = Math.min(offset + size, file.size);
    const digest = await next;
    next = hashFrom(end);
    try {
      const xhr = await put(info.upload_url, file.slice(offset, end), {
        Authorization: `Bearer ${token}`,
        "Content-Type": "application/octet-stream",
        "Content-Range": `bytes ${offset}-${end - 1}/${file.size}`,
        "x-amz-checksum-sha256": digest.base64,
      }, (loaded) => {
        meter.update(offset + loaded);
        show("uploading", (offset + loaded) / file.size, meter.text(offset + loaded));
      });
      offset = JSON.parse(xhr.responseText).received_bytes;
      failures = 0;
    } catch (error) {
      const resumable = !(error instanceof ApiError) || error.status >= 500 || error.offset !== null;
      if (!resumable || ++failures >= RETRIES) throw error;
      report(`${file.name}: ${error.message}; resuming`);
      await sleep(1000 * 2 ** failures);
      offset = (await withRetries(() => api("GET", info.upload_url, token), "status", report)).received_bytes;
      next = hashFrom(offset);
    }
  }
}

// Upload `file` to a job's file URL, continuing from what the server has; show(state,
// fraction, speed) follows the progress, report(text) tells of retries.
async function uploadFile(token, url, file, show, report) {
  const info = await withRetries(() => api("GET", url, token), "status", report);
  if (info.upload_state === "uploaded") return show("uploaded", 1);
  show("uploading", info.received_bytes / file.size);
  if (info.method === "s3-multipart") await uploadMultipart(token, info, file, show, report);
  else await uploadStream(token, info, file, show, report);
  show("uploaded", 1);
}

