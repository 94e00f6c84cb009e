"""The feature network as an ONNX model for OpenCV's dnn module, written without the
``onnx`` package: a few protobuf messages encoded by hand.

Only what :func:`feature_model` needs is encoded: a graph of ``Conv`` (3x3, pads 1) and
``Relu`` nodes with float32 initialisers, one input ``image`` (1, 1, H, W) whose size is
left free, one output ``features`` (1, C, H, W). Field numbers are those of ONNX's
``onnx.proto`` (ModelProto, GraphProto, NodeProto, AttributeProto, TensorProto,
ValueInfoProto, TypeProto, TensorShapeProto, OperatorSetIdProto).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: ONNX TensorProto.FLOAT, AttributeProto.INTS.
_FLOAT, _INTS = 1, 7
#: The IR version and the default domain's opset the model declares.
IR_VERSION, OPSET = 8, 13


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _key(field: int, wire: int) -> bytes:
    return _varint(field << 3 | wire)


def _int(field: int, value: int) -> bytes:
    return _key(field, 0) + _varint(value)


def _bytes(field: int, payload: bytes) -> bytes:
    return _key(field, 2) + _varint(len(payload)) + payload


def _str(field: int, text: str) -> bytes:
    return _bytes(field, text.encode())


def _tensor(name: str, array: np.ndarray) -> bytes:
    data = np.ascontiguousarray(array, np.float32)
    dims = b''.join(_int(1, d) for d in data.shape)
    return dims + _int(2, _FLOAT) + _str(8, name) + _bytes(9, data.tobytes())


def _ints_attribute(name: str, values: tuple[int, ...]) -> bytes:
    return _str(1, name) + b''.join(_int(8, v) for v in values) + _int(20, _INTS)


def _node(op: str, inputs: tuple[str, ...], output: str, attributes: bytes = b'') -> bytes:
    return b''.join(_str(1, i) for i in inputs) + _str(2, output) + _str(3, output) + \
        _str(4, op) + attributes


def _value_info(name: str, dims: tuple[int | str, ...]) -> bytes:
    shape = b''.join(_bytes(1, _int(1, d) if isinstance(d, int) else _str(2, d))
                     for d in dims)
    tensor_type = _int(1, _FLOAT) + _bytes(2, shape)
    return _str(1, name) + _bytes(2, _bytes(1, tensor_type))


def feature_model(kernels: tuple[NDArray[np.float32], ...],
                  biases: tuple[NDArray[np.float32], ...]) -> bytes:
    """The feature network's convolutions (kernels (3, 3, C_in, C_out), biases (C_out,))
    and a ReLU after each but the last, as a serialised ONNX ModelProto (the
    normalisation before and the division by the norm after stay outside)."""
    nodes, initialisers = [], []
    previous = 'image'
    last = len(kernels) - 1
    conv_attributes = _bytes(5, _ints_attribute('kernel_shape', (3, 3))) + \
        _bytes(5, _ints_attribute('pads', (1, 1, 1, 1)))
    for i, (kernel, bias) in enumerate(zip(kernels, biases, strict=True)):
        # ONNX's weights are (C_out, C_in, kH, kW); ours (kH, kW, C_in, C_out)
        initialisers.append(_tensor(f'w{i}', kernel.transpose(3, 2, 0, 1)))
        initialisers.append(_tensor(f'b{i}', bias))
        conv = 'features' if i == last else f'conv{i}'
        nodes.append(_node('Conv', (previous, f'w{i}', f'b{i}'), conv, conv_attributes))
        previous = conv
        if i < last:
            nodes.append(_node('Relu', (conv,), f'relu{i}'))
            previous = f'relu{i}'
    graph = b''.join(_bytes(1, n) for n in nodes) + _str(2, 'features') + \
        b''.join(_bytes(5, t) for t in initialisers) + \
        _bytes(11, _value_info('image', (1, 1, 'height', 'width'))) + \
        _bytes(12, _value_info('features', (1, kernels[-1].shape[3], 'height', 'width')))
    opset = _str(1, '') + _int(2, OPSET)
    return _int(1, IR_VERSION) + _str(2, 'depth_nodes') + _bytes(7, graph) + _bytes(8, opset)


