import csv
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper

from pipeline.classify import (
    FlashClassifier,
    ModelCard,
    center_crop_or_pad,
    default_model_path,
)
from pipeline.cli import main

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
REFERENCE = SHARED / "reference-models" / "ffnet_gp360_65_rgb.onnx"
PHONE = SHARED / "data" / "ffeye-phone-33"


def first_channel_mean_model(path: Path, size: int, layout: str = "NCHW") -> Path:
    """ONNX graph whose output is the mean of input channel 0, shape (N,)."""
    shape = ["N", 3, size, size] if layout == "NCHW" else ["N", size, size, 3]
    axis = 1 if layout == "NCHW" else 3
    index = helper.make_tensor("c0", TensorProto.INT64, [], [0])
    graph = helper.make_graph(
        [
            helper.make_node("Gather", ["x", "c0"], ["plane"], axis=axis),
            helper.make_node("ReduceMean", ["plane"], ["y"], axes=[1, 2], keepdims=0),
        ],
        "first_channel_mean",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, shape)],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["N"])],
        initializer=[index],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, str(path))
    return path


def card(**overrides: object) -> ModelCard:
    fields: dict[str, object] = {
        "name": "mean",
        "input_size": 9,
        "input_name": "x",
        "output_name": "y",
        "scale": 1 / 255,
        "output_kind": "probability",
        "threshold": 0.5,
    }
    return ModelCard(**(fields | overrides))


def write_pair(tmp_path: Path, layout: str = "NCHW", **overrides: object) -> Path:
    model = first_channel_mean_model(tmp_path / "mean.onnx", 9, layout)
    card(layout=layout, **overrides).write_json(tmp_path / "mean.json")
    return model


def red_and_blue(n: int = 2) -> np.ndarray:
    patches = np.zeros((n, 9, 9, 3), np.uint8)
    patches[0, ..., 0] = 255  # pure red
    patches[1, ..., 2] = 255  # pure blue
    return patches


def test_card_round_trip(tmp_path: Path) -> None:
    original = card(training={"seed": 3}, evaluation={"auc": 0.97})
    original.write_json(tmp_path / "c.json")
    assert ModelCard.from_json(tmp_path / "c.json") == original


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("{not json", "not valid JSON"),
        (json.dumps({"name": "x"}), "input_size"),
        (card().model_dump_json()[:-1] + ', "colour": 1}', "colour"),
        (
            card(threshold=0.5).model_dump_json().replace('"threshold":0.5', '"threshold":1.5'),
            "threshold",
        ),
    ],
)
def test_bad_card_errors_name_file_and_field(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as info:
        ModelCard.from_json(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"input_size": 11}, "does not match"),
        ({"input_name": "image"}, "card input 'image'"),
        ({"output_name": "prob"}, "card output 'prob'"),
        ({"output_kind": "softmax"}, "no flash column"),
    ],
)
def test_card_must_agree_with_model(tmp_path: Path, overrides: dict, message: str) -> None:
    model = write_pair(tmp_path, **overrides)
    with pytest.raises(ValueError, match=message):
        FlashClassifier.load(model)


def test_layout_mismatch_is_refused(tmp_path: Path) -> None:
    model = first_channel_mean_model(tmp_path / "m.onnx", 9, "NHWC")
    card(layout="NCHW").write_json(tmp_path / "m.json")
    with pytest.raises(ValueError, match="NCHW"):
        FlashClassifier.load(model)


@pytest.mark.parametrize(
    ("layout", "order", "expected"),
    [("NCHW", "RGB", [1.0, 0.0]), ("NCHW", "BGR", [0.0, 1.0]), ("NHWC", "RGB", [1.0, 0.0])],
)
def test_predict_feeds_layout_and_channel_order(
    tmp_path: Path, layout: str, order: str, expected: list[float]
) -> None:
    classifier = FlashClassifier.load(write_pair(tmp_path, layout, channel_order=order))
    np.testing.assert_allclose(classifier.predict(red_and_blue()), expected, atol=1e-6)


