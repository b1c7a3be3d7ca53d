"""The one sample request: its checks, its normal form, and `make` giving what
the runtime's own functions give, for every front end that builds it."""

import dataclasses
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from sinshape.cli.main import cli
from sinshape.core.errors import ConflictError, InputError
from sinshape.runtime import dense, edit, generate, layout, layout_files, load_model, many
from sinshape.runtime.request import MAX_PARTS, OPTIONS, Layout, SampleRequest, make, resolved, warnings
from sinshape.runtime.world import HeightMap

KEPT = "3:0%,0%,0%:60%,100%,100%"


@pytest.fixture(scope="module")
def model(tiny_model):
    return load_model(tiny_model, threads=1)


@pytest.mark.parametrize("fields, parameter", [
    ({"seed": -1}, "seed"), ({"seed": 2**63}, "seed"), ({"seed": 1.5}, "seed"), ({"seed": True}, "seed"),
    ({"size": 0}, "size"), ({"size": (1, 1)}, "size"), ({"size": float("inf")}, "size"), ({"size": "2"}, "size"),
    ({"scale": 0}, "scale"), ({"scale": float("nan")}, "scale"),
    ({"smooth": -1}, "smooth"), ({"smooth": 101}, "smooth"), ({"smooth": 1.0}, "smooth"),
    ({"smoother": "gauss"}, "smoother"), ({"frame": "world"}, "frame"),
    ({"keep": (KEPT,) * (MAX_PARTS + 1)}, "keep"), ({"keep": (3,)}, "keep"),
    ({"grow": 0.5}, "grow"), ({"grow": (2, 1, 1), "anchor": (0, 0, 2)}, "anchor"),
    ({"layout": np.ones((2, 2, 2))}, "layout"),
])
def test_a_bad_value_is_an_input_error_naming_its_field(fields, parameter):
    with pytest.raises(InputError) as refused:
        SampleRequest(**fields)
    assert not isinstance(refused.value, ConflictError) and refused.value.parameter == parameter


@pytest.mark.parametrize("fields, names", [
    ({"keep": (KEPT,), "grow": 2}, ("keep", "grow")),
    ({"grow": 2, "layout": Layout.of(np.ones((2, 2, 2)))}, ("grow", "layout")),
    ({"keep": (KEPT,), "grow": 2, "layout": Layout.of(np.ones((2, 2, 2)))}, ("keep", "grow", "layout")),
    ({"anchor": 0.5}, ("anchor", "grow")),
    ({"seed": 0, "recon": True}, ("seed", "recon")),
    ({"recon": True, "grow": 2}, ("grow", "recon", "seed")),
])
def test_values_that_do_not_go_together_are_one_conflict_naming_them_all(fields, names):
    with pytest.raises(ConflictError) as refused:
        SampleRequest(**fields)
    assert refused.value.parameter == names


# Fields and what Python makes of them, or why it refuses them: the browser's request.js
# meets the same table (tests/test_web.py). A layout is given as {shape, cells}, a height map
# as {shape, values}.
REQUEST_CASES = json.loads((Path(__file__).parent / "data" / "sample_requests.json").read_text())


def outcome(fields: dict) -> dict:
    """What a request of `fields` is, in the table's form: {"request": its fields} or {"refused": why}."""
    fields = dict(fields)
    try:
        if isinstance(fields.get("layout"), dict):
            fields["layout"] = Layout.of(np.reshape(fields["layout"]["cells"], fields["layout"]["shape"]))
        if isinstance(fields.get("heights"), dict):
            fields["heights"] = HeightMap.of(np.reshape(fields["heights"]["values"], fields["heights"]["shape"]))
        request = SampleRequest(**fields)
    except InputError as error:
        names = list(error.parameter) if isinstance(error, ConflictError) else [error.parameter]
        return {"refused": {"error": type(error).__name__, "fields": names, "message": str(error)}}
    made = {field.name: getattr(request, field.name) for field in dataclasses.fields(request)}
    made.update({name: list(made[name]) for name in ("size", "keep", "grow", "anchor", "tile", "models")
                 if made[name] is not None})
    if request.layout:
        made["layout"] = {"shape": list(request.layout.shape), "cells": request.layout.grid().ravel().astype(int).tolist()}
    if request.heights:
        made["heights"] = {"shape": list(request.heights.shape), "values": request.heights.array().ravel().tolist()}
    return {"request": made}


