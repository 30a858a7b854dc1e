"""Every parameter of every stage: validated, frozen, JSON-able pydantic models.

`ProcessParams` is what a run (CLI or service job) is configured with; it has one
sub-model per stage. The models live here, apart from the science modules that use
them, so that validating a job's parameters (the API does it on every submission)
needs pydantic alone: no OpenCV, SciPy, PyAV or onnxruntime.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Literal, Self

from pydantic import BaseModel, ConfigDict, Field, model_validator

#: Largest camera separation accepted, in metres (volunteer rigs are 1–2 m).
MAX_SEPARATION_M = 100.0

#: Default seed level of tracking in σ (`TrackingParams.threshold`), unbinned and binned.
SEED_LEVEL = 4.0
BINNED_SEED_LEVEL = 4.85
#: Default level of faint peaks in σ (`TrackingParams.lit_threshold`), unbinned and binned.
LIT_LEVEL = 3.0
BINNED_LIT_LEVEL = 4.1


def _level(chosen: float | None, unbinned: float, binned: float, bin_px: int) -> float:
    """A level in σ: the one chosen, else the default of a binned foreground or not."""
    if chosen is not None:
        return chosen
    return unbinned if bin_px == 1 else binned


def validate_separation(separation_m: float) -> None:
    """Refuse a camera separation (metres) that cannot be a real measurement.

    Raises
    ------
    ValueError
        If it is not a finite distance in ``(0, MAX_SEPARATION_M]``.
    """
    if not (math.isfinite(separation_m) and 0 < separation_m <= MAX_SEPARATION_M):
        raise ValueError(
            f"camera separation must be a finite distance in (0, {MAX_SEPARATION_M:g}] m, "
            f"got {separation_m!r}"
        )


class TrackingParams(BaseModel):
    """Parameters of flash-candidate tracking (validated; the service accepts overrides)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    tau_s: float = Field(
        default=2.0,
        gt=0,
        le=600,
        description="Background time constant τ in seconds: the EWMA's decay time, or the "
        "length of the box mean.",
    )
    background: Literal["ewma", "box"] = Field(
        default="ewma",
        description="'ewma': exponentially weighted mean over τ (restarted on a block grid, "
        "see block_s); 'box': mean of the frames in the preceding τ (memory: τ·fps frames).",
    )
    threshold: float | None = Field(
        default=None,
        gt=0,
        le=1000,
        description="Seed level of a candidate, in units of the noise σ of the matched-"
        "filtered foreground (frame − background, see matched_sigma_px), estimated per "
        "tile as the background runs (pipeline.noise): a candidate is a local maximum "
        "reaching it. None: `SEED_LEVEL` (4σ) unbinned, `BINNED_SEED_LEVEL` (4.85σ) when "
        "the foreground is binned (bin_px ≥ 2, 4K and up). Unbinned, chosen on a measured "
        "curve (docs/detection.md; simulated hard night, 640 px, seed 11): candidate "
        "recall of flash-frames of simulated SNR >= 5 is 0.98 at 3σ (120 candidates per "
        "frame), 0.96 at 4σ (20), 0.93 at 5σ (3) and 0.90 at 6σ (1); 4σ is the knee, the "
        "acceptance stage rejects the noise it lets in. Binned, the filter is matched to a "
        "spot of matched_sigma_px recording pixels, half a bin, which meets more noise "
        "peaks: 4.85σ holds the candidate rate of a 1-bin filter at 4σ (3840 px, tuning "
        "seed 12: 171/161 against 178/192 per frame on a still night).",
    )
    extent_threshold: float = Field(
        default=2.5,
        gt=0,
        le=1000,
        description="Hysteresis: a blob extends over the connected pixels above this many "
        "σ (at most `threshold`), so a flash's faint rim joins its core.",
    )
    lit_threshold: float | None = Field(
        default=None,
        gt=0,
        le=1000,
        description="Local maxima from this many σ up to the seed level are kept as faint "
        "peaks (frame, position, SNR; never classified, never flashes themselves): the "
        "acceptance stage counts them as lit frames of a spot's light curve (a glint held "
        "by the wind between its brighter moments stays lit for seconds, a flash does not; "
        "they are not counted as flicker). Below extent_threshold it is extent_threshold; "
        "at least the seed level: none kept. None: `LIT_LEVEL` (3σ) unbinned, "
        "`BINNED_LIT_LEVEL` (4.1σ) binned, where the narrower filter meets more noise "
        "peaks (4.1σ there is as rare as 3σ unbinned for Gaussian noise; tuning seed 12 at "
        "3840 px, hard-all night: 2D precision 0.82/0.87 at 3σ, 0.93/0.96 at 4.1σ, for the "
        "same recall). Tuning nights (640 px, seeds 12-15, both cameras): in wind "
        "false flashes 182 -> 86 for true ones 2,836 -> 2,804; still and hard-all nights "
        "+3 and +9 true, no false one added (docs/detection.md).",
    )
    min_noise: float = Field(
        default=0.3,
        ge=0,
        description="Floor of the noise σ in grey levels of the filtered foreground: in "
        "perfectly clean video (σ → 0) a seed still needs threshold × min_noise.",
    )
    relative_noise: float = Field(
        default=0.01,
        ge=0,
        description="Floor of the noise σ in proportion to the background level B: σ ≥ "
        "min_noise + relative_noise × B. Shot noise and compression grow with brightness; "
        "the core of a static lamp jitters by about 1 % of its level from frame to frame, "
        "which the tile estimate (dominated by dark sky) does not see.",
    )
    matched_sigma_px: float = Field(
        default=1.0,
        ge=0,
        le=10,
        description="σ of the Gaussian matched filter in pixels of the recording: the size "
        "of a point flash's spot (real GoPro 360 flashes: 1.2–1.9 px); 0 disables it. On a "
        "binned foreground it is σ / bin_px bins.",
    )
    trough_radius_px: float = Field(
        default=4.0,
        gt=0,
        le=50,
        description="Half side of the square around a candidate's peak searched for the "
        "darkest spot, in pixels of the recording (at least one analysed pixel): against "
        "the running background (the trough) and against the frames 0.1-0.4 s before (the "
        "hollow), each over the peak's response. Evidence for acceptance: a light that "
        "moved or a swaying edge leaves a dark spot beside it, a flash does not (4 and 8 "
        "px did as well on the tuning nights at 640 and 1280 px; docs/detection.md).",
    )
    bin_px: int | None = Field(
        default=None,
        ge=1,
        le=8,
        description="Side of the bins the foreground is averaged over before filtering; "
        "None: round(width / 1920), at most 2 (matched_filter.MAX_AUTO_BIN; 2 for 4K and up).",
    )
    noise_tile_px: int = Field(
        default=32,
        ge=4,
        description="Side of the tiles the noise σ is estimated in, in (binned) pixels.",
    )
    blur_px: float = Field(
        default=0.0,
        ge=0,
        le=10,
        description="Gaussian blur σ in pixels applied to the luminance before background "
        "subtraction (0 = off); about 1 px suppresses single-pixel noise in grainy video.",
    )
    min_area: int = Field(default=1, ge=1, description="Smallest blob kept, in pixels.")
    max_area: int = Field(
        default=500,
        ge=1,
        description="Largest blob kept, in pixels: fireflies are 1–10 px across even in "
        "5.6K video; larger blobs are lamps, headlights or exposure changes. A seed inside "
        "one still counts when it stands `threshold` σ above the light around it (a flash "
        "against a headlight's glow), with the spot around its peak.",
    )
    deblend: bool = Field(
        default=True,
        description="Also seed a candidate where a flash stands beside a brighter one: "
        "each peak's spot is fitted with a Gaussian and taken off its blob, and a local "
        "maximum of what is left that reaches the seed level, away from every peak, is a "
        "seed (pipeline.crowding). A swarm's flashes 3-6 px apart otherwise make one "
        "candidate (simulated swarm tuning night s12, 640 px: candidates >= 5 sigma 0.72 "
        "-> 0.81; held-out swarms s351-353 with the evidence model trained on such seeds: "
        "2D recall >= 5 sigma 0.73 -> 0.81 at precision 0.99). The shipped evidence model "
        "was trained on candidates tracked with it.",
    )
    max_candidates_per_frame: int = Field(
        default=500,
        ge=1,
        description="Blobs kept per frame, the brightest first; the rest are counted as "
        "dropped (a frame flooded by light must not blow up time or memory).",
    )
    max_faint_peaks_per_frame: int = Field(
        default=2000,
        ge=0,
        description="Faint peaks kept per frame (see lit_threshold), the brightest first; "
        "the rest are counted as dropped.",
    )
    max_foreground_px: int | None = Field(
        default=None,
        ge=1,
        description="Candidate pixels labelled per frame, in pixels of the recording; in a "
        "flooded frame only the highest-SNR ones are kept (the frame is counted as "
        "flooded). None: a quarter of the frame, which grainy video never reaches (at the "
        "2.5σ extent level noise alone lights ~1 %); a fixed 50,000 flooded 95 % of the "
        "frames of a simulated grainy 3840 × 1920 night.",
    )
    recurrence_after_s: float = Field(
        default=0.5,
        gt=0,
        description="Start of the past window in which each candidate's spot is looked up "
        "(`pipeline.recurrence`), seconds before it: longer than a flash, so a flash is not "
        "in its own window.",
    )
    recurrence_window_s: float = Field(
        default=3.0,
        gt=0,
        le=10,
        description="End of that window, seconds before the candidate: a few sway periods "
        "of foliage (0.3–2 Hz). Memory: the binned frames of this span, every other frame "
        "(83 MB at 3840 × 1920, 30 fps).",
    )
    recurrence_margin: float = Field(
        default=3.0,
        ge=0,
        description="Grey levels below a candidate's brightness that a past frame's 3 × 3 "
        "neighbourhood may stay and still count as as bright.",
    )
    lit_update_rate: float = Field(
        default=0.5,
        gt=0,
        le=1,
        description="Share of the EWMA background's rate at which pixels lit above the "
        "extent level in a frame (a flash, a glint) are folded in, once the model is no "
        "longer the running mean of its first frames: at 1 every pixel alike, and a swarm "
        "flashing at the same spots every half second lifts the background, and the noise "
        "measured against it, by a share of its own light. 0.5 chosen on tuning nights "
        "s12-13 (640 px: swarm 2D recall >= 5 sigma 0.790 -> 0.809, wind false 48 -> 26; "
        "0.25 and below flood wind with candidates); the shipped evidence model is trained "
        "on candidates tracked at 0.5 (held out s361-363 against rate 1 and its model: "
        "16,490 -> 16,554 true for 239 -> 205 false 2D flash-frames, swarm recall 0.839 "
        "-> 0.854, wind 0.817 -> 0.810; docs/detection.md). 'ewma' only.",
    )
    block_s: float = Field(
        default=30.0,
        gt=0,
        description="EWMA restart grid in seconds: each block of this length is analysed "
        "by a model warmed on the frames just before it, so chunks are exact.",
    )
    warmup_tau: float = Field(
        default=3.0,
        ge=0,
        description="EWMA warm-up before each block, in units of tau_s.",
    )

    def seed_level(self, bin_px: int) -> float:
        """The seed level in σ on a foreground binned ``bin_px × bin_px``."""
        return _level(self.threshold, SEED_LEVEL, BINNED_SEED_LEVEL, bin_px)

    def lit_level(self, bin_px: int) -> float:
        """The level of faint peaks in σ on a foreground binned ``bin_px × bin_px``."""
        return _level(self.lit_threshold, LIT_LEVEL, BINNED_LIT_LEVEL, bin_px)

    @model_validator(mode="before")
    @classmethod
    def _box_folds_every_frame(cls, data: Any) -> Any:
        # The default rate is the EWMA's; a box mean asked for without a rate gets its own.
        if isinstance(data, dict) and data.get("background") == "box":
            return {"lit_update_rate": 1.0, **data}
        return data

    @model_validator(mode="after")
    def _consistent(self) -> TrackingParams:
        lowest = self.seed_level(1)  # the lower of the two defaults
        if self.extent_threshold > lowest:
            raise ValueError(
                f"extent_threshold ({self.extent_threshold}) exceeds the seed level ({lowest:g})"
            )
        if self.max_area < self.min_area:
            raise ValueError(f"max_area ({self.max_area}) is below min_area ({self.min_area})")
        if self.recurrence_after_s > self.recurrence_window_s:
            raise ValueError(
                f"recurrence_after_s ({self.recurrence_after_s}) exceeds recurrence_window_s "
                f"({self.recurrence_window_s})"
            )
        if self.lit_update_rate < 1.0 and self.background != "ewma":
            raise ValueError(
                f"lit_update_rate ({self.lit_update_rate}) needs the 'ewma' background: the "
                "box mean folds every frame in alike"
            )
        if self.warmup_tau * self.tau_s > self.block_s:
            raise ValueError(
                f"the EWMA warm-up warmup_tau × tau_s = {self.warmup_tau * self.tau_s:g} s "
                f"must not exceed block_s = {self.block_s:g} s"
            )
        return self


