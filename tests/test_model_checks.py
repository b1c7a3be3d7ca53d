"""A model file is untrusted, numbers included (issue 10, class 5): corrupt
weights, NaN weights and nonsense manifest values are refused in one line."""

import json
from pathlib import Path

import numpy as np
import onnx
import pytest
from click.testing import CliRunner

from sinshape import models
from sinshape.cli.main import cli
from sinshape.runtime import load_model
from sinshape.runtime import manifest as fmt
from sinshape.runtime.errors import InputError
from test_cli_train import assert_one_line_error

TINY_V1 = Path(__file__).parent / "data" / "tiny_v1.onnx"


def sinrun(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def manifest_prop(model: onnx.ModelProto):
    (prop,) = (p for p in model.metadata_props if p.key == fmt.METADATA_KEY)
    return prop


def reseal(model: onnx.ModelProto) -> None:
    """Recompute the checksum, so only the change made is wrong."""
    prop = manifest_prop(model)
    manifest = json.loads(prop.value)
    weights = [(t.name, onnx.numpy_helper.to_array(t)) for t in model.graph.initializer]
    manifest["checksum"] = fmt.checksum(manifest, weights)
    prop.value = json.dumps(manifest)


def altered(source, target: Path, change, seal=True) -> Path:
    model = onnx.load(source)
    change(model)
    if seal:
        reseal(model)
    target.write_bytes(model.SerializeToString())
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
def v2_model(tiny_model):
    assert json.loads(manifest_prop(onnx.load(tiny_model)).value)["format_version"] == 2
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


def test_flipped_weight_bytes_are_named_corruption(v2_model, tmp_path):
    rng = np.random.default_rng(0)
    for trial in range(5):
        refused(altered(v2_model, tmp_path / f"flipped{trial}.onnx", flip_bytes(rng), seal=False), "corrupt model")


@pytest.mark.parametrize("name", sorted(models.available()))
def test_a_shipped_model_with_a_flipped_byte_is_named_corrupt(name, tmp_path):
    """The shipped models carry format 2's checksum, so they are protected too."""
    path = models.find(name)
    assert json.loads(manifest_prop(onnx.load(path)).value)["format_version"] == 2
    flipped = altered(path, tmp_path / f"{name}.onnx", flip_bytes(np.random.default_rng(1)), seal=False)
    with pytest.raises(InputError, match="corrupt model"):
        load_model(flipped, threads=1)


def test_an_edited_manifest_is_named_corruption(v2_model, tmp_path):
    def edit(model):
        prop = manifest_prop(model)
        manifest = json.loads(prop.value)
        manifest["levels"][1]["noise_amp"] *= 2
        prop.value = json.dumps(manifest)

    refused(altered(v2_model, tmp_path / "edited.onnx", edit, seal=False), "corrupt model")


def test_format_1_still_loads_with_a_note(tmp_path):
    assert load_model(TINY_V1, threads=1).manifest.raw["format_version"] == 1
    result = sinrun("info", TINY_V1)
    assert result.exit_code == 0 and "format 1: no checksum" in result.output
    result = sinrun("sample", TINY_V1, "-o", tmp_path / "s.ply")
    assert result.exit_code == 0 and (tmp_path / "s.ply").exists()


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_weights_are_refused(v2_model, tmp_path, value):
    def poison(model):
        for i, tensor in enumerate(model.graph.initializer):
            if tensor.name.startswith("level1.xz.conv1.weight"):
                array = onnx.numpy_helper.to_array(tensor).copy()
                array.flat[3] = value
                model.graph.initializer[i].CopyFrom(onnx.numpy_helper.from_array(array, tensor.name))

    refused(altered(v2_model, tmp_path / "poisoned.onnx", poison), "stage level1", "NaN or infinite")


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
    "planes_string": (set_field(lambda m: m.update(planes="xy")), "planes"),
}


@pytest.mark.parametrize("case", sorted(NONSENSE))
def test_nonsense_manifest_values_are_refused(v2_model, tmp_path, case):
    change, fragment = NONSENSE[case]
    seal = case not in ("deep", "long_int")  # JSON that does not parse cannot be resealed
    refused(altered(v2_model, tmp_path / f"{case}.onnx", change, seal=seal), "bad model manifest", fragment)


def test_eval_refuses_a_wrongly_typed_source(v2_model, tmp_path, tiny_pyramid):
    path = altered(v2_model, tmp_path / "source.onnx", set_field(lambda m: m.update(source=7)))
    assert_one_line_error(sinrun("eval", path, "--reference", tiny_pyramid), "source")
