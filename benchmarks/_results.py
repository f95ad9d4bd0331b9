"""What the side-by-side benchmarks share: appending their rows to a results table."""

from __future__ import annotations

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
