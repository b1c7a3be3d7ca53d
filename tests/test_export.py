"""The exported .onnx file: valid, small, ours, and equal to the torch model."""

import json

import numpy as np
import onnx
import pytest

torch = pytest.importorskip("torch")

from sinshape.core import manifest  # noqa: E402
from sinshape.runtime import generate, load, query  # noqa: E402
from sinshape.prep import pyramid  # noqa: E402
from sinshape.trainer import checkpoint, train  # noqa: E402


def test_file_is_valid_onnx_with_the_promised_ops(tiny_model):
    model = onnx.load(tiny_model)
    onnx.checker.check_model(model, full_check=True)
    assert model.ir_version == 8 and model.opset_import[0].version == 17
    ops = {n.op_type for n in model.graph.node}
    assert "InstanceNormalization" in ops and "BatchNormalization" not in ops
    assert ops <= load.ALLOWED_OPS
    # 2 levels x 3 planes x 4 convs of 32x32x3x3, plus small parts: well under 1 MB.
    assert tiny_model.stat().st_size < 1_000_000


def test_manifest_says_how_the_model_was_made(tiny_model, tiny_pyramid):
    props = {p.key: p.value for p in onnx.load(tiny_model).metadata_props}
    m = json.loads(props[manifest.METADATA_KEY])
    assert m["format"] == "sinshape" and m["format_version"] == manifest.FORMAT_VERSION
    assert [level["size"] for level in m["levels"]] == [[15, 15, 15], [20, 18, 15]]
    assert m["levels"][0]["noise_amp"] == 1.0 and 0 < m["levels"][1]["noise_amp"] < 1
    assert m["source"] == {"name": tiny_pyramid.name, "sha256": pyramid.file_sha256(tiny_pyramid),
                           "kind": "pyramid"}
    assert m["config"]["iters"] == 3 and m["config"]["levels"] == 2
    assert len(m["training"]["level_seconds"]) == 2 and m["training"]["seconds"] > 0
    assert m["channels"] == 32 and m["pool_bins"] == 8 and m["recon_seed"] == 1234
    assert m["up"] == "z"  # voxel data stands on z, unless --up says otherwise


def test_a_coloured_model_is_format_5_and_a_plain_one_format_3(tiny_model, tiny_colour_model):
    plain, coloured = (json.loads({p.key: p.value for p in onnx.load(path).metadata_props}[manifest.METADATA_KEY])
                       for path in (tiny_model, tiny_colour_model))
    assert plain["format_version"] == 3 and "colour" not in plain
    assert coloured["format_version"] == 5 and coloured["colour"]["space"] == "srgb"
    count, side = coloured["colour"]["tiles"]["count"], coloured["colour"]["tiles"]["side"]
    assert coloured["stages"]["decoder_head"]["outputs"] == ["decoder_head.occupancy", "decoder_head.colour"]
    weights = {t.name: onnx.numpy_helper.to_array(t) for t in onnx.load(tiny_colour_model).graph.initializer}
    assert weights["decoder_head.weight_colour"].shape == (32, 3) and weights["decoder_head.bias_colour"].shape == (3,)
    # The example's colour tiles, as docs/FORMAT.md lays them out.
    assert weights["colour_tiles.voxels"].shape == (count, 3) and weights["colour_tiles.voxels"].dtype == np.int32
    assert weights["colour_tiles.images"].shape == (count, side, side, 4)
    assert weights["colour_tiles.distance"].shape == tuple(coloured["levels"][-1]["size"])
    assert weights["colour_tiles.distance"].dtype == np.int8


def manifest_of(path) -> dict:
    return json.loads({p.key: p.value for p in onnx.load(path).metadata_props}[manifest.METADATA_KEY])


def test_a_geometry_only_mesh_model_is_format_5_with_its_relief_alone(tiny_relief_model):
    m = manifest_of(tiny_relief_model)
    assert m["format_version"] == 5 and "colour" not in m and set(m["relief"]) == {"tiles"}
    count, side = m["relief"]["tiles"]["count"], m["relief"]["tiles"]["side"]
    assert m["stages"]["decoder_head"]["outputs"] == ["decoder_head.occupancy"]
    weights = {t.name: onnx.numpy_helper.to_array(t) for t in onnx.load(tiny_relief_model).graph.initializer}
    assert weights["colour_tiles.images"].shape == (count, side, side, 1) and side >= 4


