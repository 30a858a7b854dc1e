import json
from pathlib import Path

import pytest

from pipeline.classify import FlashClassifier
from pipeline.cli import main


def test_train_then_evaluate(
    patch_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "models" / "tiny.onnx"
    args = ["train-classifier", "--out", str(out), "--data", str(patch_folder)]
    assert main([*args, "--epochs", "2", "--cv-folds", "2", "--threads", "1"]) == 0
    report = capsys.readouterr().out
    assert "grouped 2-fold CV on 48 patches from 4 recordings" in report
    assert "contrast features + logistic regression" in report
    assert "vid3" in report  # per-recording table
    assert "held-out recordings, calibrated" in report and "AUC2c" in report

    card = json.loads(out.with_suffix(".json").read_text())
    assert card["training"]["command"].startswith("firefly3d train-classifier --out")
    assert "--seed 0" in card["training"]["command"]
    assert card["training"]["config"]["epochs"] == 2
    assert card["training"]["calibration"]["kind"] == "platt"
    manifest = card["training"]["data_manifests"][str(patch_folder)]
    assert manifest["counts"] == {"flash": 24, "background": 24}
    held_out = card["evaluation"]["held_out_by_source"][str(patch_folder)]
    assert held_out["n_recordings"] == 4 and held_out["reliability"]
    by_source = card["evaluation"]["by_source"][str(patch_folder)]
    cv = next(v for k, v in by_source.items() if "grouped CV, calibrated" in k)
    assert 0 <= cv["auc"] <= 1 and set(cv["per_recording"]) == {"vid0", "vid1", "vid2", "vid3"}
    classifier = FlashClassifier.load(out)
    assert classifier.threshold == card["threshold"]

    assert main(["eval-classifier", "--model", str(out), "--data", str(patch_folder),
                 "--cv-folds", "2"]) == 0  # fmt: skip
    report = capsys.readouterr().out
    assert f"source: {patch_folder}" in report
    assert f"warning: {patch_folder} was used to train this model" in report
    assert "AUC" in report and "tiny" in report
    assert f"flash recall at threshold {classifier.threshold:.3f} on {patch_folder}" in report
    assert "reliability (bin: n, mean predicted -> observed flash frequency)" in report


def test_train_refuses_folder_without_patches(tmp_path: Path, capsys) -> None:
    rc = main(["train-classifier", "--out", str(tmp_path / "m.onnx"), "--data", str(tmp_path)])
    assert rc == 1
    assert "expected sub-folders" in capsys.readouterr().err
