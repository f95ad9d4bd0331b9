"""The fit's generalisation suite: scenes generated from a grid (signsplat.synth.suite) and
cameras placed one by one (scene `cameras.views`)."""

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from signsplat.config import load_sequences, validate
from signsplat.synth.scene import SceneError, camera_rig, check_scene
from signsplat.synth.suite import generate_suite, write_suite

REPO = Path(__file__).resolve().parents[2]
GRID = REPO / "config" / "scenes" / "suite" / "grid.yaml"


@pytest.fixture(scope="module")
def grid():
    return yaml.safe_load(GRID.read_text())


@pytest.fixture(scope="module")
def suite(grid):
    return generate_suite(grid)


def test_every_axis_value_is_used_and_scenes_validate(grid, suite):
    rows = [s for n, s in suite.items() if n.startswith("g")]
    assert len(rows) == grid["scenes"]
    counts = {len(s["cameras"]["views"]) for s in rows}
    assert counts == {r["count"] for r in grid["axes"]["rig"]} >= {2, 3, 4, 6, 8}
    images = {(s["cameras"]["width"], s["cameras"]["height_px"]) for s in rows}
    assert images == {tuple(i) for i in grid["axes"]["image"]}
    assert min(min(i) for i in images) == 160 and any(w != h for w, h in images)
    assert {s["max_frames"] for s in rows} == set(grid["axes"]["clip"])
    dists = {s["cameras"]["distance"] for s in rows}
    assert min(dists) == 1.5 and max(dists) == 4.0
    fovs = {round(s["cameras"]["fov_degrees"]) for s in rows}
    assert len(fovs) > 5  # distance and framing give many focal lengths
    tilts = {(s["cameras"]["height"], s["cameras"]["target"][1]) for s in rows}
    assert len(tilts) == len(grid["axes"]["height"])
    for name, spec in suite.items():
        check = validate(copy.deepcopy({k: v for k, v in spec.items() if k != "name"}),
                         "scene.schema.yaml", name)
        check_scene(check, name)
        assert len(camera_rig(check["cameras"])) == check["cameras"]["count"]
    # a scene declares only the effects of its row; one row has none beyond the basics
    eff = [[e if isinstance(e, str) else next(iter(e)) for e in s["effects"]] for s in rows]
    assert any(set(e) == {"lighting", "background"} for e in eff)
    assert any({"camera_jitter", "occluder", "motion_blur", "sensor_noise"} <= set(e)
               for e in eff)
    assert set(suite) >= {"issue29", "hard_small_baseline", "hard_back_camera", "hard_half_out"}


def test_uneven_spacing_moves_inner_cameras_and_their_distances(suite, grid):
    uneven = [s for n, s in suite.items() if n.startswith("g") and
              "distance" in s["cameras"]["views"][0]]
    assert uneven
    for s in uneven:
        az = np.array([v["azimuth_degrees"] for v in s["cameras"]["views"]])
        gaps = np.diff(np.sort(az))
        assert gaps.std() > 0.5  # not evenly spaced
        d = [v["distance"] for v in s["cameras"]["views"]]
        assert max(d) - min(d) > 0.0
    again = generate_suite(grid)  # deterministic
    assert again == suite


def test_views_place_each_camera_where_it_says():
    cams = validate({"count": 2, "width": 200, "height_px": 160, "target": [0.0, 1.3, 0.0],
                     "views": [{"azimuth_degrees": 90.0, "distance": 3.0, "height": 1.8},
                               {"azimuth_degrees": 0.0, "fov_degrees": 60.0,
                                "target": [0.5, 1.0, 0.0]}]},
                    "scene.schema.yaml#/properties/cameras")
    rig = camera_rig(cams)
    np.testing.assert_allclose(rig[0].center, [3.0, 1.8, 0.0], atol=1e-9)
    np.testing.assert_allclose(rig[1].center, [0.0, cams["height"], cams["distance"]],
                               atol=1e-9)
    # camera 1 looks at its own target: that point projects to the image centre
    p = rig[1].R @ np.array([0.5, 1.0, 0.0]) + rig[1].t
    uv = p[:2] / p[2] * rig[1].K[0, 0] + rig[1].K[:2, 2]
    np.testing.assert_allclose(uv, [(200 - 1) / 2, (160 - 1) / 2], atol=1e-6)
    assert rig[1].K[1, 1] == pytest.approx(80 / np.tan(np.radians(30)))
    assert rig[0].K[1, 1] == pytest.approx(80 / np.tan(np.radians(20)))  # section's 40 deg
    with pytest.raises(SceneError, match="count is 3"):
        camera_rig(dict(cams, count=3))
    with pytest.raises(SceneError, match="count is 3"):
        check_scene({"cameras": dict(cams, count=3)}, "x.yaml")


def test_written_suite_is_a_sequence_sheet_the_workflow_loads(tmp_path, suite):
    few = {k: suite[k] for k in ("g00", "issue29")}
    write_suite(few, tmp_path / "suite", "grid.yaml")
    (tmp_path / "suite" / "stale.yaml").write_text("seed: 0\n")
    write_suite(few, tmp_path / "suite", "grid.yaml")
    assert sorted(p.name for p in (tmp_path / "suite").glob("*.yaml")) == ["g00.yaml",
                                                                         "issue29.yaml"]
    seqs = load_sequences({"sequences": str(tmp_path / "suite" / "sequences.tsv")},
                          root="/")
    assert set(seqs) == {"g00", "issue29"}
    assert seqs["issue29"]["num_views"] == 3
    text = (tmp_path / "suite" / "issue29.yaml").read_text()
    assert text.startswith("# Generated by `signsplat suite-scenes`")
    assert "render:" not in text  # only what the grid sets (the schema fills the rest)