class FlickerParams(BaseModel):
    """Where the line between a flash train and a flickering light source is drawn."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(True, description="Reject candidates at flickering spots.")
    radius_deg: float = Field(
        3.0,
        gt=0,
        le=20,
        description="Neighbourhood radius (Chebyshev, in pixels of this angle). 3° spans the "
        "sway of a glint on a wind-shaken leaf (1–6 px at 640 px); at 1.5° half the glints of "
        "a simulated wind night escaped the test (2D precision 0.65 against 0.78 at 3°, with "
        "no loss of recall on the other scenarios; tuning seed 11).",
    )
    window_s: float = Field(2.0, gt=0, description="Length of the centred time window, seconds.")
    max_duty: float = Field(
        0.4,
        gt=0,
        le=1,
        description="Candidates per frame in the neighbourhood above which a spot flickers "
        "(flash trains measure <= 0.25; moon-through-leaves 0.5–0.9 in the simulator).",
    )
    peer_octaves: float | None = Field(
        2.0,
        ge=0,
        le=20,
        description="A neighbour counts towards a candidate's duty when its SNR is at most "
        "this many octaves below the candidate's (compared on a half-octave grid: 2 counts "
        "from 1/4–1/5.7 of its SNR up); None: every neighbour. Grain and swaying foliage "
        "make faint candidates all over a 3° box at 4K and up, and counted at any brightness "
        "they made bright flashes beside them flicker (5376 px tuning wind night s12: 11 and "
        "13 true flash-frames ≥ 10 σ a camera). 1 octave freed more of them but let "
        "headlights' and taillights' candidates stop flickering (3840 px hard-all s12: 5 "
        "more false flashes, 2 with 2 octaves; docs/detection.md).",
    )


class SyncParams(BaseModel):
    """Parameters of `estimate_delay`."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    max_delay_s: float = Field(
        default=120.0, gt=0, description="Largest |delay| searched, in seconds (both signs)."
    )
    window_s: float = Field(
        default=10.0,
        gt=0,
        description="Length of each RANSAC window of camera 1, in seconds; when camera 1's "
        "flashes span less, the windows cover two thirds of that span (with a warning).",
    )
    min_window_s: float = Field(
        default=3.0,
        gt=0,
        description="Shortest RANSAC window a short recording may shorten the windows to, in "
        "seconds; camera 1's flashes must span 1.5 times this.",
    )
    n_windows: int = Field(
        default=200,
        ge=100,
        le=10_000,
        description="Number of random RANSAC windows (at least 100).",
    )
    agree_frames: int = Field(
        default=0,
        ge=0,
        description="A window agrees with the modal delay when its vote is within this many "
        "frames (0: exact agreement).",
    )
    outlier_mads: float = Field(
        default=6.0,
        gt=0,
        description="A frame's count is a light-pollution outlier when it exceeds the median "
        "non-zero count by more than this many robust standard deviations (1.4826 MAD, at "
        "least 1 flash).",
    )
    min_confidence: float = Field(
        default=0.5, ge=0, le=1, description="Below this confidence the estimate carries a warning."
    )
    seed: int = Field(
        default=0, ge=0, description="Seed of the random window draw (deterministic)."
    )


