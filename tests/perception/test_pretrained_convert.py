"""TFLite -> ONNX: each of our four fixes on a tiny TFLite graph that needs it. The plain
converter fails on every one; ours gives TFLite's result (NumPy semantics, and the TFLite
runtime's output where ``ai-edge-litert`` is installed). Converting twice writes the same
bytes (the manifest records their hash)."""

from __future__ import annotations

import hashlib

import numpy as np
import onnxruntime as ort
import pytest
import tflite_graphs as tg

from signsplat.perception.pretrained.convert import (PINNED, ConversionError, check_versions,
                                                     convert_tflite, densify)

CASES = {
    "prelu_fp16_alpha": (tg.prelu_fp16_alpha, "prelu_rank", 1),
    "shared_pad_constant": (tg.shared_pad_constant, "pad_copies", 1),
    "densified_weights": (tg.densified_weights, "densify", 1),
    "depth_to_space": (tg.depth_to_space, "depth_to_space", 1),
}


def _run_onnx(path, x_nhwc):
    """Run a converted graph on an NHWC input; tflite2onnx turns the layout to NCHW only
    where a layout-sensitive op (conv, resize, depth-to-space) asks for it."""
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    nchw = list(sess.get_inputs()[0].shape) != list(x_nhwc.shape)
    x = x_nhwc.transpose(0, 3, 1, 2).copy() if nchw else x_nhwc
    (y,) = sess.run(None, {sess.get_inputs()[0].name: x})
    return y.transpose(0, 2, 3, 1) if nchw else y


def _run_litert(model: bytes, x):
    litert = pytest.importorskip("ai_edge_litert.interpreter",
                                 reason="ai-edge-litert (the TFLite runtime) not installed")
    it = litert.Interpreter(model_content=model)
    it.allocate_tensors()
    it.set_tensor(it.get_input_details()[0]["index"], x)
    it.invoke()
    return it.get_tensor(it.get_output_details()[0]["index"])


@pytest.mark.parametrize("case", sorted(CASES))
def test_fix_converts_what_the_plain_converter_cannot(tmp_path, case):
    make, fix, count = CASES[case]
    model, x, expected = make(np.random.default_rng(0))
    src = tmp_path / f"{case}.tflite"
    src.write_bytes(model)
    import tflite2onnx

    with pytest.raises((NotImplementedError, IndexError, AssertionError, ValueError)):
        tflite2onnx.convert(str(src), str(tmp_path / "plain.onnx"))
    report = convert_tflite(src, tmp_path / "ours.onnx")
    assert report[fix] == count
    assert sum(report.values()) == count  # no other fix touched the graph
    got = _run_onnx(tmp_path / "ours.onnx", x)
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("case", sorted(CASES))
def test_numpy_semantics_match_the_tflite_runtime(case):
    make = CASES[case][0]
    model, x, expected = make(np.random.default_rng(1))
    np.testing.assert_allclose(_run_litert(model, x), expected, rtol=1e-6, atol=1e-6)


def test_conversion_is_byte_identical_run_to_run(tmp_path):
    model, _, _ = tg.prelu_fp16_alpha(np.random.default_rng(0))
    (tmp_path / "m.tflite").write_bytes(model)
    hashes = set()
    for i in range(3):
        convert_tflite(tmp_path / "m.tflite", tmp_path / f"m{i}.onnx")
        hashes.add(hashlib.sha256((tmp_path / f"m{i}.onnx").read_bytes()).hexdigest())
    assert len(hashes) == 1


def test_densify_csr_and_blocks():
    # 4 x 6 matrix: rows dense, columns CSR
    dense = np.array([[0, 1, 0, 0, 2, 0], [0, 0, 0, 0, 0, 0], [3, 0, 0, 4, 0, 5],
                      [0, 0, 6, 0, 0, 0]], np.float32)
    out = densify(np.array([1, 2, 3, 4, 5, 6], np.float32), (4, 6), [0, 1], [],
                  [dict(format=0, dense_size=4),
                   dict(format=1, segments=[0, 2, 2, 5, 6], indices=[1, 4, 0, 3, 5, 2])])
    np.testing.assert_array_equal(out, dense)
    # the same matrix in 2 x 2 blocks of the columns' dimension split by 2: traversal (row,
    # column block, in-block column), block map [1]; blocks stored dense, block columns CSR
    # column blocks: (0,1), (2,3), (4,5); row 0 has blocks 0 and 2; row 2 blocks 0, 1, 2; row 3
    # block 1
    values = np.array([0, 1, 2, 0, 3, 0, 0, 4, 0, 5, 6, 0], np.float32)
    out = densify(values, (4, 6), [0, 1, 2], [1],
                  [dict(format=0, dense_size=4),
                   dict(format=1, segments=[0, 2, 2, 5, 6], indices=[0, 2, 0, 1, 2, 1]),
                   dict(format=0, dense_size=2)])
    np.testing.assert_array_equal(out, dense)


def test_pinned_versions_are_checked(monkeypatch):
    check_versions()  # the installed ones are the pinned ones
    import importlib.metadata

    real = importlib.metadata.version
    monkeypatch.setattr(importlib.metadata, "version",
                        lambda pkg: "9.9.9" if pkg == "tflite2onnx" else real(pkg))
    with pytest.raises(ConversionError, match=f"tflite2onnx is 9.9.9.*{PINNED['tflite2onnx']}"):
        check_versions()


def test_unconvertible_model_names_the_file(tmp_path):
    import tflite

    # HARD_SWISH (selfie segmentation's op): neither tflite2onnx nor our fixes convert it
    bad = tmp_path / "bad.tflite"
    bad.write_bytes(tg.build(
        tensors=[dict(name="x", shape=[1, 2, 2, 3], type=tg.F32),
                 dict(name="y", shape=[1, 2, 2, 3], type=tg.F32)],
        inputs=[0], outputs=[1],
        ops=[dict(code=tflite.BuiltinOperator.HARD_SWISH, inputs=[0], outputs=[1])],
        buffers=[b""]))
    with pytest.raises(ConversionError, match=r"bad\.tflite.*HARD_SWISH"):
        convert_tflite(bad, tmp_path / "bad.onnx")
    assert not (tmp_path / "bad.onnx").exists()