def expected(case: dict) -> dict:
    """What the table says of a case; a request's options the case does not
    list are at the options table's defaults (an option added later)."""
    said = {key: value for key, value in case.items() if key != "fields"}
    if "request" in said:
        said["request"] = {**{option.name: option.as_json()["default"] for option in OPTIONS}, **said["request"]}
    return said


@pytest.mark.parametrize("case", REQUEST_CASES, ids=lambda case: json.dumps(case["fields"])[:60])
def test_the_shared_table_of_requests(case):
    assert outcome(case["fields"]) == expected(case)


def test_the_reconstruction_has_only_the_training_size():
    with pytest.raises(InputError, match="only at the training size; drop size") as refused:
        SampleRequest(recon=True, size=2)
    assert refused.value.parameter == "size"


def test_equal_requests_are_equal_values():
    assert SampleRequest(size=2, grow=1.5, anchor=0.5) == SampleRequest(size=(2.0, 2.0, 2.0), grow=(1.5,) * 3,
                                                                         anchor=(0.5, 0.5, 0.5))
    grid = np.random.default_rng(0).random((5, 4, 3)) > 0.5
    assert Layout.of(grid) == Layout.of(grid.astype(np.float32))
    assert np.array_equal(Layout.of(grid).grid(), grid)
    assert len({SampleRequest(3, layout=Layout.of(grid)), SampleRequest(3, layout=Layout.of(grid.copy()))}) == 1
    assert SampleRequest().sample_seed == 0 and SampleRequest(recon=True).sample_seed is None
    assert SampleRequest(keep=KEPT).keep == (KEPT,)


def test_parts_however_written_resolve_to_one_request(model):
    size = generate.scaled_sizes(model.manifest.sizes)[-1]
    part = edit.parse_part(KEPT, model.manifest, size)
    as_text, as_part = resolved(model, SampleRequest(7, keep=(KEPT,))), resolved(model, SampleRequest(7, keep=(part,)))
    assert as_text == as_part and as_text.keep == (part,)
    assert resolved(model, as_text) is as_text
    with pytest.raises(InputError, match="leaves the sample"):
        resolved(model, SampleRequest(7, keep=(edit.Part(3, (0, 0, 0), (999, 5, 5)),)))


def test_make_is_the_runtime_function_each_request_names(model):
    grid = layout.layout(model, 5)
    cases = [
        (SampleRequest(4), generate.sample(model, 4)),
        (SampleRequest(), generate.sample(model, 0)),
        (SampleRequest(recon=True), generate.sample(model, None)),
        (SampleRequest(4, size=(1.5, 1, 1)), generate.sample(model, 4, (1.5, 1, 1))),
        (SampleRequest(7, keep=(KEPT,)), edit.compose(model, 7, [edit.parse_part(
            KEPT, model.manifest, generate.scaled_sizes(model.manifest.sizes)[-1])])),
        (SampleRequest(3, grow=(2, 1, 1), anchor=(1, 0, 0)), edit.grow(model, 3, (2, 1, 1), (1, 0, 0))),
        (SampleRequest(3, grow=(2, 1, 1)), edit.grow(model, 3, (2, 1, 1))),
        (SampleRequest(4, layout=Layout.of(grid)), layout.from_layout(model, 4, grid)),
    ]
    for request, expected in cases:
        assert np.array_equal(dense(model, make(model, request)), dense(model, expected)), request


