"""ONNX model contracts of the perception stages and their load-time checks.

Two contracts, so that real models drop in by a path in the config:

- **Segmentation (MODNet-style)**: one input, an RGB image batch ``(N, 3, H, W)`` float32,
  normalised as ``(pixel - mean) / std`` with pixel values in 0..255; the output at
  ``output_index`` is a foreground alpha or probability ``(N, 1, H, W)`` in [0, 1].
  ``input_size``, ``mean``, ``std`` and ``output_index`` are config fields (defaults are those
  of the shipped model; MODNet uses mean = std = 127.5, i.e. inputs in [-1, 1]).
- **Keypoints (RTMPose/RTMW SimCC)**: one input, a crop ``(N, 3, H, W)`` float32 normalised
  with ``mean = (123.675, 116.28, 103.53)``, ``std = (58.395, 57.12, 57.375)``; two outputs
  ``simcc_x (N, K, W*r)`` and ``simcc_y (N, K, H*r)`` with K = 133 (COCO-WholeBody) and split
  ratio r (2 for RTMPose/RTMW/DWPose). Outputs are found by name (``simcc_x``, ``simcc_y``) or,
  when a file names them otherwise, by position (x first), as rtmlib does.

A model that does not match fails at load with :class:`ModelContractError`, whose message shows
the expected and the found shapes. Dimensions a file leaves symbolic are checked on a dry run
with one zero input. Batch: when the file's batch axis is symbolic the stages run several
images per call; when it is fixed (RTMW/DWPose files from rtmlib use batch 1) one per call.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from signsplat.body.joints import NUM_KEYPOINTS
from signsplat.errors import InputError

RTM_MEAN = (123.675, 116.28, 103.53)
RTM_STD = (58.395, 57.12, 57.375)


class ModelContractError(InputError):
    """An ONNX file is missing, unreadable or does not match its stage's contract."""


@dataclass(frozen=True)
class SegmenterSpec:
    """How to feed and read a segmentation model (fields mirror the config section).

    input_size: (H, W) the image is resized to (None = the file's static size, or the image's
    own size when the file's size is symbolic; a symbolic size must then be a multiple of 32).
    mean, std: per-channel normalisation on 0..255 values, in the model's channel order.
    color_order: 'rgb' or 'bgr' channel order the model expects.
    output_index: which output holds the alpha (N, 1, H, W).
    threshold: alpha above which a pixel is foreground.
    batch_size: images per call when the model's batch axis is symbolic.
    reference_size: with ``input_size`` None, MODNet's sizing rule: a frame whose sides are
    both larger (or both smaller) than this is scaled to this shorter side; sides are rounded
    down to multiples of 32 (None = the frame's own size rounded to 32).
    device: 'auto' (CUDA when onnxruntime has it), 'cpu', or 'cuda[:N]' (the config's device).
    """

    path: str
    input_size: tuple[int, int] | None = (256, 256)
    mean: tuple[float, float, float] = (127.5, 127.5, 127.5)
    std: tuple[float, float, float] = (127.5, 127.5, 127.5)
    color_order: str = "rgb"
    output_index: int = 0
    threshold: float = 0.7
    batch_size: int = 8
    reference_size: int | None = None
    device: str = "auto"


@dataclass(frozen=True)
class KeypointSpec:
    """How to feed and read a top-down SimCC keypoint model (fields mirror the config section).

    input_size: (H, W) of the crop (None = the file's static size, as RTMW files have).
    split_ratio: SimCC bins per input pixel (r; simcc_x has W*r bins).
    padding: the person box is enlarged by this factor before the fixed-aspect crop.
    score_mode: 'clip' maps the raw SimCC maximum to [0, 1] by clipping (rtmlib thresholds
    the raw maxima at ~0.3; the shipped model outputs sigmoid probabilities, unchanged by it).
    min_area: a mask with fewer foreground pixels counts as no person (all scores 0).
    device: as in :class:`SegmenterSpec`.
    """

    path: str
    input_size: tuple[int, int] | None = None
    mean: tuple[float, float, float] = RTM_MEAN
    std: tuple[float, float, float] = RTM_STD
    color_order: str = "rgb"
    split_ratio: float = 2.0
    padding: float = 1.25
    num_keypoints: int = NUM_KEYPOINTS
    score_mode: str = "clip"
    min_area: int = 50
    batch_size: int = 16
    device: str = "auto"


