"""TFLite -> ONNX without TensorFlow: the maintained converter plus four small fixes of ours.

The converter is ``tflite2onnx`` 0.4.1 reading models with the pure-Python ``tflite`` 2.18.0
flatbuffer bindings. It converts MediaPipe's hand landmark and short-range face detection
models as they are; the other MediaPipe models need four things it lacks, done here on its
parsed graph between parsing and conversion (no fork, no edit of its files):

1. **Sparse weights** (TFLite op ``DENSIFY``): the sparse constant is expanded to a dense array
   (:func:`densify`, the TFLite sparsity format: traversal order, block map, dense and CSR
   dimensions) and the op is dropped; its output becomes a constant.
2. **DEPTH_TO_SPACE**: converted to ONNX ``DepthToSpace`` in ``DCR`` mode, which on NCHW is
   TensorFlow's NHWC ``depth_to_space`` (output channel c of block (i, j) reads input channel
   ``(i * block + j) * C_out + c``).
3. **Low-rank PReLU slopes**: tflite2onnx prepends one axis to a PReLU's ``alpha`` (for the
   batch axis) but not to the fp16 constant behind its DEQUANTIZE, so the layout transform
   fails on the constant; the slope (and its fp16 source) is padded with leading 1s to the
   input's rank.
4. **One PAD constant shared by several PAD ops**: tflite2onnx rewrites the paddings tensor in
   place per op (TFLite ``[n, 2]`` -> ONNX ``[2n]``), so a second op fails on the rewritten
   data; each further op gets its own copy.

The fixes use tflite2onnx's internal classes, so the versions are pinned and checked
(:data:`PINNED`); another version fails with a message saying so.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import logging
import os
from pathlib import Path

import numpy as np

from signsplat.errors import SignSplatError

PINNED = {"tflite2onnx": "0.4.1", "tflite": "2.18.0"}
ONNX_OPSET = 11  # what tflite2onnx 0.4.1 writes

# TFLite builtin operator codes (tflite/schema.fbs) and dimension/index vector types.
OP_DEPTH_TO_SPACE = 5
OP_DENSIFY = 124
DIM_DENSE, DIM_SPARSE_CSR = 0, 1


class ConversionError(SignSplatError):
    """A TFLite model could not be converted (the message names the file and the reason)."""


def check_versions() -> None:
    """Fail unless the pinned converter versions are installed (the fixes depend on them)."""
    for pkg, want in PINNED.items():
        try:
            have = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            raise ConversionError(f"package {pkg}=={want} is needed to convert TFLite models "
                                  f"(pip install {pkg}=={want})") from None
        if have != want:
            raise ConversionError(f"package {pkg} is {have}; the conversion fixes in "
                                  f"{__name__} were written for {pkg}=={want}")


# --- sparse tensors ---------------------------------------------------------------------------

def densify(values: np.ndarray, shape: tuple[int, ...], traversal_order: list[int],
            block_map: list[int], dims: list[dict]) -> np.ndarray:
    """Dense array of a TFLite sparse tensor.

    values: the stored (non-zero) values in traversal order; shape: the dense shape (n dims);
    traversal_order: n + k dimension ids (ids >= n are the k block dimensions);
    block_map: for each block dimension, the original dimension it splits;
    dims: per traversal level, ``{"format": 0 dense | 1 CSR, "dense_size": int,
    "segments": array, "indices": array}`` (the last two for CSR levels).
    """
    shape = tuple(int(s) for s in shape)
    n, k = len(shape), len(block_map)
    if len(traversal_order) != n + k or len(dims) != n + k:
        raise ValueError(f"sparse tensor: traversal order {traversal_order} and {len(dims)} "
                         f"dimension entries do not match shape {shape} with {k} block dims")
    block_size = {}
    for level, d in enumerate(traversal_order):
        if d >= n:
            block_size[d - n] = int(dims[level]["dense_size"])
    out = np.zeros(shape, dtype=values.dtype)
    coords = [0] * (n + k)

    def walk(level: int, pos: int) -> None:
        if level == n + k:
            idx = list(coords[:n])
            for b, orig in enumerate(block_map):
                idx[orig] = idx[orig] * block_size[b] + coords[n + b]
            out[tuple(idx)] = values[pos]
            return
        dim, meta = traversal_order[level], dims[level]
        if meta["format"] == DIM_DENSE:
            size = int(meta["dense_size"])
            for i in range(size):
                coords[dim] = i
                walk(level + 1, pos * size + i)
        else:
            seg, ind = meta["segments"], meta["indices"]
            for j in range(int(seg[pos]), int(seg[pos + 1])):
                coords[dim] = int(ind[j])
                walk(level + 1, j)

    walk(0, 0)
    return out


def _index_vector(table, kind: int) -> np.ndarray:
    """A TFLite SparseIndexVector union (Int32Vector 1, Uint16Vector 2, Uint8Vector 3)."""
    import tflite

    cls = {1: tflite.Int32Vector, 2: tflite.Uint16Vector, 3: tflite.Uint8Vector}.get(kind)
    if cls is None:
        raise ValueError(f"unknown sparse index vector type {kind}")
    vec = cls()
    vec.Init(table.Bytes, table.Pos)
    return np.asarray(vec.ValuesAsNumpy())


def sparse_tensor_to_dense(model, tensor) -> np.ndarray:
    """Dense numpy array of a sparse constant TFLite tensor (flatbuffer objects)."""
    from tflite2onnx import mapping

    sp = tensor.Sparsity()
    dtype = mapping.DTYPE_ONNX2NAME[mapping.DTYPE_TFLITE2ONNX[tensor.Type()]]
    values = np.frombuffer(model.Buffers(tensor.Buffer()).DataAsNumpy().tobytes(), dtype=dtype)
    dims = []
    for level in range(sp.DimMetadataLength()):
        dm = sp.DimMetadata(level)
        meta = {"format": dm.Format(), "dense_size": dm.DenseSize()}
        if dm.Format() == DIM_SPARSE_CSR:
            meta["segments"] = _index_vector(dm.ArraySegments(), dm.ArraySegmentsType())
            meta["indices"] = _index_vector(dm.ArrayIndices(), dm.ArrayIndicesType())
        dims.append(meta)
    block_map = sp.BlockMapAsNumpy() if sp.BlockMapLength() else []
    return densify(values, tuple(tensor.ShapeAsNumpy()), list(sp.TraversalOrderAsNumpy()),
                   [int(b) for b in block_map], dims)


# --- operator converters tflite2onnx lacks ----------------------------------------------------

def _extra_op_classes():
    """Densify and DepthToSpace converters in tflite2onnx's Operator interface."""
    import tflite
    from tflite2onnx.layout import Layout
    from tflite2onnx.op.common import Operator

    class Densify(Operator):
        """Sparse constant -> dense constant; dropped from the graph by :func:`_drop_densify`."""

        TypeMapping = {OP_DENSIFY: "Densify"}

        def __init__(self, TFactory, index):
            super().__init__(TFactory, index)
            self.setInited()

        @property
        def type(self):
            return "Densify"

        def parse(self):
            op = self.tflite
            sparse = self.graph.Tensors(op.Inputs(0))
            out = self.parseOutput(0)
            out.data = sparse_tensor_to_dense(self.model, sparse)
            self.setParsed()

        def propagatableTensors(self):
            return []

        def transform(self):
            pass

    class DepthToSpace(Operator):
        TypeMapping = {OP_DEPTH_TO_SPACE: "DepthToSpace"}

        def __init__(self, TFactory, index):
            super().__init__(TFactory, index)
            self.attrs["mode"] = "DCR"
            self.setInited()

        @property
        def type(self):
            return "DepthToSpace"

        def parse(self):
            op = self.tflite
            self.parseInput(0, Layout("NHWC", "NCHW"))
            self.parseOutput(0, Layout("NHWC", "NCHW"))
            opt = tflite.DepthToSpaceOptions()
            raw = op.BuiltinOptions()
            opt.Init(raw.Bytes, raw.Pos)
            self.attrs["blocksize"] = int(opt.BlockSize())
            self.setParsed()

        def propagatableTensors(self):
            return []

        def transform(self):
            pass

    return Densify, DepthToSpace


