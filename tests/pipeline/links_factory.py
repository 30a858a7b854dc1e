"""Hand-made `CandidateLinks` for the evidence-model tests (shared by the pipeline tests)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from pipeline.evidence_features import CandidateLinks


def links_apart(light_curve: ArrayLike, partner: ArrayLike) -> CandidateLinks:
    """Links of rows that are no light curve's neighbours: one recording, every row a
    minute after the previous one, all in one direction."""
    curve = np.asarray(light_curve, np.intp)
    n = len(curve)
    return CandidateLinks(
        light_curve=curve,
        partner=np.asarray(partner, np.intp),
        sequence=np.zeros(n, np.intp),
        time_s=60.0 * np.arange(n, dtype=np.float64),
        bearing=np.tile([1.0, 0.0, 0.0], (n, 1)),
    )
