"""Tiny TFLite models written with the ``tflite`` package's flatbuffer builders, one per
conversion fix, with the NumPy result each must give (TFLite's semantics)."""

from __future__ import annotations

import flatbuffers
import numpy as np
import tflite
from tflite import TensorType

F32, F16, I32 = TensorType.FLOAT32, TensorType.FLOAT16, TensorType.INT32
OP_ADD, OP_PAD, OP_DEQUANTIZE, OP_PRELU, OP_MAX_POOL = 0, 34, 6, 54, 17
OP_DEPTH_TO_SPACE, OP_DENSIFY = 5, 124


def _ivec(b, start, values):
    start(b, len(values))
    for v in reversed(values):
        b.PrependInt32(int(v))
    return b.EndVector()


def _bytes(b, data: bytes):
    return b.CreateByteVector(data)


def _sparsity(b, sp: dict):
    dims = []
    for d in sp["dims"]:
        seg = ind = None
        if d["format"] == 1:
            seg = _u8(b, d["segments"])
            ind = _u8(b, d["indices"])
        tflite.DimensionMetadataStart(b)
        tflite.DimensionMetadataAddFormat(b, d["format"])
        tflite.DimensionMetadataAddDenseSize(b, d.get("dense_size", 0))
        if seg is not None:
            tflite.DimensionMetadataAddArraySegmentsType(b, 3)  # Uint8Vector
            tflite.DimensionMetadataAddArraySegments(b, seg)
            tflite.DimensionMetadataAddArrayIndicesType(b, 3)
            tflite.DimensionMetadataAddArrayIndices(b, ind)
        dims.append(tflite.DimensionMetadataEnd(b))
    order = _ivec(b, tflite.SparsityParametersStartTraversalOrderVector, sp["order"])
    tflite.SparsityParametersStartDimMetadataVector(b, len(dims))
    for d in reversed(dims):
        b.PrependUOffsetTRelative(d)
    dim_vec = b.EndVector()
    tflite.SparsityParametersStart(b)
    tflite.SparsityParametersAddTraversalOrder(b, order)
    tflite.SparsityParametersAddDimMetadata(b, dim_vec)
    return tflite.SparsityParametersEnd(b)


def _u8(b, values):
    data = _bytes(b, bytes(int(v) for v in values))
    tflite.Uint8VectorStart(b)
    tflite.Uint8VectorAddValues(b, data)
    return tflite.Uint8VectorEnd(b)


def build(tensors: list[dict], inputs: list[int], outputs: list[int], ops: list[dict],
          buffers: list[bytes]) -> bytes:
    """A one-subgraph TFLite model.

    tensors: dicts name, shape, type, buffer (index), optional sparsity; ops: dicts code,
    inputs, outputs, optional options (type id, function(builder) -> offset); buffers: raw
    bytes per buffer (buffer 0 must be empty, as TFLite requires)."""
    b = flatbuffers.Builder(1024)
    buf_offs = []
    for data in buffers:
        vec = _bytes(b, data) if data else None
        tflite.BufferStart(b)
        if vec is not None:
            tflite.BufferAddData(b, vec)
        buf_offs.append(tflite.BufferEnd(b))
    t_offs = []
    for t in tensors:
        name = b.CreateString(t["name"])
        shape = _ivec(b, tflite.TensorStartShapeVector, t["shape"])
        sp = _sparsity(b, t["sparsity"]) if t.get("sparsity") else None
        tflite.TensorStart(b)
        tflite.TensorAddShape(b, shape)
        tflite.TensorAddType(b, t["type"])
        tflite.TensorAddBuffer(b, t.get("buffer", 0))
        tflite.TensorAddName(b, name)
        if sp is not None:
            tflite.TensorAddSparsity(b, sp)
        t_offs.append(tflite.TensorEnd(b))
    codes = sorted({op["code"] for op in ops})
    op_offs = []
    for op in ops:
        ins = _ivec(b, tflite.OperatorStartInputsVector, op["inputs"])
        outs = _ivec(b, tflite.OperatorStartOutputsVector, op["outputs"])
        opt = op["options"][1](b) if op.get("options") else None
        tflite.OperatorStart(b)
        tflite.OperatorAddOpcodeIndex(b, codes.index(op["code"]))
        tflite.OperatorAddInputs(b, ins)
        tflite.OperatorAddOutputs(b, outs)
        if opt is not None:
            tflite.OperatorAddBuiltinOptionsType(b, op["options"][0])
            tflite.OperatorAddBuiltinOptions(b, opt)
        op_offs.append(tflite.OperatorEnd(b))
    code_offs = []
    for c in codes:
        tflite.OperatorCodeStart(b)
        tflite.OperatorCodeAddBuiltinCode(b, c)
        tflite.OperatorCodeAddDeprecatedBuiltinCode(b, min(c, 127))
        tflite.OperatorCodeAddVersion(b, 1)
        code_offs.append(tflite.OperatorCodeEnd(b))

    def vec(start, items):
        start(b, len(items))
        for it in reversed(items):
            b.PrependUOffsetTRelative(it)
        return b.EndVector()

    tv = vec(tflite.SubGraphStartTensorsVector, t_offs)
    ov = vec(tflite.SubGraphStartOperatorsVector, op_offs)
    iv = _ivec(b, tflite.SubGraphStartInputsVector, inputs)
    outv = _ivec(b, tflite.SubGraphStartOutputsVector, outputs)
    name = b.CreateString("main")
    tflite.SubGraphStart(b)
    tflite.SubGraphAddTensors(b, tv)
    tflite.SubGraphAddInputs(b, iv)
    tflite.SubGraphAddOutputs(b, outv)
    tflite.SubGraphAddOperators(b, ov)
    tflite.SubGraphAddName(b, name)
    sg = tflite.SubGraphEnd(b)
    sgv = vec(tflite.ModelStartSubgraphsVector, [sg])
    cv = vec(tflite.ModelStartOperatorCodesVector, code_offs)
    bv = vec(tflite.ModelStartBuffersVector, buf_offs)
    desc = b.CreateString("signsplat test graph")
    tflite.ModelStart(b)
    tflite.ModelAddVersion(b, 3)
    tflite.ModelAddOperatorCodes(b, cv)
    tflite.ModelAddSubgraphs(b, sgv)
    tflite.ModelAddDescription(b, desc)
    tflite.ModelAddBuffers(b, bv)
    b.Finish(tflite.ModelEnd(b), file_identifier=b"TFL3")
    return bytes(b.Output())


