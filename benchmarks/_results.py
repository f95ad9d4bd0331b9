"""What the side-by-side benchmarks share: the commit a checkout holds, and appending their
rows to a results table."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pandas as pd


def append_rows(rows: pd.DataFrame, path: Path) -> pd.DataFrame:
    """``rows`` appended to the Parquet table at ``path`` (created when missing) and written
    atomically, so that a stopped run leaves the table as it was; returns the whole table."""
    if path.exists():
        rows = pd.concat([pd.read_parquet(path), rows], ignore_index=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    rows.to_parquet(tmp, index=False)
    tmp.replace(path)
    return rows


def commit_of(checkout: Path) -> str:
    """The short hash of the commit ``checkout`` holds (what runs, not what is committed)."""
    return subprocess.run(["git", "-C", str(checkout), "rev-parse", "--short", "HEAD"],
                          capture_output=True, text=True, check=True).stdout.strip()
