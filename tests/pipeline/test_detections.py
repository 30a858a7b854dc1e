import numpy as np
import pytest

from pipeline.detections import Detections


def _sample(n: int = 5) -> Detections:
    rng = np.random.default_rng(0)
    return Detections.from_columns(
        np.arange(n) // 2,
        rng.uniform(0, 640, n),
        rng.uniform(0, 320, n),
        area=rng.integers(1, 9, n),
        peak=rng.uniform(50, 255, n),
        flash_probability=rng.uniform(0, 1, n),
    )


def test_csv_round_trip(tmp_path) -> None:
    det = _sample()
    path = tmp_path / "flashes.csv"
    det.to_csv(path)
    assert path.read_text().splitlines()[0] == "frame,x,y,area,peak,flash_probability,snr"
    back = Detections.from_csv(path)
    np.testing.assert_array_equal(back.frame, det.frame)
    np.testing.assert_allclose(back.x, det.x, atol=1e-4)
    np.testing.assert_allclose(back.flash_probability, det.flash_probability, atol=1e-5)


def test_csv_minimal_columns_and_nan(tmp_path) -> None:
    path = tmp_path / "other_tracker.csv"
    path.write_text("frame,x,y,extra\n3,10.5,20.25,7\n4,11,21,\n")
    det = Detections.from_csv(path)
    assert len(det) == 2
    assert np.isnan(det.flash_probability).all()
    np.testing.assert_array_equal(det.peak_x, [10, 11])


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty file"),
        ("frame,x\n1,2\n", "missing column"),
        ("frame,x,y\n1,2\n", "line 2 has 2 fields"),
        ("frame,x,y\n1,abc,3\n", "line 2"),
        ("frame,x,y\n1.5,2,3\n", "integers"),
    ],
)
def test_csv_errors_name_the_file(tmp_path, text: str, message: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as info:
        Detections.from_csv(path)
    assert "bad.csv" in str(info.value)


def test_npz_round_trip_is_exact(tmp_path) -> None:
    det = _sample(11)
    det.to_npz(tmp_path / "d.npz")
    back = Detections.from_npz(tmp_path / "d.npz")
    for name, col in det.columns().items():
        np.testing.assert_array_equal(getattr(back, name), col)


def test_spots_only_npz_keeps_frame_position_and_snr(tmp_path) -> None:
    det = Detections.from_columns(
        [3, 3, 900_000], [0.123456, 7679.987, 12.5], [1.5, 3839.25, 0.0], snr=[3.2, 3.9, 3.0]
    )
    det.to_npz(tmp_path / "spots.npz", spots_only=True)
    with np.load(tmp_path / "spots.npz") as data:
        assert sorted(data.files) == ["frame", "snr", "x", "y"]
    back = Detections.from_npz(tmp_path / "spots.npz")
    np.testing.assert_array_equal(back.frame, det.frame)
    np.testing.assert_allclose(back.x, det.x, atol=1e-3)
    np.testing.assert_allclose(back.y, det.y, atol=1e-3)
    np.testing.assert_array_equal(back.snr, det.snr)
    assert np.isnan(back.flash_probability).all() and np.all(back.area == 1)


def test_counts_concat_select() -> None:
    det = _sample(6)
    np.testing.assert_array_equal(det.counts_per_frame(4), [2, 2, 2, 0])
    both = Detections.concat([det, det.select(det.frame == 1)])
    assert len(both) == 8
    assert len(Detections.concat([])) == 0