class PoseParams(BaseModel):
    """Parameters of `estimate_pose`."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    min_pairs: int = Field(
        default=12,
        ge=8,
        description="Fewest calibration pairs (and inliers) accepted; the 8-point start "
        "needs at least 8.",
    )
    inlier_sigmas: float = Field(
        default=3.0,
        gt=0,
        description="Inlier threshold on the depth-normalised gap, in robust standard "
        "deviations (1.4826 × median residual), so that it follows the bearing noise.",
    )
    min_threshold_deg: float = Field(
        default=0.1,
        gt=0,
        description="Smallest inlier threshold (degrees); also the scale of the robust loss.",
    )
    max_threshold_deg: float = Field(
        default=2.0,
        gt=0,
        description="Largest inlier threshold (degrees): when most pairs are mismatched the "
        "noise estimate is meaningless, and a miss this large is never an inlier.",
    )
    max_start_pairs: int = Field(
        default=1000,
        ge=8,
        description="The starts compete on at most this many evenly spread pairs; the best "
        "is then refined on all pairs.",
    )
    max_refits: int = Field(
        default=3,
        ge=1,
        le=20,
        description="Refits on inliers, stopped early when the inlier set is stable.",
    )
    min_agreement: float = Field(
        default=0.2,
        ge=0,
        le=1,
        description="Fewest inliers as a share of the pairs: below it the pairs are taken "
        "as unrelated and no pose is fitted. Unrelated pairs agree by chance in 4–9 % "
        "(synthetic, 200–600 pairs); pairs that are half mismatched keep 45–50 %.",
    )
    min_inlier_fraction: float = Field(
        default=0.5,
        ge=0,
        le=1,
        description="Below this fraction of inliers the estimate carries a warning.",
    )
    max_median_residual_px: float = Field(
        default=0.25,
        gt=0,
        description="Above this median inlier residual, in pixels of angle (360° / width), "
        "the estimate carries a warning: good fits measure 0.05–0.1 px on simulated nights; "
        "a held-out windy night whose glint-contaminated pairs gave a pose 16.6° off "
        "measured 0.53 px with 55 % inliers.",
    )
    max_rotation_se_deg: float = Field(
        default=0.3,
        gt=0,
        description="Above this standard error of the rotation (degrees, from the fit's "
        "Jacobian) the estimate carries a warning: on 34 simulated hard tuning nights the "
        "good fits measured 0.03–0.19°, the four wrong ones (2–28° off, some fitting their "
        "pairs to 0.04–0.09 px) 0.6–9.6°.",
    )
    max_translation_se_deg: float = Field(
        default=0.5,
        gt=0,
        description="Above this standard error of the baseline's direction (degrees, the "
        "Jacobian's scaled like the rotation's by the block jackknife) the pose kept "
        "carries a warning: a direction δ off moves ranges by up to about δ in radians of "
        "themselves. On 18 simulated tuning nights (640 px 8 and 12 s, 4K 12 s) the "
        "final fits measured 0.04-0.35° except three, at 0.58-1.11°, whose baselines were "
        "0.8-3.0° off (two swarms 1.1° off measured 0.25-0.35°: a bias the pairs share "
        "is not seen); on 12 held-out 20 s nights none warned (poses within 0.42°).",
    )
    onset_radius_deg: float | None = Field(
        default=1.0,
        gt=0,
        le=20,
        description="Frames where exactly one flash begins in each camera (no flash of the "
        "previous frame within this angle, degrees) are calibration pairs too, besides the "
        "frames that hold a single flash: a simulated night of 80 fireflies had 11 single-"
        "flash frames in 20 s, too few for a pose. None: single-flash frames only.",
    )
    refit_snr: tuple[float, ...] = Field(
        default=(12.0, 16.0, 24.0),
        description="A fit with warnings (few inliers, or a median residual above "
        "max_median_residual_px) is refitted from the flashes at or above each of these "
        "SNRs (σ) in turn, the first fit without warnings kept: glints through swaying "
        "leaves pass as flashes near the confident floor and pull the pose. Empty: no refit.",
    )
    refit_from_accepted: bool = Field(
        default=True,
        description="Once the flashes are accepted, fit the pose again on every stereo "
        "match of them (pipeline.pose_refit), not only on the frames with one confident "
        "flash per camera: on 24 simulated hard tuning nights (640 px) the rotation error's "
        "rms fell from 0.19° to 0.09° (worst night 0.82° -> 0.19°). False: keep the first.",
    )
    refit_min_snr: float = Field(
        default=8.0,
        ge=0,
        description="The refit from the accepted flashes uses the matches whose two flashes "
        "are both at least this SNR (σ): faint flashes carry the heavy tail of position "
        "errors. 0: every match.",
    )

    @model_validator(mode="after")
    def _ordered_thresholds(self) -> PoseParams:
        if self.min_threshold_deg > self.max_threshold_deg:
            raise ValueError(
                f"min_threshold_deg ({self.min_threshold_deg}) exceeds max_threshold_deg "
                f"({self.max_threshold_deg})"
            )
        return self


class TriangulationParams(BaseModel):
    """Parameters of `triangulate`."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    gate: float = Field(
        default=0.2,
        gt=0,
        description="Largest ray gap of a match, in units of the camera separation.",
    )
    max_range_m: float = Field(
        default=20.0, gt=0, description="Points farther than this from camera 1 (m) are dropped."
    )
    localisation_px: float = Field(
        default=0.55,
        gt=0,
        description="Position error (1 σ, pixels of 360° / width) of a detection at 1 σ "
        "SNR; at SNR s it is this / √s. It sets each point's range_sd_m. Fitted on the "
        "refined positions of simulated tuning nights at 640 px (0.25 px at 5 σ, 0.13 px "
        "at 20 σ, 0.05 px at 100 σ).",
    )
    pose_error_scale: float = Field(
        default=1.6,
        ge=0,
        le=10,
        description="The pose's standard errors are taken this many times over in each "
        "point's range_sd_m: fitted poses are off by more than their fit says (on 26 "
        "simulated hard tuning nights, hard-all and hard-wind 12-19 and 41-45, by a median "
        "1.5 x in the baseline's direction and 1.8 x in rotation). On tuning nights 12-14 "
        "1.6 raised the coverage of the range errors by 2 range_sd_m from 0.75 to 0.82 in "
        "wind and from 0.80 to 0.89 on hard-all. 0 leaves the pose's error out.",
    )
    max_gap_deg: float = Field(
        default=1.0,
        gt=0,
        description="Largest ray gap of a match as an angle seen from the farther camera, "
        "degrees: near the cameras a gap under `gate` can still be a gross mismatch "
        "(simulated true matches measure <= 0.3 deg, mismatches >= 1.2 deg).",
    )
    min_parallax_px: float = Field(
        default=2.0,
        ge=0,
        description="Smallest angle the baseline subtends at a point, in pixels of angle "
        "(360 deg / width). Near the baseline's axis a tenth of a pixel of localisation "
        "error moves the point by several percent of its range; such points are dropped.",
    )