@contextlib.contextmanager
def _registered_extra_ops():
    """Register the extra converters in tflite2onnx's op registry for one conversion."""
    from tflite2onnx.op.common import OpFactory

    classes = _extra_op_classes()
    added = []
    for cls in classes:
        for code in cls.TypeMapping:
            if code not in OpFactory.registry:
                OpFactory.registry[code] = cls
                added.append(code)
    try:
        yield classes
    finally:
        for code in added:
            OpFactory.registry.pop(code, None)


# --- graph passes on tflite2onnx's parsed graph -----------------------------------------------

def _drop_densify(graph) -> int:
    """Remove Densify ops: their outputs already hold the dense constants."""
    dropped = [op for op in graph.ops if op.type == "Densify"]
    for op in dropped:
        graph.ops.remove(op)
        op.outputs[0].removeProducer(op)
    return len(dropped)


def _pad_prelu_slopes(graph) -> int:
    """Pad each PReLU slope (and the fp16 constant behind it) to its input's rank."""
    fixed = 0
    for op in graph.ops:
        if op.type != "PRelu":
            continue
        x, alpha = op.inputs[0], op.inputs[1]
        rank = len(x.shape)
        chain = [alpha]
        if alpha.producers and alpha.producers[0].type == "DequantizeLinear":
            chain.append(alpha.producers[0].inputs[0])
        changed = False
        for t in chain:
            if len(t.shape) < rank:
                t.shape = [1] * (rank - len(t.shape)) + list(t.shape)
                if t.data is not None:
                    t.data = np.asarray(t.data).reshape(t.shape)
                changed = True
        fixed += int(changed)
    return fixed


