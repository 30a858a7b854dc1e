"""Probing and decoding of chapter-split equirectangular videos (pipeline.video)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import av
import numpy as np
import pytest

from pipeline.probe import VideoError, VideoInfo
from pipeline.video import (
    Frame,
    YuvEncoding,
    check_stereo_pair,
    iter_frames,
    probe_video,
)
from tests.pipeline import video_factory as vf

CHAPTERS = (30, 25, 20)
N_FRAMES = sum(CHAPTERS)


@pytest.fixture(scope="module", params=["h264", "hevc"])
def camera(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> VideoInfo:
    """A camera of three chapters whose pictures carry their global frame index."""
    directory = tmp_path_factory.mktemp(f"cam_{request.param}")
    pictures = [vf.index_picture(i) for i in range(N_FRAMES)]
    paths = vf.write_chapters(directory, "cam1", pictures, CHAPTERS, codec=request.param, gop=8)
    return probe_video(paths)


@pytest.fixture(scope="module")
def decoded(camera: VideoInfo) -> list[Frame]:
    """Every frame of `camera`, decoded front to back (copies of the planes)."""
    return [
        Frame(f.index, f.y.copy(), f.u.copy(), f.v.copy(), f.encoding) for f in iter_frames(camera)
    ]


def _one_video(path: Path, n: int = 10, **options: object) -> Path:
    return vf.write_video(path, [vf.index_picture(i) for i in range(n)], **options)  # type: ignore[arg-type]


# -- probing ---------------------------------------------------------------------------


def test_probe_reads_size_rate_count_and_codec(camera: VideoInfo) -> None:
    assert (camera.width, camera.height) == (640, 320)
    assert camera.fps == pytest.approx(30.0)
    assert camera.n_frames == N_FRAMES
    assert camera.codec in ("h264", "hevc")
    assert [ch.n_frames for ch in camera.chapters] == list(CHAPTERS)
    assert [ch.first_frame for ch in camera.chapters] == [0, 30, 55]
    assert camera.duration_s == pytest.approx(N_FRAMES / 30.0)


def test_probe_record_round_trips_through_json(camera: VideoInfo) -> None:
    record = json.loads(json.dumps(camera.to_dict()))
    assert isinstance(record["chapters"][0]["path"], str)
    assert VideoInfo.from_dict(record) == camera


def test_probe_measures_the_bits_spent_per_pixel(camera: VideoInfo) -> None:
    frame_bytes = [sum(size for _, size in vf.sample_offsets(ch.path)) for ch in camera.chapters]
    assert [ch.video_bytes for ch in camera.chapters] == frame_bytes
    pixels = camera.n_frames * camera.width * camera.height
    assert camera.bits_per_pixel == pytest.approx(8 * sum(frame_bytes) / pixels)
    # The whole file holds the container's boxes too: more than the frames' bytes.
    assert sum(ch.path.stat().st_size for ch in camera.chapters) > sum(frame_bytes)


def test_a_matroska_file_is_counted_frame_by_frame(tmp_path: Path) -> None:
    """No sample table: packets are counted, the first ones carrying no decode time."""
    path = _one_video(tmp_path / "night.mkv", n=12)
    with av.open(str(path)) as container:
        packets = [p for p in container.demux(container.streams.video[0]) if p.size]
    assert any(p.dts is None for p in packets)  # what made the count short before
    info = probe_video([path])
    assert info.n_frames == 12 == len(list(iter_frames(info)))
    assert info.chapters[0].video_bytes == sum(p.size for p in packets)


def test_a_probe_record_without_sizes_has_no_bits_per_pixel(camera: VideoInfo) -> None:
    record = camera.to_dict()
    for chapter in record["chapters"]:
        del chapter["video_bytes"]
    assert VideoInfo.from_dict(record).bits_per_pixel is None


def test_from_dict_names_a_missing_field(camera: VideoInfo) -> None:
    record = camera.to_dict()
    del record["fps"]
    with pytest.raises(VideoError, match=r"malformed video probe record.*fps"):
        VideoInfo.from_dict(record)


def test_chapters_for_a_range_and_local_paths(camera: VideoInfo, tmp_path: Path) -> None:
    assert camera.chapters_for(0, 30) == (0,)
    assert camera.chapters_for(29, 31) == (0, 1)
    assert camera.chapters_for(55, 75) == (2,)
    moved = camera.with_paths({2: tmp_path / "copy.mp4"})
    assert moved.chapters[2].path == tmp_path / "copy.mp4"
    assert moved.chapters[:2] == camera.chapters[:2]


# -- decoding --------------------------------------------------------------------------


def test_frames_carry_their_global_index(decoded: list[Frame]) -> None:
    assert [f.index for f in decoded] == list(range(N_FRAMES))
    assert [vf.read_index(f.y) for f in decoded] == list(range(N_FRAMES))
    assert decoded[0].y.shape == (320, 640)
    assert decoded[0].u.shape == decoded[0].v.shape == (160, 320)


@pytest.mark.parametrize(
    ("start", "stop"),
    [
        (0, 4),  # the very start
        (27, 34),  # across the first chapter boundary
        (41, 47),  # starting mid-chapter, after a keyframe
        (54, 56),  # the last frame of chapter 2 and the first of chapter 3
        (12, 75),  # through every boundary to the end
        (74, 75),  # the last frame
    ],
)
def test_a_range_decodes_the_same_frames_as_a_full_pass(
    camera: VideoInfo, decoded: list[Frame], start: int, stop: int
) -> None:
    frames = list(iter_frames(camera, start, stop))
    assert [f.index for f in frames] == list(range(start, stop))
    for frame in frames:
        reference = decoded[frame.index]
        assert vf.read_index(frame.y) == frame.index
        assert np.array_equal(frame.y, reference.y)
        assert np.array_equal(frame.u, reference.u)
        assert np.array_equal(frame.v, reference.v)


def test_frames_coded_whole_are_flagged_key(camera: VideoInfo, decoded: list[Frame]) -> None:
    keys = [f.index for f in iter_frames(camera) if f.key]
    if camera.codec == "hevc":  # x265 at a fixed interval: every 8th frame of each chapter
        assert keys == [0, 8, 16, 24, 30, 38, 46, 54, 55, 63, 71]
    else:  # x264 also codes a frame whole where the picture changes a lot (scene cut)
        assert {0, 8, 30, 55} <= set(keys) and len(keys) < N_FRAMES // 2
    # A range decoded on its own flags the same frames.
    assert [f.index for f in iter_frames(camera, 41, 60) if f.key] == [
        k for k in keys if 41 <= k < 60
    ]


def test_ten_bit_video_is_handed_out_as_8_bit_planes(tmp_path: Path) -> None:
    pictures = [vf.index_picture(i) for i in range(6)]
    path = vf.write_video(tmp_path / "hdr.mp4", pictures, codec="hevc", pix_fmt="yuv420p10le")
    frames = list(iter_frames(probe_video([path])))
    assert all(f.y.dtype == np.uint8 and f.u.dtype == np.uint8 for f in frames)
    assert [vf.read_index(f.y) for f in frames] == list(range(6))
    assert np.abs(frames[0].y.astype(int) - pictures[0]).mean() < 2


def test_ranges_outside_the_video_are_refused(camera: VideoInfo) -> None:
    with pytest.raises(ValueError, match=r"\[70, 80\) is outside the video's 0\.\.75 frames"):
        list(iter_frames(camera, 70, 80))
    with pytest.raises(ValueError, match="outside"):
        list(iter_frames(camera, 5, 4))
    assert list(iter_frames(camera, 5, 5)) == []


def test_a_file_shorter_than_probed_is_reported_with_the_frame(camera: VideoInfo) -> None:
    # A chapter replaced after probing by a shorter one: decoding runs out early.
    last = camera.chapters[-1]
    claimed = replace(last, n_frames=last.n_frames + 5)
    info = replace(camera, chapters=(*camera.chapters[:-1], claimed), n_frames=N_FRAMES + 5)
    with pytest.raises(VideoError, match=rf"{last.path.name}: truncated or corrupt at frame 20 "):
        list(iter_frames(info, 70))


@pytest.mark.parametrize(
    ("matrix", "full_range", "size", "tag", "expected"),
    [
        ("bt709", True, (640, 320), True, YuvEncoding("bt709", True)),
        ("bt601", False, (640, 320), True, YuvEncoding("bt601", False)),
        ("bt601", False, (640, 320), False, YuvEncoding("bt601", False)),  # untagged SD
        ("bt709", False, (1440, 720), False, YuvEncoding("bt709", False)),  # untagged HD
    ],
)
def test_yuv_encoding_is_read_from_the_stream(
    tmp_path: Path,
    matrix: str,
    full_range: bool,
    size: tuple[int, int],
    tag: bool,
    expected: YuvEncoding,
) -> None:
    width, height = size
    pictures = [np.full((height, width, 3), 100, np.uint8)] * 2
    path = vf.write_video(
        tmp_path / "c.mp4",
        pictures,
        matrix=matrix,
        full_range=full_range,
        tag_colour=tag,  # type: ignore[arg-type]
    )
    frame = next(iter_frames(probe_video([path])))
    assert frame.encoding == expected


# -- refusals --------------------------------------------------------------------------


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(VideoError, match=r"cam1_07\.mp4: file not found"):
        probe_video([tmp_path / "cam1_07.mp4"])


def test_no_files() -> None:
    with pytest.raises(VideoError, match="no video files given"):
        probe_video([])


def test_not_a_video(tmp_path: Path) -> None:
    notes = tmp_path / "notes.mp4"
    notes.write_text("field notes, not a video\n" * 20)
    with pytest.raises(VideoError, match=r"notes\.mp4: not a readable video file"):
        probe_video([notes])


def test_garbage_bytes(tmp_path: Path) -> None:
    garbage = tmp_path / "garbage.mp4"
    garbage.write_bytes(np.random.default_rng(0).integers(0, 256, 50_000, np.uint8).tobytes())
    with pytest.raises(VideoError, match=r"garbage\.mp4: not a readable video file"):
        probe_video([garbage])


def test_zero_byte_file(tmp_path: Path) -> None:
    empty = tmp_path / "upload.mp4"
    empty.touch()
    with pytest.raises(VideoError, match=r"upload\.mp4: empty file \(0 bytes\)"):
        probe_video([empty])


def test_video_without_frames(tmp_path: Path) -> None:
    path = vf.write_empty_video(tmp_path / "cam2_00.mp4")
    with pytest.raises(VideoError, match=r"cam2_00\.mp4: the video stream has no frames"):
        probe_video([path])


def test_audio_only_file(tmp_path: Path) -> None:
    path = tmp_path / "sound.m4a"
    with av.open(str(path), "w") as container:
        stream = container.add_stream("aac", rate=44100)
        for i in range(5):
            samples = av.AudioFrame.from_ndarray(
                np.zeros((1, 1024), np.float32), format="fltp", layout="mono"
            )
            samples.sample_rate, samples.pts = 44100, i * 1024
            container.mux(stream.encode(samples))
        container.mux(stream.encode(None))
    with pytest.raises(
        VideoError, match=r"sound\.m4a: no video stream in the file \(found: audio\)"
    ):
        probe_video([path])


def test_not_equirectangular(tmp_path: Path) -> None:
    path = vf.write_video(tmp_path / "flat.mp4", [np.zeros((480, 640), np.uint8)] * 3)
    with pytest.raises(VideoError, match=r"flat\.mp4: frame size 640×480 is not equirectangular"):
        probe_video([path])


def test_truncated_upload_with_sample_table_up_front(tmp_path: Path) -> None:
    path = _one_video(tmp_path / "cut.mp4", n=40, faststart=True)
    vf.truncate(path, 0.5)
    with pytest.raises(
        VideoError, match=r"cut\.mp4: truncated: the file lists 40 frames .*only \d+"
    ):
        probe_video([path])


def test_truncated_upload_without_sample_table(tmp_path: Path) -> None:
    path = _one_video(tmp_path / "cut.mp4", n=40)  # the sample table is written last
    vf.truncate(path, 0.5)
    with pytest.raises(VideoError, match=r"cut\.mp4: not a readable video file.*truncated"):
        probe_video([path])


def test_overwritten_header(tmp_path: Path) -> None:
    path = _one_video(tmp_path / "hdr.mp4")
    data = bytearray(path.read_bytes())
    data[:64] = bytes(range(64))
    path.write_bytes(bytes(data))
    with pytest.raises(VideoError, match=r"hdr\.mp4: not a readable video file"):
        probe_video([path])


@pytest.mark.parametrize("codec", ["h264", "hevc"])
def test_overwritten_frame_data_names_the_frame(tmp_path: Path, codec: str) -> None:
    path = _one_video(tmp_path / "bad.mp4", n=40, codec=codec, gop=10)
    vf.overwrite_sample(path, 21)
    info = probe_video([path])  # the container is intact: only decoding finds it
    with pytest.raises(VideoError, match=r"bad\.mp4: corrupt video data.* near frame (\d+)") as err:
        list(iter_frames(info))
    reported = int(err.value.args[0].split("near frame ")[1].split()[0])
    assert 18 <= reported <= 26  # reordering and frame threads report it a few frames late


def test_chapters_of_different_size(tmp_path: Path) -> None:
    first = _one_video(tmp_path / "a.mp4")
    second = vf.write_video(tmp_path / "b.mp4", [np.zeros((160, 320), np.uint8)] * 3)
    with pytest.raises(VideoError, match=r"b\.mp4: frame size 320×160 differs from 640×320"):
        probe_video([first, second])


def test_chapters_of_different_rate(tmp_path: Path) -> None:
    first = _one_video(tmp_path / "a.mp4")
    second = _one_video(tmp_path / "b.mp4", fps=25.0)
    with pytest.raises(VideoError, match=r"b\.mp4: frame rate 25\.000 fps differs from 30\.000"):
        probe_video([first, second])


def test_stereo_pair_checks(tmp_path: Path) -> None:
    base = probe_video([_one_video(tmp_path / "cam1.mp4")])
    check_stereo_pair(base, base)
    check_stereo_pair(base, replace(base, fps=30.0 * (1 + 2e-4)))  # rounded metadata
    ntsc = probe_video([_one_video(tmp_path / "cam2.mp4", fps=30000 / 1001)])
    with pytest.raises(VideoError, match=r"camera 1 30\.000 fps .* camera 2 29\.970 fps"):
        check_stereo_pair(base, ntsc)
    small = replace(base, width=320, height=160)
    with pytest.raises(VideoError, match=r"camera 1 640×320 .* camera 2 320×160"):
        check_stereo_pair(base, small)