class LinkingParams(BaseModel):
    """Parameters of `link`."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    streak_radius_m: float = Field(
        default=0.3,
        gt=0,
        description="Largest distance (m) between a flash's positions in consecutive frames.",
    )
    trajectory_radius_m: float = Field(
        default=1.0,
        gt=0,
        description="Largest distance (m) between a streak's end and the next streak's start.",
    )
    max_gap_s: float = Field(
        default=1.0,
        gt=0,
        description="Longest time (s) from a streak's end to the next streak's start.",
    )
    ambiguity_ratio: float = Field(
        default=3.0,
        ge=0,
        description="A streak joins a later one only when no other streak starting at "
        "the same moment (within ambiguity_window_s) lies within this many times the "
        "distance of its end, nor another streak ending then of its start: in a "
        "synchronous swarm a firefly whose next flash was missed would otherwise take "
        "a neighbour's. On 6 simulated swarm tuning nights (640 px) trajectory purity "
        "0.80 -> 0.96 (share of each firefly's points in its main trajectory 0.41 -> "
        "0.34; on 9 sparser nights 0.99 -> 0.99 and 0.48 -> 0.45). 0: the nearest "
        "candidate, whatever its rivals.",
    )
    ambiguity_window_s: float = Field(
        default=0.1,
        gt=0,
        description="Streaks starting (or ending) within this many seconds of each other "
        "are rivals for the same link (ambiguity_ratio); a firefly's later flashes, "
        "a beat or more away, are not.",
    )


class PatternParams(BaseModel):
    """How flash patterns are read from the trajectories (`pipeline.patterns`)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    join_gap_frames: int = Field(
        default=1,
        ge=0,
        le=10,
        description="Streaks of one trajectory separated by at most this many dark frames "
        "are one flash (a frame the detector missed mid-flash; 0 = every streak a flash).",
    )
    train_gap_s: float = Field(
        default=2.0,
        gt=0,
        description="Onset-to-onset interval (s) above which two flashes of a trajectory "
        "belong to different trains: not an inter-flash interval.",
    )
    period_range_s: tuple[float, float] = Field(
        default=(0.2, 2.0),
        description="Range of periods (s) searched in the night's flash-count series "
        "(low, high); synchronous species flash every 0.3–1 s within a burst.",
    )
    n_surrogates: int = Field(
        default=20,
        ge=5,
        le=500,
        description="Surrogate nights (each trajectory shifted at random) the count series' "
        "autocorrelation is compared with.",
    )
    surrogate_shift_s: float = Field(
        default=10.0,
        gt=0,
        description="Trajectories are shifted by up to ± this many seconds in a surrogate: "
        "long against the periods searched, short against changes of activity.",
    )
    min_sync_strength: float = Field(
        default=0.1,
        ge=0,
        le=1,
        description="Synchrony needs the count series' autocorrelation at the period to "
        "exceed the surrogates' mean by at least this much.",
    )
    min_sync_z: float = Field(
        default=4.0,
        ge=0,
        description="…and by at least this many standard deviations of the surrogates.",
    )
    min_trajectories: int = Field(
        default=5,
        ge=2,
        description="Fewest trajectories for a synchrony test (fewer: not assessed).",
    )
    seed: int = Field(default=0, ge=0, description="Seed of the surrogate shifts.")

    @model_validator(mode="after")
    def _ordered_range(self) -> PatternParams:
        low, high = self.period_range_s
        if not 0 < low < high:
            raise ValueError(f"period_range_s must be 0 < low < high, got {self.period_range_s}")
        return self