def _unshare_pad_constants(graph) -> int:
    """Give every PAD op after the first its own copy of a shared paddings constant."""
    seen, copies = set(), 0
    for op in graph.ops:
        if op.type != "Pad":
            continue
        pads = op.inputs[1]
        if id(pads) not in seen:
            seen.add(id(pads))
            continue
        copy = op.TFactory.getWithRef(pads, f"{pads.name}__for_{op.name}", True)
        copy.data = np.array(pads.data, copy=True)
        copy.setParsed()
        op.replaceInput(pads, copy)
        pads.removeConsumer(op)
        copy.addConsumer(op)
        copies += 1
    return copies


def _sort_by_name(g) -> None:
    """Initializers and value infos in name order: tflite2onnx collects them in sets, whose
    order changes run to run; sorted, the same model converts to the same bytes (hashable)."""
    for field in (g.initializer, g.value_info):
        items = sorted(field, key=lambda t: t.name)
        del field[:]
        field.extend(items)


def convert_tflite(src: str | os.PathLike, dst: str | os.PathLike) -> dict[str, int]:
    """Convert ``src`` (.tflite) to ``dst`` (.onnx, opset 11); returns how often each fix
    applied (``densify``, ``depth_to_space``, ``prelu_rank``, ``pad_copies``).

    Raises :class:`ConversionError` naming the file when the model cannot be converted.
    """
    check_versions()
    import onnx
    import tflite
    from onnx import helper
    from tflite2onnx.model import Model

    src, dst = Path(src), Path(dst)
    logging.getLogger("tflite2onnx").setLevel(logging.ERROR)
    try:
        fb = tflite.Model.GetRootAsModel(src.read_bytes(), 0)
        with _registered_extra_ops():
            model = Model(fb)
            model.parse()
            if len(model.graphes) != 1:
                raise ConversionError(f"{src}: {len(model.graphes)} subgraphs; one is supported")
            graph = model.graphes[0]
            report = {
                "densify": _drop_densify(graph),
                "depth_to_space": sum(op.type == "DepthToSpace" for op in graph.ops),
                "prelu_rank": _pad_prelu_slopes(graph),
                "pad_copies": _unshare_pad_constants(graph),
            }
            graph._collectOpAndTensor()
            graph.convert({})
    except ConversionError:
        raise
    except (NotImplementedError, ValueError, AssertionError, IndexError, KeyError) as exc:
        raise ConversionError(f"{src}: tflite2onnx {PINNED['tflite2onnx']} cannot convert it "
                              f"({type(exc).__name__}: {exc})") from exc
    _sort_by_name(graph.onnx)
    proto = helper.make_model(
        graph.onnx, producer_name="tflite2onnx+signsplat", ir_version=6,
        opset_imports=[helper.make_operatorsetid(onnx.defs.ONNX_DOMAIN, ONNX_OPSET)])
    onnx.checker.check_model(proto)
    from signsplat.io.atomic import atomic_path

    with atomic_path(dst) as tmp:
        onnx.save(proto, str(tmp))
    return report
