// The job page's summary: the run summary (pipeline/summary.py) with plain names and
// units, in the order of FIELDS. FIELDS maps a key path to [label, unit, scale]; "{c}"
// stands for a camera number, "{s}" for a stage. Keys not listed are still shown, last,
// under their key path.
"use strict";

const FIELDS = [
  ["counts.trajectories", "Trajectories"],
  ["counts.streaks", "Streaks"],
  ["counts.ambiguous_links", "Candidate links between streaks refused: another flash of that moment nearly as close"],
  ["counts.points", "Triangulated flashes"],
  ["counts.points_sure", "Triangulated flashes sure of their range to 2 %"],
  ["clock.start_local", "Recording started (local time)"],
  ["clock.start_utc", "Recording started (UTC)"],
  ["clock.start_minutes_after_sunset", "Recording started after sunset", "min"],
  ["clock.sunset_utc", "Sunset (UTC)"],
  ["clock.source", "Time of night from"],
  ["clock.time_zone", "Time zone of the site"],
  ["patterns.flash_duration_s.median", "Flash duration, median", "s"],
  ["patterns.flash_duration_s.q25", "Flash duration, 1st quartile", "s"],
  ["patterns.flash_duration_s.q75", "Flash duration, 3rd quartile", "s"],
  ["patterns.ifi_s.median", "Inter-flash interval, median", "s"],
  ["patterns.ifi_s.q25", "Inter-flash interval, 1st quartile", "s"],
  ["patterns.ifi_s.q75", "Inter-flash interval, 3rd quartile", "s"],
  ["patterns.ifi_s.mode", "Inter-flash interval, histogram peak", "s"],
  ["patterns.synchronous", "Synchronous flashing"],
  ["patterns.period_s", "Synchrony test: period of the strongest joint peak", "s"],
  ["patterns.strength", "Synchrony test: strength (0 = independent)"],
  ["patterns.z", "Synchrony test: significance", "σ"],
  ["patterns.count_period_s", "Period of the flash-count series", "s"],
  ["patterns.count_autocorrelation", "Flash-count autocorrelation at that period"],
  ["patterns.flashes_per_train", "Flashes per train, median"],
  ["patterns.n_trains", "Flash trains"],
  ["patterns.n_flashes", "Flashes (streaks)"],
  ["patterns.n_trajectories", "Trajectories with flashes"],
  ["patterns.flash_duration_s.n", "Flashes timed (not cut by the recording's ends)"],
  ["patterns.ifi_s.n", "Inter-flash intervals"],
  ["recording.width", "Frame width", "px"],
  ["recording.height", "Frame height", "px"],
  ["recording.fps", "Frame rate", "frames/s"],
  ["recording.codec_cam{c}", "Codec, camera {c}"],
  ["recording.bits_per_pixel_cam{c}", "Encoder's bits per pixel and frame, camera {c}"],
  ["recording.n_frames_cam{c}", "Frames recorded, camera {c}"],
  ["recording.chapters_cam{c}", "Chapter files, camera {c}"],
  ["counts.flashes_cam{c}", "Flashes accepted, camera {c}"],
  ["counts.candidates_cam{c}", "Candidates tracked, camera {c}"],
  ["counts.refined_cam{c}", "Candidate positions refined along their light curve, camera {c}"],
  ["acceptance.decided_by", "Flashes decided by"],
  ["acceptance.cam{c}.accepted_confident", "Accepted: classifier and SNR agree, camera {c}"],
  ["acceptance.cam{c}.accepted_stereo", "Accepted: doubtful, matched by the other camera, camera {c}"],
  ["acceptance.cam{c}.accepted_single_camera", "Accepted: doubtful, from its own evidence, camera {c}"],
  ["acceptance.cam{c}.accepted_over_rules", "Accepted although a single test rejected it, camera {c}"],
  ["acceptance.cam{c}.rejected_confident", "Rejected: confident, but not by all the evidence, camera {c}"],
  ["acceptance.cam{c}.rejected_unconfirmed", "Rejected: doubtful, not confirmed, camera {c}"],
  ["acceptance.cam{c}.rejected_classifier", "Rejected by the classifier, camera {c}"],
  ["acceptance.cam{c}.rejected_flicker", "Rejected: flickering spot, camera {c}"],
  ["acceptance.cam{c}.rejected_light_curve", "Rejected: lit too long for a flash, camera {c}"],
  ["acceptance.cam{c}.rejected_recurrent", "Rejected: spot as bright again and again (swaying foliage), camera {c}"],
  ["acceptance.cam{c}.accepted", "Flashes accepted, camera {c}"],
  ["acceptance.cam{c}.candidates", "Candidates weighed, camera {c}"],
  ["counts.calibration_pairs", "Calibration pairs of the pose (after the refit: stereo matches of accepted flashes)"],
  ["counts.calibration_inliers", "Calibration pairs that fit the pose"],
  ["pose_refit.min_snr", "Pose refit: matches at least this bright", "σ"],
  ["pose_refit.rotation_change_deg", "Pose refit: rotation change from the first pose", "°"],
  ["pose_refit.translation_change_deg", "Pose refit: baseline direction change from the first pose", "°"],
  ["pose_refit.median_residual_px", "Pose refit: median residual", "px"],
  ["pose_refit.covariance_scale", "Pose refit: covariance scaled up to the jackknife's by", "×"],
  ["delay_frames", "Camera 2 delay", "frames"],
  ["delay_confidence", "Delay confidence", "%", 100],
  ["delay_set_aside.cam{c}", "Frames the delay search set aside (light pollution, key frames), camera {c}"],
  ["translation", "Direction of camera 2 from camera 1 (unit vector)"],
  ["rotation", "Rotation of camera 2 (matrix)"],
  ["residuals.median_deg", "Calibration residual, median", "°"],
  ["residuals.mean_deg", "Calibration residual, mean", "°"],
  ["residuals.p90_deg", "Calibration residual, 90th percentile", "°"],
  ["residuals.median_gap", "Ray gap, median", "× separation"],
  ["residuals.mean_gap", "Ray gap, mean", "× separation"],
  ["residuals.p90_gap", "Ray gap, 90th percentile", "× separation"],
  ["tracking.cam{c}.frames", "Frames tracked, camera {c}"],
  ["tracking.cam{c}.candidates", "Candidates, camera {c}"],
  ["tracking.cam{c}.warmup_frames", "Frames decoded to warm up, camera {c}"],
  ["tracking.cam{c}.flooded_frames", "Frames too bright to track, camera {c}"],
  ["tracking.cam{c}.dropped_by_area", "Blobs too small or large, camera {c}"],
  ["tracking.cam{c}.dropped_over_cap", "Blobs over the per-frame cap, camera {c}"],
  ["tracking.cam{c}.faint_peaks", "Faint peaks (lit below the seed level), camera {c}"],
  ["tracking.cam{c}.faint_over_cap", "Faint peaks over the per-frame cap, camera {c}"],
  ["tracking.cam{c}.seconds", "Tracking time, camera {c}", "s"],
  ["tracking.cam{c}.fps", "Tracking speed, camera {c}", "frames/s"],
  ["timings_s.{s}", "Time, {s}", "s"],
];
const NOT_SHOWN = ["parameters", "warnings"];

