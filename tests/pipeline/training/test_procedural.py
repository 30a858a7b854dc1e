"""Domain-randomised procedural patches and the held-out calibration they allow."""

from dataclasses import replace

import numpy as np
from scipy.special import expit

from pipeline.training.calibration import fit_platt, reliability
from pipeline.training.dataset import folder_manifest, load_patch_folder
from pipeline.training.metrics import expected_calibration_error, roc_auc
from pipeline.training.simdata import SYNTH_MANIFEST, build_procedural_dataset, procedural_patches
from pipeline.training.trainer import TrainConfig, predict_logits, train_model


def test_procedural_patches_are_centred_labelled_and_reproducible() -> None:
    a = procedural_patches(n_recordings=2, per_recording=40, size=33, seed=3)
    b = procedural_patches(n_recordings=2, per_recording=40, size=33, seed=3)
    np.testing.assert_array_equal(a.images, b.images)
    assert a.images.shape == (80, 33, 33, 3) and a.images.dtype == np.uint8
    assert set(np.unique(a.groups)) == {"synth3r0", "synth3r1"}
    assert 0.3 < a.labels.mean() < 0.7
    # the blob's brightest pixel (channel sum) is at the centre, as the tracker cuts
    # patches (other objects further out may be brighter)
    lum = a.images.astype(int).sum(axis=3)
    local_max = lum[:, 12:21, 12:21].reshape(80, -1).max(axis=1)
    assert (lum[:, 16, 16] == local_max).all()
    c = procedural_patches(n_recordings=2, per_recording=40, size=33, seed=4)
    assert not np.array_equal(a.images, c.images)


def test_procedural_folder_round_trip_and_manifest(tmp_path) -> None:
    manifest = build_procedural_dataset(tmp_path / "p", 2, 10, size=33, seed=1)
    loaded = load_patch_folder(tmp_path / "p")
    assert len(loaded) == 20 and loaded.size == 33
    assert loaded.labels.sum() == manifest["n_flash"]
    assert set(np.unique(loaded.groups)) == {"synth1r0", "synth1r1"}
    identity = folder_manifest(tmp_path / "p")
    assert identity["counts"] == {
        "flash": manifest["n_flash"],
        "background": 20 - manifest["n_flash"],
    }
    assert identity["generator"]["seed"] == 1 and (tmp_path / "p" / SYNTH_MANIFEST).is_file()
    (
        tmp_path
        / "p"
        / "flash"
        / next(iter(sorted(p.name for p in (tmp_path / "p" / "flash").iterdir())))
    ).write_bytes(b"x")
    assert folder_manifest(tmp_path / "p")["sha256"] != identity["sha256"]


def test_calibration_on_held_out_simulated_recordings() -> None:
    """Platt scaling fitted on held-out recordings makes the probability honest on
    other held-out recordings: predicted vs observed within 0.1 per populated bin,
    where the raw network output is not."""
    train = procedural_patches(n_recordings=4, per_recording=150, size=33, seed=10)
    calib = procedural_patches(n_recordings=6, per_recording=200, size=33, seed=11)
    test = procedural_patches(n_recordings=6, per_recording=200, size=33, seed=12)
    config = TrainConfig(epochs=4, batch_size=32, widths=(4, 8, 8), threads=1)
    model = train_model(train, replace(config, balance=False))
    platt = fit_platt(predict_logits(model, calib.images), calib.labels)
    logits = predict_logits(model, test.images)
    assert roc_auc(test.labels, logits) > 0.8
    bins = [b for b in reliability(test.labels, platt(logits)) if b["n"] >= 60]
    assert len(bins) >= 3
    gaps = [abs(b["predicted"] - b["observed"]) for b in bins]
    assert max(gaps) <= 0.1, bins
    raw = expected_calibration_error(test.labels, expit(logits))
    assert expected_calibration_error(test.labels, platt(logits)) < raw