@dataclass
class LoadedModel:
    """An onnxruntime session with the facts the stages need (after the contract check)."""

    session: object  # onnxruntime.InferenceSession
    path: str
    input_name: str
    output_names: list[str]
    input_size: tuple[int, int] | None  # (H, W), None when symbolic and not configured
    dynamic_batch: bool
    extra: dict = field(default_factory=dict)

    def run(self, batch: np.ndarray) -> list[np.ndarray]:
        """Run the model on a float32 (N, 3, H, W) batch; one call per item if batch is fixed."""
        if self.dynamic_batch or batch.shape[0] == 1:
            return self.session.run(self.output_names, {self.input_name: batch})
        parts = [self.session.run(self.output_names, {self.input_name: batch[i:i + 1]})
                 for i in range(batch.shape[0])]
        return [np.concatenate([p[j] for p in parts]) for j in range(len(self.output_names))]


def providers(device: str = "auto") -> list:
    """onnxruntime execution providers for a device: with 'auto' CUDA first when this build
    has it, then the CPU; 'cpu' the CPU only; 'cuda[:N]' that GPU (an error without one)."""
    import onnxruntime as ort

    avail = ort.get_available_providers()
    if device == "cpu":
        return ["CPUExecutionProvider"]
    if device.startswith("cuda"):
        if "CUDAExecutionProvider" not in avail:
            raise ModelContractError(f"device {device!r}: this onnxruntime build has no CUDA "
                                     f"provider (it has {avail}); allowed here: auto, cpu")
        index = int(device.split(":")[1]) if ":" in device else 0
        return [("CUDAExecutionProvider", {"device_id": index}), "CPUExecutionProvider"]
    return [p for p in ("CUDAExecutionProvider", "CPUExecutionProvider") if p in avail]


def open_session(path: str | os.PathLike, threads: int = 1, what: str = "model",
                 device: str = "auto"):
    """An onnxruntime session for ``path`` on ``device`` (:func:`providers`); a missing or
    unreadable file names the file."""
    import onnxruntime as ort

    path = Path(path)
    if not path.is_file():
        raise ModelContractError(f"{path}: {what} file not found")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = max(1, int(threads))
    opts.inter_op_num_threads = 1
    # Pool threads sleep between parallel sections instead of spinning: beside other work
    # (two sequences side by side, a shared node) spinning takes the cores that work needs
    # (docs/architecture.md)
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    opts.log_severity_level = 3
    try:
        return ort.InferenceSession(str(path), sess_options=opts, providers=providers(device))
    except Exception as exc:  # onnxruntime raises its own exception types for bad files
        raise ModelContractError(f"{path}: not a loadable ONNX {what} ({exc})") from exc


def _shape(arg) -> tuple:
    """Static dims as ints, symbolic ones as None."""
    return tuple(d if isinstance(d, int) and d > 0 else None for d in arg.shape)


def _fmt(shape) -> str:
    return "(" + ", ".join("?" if d is None else str(d) for d in shape) + ")"


def _matches(found: tuple, expected: tuple) -> bool:
    """True when ranks agree and every dim known on both sides agrees."""
    return len(found) == len(expected) and all(
        f is None or e is None or f == e for f, e in zip(found, expected))


def _fail(path, contract: str, what: str, expected, found) -> None:
    exp = expected if isinstance(expected, str) else _fmt(expected)
    fnd = found if isinstance(found, str) else _fmt(found)
    raise ModelContractError(
        f"{path}: model does not match the {contract} contract: {what} expected {exp}, "
        f"found {fnd}")


def _resolve_size(path, contract, declared: tuple, configured) -> tuple[int, int] | None:
    h, w = declared[2], declared[3]
    if configured is not None:
        configured = (int(configured[0]), int(configured[1]))
        if (h is not None and h != configured[0]) or (w is not None and w != configured[1]):
            _fail(path, contract, "input (N, 3, H, W) with the configured input_size",
                  (None, 3, *configured), declared)
        return configured
    if h is not None and w is not None:
        return (h, w)
    return None


def _open_image_model(path, threads: int, what: str, contract: str, batch, device: str):
    """Open an ONNX model with one image input (batch, 3, H, W); ``batch`` is how the
    contract names the batch axis in messages (None = any N). Returns (session, inputs,
    outputs, input shape)."""
    sess = open_session(path, threads, what, device)
    inputs, outputs = sess.get_inputs(), sess.get_outputs()
    n = "N" if batch is None else str(batch)
    if len(inputs) != 1:
        _fail(path, contract, "inputs", f"1 input ({n}, 3, H, W)",
              f"{len(inputs)} inputs {[_fmt(_shape(i)) for i in inputs]}")
    ishape = _shape(inputs[0])
    if not _matches(ishape, (None, 3, None, None)):
        _fail(path, contract, "input", (batch, 3, None, None), ishape)
    return sess, inputs, outputs, ishape