def _add_options(b):
    tflite.AddOptionsStart(b)
    return tflite.AddOptionsEnd(b)


def _pad_options(b):
    tflite.PadOptionsStart(b)
    return tflite.PadOptionsEnd(b)


def _d2s_options(block):
    def make(b):
        tflite.DepthToSpaceOptionsStart(b)
        tflite.DepthToSpaceOptionsAddBlockSize(b, block)
        return tflite.DepthToSpaceOptionsEnd(b)
    return make


def _pool_options(b):
    """A 1 x 1 max pool with stride 1: the identity, but layout-sensitive, so the converter
    turns the graph to NCHW as it does MediaPipe's conv nets."""
    tflite.Pool2DOptionsStart(b)
    tflite.Pool2DOptionsAddPadding(b, tflite.Padding.VALID)
    tflite.Pool2DOptionsAddStrideW(b, 1)
    tflite.Pool2DOptionsAddStrideH(b, 1)
    tflite.Pool2DOptionsAddFilterWidth(b, 1)
    tflite.Pool2DOptionsAddFilterHeight(b, 1)
    return tflite.Pool2DOptionsEnd(b)


ADD_OPTIONS = (tflite.BuiltinOptions.AddOptions, _add_options)
POOL_OPTIONS = (tflite.BuiltinOptions.Pool2DOptions, _pool_options)
PAD_OPTIONS = (tflite.BuiltinOptions.PadOptions, _pad_options)


def prelu_fp16_alpha(rng) -> tuple[bytes, np.ndarray, np.ndarray]:
    """x (1, 3, 4, 5) NHWC -> (1 x 1 max pool) -> PReLU with an fp16 slope (1, 1, 5) behind a
    DEQUANTIZE, as in MediaPipe's palm and face models. Returns the model, an input and
    TFLite's output for it."""
    alpha = rng.uniform(0.05, 0.5, (1, 1, 5)).astype(np.float16)
    model = build(
        tensors=[dict(name="x", shape=[1, 3, 4, 5], type=F32),
                 dict(name="alpha16", shape=[1, 1, 5], type=F16, buffer=1),
                 dict(name="alpha", shape=[1, 1, 5], type=F32),
                 dict(name="y", shape=[1, 3, 4, 5], type=F32),
                 dict(name="x1", shape=[1, 3, 4, 5], type=F32)],
        inputs=[0], outputs=[3],
        ops=[dict(code=OP_MAX_POOL, inputs=[0], outputs=[4], options=POOL_OPTIONS),
             dict(code=OP_DEQUANTIZE, inputs=[1], outputs=[2]),
             dict(code=OP_PRELU, inputs=[4, 2], outputs=[3])],
        buffers=[b"", alpha.tobytes()])
    x = rng.normal(0, 1, (1, 3, 4, 5)).astype(np.float32)
    y = np.where(x >= 0, x, x * alpha.astype(np.float32))
    return model, x, y


