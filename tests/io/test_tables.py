"""Tables: columns checked on write and read, files written atomically, metadata kept."""

import numpy as np
import pandas as pd
import pytest

from signsplat.io.atomic import atomic_path, is_temporary
from signsplat.io.tables import TableError, read_table, write_table


def _timings():
    return pd.DataFrame({"scene": ["a"], "stage": ["s"], "step": ["x"], "seconds": [1.5],
                         "count": [3]})


def test_round_trip_with_metadata(tmp_path):
    path = write_table(_timings(), tmp_path / "t.parquet", "timings", metadata={"k": "v"})
    df = read_table(path, "timings")
    assert df["seconds"].tolist() == [1.5]
    assert df.attrs == {"k": "v"}


def test_list_columns_round_trip(tmp_path):
    df = pd.DataFrame({
        "scene": ["s", "s"], "frame": [0, 1],
        **{name: [np.arange(n, dtype=np.float32)] * 2 for name, n in
           [("betas", 10), ("expression", 10), ("global_orient", 3), ("body_pose", 63),
            ("jaw_pose", 3), ("leye_pose", 3), ("reye_pose", 3), ("left_hand_pose", 45),
            ("right_hand_pose", 45), ("transl", 3)]},
    })
    out = read_table(write_table(df, tmp_path / "p.parquet", "smplx_params",
                                 metadata={"hand_mean": "flat"}), "smplx_params")
    assert np.allclose(np.stack(out["body_pose"]), np.arange(63))
    assert out.attrs["hand_mean"] == "flat"


def test_missing_and_unknown_columns_are_named(tmp_path):
    with pytest.raises(TableError, match=r"lacks column\(s\) \['count'\]"):
        write_table(_timings().drop(columns="count"), tmp_path / "t.parquet", "timings")
    with pytest.raises(TableError, match="unknown column"):
        write_table(_timings().assign(extra=1), tmp_path / "t.parquet", "timings")
    assert not (tmp_path / "t.parquet").exists()


def test_read_errors_name_the_file(tmp_path):
    with pytest.raises(TableError, match="nope.parquet: file not found"):
        read_table(tmp_path / "nope.parquet", "timings")
    corrupt = tmp_path / "corrupt.parquet"
    corrupt.write_bytes(b"PAR1 not really")
    with pytest.raises(TableError, match="corrupt.parquet: not a readable Parquet"):
        read_table(corrupt, "timings")


def test_atomic_path_keeps_old_file_on_failure(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half written")
            raise RuntimeError("killed mid-write")
    assert target.read_text() == "old"
    assert list(tmp_path.iterdir()) == [target], "no temporary file left behind"


def test_a_terminated_command_leaves_no_temporary_file(tmp_path):
    # SIGTERM (how Snakemake cancels a job and SLURM ends one past its limit) runs the clean-up
    # of atomic_path under the CLI's handler; without it the process dies with the file left
    import signal
    import subprocess
    import sys
    import textwrap

    target = tmp_path / "out.parquet"
    target.write_text("old")
    script = textwrap.dedent(f"""
        import sys, time
        from signsplat.cli import terminate_cleanly
        from signsplat.io.atomic import atomic_path, is_temporary
        with terminate_cleanly():
            with atomic_path({str(target)!r}) as tmp:
                tmp.write_text("half written")
                print("ready", flush=True)
                time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    left = [p for p in tmp_path.iterdir() if p != target]
    assert len(left) == 1 and is_temporary(left[0])  # the writer's temporary file, mid-write
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=30) == 128 + signal.SIGTERM
    assert target.read_text() == "old"
    assert list(tmp_path.iterdir()) == [target], "no temporary file left behind"
    assert not is_temporary(target)