def load_segmenter(spec: SegmenterSpec, threads: int = 1) -> LoadedModel:
    """Open a segmentation model and check it against the MODNet-style contract."""
    contract = "segmentation (MODNet-style)"
    sess, inputs, outputs, ishape = _open_image_model(spec.path, threads, "segmentation model",
                                                      contract, None, spec.device)
    if not 0 <= spec.output_index < len(outputs):
        _fail(spec.path, contract, f"output index {spec.output_index}",
              "an output (N, 1, H, W)", f"{len(outputs)} output(s)")
    out = outputs[spec.output_index]
    oshape = _shape(out)
    if not _matches(oshape, (None, 1, None, None)):
        _fail(spec.path, contract, f"output {out.name!r}", (None, 1, None, None), oshape)
    size = _resolve_size(spec.path, contract, ishape, spec.input_size)
    model = LoadedModel(sess, str(spec.path), inputs[0].name, [out.name], size,
                        dynamic_batch=ishape[0] is None)
    # dry run: the real output shape for a (1, 3, H, W) input
    h, w = size if size is not None else (256, 256)
    try:
        (alpha,) = model.run(np.zeros((1, 3, h, w), np.float32))
    except Exception as exc:  # onnxruntime fails with its own types on shape errors
        raise ModelContractError(f"{spec.path}: dry run with input (1, 3, {h}, {w}) failed "
                                 f"({exc})") from exc
    if alpha.shape != (1, 1, h, w):
        _fail(spec.path, contract, f"output {out.name!r} for input (1, 3, {h}, {w})",
              (1, 1, h, w), alpha.shape)
    return model


def load_keypointer(spec: KeypointSpec, threads: int = 1) -> LoadedModel:
    """Open a keypoint model and check it against the RTMPose/RTMW SimCC contract."""
    contract = "RTMPose/RTMW SimCC keypoint"
    sess, inputs, outputs, ishape = _open_image_model(spec.path, threads, "keypoint model",
                                                      contract, 1, spec.device)
    size = _resolve_size(spec.path, contract, ishape, spec.input_size)
    if size is None:
        _fail(spec.path, contract, "input size", "static H, W or keypoints.input_size set",
              ishape)
    h, w = size
    k, r = spec.num_keypoints, spec.split_ratio
    exp_x, exp_y = (None, k, int(round(w * r))), (None, k, int(round(h * r)))
    names = [o.name for o in outputs]
    if "simcc_x" in names and "simcc_y" in names:
        ox, oy = outputs[names.index("simcc_x")], outputs[names.index("simcc_y")]
    elif len(outputs) == 2:
        ox, oy = outputs
    else:
        _fail(spec.path, contract, "outputs", f"simcc_x {_fmt(exp_x)} and simcc_y {_fmt(exp_y)}",
              ", ".join(f"{o.name} {_fmt(_shape(o))}" for o in outputs))
    for o, exp, label in ((ox, exp_x, "simcc_x"), (oy, exp_y, "simcc_y")):
        if not _matches(_shape(o), exp):
            _fail(spec.path, contract, f"output {label} ({o.name!r}) for input {_fmt((1, 3, h, w))}"
                  f" and split ratio {r:g}", exp, _shape(o))
    model = LoadedModel(sess, str(spec.path), inputs[0].name, [ox.name, oy.name], size,
                        dynamic_batch=ishape[0] is None)
    try:
        sx, sy = model.run(np.zeros((1, 3, h, w), np.float32))
    except Exception as exc:  # onnxruntime fails with its own types on shape errors
        raise ModelContractError(f"{spec.path}: dry run with input (1, 3, {h}, {w}) failed "
                                 f"({exc})") from exc
    for arr, exp, label in ((sx, exp_x, "simcc_x"), (sy, exp_y, "simcc_y")):
        if arr.shape != (1,) + exp[1:]:
            _fail(spec.path, contract, f"{label} from a dry run with input (1, 3, {h}, {w})",
                  (1,) + exp[1:], arr.shape)
    return model
