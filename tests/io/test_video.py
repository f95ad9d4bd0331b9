"""Frame extraction from real footage and streaming video writing."""

import numpy as np
import pytest
import yaml

from signsplat.errors import InputError
from signsplat.io.images import read_rgb, write_png
from signsplat.io.ingest import extract_sequence
from signsplat.io.tables import read_table
from signsplat.io.video import VideoWriter, iter_frames


def _video(path, n, size=(64, 48), fps=25):
    w, h = size
    with VideoWriter(path, fps=fps) as writer:
        for i in range(n):
            frame = np.zeros((h, w, 3), np.uint8)
            frame[:, : (i * 5) % w] = (200, 40, 10)
            writer.write(frame)
    return path


def test_writer_round_trip_and_odd_sizes(tmp_path):
    path = _video(tmp_path / "a.mp4", 7, size=(63, 47))
    frames = list(iter_frames(path))
    assert len(frames) == 7
    assert frames[0][1].shape == (48, 64, 3)  # padded to even size for H.264
    assert frames[6][1][10, 20, 0] > 150  # content survives encoding
    assert [p.name for p in tmp_path.iterdir()] == ["a.mp4"]


def test_writer_killed_midway_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError):
        with VideoWriter(tmp_path / "b.mp4", fps=25) as writer:
            writer.write(np.zeros((16, 16, 3), np.uint8))
            raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []


def test_extract_two_cameras_with_calibration(tmp_path):
    cams = [_video(tmp_path / f"c{i}.mp4", 6) for i in range(2)]
    calib = tmp_path / "calib.yaml"
    calib.write_text(yaml.safe_dump({"views": [{"fx": 50, "fy": 50, "cx": 16, "cy": 12}] * 2}))
    out = tmp_path / "out"
    frames = extract_sequence("s", cams, out, start=1, end=5, size=(32, 24), calibration=calib)
    assert len(frames) == 8 and sorted(frames["frame"].unique()) == [0, 1, 2, 3]
    table = read_table(out / "frames.parquet", "frames")
    assert read_rgb(out / table["image"].iloc[0]).shape == (24, 32, 3)
    cams_df = read_table(out / "cameras.parquet", "cameras")
    assert cams_df["width"].tolist() == [32, 32] and cams_df["frame"].tolist() == [-1, -1]


def test_image_folder_input(tmp_path):
    folder = tmp_path / "imgs"
    for i in range(3):
        write_png(folder / f"{i:03d}.png", np.full((8, 8, 3), i * 40, np.uint8))
    frames = extract_sequence("s", [folder], tmp_path / "out")
    assert len(frames) == 3


def test_mismatched_counts_name_every_file(tmp_path):
    a, b = _video(tmp_path / "a.mp4", 5), _video(tmp_path / "b.mp4", 3)
    with pytest.raises(InputError, match=r"a\.mp4: 5.*b\.mp4: 3"):
        extract_sequence("s", [a, b], tmp_path / "out")
    assert not (tmp_path / "out" / "frames.parquet").exists()


def test_corrupt_and_missing_videos_name_the_file(tmp_path):
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"\x00\x00\x00\x18ftypmp42 this is not a video")
    with pytest.raises(InputError, match="bad.mp4"):
        extract_sequence("s", [bad], tmp_path / "out")
    with pytest.raises(InputError, match="missing.mp4: camera input not found"):
        extract_sequence("s", [tmp_path / "missing.mp4"], tmp_path / "out")
    bad_calib = tmp_path / "calib.yaml"
    bad_calib.write_text(yaml.safe_dump({"views": [{"fx": 1}]}))
    with pytest.raises(InputError, match=r"calib.yaml: views\[0\] lacks key"):
        extract_sequence("s", [_video(tmp_path / "ok.mp4", 2)], tmp_path / "o2",
                         calibration=bad_calib)