def shared_pad_constant(rng) -> tuple[bytes, np.ndarray, np.ndarray]:
    """x (1, 2, 3, 2) -> (1 x 1 max pool) -> PAD -> PAD with one paddings tensor
    [[0,0],[1,2],[2,1],[0,0]], as MediaPipe's pose models share it."""
    pads = np.array([[0, 0], [1, 2], [2, 1], [0, 0]], np.int32)
    model = build(
        tensors=[dict(name="x", shape=[1, 2, 3, 2], type=F32),
                 dict(name="pads", shape=[4, 2], type=I32, buffer=1),
                 dict(name="p1", shape=[1, 5, 6, 2], type=F32),
                 dict(name="y", shape=[1, 8, 9, 2], type=F32),
                 dict(name="x1", shape=[1, 2, 3, 2], type=F32)],
        inputs=[0], outputs=[3],
        ops=[dict(code=OP_MAX_POOL, inputs=[0], outputs=[4], options=POOL_OPTIONS),
             dict(code=OP_PAD, inputs=[4, 1], outputs=[2], options=PAD_OPTIONS),
             dict(code=OP_PAD, inputs=[2, 1], outputs=[3], options=PAD_OPTIONS)],
        buffers=[b"", pads.tobytes()])
    x = rng.normal(0, 1, (1, 2, 3, 2)).astype(np.float32)
    y = np.pad(np.pad(x, pads), pads)
    return model, x, y


def densified_weights(rng) -> tuple[bytes, np.ndarray, np.ndarray]:
    """x (1, 2, 2, 6) + a constant stored sparse (dims 0-2 dense, the channel dimension CSR,
    fp16) -> DENSIFY -> DEQUANTIZE -> ADD, as MediaPipe's pose detector stores its weights."""
    dense = rng.normal(0, 1, (1, 2, 2, 6)).astype(np.float16)
    dense[rng.random(dense.shape) < 0.5] = 0
    rows = dense.reshape(4, 6)
    segments, indices, values = [0], [], []
    for row in rows:
        nz = np.flatnonzero(row)
        indices += nz.tolist()
        values += row[nz].tolist()
        segments.append(len(indices))
    sparsity = dict(order=[0, 1, 2, 3], dims=[
        dict(format=0, dense_size=1), dict(format=0, dense_size=2), dict(format=0, dense_size=2),
        dict(format=1, segments=segments, indices=indices)])
    model = build(
        tensors=[dict(name="x", shape=[1, 2, 2, 6], type=F32),
                 dict(name="w_sparse", shape=[1, 2, 2, 6], type=F16, buffer=1,
                      sparsity=sparsity),
                 dict(name="w16", shape=[1, 2, 2, 6], type=F16),
                 dict(name="w", shape=[1, 2, 2, 6], type=F32),
                 dict(name="y", shape=[1, 2, 2, 6], type=F32)],
        inputs=[0], outputs=[4],
        ops=[dict(code=OP_DENSIFY, inputs=[1], outputs=[2]),
             dict(code=OP_DEQUANTIZE, inputs=[2], outputs=[3]),
             dict(code=OP_ADD, inputs=[0, 3], outputs=[4], options=ADD_OPTIONS)],
        buffers=[b"", np.array(values, np.float16).tobytes()])
    x = rng.normal(0, 1, (1, 2, 2, 6)).astype(np.float32)
    return model, x, x + dense.astype(np.float32)


def depth_to_space(rng, block: int = 2) -> tuple[bytes, np.ndarray, np.ndarray]:
    """x (1, 3, 2, 4 * 3) NHWC -> DEPTH_TO_SPACE(2) -> (1, 6, 4, 3): TensorFlow's layout,
    output[h*b + i, w*b + j, c] = input[h, w, (i*b + j)*C + c]."""
    n, h, w, c = 1, 3, 2, 3
    model = build(
        tensors=[dict(name="x", shape=[n, h, w, c * block * block], type=F32),
                 dict(name="y", shape=[n, h * block, w * block, c], type=F32)],
        inputs=[0], outputs=[1],
        ops=[dict(code=OP_DEPTH_TO_SPACE, inputs=[0], outputs=[1],
                  options=(tflite.BuiltinOptions.DepthToSpaceOptions, _d2s_options(block)))],
        buffers=[b""])
    x = rng.normal(0, 1, (n, h, w, c * block * block)).astype(np.float32)
    y = x.reshape(n, h, w, block, block, c).transpose(0, 1, 3, 2, 4, 5)
    return model, x, y.reshape(n, h * block, w * block, c)