class AcceptanceParams(BaseModel):
    """How the evidence on each candidate decides whether it is a flash (`pipeline.acceptance`)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(
        True,
        description="Weigh the evidence; false = every candidate is a flash (the background-"
        "subtraction baseline of --no-classifier).",
    )
    confident_snr: float = Field(
        8.0,
        ge=0,
        description="A candidate the classifier accepts is confident from this SNR (σ) up; "
        "fainter ones are doubtful and need stereo confirmation. The delay and the pose "
        "are estimated from confident flashes only.",
    )
    single_frame_snr: float = Field(
        12.0,
        ge=0,
        description="A candidate whose spot is lit in one frame only is confident from this "
        "SNR (σ) up; fainter, it is doubtful. High-ISO grain makes one-frame spots of 8–12 σ "
        "that the classifier believes, while a flash lights its spot for 2–15 frames "
        "(tuning nights, accepted candidates lit one frame at 8–12 σ: 182 false and 4 true "
        "with every artifact, 51 and 7 on a still hard night).",
    )
    doubt_probability: float = Field(
        0.05,
        ge=0,
        le=1,
        description="Below this flash probability a candidate is rejected outright; between "
        "it and the classifier's threshold it is doubtful.",
    )
    max_flash_s: float = Field(
        0.5,
        gt=0,
        description="A spot lit without a break for longer than this (s) is a lamp or a held "
        "glint, not a flash (flashes last 0.03–0.3 s).",
    )
    max_recurrence: float = Field(
        0.25,
        gt=0,
        le=1.01,
        description="A candidate whose spot was as bright in at least this share of the "
        "frames 0.5–3 s before (tracking.recurrence_*) is foliage swinging light in and out "
        "(sky through leaf holes, glints): rejected. Simulated nights (tuning): about half "
        "the false flashes accepted otherwise in wind, 0.8 % of the true ones (0–0.4 % on "
        "still and foliage nights). Above 1: off.",
    )
    radius_deg: float = Field(
        1.0,
        gt=0,
        le=20,
        description="Radius (degrees) within which candidates of consecutive frames belong "
        "to the same lit spot (the light curve).",
    )
    position_window_s: float = Field(
        0.07,
        ge=0,
        le=1,
        description="Each candidate's position is refined by a straight-line fit, weighted "
        "by SNR², through the positions of its light curve within this many seconds on "
        "either side (pipeline.refine): grain and compression are new in every frame, a "
        "firefly's drift is smooth. 0: positions as measured. Simulated hard nights "
        "(tuning, 640 px): median position error 0.19 → 0.15 px, 3D points true 0.92 → 0.95.",
    )
    stereo: bool = Field(True, description="Confirm doubtful candidates with the other camera.")
    min_streak: int = Field(
        3,
        ge=1,
        description="A doubtful candidate is confirmed when its light curve and the other "
        "camera's are matched with each other in at least this many frames (stereo "
        "matches between the same two lit spots).",
    )
    streak_peak_snr: float = Field(
        5.0,
        ge=0,
        description="…of which at least one frame stands this many σ above the noise in both "
        "cameras (a flash rises to a peak; wind-shaken leaves can agree frame after frame "
        "but stay faint).",
    )
    stereo_snr: float = Field(
        6.0,
        ge=0,
        description="…or when both candidates of the match stand this many σ above the noise "
        "(noise candidates: 99 % under 6.3 σ in one camera on simulated nights).",
    )
    stereo_max_gap_deg: float = Field(
        1.0,
        gt=0,
        description="Largest ray gap (degrees) of a confirming stereo match (at most "
        "triangulation.max_gap_deg).",
    )
    anchored: bool = Field(
        False,
        description="Confirm only light-curve pairs that hold at least one confident flash.",
    )
    evidence_model: str | None = Field(
        "default",
        description="The final decision once the delay and the pose are known: 'default' "
        "(the shipped evidence model, pipeline/models/evidence_trees.json) or a model "
        "file's path weighs every kind of evidence at once (pipeline.evidence_model); "
        "None: the rules (confident flashes plus the doubtful ones stereo confirms). The "
        "rules decide anyway when the patch classifier is not the model's.",
    )
    evidence_threshold: float | None = Field(
        None,
        ge=0,
        le=1,
        description="Flash probability from which the evidence model accepts a candidate; "
        "None: the model's own threshold.",
    )


class ClassifierParams(BaseModel):
    """Which flash classifier to run on candidate patches, and where to cut."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(True, description="Classify candidates; false = tracking only.")
    model: str | None = Field(None, description="ONNX model path; None = the shipped model.")
    card: str | None = Field(None, description="Model card JSON; None = beside the model.")
    threshold: float | None = Field(
        None, ge=0.0, le=1.0, description="Accept at probability >= this; None = the card's."
    )


