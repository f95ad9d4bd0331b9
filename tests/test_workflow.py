"""The workflow: `snakemake -n` plans the default config; the simulate rule runs on a tiny scene."""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]


def snakemake(*args, timeout=900):
    cmd = [sys.executable, "-m", "snakemake", "--cores", "2", "--nolock", *args]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout)


def job_counts(stdout: str) -> dict[str, int]:
    """Parse the 'Job stats' table of a dry run."""
    lines = stdout.splitlines()
    start = lines.index("Job stats:")
    counts = {}
    for line in lines[start + 3:]:
        parts = line.split()
        if len(parts) != 2 or not parts[1].isdigit():
            break
        counts[parts[0]] = int(parts[1])
    return counts


def test_dry_run_lists_the_jobs_of_the_default_config(tmp_path):
    res = snakemake("-n", "--config", f"results={tmp_path}")
    assert res.returncode == 0, res.stderr + res.stdout
    counts = job_counts(res.stdout)
    default = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    assert counts["body_model"] == 1 and counts["gloss_library"] == 1
    assert counts["simulate"] >= 2  # studio6 and single at least
    assert counts["all"] == 1
    assert default["results"] == "results"


def test_dry_run_rejects_an_unknown_effect(tmp_path):
    spec = tmp_path / "bad.yaml"
    spec.write_text("cameras: {count: 1}\nmotion: {glosses: [HELLO]}\n"
                    "effects: [lighting, bloom]\n")
    sheet = tmp_path / "sequences.tsv"
    sheet.write_text(f"sequence\tsource\tspec\nbadfx\tsynthetic\t{spec}\n")
    cfg = tmp_path / "config.yaml"
    cfg.write_text(yaml.safe_dump({"results": str(tmp_path), "sequences": str(sheet),
                                   "scenes": []}))
    res = snakemake("-n", "--configfile", str(cfg))
    assert res.returncode != 0
    out = res.stdout + res.stderr
    assert "bloom" in out and "camera_jitter" in out


@pytest.mark.slow
def test_simulate_rule_runs_on_the_tiny_scene(tmp_path):
    cfg = tmp_path / "config.yaml"
    cfg.write_text(yaml.safe_dump({"results": str(tmp_path / "results"), "sequences": None,
                                   "scenes": ["tiny"]}))
    target = tmp_path / "results" / "tiny" / "sim" / "frames.parquet"
    res = snakemake(str(target), "--configfile", str(cfg))
    assert res.returncode == 0, res.stderr[-4000:]
    sim = target.parent
    for name in ("frames", "cameras", "smplx_gt", "keypoints_gt"):
        assert (sim / f"{name}.parquet").is_file()
    assert len(list((sim / "images").rglob("*.png"))) == 2 * 4
    assert len(list((sim / "masks").rglob("*.png"))) == 2 * 4
    log = (tmp_path / "results" / "_logs" / "tiny" / "simulate.log").read_text()
    assert "ms per frame per view" in log
    assert (tmp_path / "results" / "_benchmarks" / "tiny" / "simulate.tsv").is_file()
    # nothing left to do: a second dry run plans no job
    res = snakemake("-n", str(target), "--configfile", str(cfg))
    assert res.returncode == 0 and "Nothing to be done" in res.stdout + res.stderr
