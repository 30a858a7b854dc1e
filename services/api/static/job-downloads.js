// The job page's downloads: links are signed when clicked (POST …/links), so a page
// left open for hours still downloads; "download all" is one zip streamed by the API;
// report plots are shown with fresh links, signed again if one has expired.
"use strict";

async function freshLink(token, name) {
  return (await api("POST", `/api/v1/jobs/${JOB_ID}/links`, token, { name })).url;
}

function downloadLink(token, artifact) {
  const link = el("a", { href: "#", "data-name": artifact.name }, artifact.name);
  link.addEventListener("click", async (event) => {
    event.preventDefault();
    window.location.assign(await freshLink(token, artifact.name));
  });
  return el("li", {}, link, ` (${artifact.size.toLocaleString()} bytes)`);
}

function plot(token, artifact) {
  const img = el("img", { src: artifact.url, alt: artifact.name });
  let retried = false;
  img.addEventListener("error", async () => {  // an expired link: sign it again, once
    if (retried) return;
    retried = true;
    img.src = await freshLink(token, artifact.name);
  });
  return el("figure", {}, img, el("figcaption", {}, artifact.name));
}

jobPage.register({
  async finished(job, token) {
    if (job.status !== "succeeded") return;
    const artifacts = await api("GET", `/api/v1/jobs/${JOB_ID}/artifacts`, token);
    const results = artifacts.filter((a) => a.category === "result");
    const isImage = (a) => a.content_type.startsWith("image/");
    $("results").replaceChildren(...results.filter((a) => !isImage(a)).map((a) => downloadLink(token, a)));
    $("intermediates").replaceChildren(
      ...artifacts.filter((a) => a.category !== "result").map((a) => downloadLink(token, a)));
    $("plots").replaceChildren(...results.filter(isImage).map((a) => plot(token, a)));
    $("download-all").onclick = async () => window.location.assign(await freshLink(token, null));
    $("downloads").hidden = false;
  },
});
