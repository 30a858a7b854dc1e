// The job page's interactive 3D view of the trajectories (three.js, vendored: no CDN).
// Loads trajectories.csv and calibration.json through freshly signed links once the job
// has succeeded; draws each trajectory's flashes joined in time order, the two cameras
// and the ground; a time slider (or Play) shows the flashes of a time window, coloured
// by trajectory or by time. The canvas reports what it draws in data-visible (points
// drawn) and data-renders (frames rendered), which the browser tests read.
import {
  BufferGeometry, Color, Float32BufferAttribute, GridHelper, LineBasicMaterial, LineSegments,
  Mesh, MeshBasicMaterial, OrbitControls, PerspectiveCamera, Points, PointsMaterial, Scene,
  SphereGeometry, Vector3, WebGLRenderer,
} from "./vendor/three-viewer.min.js";

// Matplotlib's tab20: the report's trajectory colours.
const PALETTE = ["#1f77b4", "#aec7e8", "#ff7f0e", "#ffbb78", "#2ca02c", "#98df8a", "#d62728",
  "#ff9896", "#9467bd", "#c5b0d5", "#8c564b", "#c49c94", "#e377c2", "#f7b6d2", "#7f7f7f",
  "#c7c7c7", "#bcbd22", "#dbdb8d", "#17becf", "#9edae5"].map((hex) => new Color(hex));

const v$ = (id) => document.getElementById(id);

// Columns of a numeric CSV by name (empty cells: NaN); text columns are skipped.
function parseCsv(text, wanted) {
  const lines = text.split("\n").filter((line) => line.trim() !== "");
  const header = lines[0].split(",");
  const index = Object.fromEntries(wanted.map((name) => [name, header.indexOf(name)]));
  const missing = wanted.filter((name) => index[name] < 0);
  if (missing.length) throw new Error(`trajectories.csv lacks ${missing.join(", ")}`);
  const columns = Object.fromEntries(wanted.map((name) => [name, new Float64Array(lines.length - 1)]));
  for (let row = 1; row < lines.length; row += 1) {
    const cells = lines[row].split(",");
    for (const name of wanted) columns[name][row - 1] = cells[index[name]] === "" ? NaN : Number(cells[index[name]]);
  }
  const start = header.indexOf("timestamp_utc");
  const firstStamp = start >= 0 && lines.length > 1 ? lines[1].split(",")[start] : "";
  return { columns, n: lines.length - 1, firstStamp };
}

// Viridis-like ramp for colouring by time (t in 0..1).
function ramp(t) {
  const stops = [[0.267, 0.005, 0.329], [0.229, 0.322, 0.546], [0.128, 0.567, 0.551],
    [0.369, 0.789, 0.383], [0.993, 0.906, 0.144]];
  const x = Math.min(Math.max(t, 0), 1) * (stops.length - 1);
  const i = Math.min(Math.floor(x), stops.length - 2);
  const f = x - i;
  return new Color(...stops[i].map((c, k) => c + f * (stops[i + 1][k] - c)));
}

class Viewer {
  constructor(canvas, data, calibration) {
    this.canvas = canvas;
    this.data = data;
    const { x, y, z, time_s: time, trajectory_id: id, frame } = data.columns;
    // Points in time order (the window is a contiguous draw range); lines in trajectory order.
    this.byTime = Array.from({ length: data.n }, (_, i) => i).sort((a, b) => time[a] - time[b]);
    this.times = Float64Array.from(this.byTime, (i) => time[i]);
    this.t0 = data.n ? this.times[0] : 0;
    this.t1 = data.n ? this.times[data.n - 1] : 1;

    this.renderer = new WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(1);
    this.scene = new Scene();
    this.scene.background = new Color("#0b1020");
    this.camera = new PerspectiveCamera(50, 1, 0.05, 500);
    this.camera.up.set(0, 0, 1); // the data are z-up (DESIGN.md)

    const positions = new Float32Array(data.n * 3);
    this.byTime.forEach((i, k) => positions.set([x[i], y[i], z[i]], 3 * k));
    this.points = new Points(new BufferGeometry(), new PointsMaterial({
      size: 4, sizeAttenuation: false, vertexColors: true }));
    this.points.geometry.setAttribute("position", new Float32BufferAttribute(positions, 3));
    this.points.geometry.setAttribute("color", new Float32BufferAttribute(new Float32Array(data.n * 3), 3));
    this.scene.add(this.points);

    const order = Array.from({ length: data.n }, (_, i) => i)
      .sort((a, b) => id[a] - id[b] || frame[a] - frame[b]);
    const segments = [];
    for (let k = 1; k < order.length; k += 1) {
      if (id[order[k]] === id[order[k - 1]]) segments.push(order[k - 1], order[k]);
    }
    this.segments = segments;
    const linePositions = new Float32Array(segments.length * 3);
    segments.forEach((i, k) => linePositions.set([x[i], y[i], z[i]], 3 * k));
    this.lines = new LineSegments(new BufferGeometry(), new LineBasicMaterial({
      vertexColors: true, transparent: true, opacity: 0.45 }));
    this.lines.geometry.setAttribute("position", new Float32BufferAttribute(linePositions, 3));
    this.lines.geometry.setAttribute("color", new Float32BufferAttribute(new Float32Array(segments.length * 3), 3));
    this.scene.add(this.lines);

    this.addRig(calibration);
    this.frameView(positions);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.target.copy(this.centre);
    this.controls.addEventListener("change", () => this.render());
    this.colourBy("trajectory");
  }

