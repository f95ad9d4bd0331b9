"""The footage benchmarks' last step: a table stamped with its sequence and date, printed and
written atomically (bench_footage_hands.py, bench_footage_signer.py)."""

from __future__ import annotations

import datetime as dt

import pandas as pd

from signsplat.io.atomic import atomic_path


def publish(df: pd.DataFrame, sequence: str, out: str) -> None:
    """Prefix ``sequence``, append today's date, print ``df`` and write it to ``out``."""
    df.insert(0, "sequence", sequence)
    df["date"] = dt.date.today().isoformat()
    print(df.to_string(index=False))
    with atomic_path(out) as tmp:
        df.to_parquet(tmp, index=False)
    print(f"wrote {out}")