def test_warnings_name_what_was_clamped(model):
    assert warnings(model, SampleRequest()) == []
    size, scale = warnings(model, SampleRequest(size=0.05, scale=0.0001))
    assert size.parameter == "size" and "shrinks some levels below 2" in str(size)
    assert scale.parameter == "scale" and "leaves under 2 grid points" in str(scale)


def test_a_batch_job_edits_every_seed_as_one_sample_would(tiny_model, model, tmp_path):
    many.sample_many(tiny_model, range(2), tmp_path / "{seed}.npz", workers=1, keep=(KEPT,))
    for seed in range(2):
        one = tmp_path / f"one{seed}.npz"
        assert CliRunner().invoke(cli, ["sample", str(tiny_model), "--seed", str(seed), "--keep", KEPT,
                                        "-o", str(one)]).exit_code == 0
        assert np.array_equal(np.load(tmp_path / f"{seed}.npz")["occupancy"], np.load(one)["occupancy"])
    with pytest.raises(ConflictError) as refused:
        many.sample_many(tiny_model, range(2), tmp_path / "{seed}.npz", request=SampleRequest(3))
    assert refused.value.parameter == ("seeds", "seed")


@pytest.mark.parametrize("options, says", [
    (["--seed", "1", "--seeds", "0-1"], "give --seeds or --seed, not both"),
    (["--recon", "--seeds", "0-1"], "give --seeds or --recon, not both"),
    (["--seed", "0", "--recon"], "give --seed or --recon, not both"),
    (["--recon", "--grow", "2"], "--grow edits a new sample"),
    (["--workers", "2"], "are for many samples: give --seeds"),
    (["--grow", "2", "--layout", "x.vox"], "give one of --grow, --layout"),
])
def test_the_command_line_says_a_conflict_once_with_its_options(tiny_model, tmp_path, options, says):
    if "--layout" in options:
        layout_files.export(load_model(tiny_model), 1, tmp_path / "x.vox")
        options = [str(tmp_path / o) if o == "x.vox" else o for o in options]
    result = CliRunner().invoke(cli, ["sample", str(tiny_model), *options, "-o", str(tmp_path / "s_{seed}.ply")])
    assert result.exit_code == 2 and says in result.output and "Traceback" not in result.output, result.output
    assert not list(tmp_path.glob("*.ply"))


def test_a_request_is_what_a_replaced_seed_makes():
    grown = SampleRequest(grow=2, anchor=0.5, smooth=3)
    assert grown.with_seed(9) == dataclasses.replace(grown, seed=9) and grown.with_seed(9).smooth == 3
    assert json.dumps(grown.mesh_options()) == json.dumps(
        {"scale": 1.0, "smooth": 3, "smoother": "laplacian", "largest": False, "frame": "input",
         "detail": True})


def test_make_refuses_a_tile_it_has_no_tri_plane_for(model):
    with pytest.raises(InputError, match="no tri-plane of its own") as refused:
        make(model, SampleRequest(3, tile=(0, 0)))
    assert refused.value.parameter == "tile"
    with pytest.raises(InputError, match="frame tile .* is for the tiles of a world") as refused:
        make(model, SampleRequest(3, frame="tile"))
    assert refused.value.parameter == "frame"


def test_a_worlds_other_model_is_read_again_once_its_file_is_written_again(tmp_path):
    """A world's models are read once per process, but a file written since is read anew, not served stale."""
    from conftest import TINY_ONNX, TINY_RELIEF_ONNX
    from sinshape.runtime.request import other_model

    path = tmp_path / "other.onnx"
    shutil.copy(TINY_ONNX, path)
    first = other_model(str(path))
    assert other_model(str(path)) is first  # read once while the file stays
    shutil.copy(TINY_RELIEF_ONNX, path)
    os.utime(path, ns=(os.stat(path).st_atime_ns, os.stat(path).st_mtime_ns + 10**9))  # past the clock's grain
    again = other_model(str(path))
    assert again is not first and again.example_tiles is not None and first.example_tiles is None