  addRig(calibration) {
    const camera = (colour, at) => {
      const mark = new Mesh(new SphereGeometry(0.12, 16, 12), new MeshBasicMaterial({ color: colour }));
      mark.position.copy(at);
      this.scene.add(mark);
    };
    const s = calibration.separation_m ?? 1;
    const t = calibration.translation ?? [1, 0, 0];
    this.camera2 = new Vector3(t[0] * s, t[1] * s, t[2] * s);
    camera("#ffffff", new Vector3(0, 0, 0));
    camera("#ff4040", this.camera2);
    const baseline = new BufferGeometry().setFromPoints([new Vector3(0, 0, 0), this.camera2]);
    this.scene.add(new LineSegments(baseline, new LineBasicMaterial({ color: "#ffffff" })));
    // The ground (10 m grid of 1 m) when the camera height is known.
    if (calibration.camera_height_m != null) {
      const grid = new GridHelper(20, 20, "#3a4a3a", "#243024");
      grid.rotation.x = Math.PI / 2; // GridHelper lies in x-z; ours is the x-y plane
      grid.position.z = -calibration.camera_height_m;
      this.scene.add(grid);
    }
  }

  frameView(positions) {
    const centre = new Vector3();
    let count = 0;
    for (let k = 0; k < positions.length; k += 3) {
      centre.add(new Vector3(positions[k], positions[k + 1], positions[k + 2]));
      count += 1;
    }
    this.centre = count ? centre.divideScalar(count) : new Vector3();
    let radius = 2;
    for (let k = 0; k < positions.length; k += 3) {
      radius = Math.max(radius, this.centre.distanceTo(new Vector3(positions[k], positions[k + 1], positions[k + 2])));
    }
    this.camera.position.copy(this.centre).add(new Vector3(radius * 0.8, -radius * 1.1, radius * 0.7));
    this.camera.lookAt(this.centre);
  }

  colourBy(mode) {
    const { trajectory_id: id, time_s: time } = this.data.columns;
    const span = Math.max(this.t1 - this.t0, 1e-9);
    const colourOf = (i) => (mode === "time" ? ramp((time[i] - this.t0) / span) : PALETTE[((id[i] % 20) + 20) % 20]);
    const pointColours = this.points.geometry.getAttribute("color");
    this.byTime.forEach((i, k) => { const c = colourOf(i); pointColours.setXYZ(k, c.r, c.g, c.b); });
    pointColours.needsUpdate = true;
    const lineColours = this.lines.geometry.getAttribute("color");
    this.segments.forEach((i, k) => { const c = colourOf(i); lineColours.setXYZ(k, c.r, c.g, c.b); });
    lineColours.needsUpdate = true;
    this.render();
  }

  // Show the points of [end - width, end] seconds (all points when width is null).
  showWindow(end, width) {
    let first = 0;
    let last = this.data.n;
    if (width !== null) {
      first = lowerBound(this.times, end - width);
      last = lowerBound(this.times, end + 1e-9);
    }
    this.points.geometry.setDrawRange(first, last - first);
    this.lines.visible = width === null || v$("viewer-trails").checked;
    this.canvas.dataset.visible = String(last - first);
    this.render();
  }

