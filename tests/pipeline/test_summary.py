"""The run summary from the units' records."""

from __future__ import annotations

from pipeline.graph import StageResult, Unit
from pipeline.params import ProcessParams
from pipeline.summary import summarise


def test_summary_gathers_counts_calibration_tracking_warnings_and_timings() -> None:
    tracking = {"frames": 600, "flooded_frames": 2, "dropped_over_cap": 7, "seconds": 3.0}
    records = {
        Unit("probe"): StageResult(
            {"width": 640, "bits_per_pixel_cam1": 0.05, "seconds": 0.4},
            ["camera 1: encoded at 0.050 bit per pixel"],
        ),
        Unit("link"): StageResult(
            {
                "n_points": 40,
                "n_streaks": 9,
                "n_trajectories": 3,
                "n_ambiguous_links": 2,
                "seconds": 0.1,
            }
        ),
        Unit("triangulate"): StageResult({"n_points": 40, "n_points_sure": 31}),
        Unit("sync"): StageResult(
            {
                "delay_frames": -4,
                "delay_confidence": 0.9,
                "n_flashes_cam1": 50,
                "n_flashes_cam2": 45,
                "frames_set_aside_cam1": 12,
                "frames_set_aside_cam2": 13,
            },
            ["low confidence"],
        ),
        Unit("merge", 1): StageResult(
            {"n_candidates": 80, "n_refined_positions": 61, "tracking": tracking, "seconds": 0.2}
        ),
        Unit("accept"): StageResult(
            {"cam1": {"accepted": 52, "accepted_stereo": 4}, "cam2": {"accepted": 47}}
        ),
        Unit("pose"): StageResult(
            {
                "n_calibration_pairs": 30,
                "n_calibration_inliers": 28,
                "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
                "translation": [0, 0.99, 0.14],
                "residuals": {"median_deg": 0.02},
            },
            ["few inliers"],
        ),
        # The calibration is the refit's, from the accepted flashes' stereo matches.
        Unit("refit"): StageResult(
            {
                "n_calibration_pairs": 120,
                "n_calibration_inliers": 110,
                "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
                "translation": [0, 1, 0],
                "residuals": {"median_deg": 0.01},
                "refit": {"rotation_change_deg": 0.4},
            }
        ),
    }
    summary = summarise(records, ProcessParams())
    assert summary["counts"] == {
        "candidates_cam1": 80,
        "refined_cam1": 61,
        "flashes_cam1": 52,
        "candidates_cam2": None,
        "refined_cam2": None,
        "flashes_cam2": 47,
        "calibration_pairs": 120,
        "calibration_inliers": 110,
        "points": 40,
        "points_sure": 31,
        "streaks": 9,
        "trajectories": 3,
        "ambiguous_links": 2,
    }
    assert (summary["delay_frames"], summary["delay_confidence"]) == (-4, 0.9)
    assert summary["delay_set_aside"] == {"cam1": 12, "cam2": 13}
    assert summary["translation"] == [0, 1, 0] and summary["residuals"] == {"median_deg": 0.01}
    assert summary["pose_refit"] == {"rotation_change_deg": 0.4}
    assert summary["tracking"] == {"cam1": tracking}
    assert summary["acceptance"]["cam1"] == {"accepted": 52, "accepted_stereo": 4}
    assert summary["recording"] == {"width": 640, "bits_per_pixel_cam1": 0.05}
    # In pipeline order; the first pose's warning is gone with the pose it was about.
    assert summary["warnings"] == ["camera 1: encoded at 0.050 bit per pixel", "low confidence"]
    assert summary["timings_s"]["track_cam1"] == 3.0 and summary["timings_s"]["link"] == 0.1
    assert summary["parameters"] == ProcessParams().model_dump(mode="json")
    # Where the first pose was kept, its warning stands.
    records[Unit("refit")] = StageResult({**records[Unit("refit")].metrics, "refit": None})
    assert "few inliers" in summarise(records, ProcessParams())["warnings"]


def test_summary_of_a_run_that_has_not_started_is_empty_but_complete() -> None:
    summary = summarise({}, ProcessParams())
    assert summary["counts"]["points"] is None and summary["delay_frames"] is None
    assert summary["warnings"] == [] and summary["tracking"] == {}
    assert summary["acceptance"] is None and summary["recording"] is None
