"""The runtime's own reader of ONNX files (runtime/onnxfile.py) reads what
the onnx package reads, and refuses broken bytes with ValueError only."""

import numpy as np
import onnx
import pytest

from conftest import TINY_ONNX
from sinshape.runtime import onnxfile


def test_it_reads_what_onnx_reads():
    data = TINY_ONNX.read_bytes()
    ours, theirs = onnxfile.parse(data), onnx.load_model_from_string(data)
    assert [(n.op_type, n.domain, n.name, n.inputs, n.outputs) for n in ours.nodes] == \
        [(n.op_type, n.domain, n.name, list(n.input), list(n.output)) for n in theirs.graph.node]
    assert ours.metadata == {p.key: p.value for p in theirs.metadata_props}
    assert list(ours.inputs) == [v.name for v in theirs.graph.input]
    assert list(ours.outputs) == [v.name for v in theirs.graph.output]
    assert ours.ir_version == theirs.ir_version
    for tensor in theirs.graph.initializer:
        np.testing.assert_array_equal(onnxfile.tensor_array(ours.weights[tensor.name]),
                                      onnx.numpy_helper.to_array(tensor))


def test_a_stage_cut_from_the_file_is_a_model_onnx_accepts():
    ours = onnxfile.parse(TINY_ONNX.read_bytes())
    node = next(n for n in ours.nodes if n.op_type == "Conv")
    weights = [name for name in node.inputs if name in ours.weights]
    stage = onnx.load_model_from_string(onnxfile.stage_bytes(ours, [node], weights, [], []))
    assert [n.op_type for n in stage.graph.node] == ["Conv"]
    assert sorted(t.name for t in stage.graph.initializer) == sorted(weights)
    assert stage.opset_import[0].version == onnx.load(TINY_ONNX).opset_import[0].version


def test_new_metadata_replaces_the_old_and_leaves_the_graph_as_it_was():
    data = TINY_ONNX.read_bytes()
    changed = onnxfile.with_metadata(data, {"a": "1", "sinshape": "{}"})
    theirs, before = onnx.load_model_from_string(changed), onnx.load_model_from_string(data)
    assert {p.key: p.value for p in theirs.metadata_props} == {"a": "1", "sinshape": "{}"}
    assert theirs.graph.SerializeToString() == before.graph.SerializeToString()
    assert list(theirs.opset_import) == list(before.opset_import) and theirs.ir_version == before.ir_version


def test_float_data_weights_read_as_raw_ones():
    values = np.arange(6, dtype=np.float32).reshape(2, 3)
    tensor = onnx.helper.make_tensor("w", onnx.TensorProto.FLOAT, [2, 3], values.ravel().tolist())
    parsed = onnxfile.Tensor("w", b"", tensor.SerializeToString(), False)
    np.testing.assert_array_equal(onnxfile.tensor_array(parsed), values)
    tensor.dims[:] = [4, 3]  # more values claimed than held
    with pytest.raises(ValueError, match="6 values for shape"):
        onnxfile.tensor_array(onnxfile.Tensor("w", b"", tensor.SerializeToString(), False))


def test_broken_bytes_raise_value_error_and_nothing_else():
    data = TINY_ONNX.read_bytes()
    with pytest.raises(ValueError, match="runs past its message"):
        onnxfile.parse(data[:len(data) // 2])  # the graph's length says more than is left
    for wire in (3, 4, 6, 7):  # group and unknown wire types
        with pytest.raises(ValueError, match="wire type"):
            onnxfile.parse(bytes([1 << 3 | wire]) + data)
    for at in range(0, 20000, 97):  # cuts and flipped bits: a model or ValueError, never IndexError & co
        for broken in (data[:at], data[:at] + bytes([data[at] ^ 0x80]) + data[at + 1:]):
            try:
                model = onnxfile.parse(broken)
                for tensor in model.weights.values():
                    onnxfile.tensor_array(tensor)
            except ValueError:
                pass
