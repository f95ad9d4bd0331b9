"""The detector training set: valid, varied, reproducible specs; resumable simulation."""

from __future__ import annotations

from signsplat.synth.training_set import training_scene_specs


def test_training_scene_specs_are_valid_varied_and_reproducible():
    from signsplat.config import validate
    from signsplat.synth.scene import check_scene

    names = ["HELLO", "BOOK", "HOUSE", "NAME", "WHAT", "FRIEND"]
    a, b = training_scene_specs(6, 0, names), training_scene_specs(6, 0, names)
    assert a == b
    assert training_scene_specs(6, 1, names) != a
    for spec in a:
        validate(spec, "scene.schema.yaml", spec["name"])
        check_scene(spec, spec["name"])
    assert len({s["signer"]["appearance_seed"] for s in a}) == 6
    assert len({s["cameras"]["distance"] for s in a}) == 6
    assert all(s["seed"] >= 1000 for s in a)  # disjoint from the evaluation scenes' seeds


def test_simulate_training_set_reuses_finished_scenes(tmp_path, monkeypatch, gloss_library_path):
    """A finished scene (same spec, ground truth written) is kept; a changed spec is redone."""
    import signsplat.synth.simulate as sim
    from signsplat.synth.training_set import simulate_training_set

    calls = []

    def fake_simulate(spec, body, glosses, out, threads=1, progress=True):
        calls.append(spec["name"])
        out.mkdir(parents=True)
        (out / "keypoints_gt.parquet").write_bytes(b"x")

    monkeypatch.setattr(sim, "simulate_scene", fake_simulate)
    dirs = simulate_training_set(3, 0, "body.npz", gloss_library_path, tmp_path, progress=False)
    assert [d.parent.name for d in dirs] == ["train000", "train001", "train002"]
    assert calls == ["train000", "train001", "train002"]
    simulate_training_set(3, 0, "body.npz", gloss_library_path, tmp_path, progress=False)
    assert len(calls) == 3  # nothing simulated again
    (dirs[1] / "keypoints_gt.parquet").unlink()  # an interrupted scene
    simulate_training_set(3, 0, "body.npz", gloss_library_path, tmp_path, progress=False)
    assert calls[3:] == ["train001"]
    simulate_training_set(3, 1, "body.npz", gloss_library_path, tmp_path, progress=False)
    assert calls[4:] == ["train000", "train001", "train002"]  # other seed: other specs


def test_wide_training_scenes_cover_other_rigs_and_leave_the_studio_set_as_it_was():
    """The ``wide`` camera space: rings with views from behind, 1.5-4 m, small and non-square
    images; its own seeds. The ``studio`` set (the shipped models' training scenes) is drawn
    exactly as before the wide space was added (the digest of its specs then)."""
    import hashlib
    import json

    import numpy as np
    import pytest

    from signsplat.config import validate
    from signsplat.synth.scene import check_scene

    names = ["HELLO", "BOOK", "HOUSE", "NAME", "WHAT", "FRIEND"]
    studio = training_scene_specs(8, 0, names)
    wide = training_scene_specs(24, 0, names, cameras="wide")
    digest = hashlib.sha256(json.dumps(studio, sort_keys=True).encode()).hexdigest()
    assert digest.startswith("a0fe1c8a8be19f82")
    for spec in wide:
        validate(spec, "scene.schema.yaml", spec["name"])
        check_scene(spec, spec["name"])
    cams = [s["cameras"] for s in wide]
    assert all(s["seed"] >= 3000 and s["name"].startswith("wide") for s in wide)
    assert {s["signer"]["appearance_seed"] for s in wide}.isdisjoint(
        s["signer"]["appearance_seed"] for s in studio)
    assert min(c["distance"] for c in cams) < 2.0 and max(c["distance"] for c in cams) > 3.5
    assert any(c["width"] != c["height_px"] for c in cams)
    assert min(min(c["width"], c["height_px"]) for c in cams) <= 160
    azimuths = np.concatenate([[v["azimuth_degrees"] for v in c["views"]] for c in cams])
    assert np.any(np.abs(azimuths) > 135)  # views from behind the signer
    assert all(len(c["views"]) == c["count"] for c in cams)
    with pytest.raises(ValueError, match="allowed values are"):
        training_scene_specs(2, 0, names, cameras="ring")