def test_predict_applies_mean_std_and_sigmoid(tmp_path: Path) -> None:
    model = write_pair(tmp_path, mean=(0.5, 0.5, 0.5), std=(0.25, 1, 1), output_kind="sigmoid")
    # red plane: (1 - 0.5) / 0.25 = 2 -> sigmoid(2); black: (0 - 0.5) / 0.25 = -2
    got = FlashClassifier.load(model).predict(red_and_blue())
    np.testing.assert_allclose(got, 1 / (1 + np.exp([-2.0, 2.0])), rtol=1e-6)


def test_card_found_beside_model_else_clear_error(tmp_path: Path) -> None:
    model = write_pair(tmp_path)
    assert FlashClassifier.load(model).card.name == "mean"
    lonely = tmp_path / "lonely.onnx"
    shutil.copy(model, lonely)
    with pytest.raises(FileNotFoundError, match=r"lonely\.json"):
        FlashClassifier.load(lonely)
    explicit = FlashClassifier.load(lonely, tmp_path / "mean.json")
    assert explicit.input_size == 9


def test_missing_model_is_named(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"nothing\.onnx"):
        FlashClassifier.load(tmp_path / "nothing.onnx")


def test_wrong_patch_size_is_refused() -> None:
    classifier = FlashClassifier.load()
    with pytest.raises(ValueError, match=r"\(N, 33, 33, 3\)"):
        classifier.predict(np.zeros((2, 31, 31, 3), np.uint8))


def test_default_model_and_card() -> None:
    classifier = FlashClassifier.load()
    assert default_model_path().stat().st_size < 5_000_000
    assert classifier.input_size == 33
    assert 0 < classifier.threshold < 1
    training = classifier.card.training
    assert training["command"].startswith("firefly3d train-classifier")
    assert "--seed" in training["command"] and "--threads 1" in training["command"]
    assert training["calibration"]["kind"] == "platt"
    # every data folder is identified by its counts and a hash of its files
    assert all({"counts", "sha256"} <= set(m) for m in training["data_manifests"].values())
    held_out = classifier.card.evaluation["held_out_by_source"]
    assert any("gp360" in source for source in held_out)
    assert classifier.predict(np.zeros((0, 33, 33, 3), np.uint8)).shape == (0,)


