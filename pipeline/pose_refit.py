"""The pose refitted on the stereo matches of every accepted flash.

The first pose (`pipeline.pose.calibrate_pose`) is fitted before acceptance, on the
frames where each camera sees exactly one confident flash (or one flash begin). On a
night of a few fireflies those frames come from a handful of them, each contributing a
dozen frames whose position errors it shares (its spot's shape, the leaves behind it),
so the fit rests on a few independent directions: a fit of 68 pairs from 7 fireflies
was 0.9° off with a standard error of 0.15° (held-out wind night s303, 640 px), and a
swarm night 0.8° off. Once the flashes are accepted and the delay and that pose are
known, every frame's flashes can be matched between the cameras within the
triangulation's gates (`pipeline.triangulate.triangulate`): 3–5 times the pairs, from
every firefly in view. The pose is fitted again, from scratch and with the same robust
estimator (`pipeline.pose.estimate_pose`), on the matches whose two flashes both reach
``PoseParams.refit_min_snr`` (`stereo_match_pairs`; faint flashes carry the heavy tail of
position errors).

Its covariance is the Jacobian's, scaled up so that the rotation's standard error is
the block jackknife's where that is larger (`jackknife_scaled`): the matches of one
firefly share their errors, and the points' ``range_sd_m`` should say so.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from pipeline.detections import Detections
from pipeline.geometry import Pose, pixel_to_bearing
from pipeline.params import TriangulationParams
from pipeline.pose import CalibrationPairs, PoseEstimate, jackknife_scale
from pipeline.triangulate import triangulate

FloatArray = NDArray[np.float64]


def stereo_match_pairs(
    det1: Detections,
    det2: Detections,
    delay_frames: int,
    pose: Pose,
    width: int,
    separation_m: float,
    params: TriangulationParams,
    min_snr: float,
) -> CalibrationPairs:
    """Bearings of the flashes the triangulation matches under `pose`, both at least
    `min_snr` (an unknown SNR, NaN, passes).

    Parameters
    ----------
    det1, det2 : Detections
        Accepted flashes of camera 1 and camera 2 (pixels, ``x = u``, ``y = v``).
    delay_frames : int
        ``dk``: camera-1 frame ``k`` is camera-2 frame ``k + dk``.
    pose : Pose
        The pose the matches are made under (unit translation).
    width : int
        Frame width in pixels (equirectangular).
    separation_m : float
        Distance between the cameras in metres (the triangulation's range gate).
    params : TriangulationParams
        The matching gates.
    min_snr : float
        Smallest SNR (σ) of either flash of a pair kept.

    Returns
    -------
    CalibrationPairs
        One pair per match kept, sorted by camera-1 frame.
    """
    points = triangulate(det1, det2, delay_frames, pose, width, separation_m, params)
    i1, i2 = points.index1, points.index2
    keep = ~(np.fmin(det1.snr[i1], det2.snr[i2]) < min_snr)
    i1, i2 = i1[keep], i2[keep]
    order = np.argsort(det1.frame[i1], kind="stable")
    i1, i2 = i1[order], i2[order]
    return CalibrationPairs(
        frame1=det1.frame[i1].astype(np.int64),
        bearing1=pixel_to_bearing(det1.x[i1], det1.y[i1], width),
        bearing2=pixel_to_bearing(det2.x[i2], det2.y[i2], width),
    )


def jackknife_scaled(estimate: PoseEstimate) -> FloatArray:
    """The pose covariance scaled by ``(jackknife SE / Jacobian SE)²`` of the rotation
    when the block jackknife's standard error is the larger (and known)."""
    return estimate.covariance * jackknife_scale(estimate) ** 2
