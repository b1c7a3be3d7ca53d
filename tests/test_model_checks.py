"""A model file is untrusted, numbers included: a corrupt byte anywhere,
NaN weights and nonsense manifest values are refused in one line."""

import json
from pathlib import Path

import numpy as np
import onnx
import pytest
from click.testing import CliRunner

from conftest import sealed_bytes
from sinshape import models
from sinshape.cli.main import cli
from sinshape.runtime import load, load_model
from sinshape.core import manifest as fmt
from sinshape.core.errors import InputError
from test_cli_train import assert_one_line_error

TINY_V1 = Path(__file__).parent / "data" / "tiny_v1.onnx"
TINY_V2 = Path(__file__).parent / "data" / "tiny_v2.onnx"


def sinrun(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def manifest_prop(model: onnx.ModelProto):
    (prop,) = (p for p in model.metadata_props if p.key == fmt.METADATA_KEY)
    return prop


def altered(source, target: Path, change, seal=True) -> Path:
    """`source` changed; resealed (so only the change made is wrong), or with
    its old seal kept, as an editor that knows nothing of seals leaves it."""
    model = onnx.load(source)
    change(model)
    target.write_bytes(sealed_bytes(model) if seal else model.SerializeToString())
    return target


def refused(path: Path, *fragments) -> None:
    """Refused in one line by load_model, and by `sinrun info` and `sample`."""
    with pytest.raises(InputError) as error:
        load_model(path, threads=1)
    assert all(f in str(error.value) for f in fragments), str(error.value)
    assert_one_line_error(sinrun("info", path), *fragments)
    out = path.with_suffix(".ply")
    assert_one_line_error(sinrun("sample", path, "-o", out), *fragments)
    assert not out.exists()


@pytest.fixture(scope="module")
def v3_model(tiny_model):
    assert json.loads(manifest_prop(onnx.load(tiny_model)).value)["format_version"] == 3
    return tiny_model


def flip_bytes(rng):
    """A change that inverts 8 bytes at a random place of a random weight."""
    def flip(model):
        tensor = model.graph.initializer[int(rng.integers(len(model.graph.initializer)))]
        if not tensor.raw_data:  # stored as float_data
            tensor.raw_data = onnx.numpy_helper.to_array(tensor).astype("<f4").tobytes()
            del tensor.float_data[:]
        data = bytearray(tensor.raw_data)
        at = int(rng.integers(len(data) - 8))
        data[at:at + 8] = bytes(b ^ 0xFF for b in data[at:at + 8])
        tensor.raw_data = bytes(data)
    return flip


def test_flipped_weight_bytes_are_named_corruption(v3_model, tmp_path):
    rng = np.random.default_rng(0)
    for trial in range(5):
        refused(altered(v3_model, tmp_path / f"flipped{trial}.onnx", flip_bytes(rng), seal=False), "corrupt model")


@pytest.mark.parametrize("name", sorted(models.available()))
def test_a_shipped_model_with_a_flipped_byte_is_named_corrupt(name, tmp_path):
    """The shipped models are sealed format 3 files (5 when coloured), so they are protected too."""
    path = models.find(name)
    assert json.loads(manifest_prop(onnx.load(path)).value)["format_version"] in (3, 5)
    flipped = altered(path, tmp_path / f"{name}.onnx", flip_bytes(np.random.default_rng(1)), seal=False)
    with pytest.raises(InputError, match="corrupt model"):
        load_model(flipped, threads=1)


def flip_bit(source: Path, target: Path, at: int, bit: int) -> Path:
    data = bytearray(source.read_bytes())
    data[at] ^= bit
    target.write_bytes(bytes(data))
    return target


def node_attribute_offset(path: Path, op_type: str, name: str) -> int:
    """Where a node attribute's float value lies in the file's bytes."""
    model = onnx.load(path)
    attribute = next(a for n in model.graph.node if n.op_type == op_type for a in n.attribute if a.name == name)
    raw = attribute.SerializeToString()
    at = path.read_bytes().find(raw)
    assert at >= 0 and raw.count(raw[-4:]) == 1
    return at + len(raw) - 4  # the float is the last field of the attribute


def test_a_flipped_graph_attribute_is_named_corrupt(v3_model, tmp_path):
    """Every byte is sealed: a LeakyRelu slope, outside the weights, too (0.2 once became 6.8e37)."""
    at = node_attribute_offset(v3_model, "LeakyRelu", "alpha") + 3
    for bit in (0x40, 0x01):
        refused(flip_bit(v3_model, tmp_path / f"slope{bit}.onnx", at, bit), "corrupt model", "SHA-256")


def test_bit_flips_anywhere_in_a_sealed_file_are_refused(v3_model, tmp_path):
    size = v3_model.stat().st_size
    for at in np.random.default_rng(2).integers(0, size, 40):
        path = flip_bit(v3_model, tmp_path / "flip.onnx", int(at), 1 << int(at % 8))
        with pytest.raises(InputError):
            load_model(path, threads=1)


def test_format_2_files_still_verify(tmp_path):
    assert load_model(TINY_V2, threads=1).manifest.raw["format_version"] == 2
    result = sinrun("info", TINY_V2)
    assert result.exit_code == 0 and "sinshape 2, checksum over weights and manifest" in result.output
    refused(altered(TINY_V2, tmp_path / "flipped.onnx", flip_bytes(np.random.default_rng(3)), seal=False),
            "corrupt model",
            "checksum of its weights")


def test_damaged_weight_headers_in_format_2_are_named_corrupt(tmp_path):
    """A flip in a weight's dims, type or name gave a traceback in the checksum step."""
    def damage(field):
        def change(model):
            tensor = next(t for t in model.graph.initializer if t.name.startswith("level0.xy.conv1"))
            if field == "dims":
                tensor.dims[0] += 8
            elif field == "type":
                tensor.data_type = onnx.TensorProto.INT64
            else:
                tensor.name = "level0.xy.conv1.weigh\u00f4"
        return change

    for field in ("dims", "type", "name"):
        refused(altered(TINY_V2, tmp_path / f"{field}.onnx", damage(field), seal=False), "corrupt model")


def test_a_version_flipped_from_2_to_3_is_named_corrupt(tmp_path):
    """Not "upgrade sinshape": a format-3 file ends with a seal, and this one has none."""
    path = altered(TINY_V2, tmp_path / "v3.onnx", set_field(lambda m: m.update(format_version=3)), seal=False)
    refused(path, "corrupt model", "ends with a seal")


def test_older_models_are_sealed_as_format_3_unchanged(tmp_path):
    for source in (TINY_V1, TINY_V2):
        old = load_model(source, threads=1)
        path = tmp_path / f"{source.stem}_3.onnx"
        path.write_bytes(load.format3_bytes(old))
        new = load_model(path, threads=1)
        assert new.manifest.raw["format_version"] == 3 and "checksum" not in new.manifest.raw
        assert new.manifest.sizes == old.manifest.sizes
        seed = np.random.default_rng(4).integers(0, 2**31)
        from sinshape import runtime
        assert np.array_equal(runtime.dense(old, runtime.sample(old, int(seed))),
                              runtime.dense(new, runtime.sample(new, int(seed))))


def test_an_edited_manifest_is_named_corruption(v3_model, tmp_path):
    def edit(model):
        prop = manifest_prop(model)
        manifest = json.loads(prop.value)
        manifest["levels"][1]["noise_amp"] *= 2
        prop.value = json.dumps(manifest)

    refused(altered(v3_model, tmp_path / "edited.onnx", edit, seal=False), "corrupt model")


def test_format_1_still_loads_with_a_note(tmp_path):
    assert load_model(TINY_V1, threads=1).manifest.raw["format_version"] == 1
    result = sinrun("info", TINY_V1)
    assert result.exit_code == 0 and "sinshape 1, no checksum" in result.output
    result = sinrun("sample", TINY_V1, "-o", tmp_path / "s.ply")
    assert result.exit_code == 0 and (tmp_path / "s.ply").exists()


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_weights_are_refused(v3_model, tmp_path, value):
    def poison(model):
        for i, tensor in enumerate(model.graph.initializer):
            if tensor.name.startswith("level1.xz.conv1.weight"):
                array = onnx.numpy_helper.to_array(tensor).copy()
                array.flat[3] = value
                model.graph.initializer[i].CopyFrom(onnx.numpy_helper.from_array(array, tensor.name))

    refused(altered(v3_model, tmp_path / "poisoned.onnx", poison), "stage level1", "NaN or infinite")


def test_a_sample_that_overflows_is_an_error_and_no_file(v3_model, tmp_path):
    """Huge finite weights pass the probe runs on zeros, then overflow on noise."""
    def inflate(model):
        for i, tensor in enumerate(model.graph.initializer):
            if tensor.name.startswith("level1.") and tensor.name.endswith("conv1.weight"):
                array = onnx.numpy_helper.to_array(tensor) * np.float32(1e37)
                model.graph.initializer[i].CopyFrom(onnx.numpy_helper.from_array(array, tensor.name))

    path = altered(v3_model, tmp_path / "huge.onnx", inflate)
    out = tmp_path / "s.npz"
    assert_one_line_error(sinrun("sample", path, "--seed", 1, "-o", out), "NaN or infinite values for this sample")
    assert not out.exists()


def set_manifest_text(change_text):
    def change(model):
        prop = manifest_prop(model)
        prop.value = change_text(prop.value)
    return change


def set_field(edit):
    def change(model):
        prop = manifest_prop(model)
        manifest = json.loads(prop.value)
        edit(manifest)
        prop.value = json.dumps(manifest)
    return change


NONSENSE = {
    "deep": (set_manifest_text(lambda t: t.rstrip()[:-1] + ', "deep": ' + "[" * 100000 + "]" * 100000 + "}"),
             "nested deeper"),
    "long_int": (set_manifest_text(lambda t: t.rstrip()[:-1] + ', "big": ' + "9" * 5000 + "}"), "too large"),
    "huge_recon_seed": (set_field(lambda m: m.update(recon_seed=10**3000)), "recon_seed"),
    "training_list": (set_field(lambda m: m.update(training=[1, 2])), "training"),
    "training_seconds": (set_field(lambda m: m["training"].update(seconds="long")), "training seconds"),
    "level_seconds_number": (set_field(lambda m: m["training"].update(level_seconds=5)), "training seconds"),
    "source_string": (set_field(lambda m: m.update(source="terrain.h5")), "source"),
    "source_name_number": (set_field(lambda m: m["source"].update(name=3)), "source"),
    "config_string": (set_field(lambda m: m.update(config="tiny")), "config"),
    "config_nested": (set_field(lambda m: m["config"].update(iters={"a": 1})), "config"),
    "spacing_1e308": (set_field(lambda m: m["frame"].update(spacing=[1e308, 1, 1])), "spacing"),
    "origin_1e300": (set_field(lambda m: m["frame"].update(origin=[1e300, 0, 0])), "origin"),
    "noise_amp_1e30": (set_field(lambda m: m["levels"][1].update(noise_amp=1e30)), "noise_amp"),
    "created_by_list": (set_field(lambda m: m.update(created_by=["x"])), "created_by"),
    "contrast_9": (set_field(lambda m: m.update(contrast=9)), "contrast must be a number in [0.5, 4]"),
    "contrast_string": (set_field(lambda m: m.update(contrast="high")), "contrast"),
    "object_scale_0": (set_field(lambda m: m.update(object_scale=0)), "object_scale must be a number in [0.0625, 16]"),
    "object_scale_string": (set_field(lambda m: m.update(object_scale="big")), "object_scale"),
    "planes_string": (set_field(lambda m: m.update(planes="xy")), "planes"),
    "spacing_1e-300": (set_field(lambda m: m["frame"].update(spacing=[1e-300, 1, 1])), "spacing"),
    "spacing_below_origin_step": (set_field(lambda m: m["frame"].update(origin=[1e9, 0, 0], spacing=[1e-3, 1, 1])),
                                  "float32's step"),
    "last_level_2": (set_field(lambda m: m["levels"][1].update(size=[2, 2, 2])), "level 1 size"),
    "levels_shrink": (set_field(lambda m: m["levels"][1].update(size=m["levels"][0]["size"][:2] + [8])),
                      "levels grow"),
    # colour: only in format 4, always there, and only sRGB
    "colour_in_v3": (set_field(lambda m: m.update(colour={"space": "srgb"})), "colour must be"),
    "v4_without_colour": (set_field(lambda m: m.update(format_version=4)), "colour must be"),
    "v4_linear": (set_field(lambda m: m.update(format_version=4, colour={"space": "linear"})), "colour must be"),
    "v4_without_colour_output": (set_field(lambda m: m.update(format_version=4, colour={"space": "srgb"})),
                                 "stages"),
    # relief: only from format 5, alone or as colour's tiles, never both
    "relief_in_v3": (set_field(lambda m: m.update(relief={"tiles": {"count": 1, "side": 2}})),
                     "relief is read from format 5 on, not 3"),
    "v5_without_tiles": (set_field(lambda m: m.update(format_version=5)), "needs colour"),
    "v5_relief_in_srgb": (set_field(lambda m: m.update(format_version=5, relief={
        "space": "srgb", "tiles": {"count": 1, "side": 2}})), "needs colour"),
    "v5_colour_and_relief": (set_field(lambda m: m.update(format_version=5, relief={"tiles": {"count": 1, "side": 2}},
                                                          colour={"space": "srgb", "tiles": {"count": 1, "side": 2}})),
                             "colour or relief, not both"),
}


@pytest.mark.parametrize("case", sorted(NONSENSE))
def test_nonsense_manifest_values_are_refused(v3_model, tmp_path, case):
    change, fragment = NONSENSE[case]
    refused(altered(v3_model, tmp_path / f"{case}.onnx", change), "bad model manifest", fragment)


def test_info_escapes_control_characters(v3_model, tmp_path):
    path = altered(v3_model, tmp_path / "fake.onnx", set_field(lambda m: m.update(created_by="x\r\nError: fake")))
    result = sinrun("info", path)
    assert result.exit_code == 0 and "\nError: fake" not in result.output and "x\\r\\nError: fake" in result.output


def test_eval_refuses_a_wrongly_typed_source(v3_model, tmp_path, tiny_pyramid):
    path = altered(v3_model, tmp_path / "source.onnx", set_field(lambda m: m.update(source=7)))
    assert_one_line_error(sinrun("eval", path, "--reference", tiny_pyramid), "source")


def test_a_weight_given_twice_is_named_corrupt(tmp_path):
    # ONNX names each initializer once; a resealed file with a second, all-zero copy of a weight
    # (which a reader would take, the last one winning) is refused, naming it.
    from conftest import TINY_COLOUR_ONNX

    proto = onnx.load(TINY_COLOUR_ONNX)
    tensor = next(t for t in proto.graph.initializer if t.name == "colour_tiles.images")
    copy = proto.graph.initializer.add()
    copy.CopyFrom(tensor)
    copy.raw_data = bytes(len(copy.raw_data))
    path = tmp_path / "twice.onnx"
    path.write_bytes(sealed_bytes(proto))
    with pytest.raises(InputError, match="corrupt model: it holds the weight colour_tiles.images twice"):
        load_model(path)