def phone_patches(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The first ``n`` flash and ``n`` background real patches, RGB, and their labels."""
    files = (
        sorted((PHONE / "flash").glob("*.png"))[:n]
        + sorted((PHONE / "background").glob("*.png"))[:n]
    )
    images = np.stack([cv2.imread(str(f))[..., ::-1] for f in files])
    return images, np.repeat([1, 0], n)


def test_batching_equals_single_calls() -> None:
    images, _ = phone_patches(10)
    batched = FlashClassifier.load(batch_size=7).predict(images)
    single = FlashClassifier.load(batch_size=1)
    one_by_one = np.concatenate([single.predict(images[i : i + 1]) for i in range(len(images))])
    np.testing.assert_allclose(batched, one_by_one, atol=1e-6)
    assert ((batched >= 0) & (batched <= 1)).all()


def test_shipped_model_separates_real_patches() -> None:
    images, labels = phone_patches(40)
    p = FlashClassifier.load().predict(images)
    assert p[labels == 1].mean() > p[labels == 0].mean() + 0.5


def test_reference_model_through_its_shipped_card() -> None:
    classifier = FlashClassifier.load(REFERENCE)
    assert (classifier.card.name, classifier.input_size) == ("ffnet_gp360_65_rgb", 65)
    assert classifier.threshold == 0.98
    images, labels = phone_patches(20)
    padded = center_crop_or_pad(images, 65)
    got = classifier.predict(padded)
    # the card says: raw 0-255 RGB, NCHW, column 0 of the softmax is the flash
    session = ort.InferenceSession(str(REFERENCE), providers=["CPUExecutionProvider"])
    raw = session.run(None, {"imageinput": padded.transpose(0, 3, 1, 2).astype(np.float32)})[0]
    np.testing.assert_allclose(got, raw[:, 0], atol=1e-6)
    assert got[labels == 1].mean() > got[labels == 0].mean()


def test_center_crop_or_pad_keeps_the_centre_pixel() -> None:
    image = np.arange(5 * 5).reshape(1, 5, 5, 1)
    cropped = center_crop_or_pad(image, 3)
    np.testing.assert_array_equal(cropped[0, :, :, 0], image[0, 1:4, 1:4, 0])
    padded = center_crop_or_pad(image, 7)
    assert padded[0, 3, 3, 0] == image[0, 2, 2, 0]
    np.testing.assert_array_equal(padded[0, 0, 1:6, 0], image[0, 0, :, 0])  # edge replicated
    np.testing.assert_array_equal(padded[0, :, 0, 0], padded[0, :, 1, 0])


def write_image(path: Path, rgb: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), rgb[..., ::-1])
    return path


def test_classify_command_writes_scores_and_skips_unreadable(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    images, _ = phone_patches(2)
    folder = tmp_path / "patches"
    a = write_image(folder / "a.png", images[0])
    b = write_image(folder / "nested" / "b.jpg", images[1])  # lossy, still scored
    big = write_image(folder / "nested" / "big.png", center_crop_or_pad(images[2:3], 41)[0])
    broken = folder / "broken.png"
    broken.write_bytes(b"\x89PNG not really")
    (folder / "notes.txt").write_text("ignored: not an image suffix")
    single = write_image(tmp_path / "single.png", images[3])
    out = tmp_path / "scores.csv"

    rc = main(["classify", str(folder), str(single), str(tmp_path / "gone"), "--out", str(out)])

    assert rc == 0
    err = capsys.readouterr().err
    assert f"skipped {broken}: not a readable image" in err
    assert "gone: no such file" in err
    with out.open() as stream:
        rows = list(csv.reader(stream))
    assert rows[0] == ["path", "flash_probability"]
    scores = {path: float(p) for path, p in rows[1:]}
    assert set(scores) == {str(a), str(b), str(big), str(single)}
    classifier = FlashClassifier.load()
    expected = classifier.predict(np.stack([images[0], images[2], images[3]]))
    got = [scores[str(a)], scores[str(big)], scores[str(single)]]
    np.testing.assert_allclose(got, expected, atol=1e-5)  # 41 px was centre-cropped


GOPRO = SHARED / "data" / "ffeye-gp360-65"


def test_classify_command_on_65_and_33_pixel_patches(tmp_path: Path) -> None:
    """GoPro patches (65×65) are centre-cropped to the model's 33×33: scoring the
    65-pixel file and its 33-pixel crop gives the same probability."""
    files = sorted((GOPRO / "flash").glob("*.png"))[:6]
    big = np.stack([cv2.imread(str(f))[..., ::-1] for f in files])
    assert big.shape[1:] == (65, 65, 3)
    small = center_crop_or_pad(big, 33)
    for i in range(len(files)):
        write_image(tmp_path / "p65" / f"{i}.png", big[i])
        write_image(tmp_path / "p33" / f"{i}.png", small[i])
    scores = {}
    for name in ("p65", "p33"):
        out = tmp_path / f"{name}.csv"
        assert main(["classify", str(tmp_path / name), "--out", str(out)]) == 0
        with out.open() as stream:
            scores[name] = [float(row["flash_probability"]) for row in csv.DictReader(stream)]
    np.testing.assert_allclose(scores["p65"], scores["p33"], atol=1e-6)
    np.testing.assert_allclose(scores["p33"], FlashClassifier.load().predict(small), atol=1e-5)


def test_classify_command_fails_when_nothing_is_readable(tmp_path: Path) -> None:
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"")
    out = tmp_path / "scores.csv"
    assert main(["classify", str(bad), "--out", str(out)]) == 1
    assert out.read_text().splitlines() == ["path,flash_probability"]