def test_relief_added_to_a_model_trained_before_it_is_the_trainers_own(tiny_relief_model, tmp_path):
    # The relief model as a format-3 file (what training gave before relief), then export.remake_tiles
    # from the same mesh: the tiles and manifest the trainer wrote, to the byte; another mesh is refused.
    from conftest import PAINTED_BOX, RIDGED_BOX, sealed_bytes
    from sinshape.core.errors import InputError
    from sinshape.trainer.export import remake_tiles

    proto = onnx.load(tiny_relief_model)
    for tensor in [t for t in proto.graph.initializer if t.name in manifest.TILE_TENSORS]:
        proto.graph.initializer.remove(tensor)
    old = manifest_of(tiny_relief_model)
    plain = {k: v for k, v in old.items() if k != "relief"} | {"format_version": 3}
    next(p for p in proto.metadata_props if p.key == manifest.METADATA_KEY).value = json.dumps(plain)
    before = tmp_path / "before.onnx"
    before.write_bytes(sealed_bytes(proto))
    assert load.load_model(before).example_tiles is None
    after = tmp_path / "after.onnx"
    assert remake_tiles(before, RIDGED_BOX, after) == old
    tiles, again = load.load_model(tiny_relief_model).example_tiles, load.load_model(after).example_tiles
    for name in ("voxels", "directions", "depth", "distance"):
        np.testing.assert_array_equal(getattr(again, name), getattr(tiles, name))
    with pytest.raises(InputError, match="not the file"):
        remake_tiles(before, PAINTED_BOX, tmp_path / "wrong.onnx")
    assert not (tmp_path / "wrong.onnx").exists()


def test_a_coloured_models_tiles_made_again_are_the_trainers_own(tiny_colour_model, tmp_path):
    # Tiles a model already has, replaced by those made again from its mesh: the same, here (this
    # version made both), in place of the old initializers, not beside them.
    from conftest import PAINTED_BOX
    from sinshape.trainer.export import remake_tiles

    out = tmp_path / "again.onnx"
    assert remake_tiles(tiny_colour_model, PAINTED_BOX, out) == manifest_of(tiny_colour_model)
    names = [t.name for t in onnx.load(out).graph.initializer]
    assert all(names.count(name) == 1 for name in manifest.TILE_TENSORS)
    tiles, again = load.load_model(tiny_colour_model).example_tiles, load.load_model(out).example_tiles
    for name in ("voxels", "depth", "distance"):
        np.testing.assert_array_equal(getattr(again, name), getattr(tiles, name))
    np.testing.assert_array_equal(again.mips[0], tiles.mips[0])


@pytest.mark.parametrize("seed, factors", [(None, (1, 1, 1)), (11, (1, 1, 1)), (12, (1.5, 1, 0.7))])
@pytest.mark.parametrize("coloured", [False, True])
def test_onnxruntime_equals_torch(tiny_model, tiny_colour_model, seed, factors, coloured):
    """Parity: reconstruction (seed None) and random draws, at the training size
    and another, the same noise fed to both; occupancy and, for a coloured
    model, the colour at every voxel."""
    tiny_model = tiny_colour_model if coloured else tiny_model
    generator, sizes, amps = checkpoint.load_generator(train.default_checkpoint_path(tiny_model))
    model = load.load_model(tiny_model)
    sizes = generate.scaled_sizes(sizes, factors)
    if seed is None:
        sample = generate.reconstruction_noise(model, sizes)
    else:
        sample = generate.draw_noise(seed, sizes, model.manifest.channels)
    triplane = generate.triplane(model, sample, sizes)
    ours = query.dense(model, triplane, 1.0)

    z0 = torch.from_numpy(sample.z0)[None, None]
    noises = [None if planes is None else [amps[i] * torch.from_numpy(p)[None] for p in planes]
              for i, planes in enumerate(sample.planes)]
    with torch.no_grad():
        reference = generator(z0, noises, sizes)[0].numpy()
    if coloured:
        index = np.argwhere(np.ones(sizes[-1], bool))[::7]
        head = query.colouring(model, triplane)(index.astype(float))  # the colour head, exported
        np.testing.assert_allclose(head, reference[1:][(slice(None), *index.T)].T, atol=1e-4)
        reference = reference[0]
    assert ours.shape == reference.shape == sizes[-1]
    assert np.abs(ours - reference).max() < 1e-4
    assert 0.05 < (ours > 0.5).mean() < (1 if coloured else 0.95)  # a shape (the box fills most of its grid)
