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


def _faststart_video(path, n, size=(64, 48)):
    """A video with its index first (as streamed files are), so a cut file opens and fails
    where its data ends."""
    import av

    w, h = size
    with av.open(str(path), "w", options={"movflags": "faststart"}) as c:
        s = c.add_stream("libx264", rate=25)
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        rng = np.random.default_rng(0)
        for _ in range(n):
            frame = av.VideoFrame.from_ndarray(rng.integers(0, 255, (h, w, 3), np.uint8),
                                               format="rgb24")
            for p in s.encode(frame):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


def test_cut_video_names_the_file_and_the_frame(tmp_path):
    full = _faststart_video(tmp_path / "full.mp4", 40)
    cut = tmp_path / "cut.mp4"
    data = full.read_bytes()
    cut.write_bytes(data[:len(data) // 2])
    with pytest.raises(InputError, match=r"cut\.mp4: corrupt video, decoding failed at frame "
                                         r"(\d+)") as err:
        extract_sequence("s", [cut], tmp_path / "out")
    assert 0 < int(err.value.args[0].split("at frame ")[1].split()[0]) < 40
    assert not (tmp_path / "out" / "frames.parquet").exists()


def test_crop_box_applies_before_resize_and_is_recorded(tmp_path):
    import json

    path = _video(tmp_path / "a.mp4", 3, size=(64, 48))
    out = tmp_path / "out"
    extract_sequence("s", [path], out, crop=(10, 4, 32, 40), size=(16, 20))
    table = read_table(out / "frames.parquet", "frames")
    assert read_rgb(out / table["image"].iloc[0]).shape == (20, 16, 3)
    assert json.loads(table.attrs["cameras"]) == [str(path)]
    frame = next(iter_frames(path, crop=(10, 4, 32, 40)))[1]
    whole = next(iter_frames(path))[1]
    np.testing.assert_array_equal(frame, whole[4:44, 10:42])
    with pytest.raises(InputError, match=r"a\.mp4: frame 0: crop box x,y,w,h = 40,0,32,48 does "
                                         r"not fit the 64x48 frame"):
        extract_sequence("s", [path], tmp_path / "o2", crop=(40, 0, 32, 48))


def test_sheet_row_crop_reaches_ingest(tmp_path):
    import json

    from signsplat.cli import main

    path = _video(tmp_path / "a.mp4", 2, size=(64, 48))
    row = {"sequence": "s", "cameras": str(path), "crop": "8,8,32,24", "resize": None}
    assert main(["extract-frames", "--sequence-json", json.dumps(row), "--out",
                 str(tmp_path / "out")]) == 0
    table = read_table(tmp_path / "out" / "frames.parquet", "frames")
    assert read_rgb(tmp_path / "out" / table["image"].iloc[0]).shape == (24, 32, 3)