class ProcessParams(BaseModel):
    """Every parameter of every stage; JSON-able, validated, immutable."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    tracking: TrackingParams = TrackingParams()
    classifier: ClassifierParams = ClassifierParams()
    sync: SyncParams = SyncParams()
    pose: PoseParams = PoseParams()
    triangulation: TriangulationParams = TriangulationParams()
    linking: LinkingParams = LinkingParams()
    flicker: FlickerParams = FlickerParams()
    acceptance: AcceptanceParams = AcceptanceParams()
    patterns: PatternParams = PatternParams()
    chunk_s: float = Field(60.0, gt=0, description="Length of a tracking chunk, seconds.")

    def merged(self, overrides: Mapping[str, Any]) -> Self:
        """These parameters with ``overrides`` deep-merged in, validated.

        Raises
        ------
        pydantic.ValidationError
            If an override names an unknown parameter or has an invalid value.
        """
        return self.model_validate(_deep_merge(self.model_dump(), overrides))


#: Overrides of the background-subtraction-only baseline (``--no-classifier``): no patch
#: classifier, no flicker test, no acceptance evidence; every candidate is a flash.
BACKGROUND_SUBTRACTION_ONLY: dict[str, dict[str, Any]] = {
    "classifier": {"enabled": False},
    "flicker": {"enabled": False},
    "acceptance": {"enabled": False},
}


def with_overrides(*layers: Mapping[str, Any]) -> dict[str, Any]:
    """Overrides of several sources deep-merged in order (later layers win)."""
    merged: dict[str, Any] = {}
    for layer in layers:
        merged = _deep_merge(merged, layer)
    return merged


def _deep_merge(base: dict[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in overrides.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), dict):
            merged[key] = _deep_merge(merged[key], value)
        else:
            merged[key] = value
    return merged
