// Web Worker of the upload page: SHA-256 of file parts with hash-wasm (WebAssembly),
// off the page's thread so that it stays responsive. Message {id, blob} → {id, hex,
// base64} or {id, error}. Requests are hashed one after another (one hasher).
"use strict";
importScripts("vendor/hash-wasm-sha256.umd.min.js");

const SLICE = 4 << 20; // bytes read at once: memory stays small whatever the part size
let hasher = null;
let queue = Promise.resolve();

async function digest(blob) {
  hasher = hasher || await hashwasm.createSHA256();
  hasher.init();
  for (let offset = 0; offset < blob.size; offset += SLICE) {
    hasher.update(new Uint8Array(await blob.slice(offset, offset + SLICE).arrayBuffer()));
  }
  const bytes = hasher.digest("binary");
  const hex = Array.from(bytes, (b) => b.toString(16).padStart(2, "0")).join("");
  return { hex, base64: btoa(String.fromCharCode(...bytes)) };
}

self.onmessage = ({ data }) => {
  queue = queue.then(async () => {
    try {
      self.postMessage({ id: data.id, ...(await digest(data.blob)) });
    } catch (error) {
      self.postMessage({ id: data.id, error: String(error) });
    }
  });
};
