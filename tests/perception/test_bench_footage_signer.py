"""benchmarks/bench_footage_signer.py: frames judged by where the signer stands."""

import pandas as pd
from benchmark_scripts import load_benchmark


def test_judge_counts_the_signer_another_person_and_nobody():
    judge = load_benchmark("bench_footage_signer").judge
    rows = []
    for f, hip, how in [(0, 100.0, "box"), (1, 105.0, "tracked"), (2, 300.0, "tracked"),
                        (4, 110.0, "appearance"), (5, 40.0, "tracked")]:
        rows.append(dict(frame=f, hip_x=hip, chosen=True, chosen_by=how))
        rows.append(dict(frame=f, hip_x=hip + 150, chosen=False, chosen_by=""))
    got = judge(pd.DataFrame(rows), [[0, 3, 80, 120], [4, 5, 90, 130]])
    assert got["frames"].tolist() == ["0-3", "4-5", "all"]
    # frame 2 took someone at x 300, frame 3 nobody, frame 5 someone at x 40
    assert got[["judged", "signer", "other", "none", "appearance"]].values.tolist() == [
        [4, 2, 1, 1, 0], [2, 1, 1, 0, 1], [6, 3, 2, 1, 1]]