  resize() {
    const width = this.canvas.clientWidth || 800;
    const height = this.canvas.clientHeight || 500;
    this.renderer.setSize(width, height, false);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  render() {
    this.renderer.render(this.scene, this.camera);
    this.canvas.dataset.renders = String(Number(this.canvas.dataset.renders || 0) + 1);
  }
}

function lowerBound(sorted, value) {
  let lo = 0;
  let hi = sorted.length;
  while (lo < hi) {
    const mid = (lo + hi) >> 1;
    if (sorted[mid] < value) lo = mid + 1; else hi = mid;
  }
  return lo;
}

// "21:47:05 (UTC)" or "+12.5 s" for a time on camera 1's clock.
function clockLabel(seconds, data) {
  if (data.firstStamp) {
    const first = data.columns.time_s[0];
    const when = new Date(Date.parse(data.firstStamp) + (seconds - first) * 1000);
    return `${when.toISOString().slice(11, 19)} UTC`;
  }
  return `${seconds.toFixed(1)} s`;
}

async function fetchArtifact(token, name) {
  const link = await api("POST", `/api/v1/jobs/${JOB_ID}/links`, token, { name });
  const response = await fetch(link.url);
  if (!response.ok) throw new Error(`${name}: HTTP ${response.status}`);
  return response.text();
}

function wireControls(viewer) {
  const slider = v$("viewer-time");
  const width = v$("viewer-width");
  const whole = v$("viewer-whole");
  const span = viewer.t1 - viewer.t0;
  slider.min = String(viewer.t0);
  slider.max = String(viewer.t1);
  slider.step = String(Math.max(span / 1000, 0.01));
  slider.value = String(viewer.t1);
  width.max = String(Math.max(Math.ceil(span), 1));
  const update = () => {
    const end = Number(slider.value);
    const seconds = Number(width.value);
    v$("viewer-width-label").textContent = `${seconds} s`;
    v$("viewer-clock").textContent = whole.checked ? "whole night"
      : `${clockLabel(end - seconds, viewer.data)} – ${clockLabel(end, viewer.data)}`;
    viewer.showWindow(end, whole.checked ? null : seconds);
  };
  for (const control of [slider, width, v$("viewer-trails")]) control.addEventListener("input", update);
  slider.addEventListener("input", () => { whole.checked = false; update(); });
  whole.addEventListener("change", update);
  v$("viewer-colour").addEventListener("change", (event) => viewer.colourBy(event.target.value));
  let playing = null;
  v$("viewer-play").addEventListener("click", () => {
    if (playing !== null) {
      cancelAnimationFrame(playing);
      playing = null;
      v$("viewer-play").textContent = "Play";
      return;
    }
    whole.checked = false;
    if (Number(slider.value) >= viewer.t1) slider.value = String(viewer.t0);
    v$("viewer-play").textContent = "Pause";
    let last = performance.now();
    const step = (now) => {
      const speed = Number(v$("viewer-speed").value);
      slider.value = String(Math.min(Number(slider.value) + ((now - last) / 1000) * speed, viewer.t1));
      last = now;
      update();
      if (Number(slider.value) >= viewer.t1) { playing = null; v$("viewer-play").textContent = "Play"; return; }
      playing = requestAnimationFrame(step);
    };
    playing = requestAnimationFrame(step);
  });
  new ResizeObserver(() => viewer.resize()).observe(viewer.canvas);
  update();
}

jobPage.register({
  async finished(job, token) {
    if (job.status !== "succeeded") return;
    try {
      const [csv, calibration] = await Promise.all([
        fetchArtifact(token, "trajectories.csv"), fetchArtifact(token, "calibration.json")]);
      const data = parseCsv(csv, ["x", "y", "z", "frame", "time_s", "trajectory_id"]);
      v$("viewer").hidden = false;
      v$("viewer-count").textContent = `${data.n.toLocaleString()} flash points`;
      const viewer = new Viewer(v$("viewer-canvas"), data, JSON.parse(calibration));
      viewer.resize();
      wireControls(viewer);
    } catch (error) {
      v$("viewer").hidden = false;
      v$("viewer-error").hidden = false;
      v$("viewer-error").textContent = `3D view unavailable: ${error.message}`;
    }
  },
});