const FIELD_PATTERNS = FIELDS.map(([path, label, unit = "", scale = 1]) => ({
  regex: new RegExp(`^${path.replace(/\./g, "\\.").replace("{c}", "(\\d+)").replace("{s}", "(.+)")}$`),
  label, unit, scale,
}));

function describe(key) {
  for (const [order, field] of FIELD_PATTERNS.entries()) {
    const match = key.match(field.regex);
    if (match) {
      const label = field.label.replace("{c}", match[1]).replace("{s}", (match[1] || "").replaceAll("_", " "));
      return { label, unit: field.unit, scale: field.scale, order };
    }
  }
  return { label: key, unit: "", scale: 1, order: FIELD_PATTERNS.length };
}

function flatten(value, prefix = "") {
  if (value === null || typeof value !== "object" || Array.isArray(value)) return [[prefix, value]];
  return Object.entries(value)
    .filter(([key]) => !(prefix === "" && NOT_SHOWN.includes(key)))
    .flatMap(([key, inner]) => flatten(inner, prefix ? `${prefix}.${key}` : key));
}

const rounded = (value) => (typeof value === "number" ? +value.toPrecision(4) : value);

function formatValue(value, unit, scale) {
  if (Array.isArray(value)) {
    return value.map((v) => (Array.isArray(v) ? `[${v.map(rounded).join(", ")}]` : rounded(v))).join(", ");
  }
  if (typeof value === "boolean") return value ? "yes" : "no";
  if (typeof value === "string") return value;
  if (typeof value !== "number") return JSON.stringify(value);
  const scaled = value * scale;
  const text = Number.isInteger(scaled) ? scaled.toLocaleString() : String(+scaled.toPrecision(4));
  return unit ? `${text} ${unit}` : text;
}

jobPage.register({
  update(job) {
    const rows = flatten(job.summary).filter(([, value]) => value !== null)
      .map(([key, value]) => ({ key, value, ...describe(key) }))
      .sort((a, b) => a.order - b.order);
    $("summary").hidden = !rows.length;
    $("summary-list").replaceChildren(...rows.flatMap((row) => [
      el("dt", { "data-key": row.key, title: row.key }, row.label),
      el("dd", { "data-key": row.key }, formatValue(row.value, row.unit, row.scale))]));
    $("summary-warnings").replaceChildren(...(job.summary.warnings || []).map((w) => el("li", {}, w)));
  },
});
