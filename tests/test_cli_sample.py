"""`sinrun sample / interpolate / info / models`: torch-free, deterministic, one-line errors."""

import json
import subprocess
import sys

import numpy as np
import onnx
import pytest
import trimesh
from click.testing import CliRunner

from conftest import TINY_ONNX, sealed_bytes

from sinshape.cli.main import cli
from sinshape.core import manifest as fmt
from test_cli_train import BLOCK_TORCH, assert_one_line_error


def sinrun(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def sample_in_a_process(model, out, check, block_torch: bool) -> dict:
    """Run `sinrun sample` in a fresh process; its exit code and the modules it imported."""
    code = ((BLOCK_TORCH if block_torch else "") + "import json, sys\n"
            "from sinshape.cli.main import cli\n"  # not main(), which ends the process on success
            "try:\n    cli(prog_name='sinrun')\nexcept SystemExit as e:\n    code = e.code\n"
            f"json.dump({{'code': code, 'modules': sorted(sys.modules)}}, open({str(check)!r}, 'w'))\n")
    result = subprocess.run([sys.executable, "-c", code, "sample", str(model), "--seed", "3",
                             "--scale", "2", "-o", str(out)], capture_output=True, text=True)
    report = json.loads(check.read_text())
    assert report["code"] in (0, None), result.stderr
    return report


def test_sampling_works_with_torch_unimportable(tiny_model, tmp_path):
    blocked = sample_in_a_process(tiny_model, tmp_path / "s.ply", tmp_path / "blocked.json", block_torch=True)
    assert trimesh.load(tmp_path / "s.ply").is_watertight
    # Where torch is installed, sampling still leaves it (and the trainer) alone:
    # no code path quietly prefers torch when it happens to be there.
    free = sample_in_a_process(tiny_model, tmp_path / "t.ply", tmp_path / "free.json", block_torch=False)
    assert (tmp_path / "s.ply").read_bytes() == (tmp_path / "t.ply").read_bytes()
    for report in (blocked, free):
        assert not [m for m in report["modules"] if m.startswith("sinshape.trainer")]
    assert not [m for m in free["modules"] if m == "torch" or m.startswith("torch.")]


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl", ".off", ".glb", ".npz"])
def test_same_seed_same_bytes(tiny_model, tmp_path, suffix):
    paths = [tmp_path / f"{name}{suffix}" for name in ("a", "b", "c")]
    for path, seed in zip(paths, (4, 4, 5)):
        assert sinrun("sample", tiny_model, "--seed", seed, "--scale", "1.5", "-o", path).exit_code == 0
    a, b, c = (p.read_bytes() for p in paths)
    assert a == b and a != c


def test_npz_holds_the_occupancy_grid(tiny_model, tmp_path):
    out = tmp_path / "g.npz"
    assert sinrun("sample", tiny_model, "--recon", "--scale", "2", "-o", out).exit_code == 0
    with np.load(out) as data:
        grid = data["occupancy"]
        assert grid.shape == tuple(2 * n for n in (20, 18, 15)) and grid.dtype == np.float32
        assert 0 <= grid.min() and grid.max() <= 1


def test_many_seeds_one_file_each(tiny_model, tmp_path):
    result = sinrun("sample", tiny_model, "--seeds", "2-4,9", "-o", tmp_path / "s.obj")
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s_index.jsonl"] + [f"s_seed{s}.obj" for s in (2, 3, 4, 9)]
    result = sinrun("sample", tiny_model, "--seeds", "1,2", "-o", tmp_path / "x{seed}.ply")
    assert (tmp_path / "x1.ply").exists() and (tmp_path / "x2.ply").exists()


def test_a_seed_range_is_lazy():
    """--seeds 0-100000000 must not build a hundred million seeds up front."""
    from sinshape.cli.params import SEEDS

    seeds = SEEDS.convert("0-100000000,7", None, None)
    assert all(isinstance(r, range) for r in seeds.ranges)
    assert (len(seeds), seeds.first, seeds.last) == (100_000_002, 0, 7)
    assert list(SEEDS.convert("2-4,9", None, None)) == [2, 3, 4, 9]


@pytest.mark.parametrize("option, value, says", [
    ("--seeds", "1-x", "not a seed list"), ("--seeds", "5-3", "counts down; write 3-5"),
    ("--size", "1,1", "positive factors"), ("--focus", "2,0,0", "fractions in [0, 1]"),
])
def test_bad_seeds_and_triples_are_usage_errors_naming_the_option(tiny_model, tmp_path, option, value, says):
    command = "render" if option == "--focus" else "sample"
    result = sinrun(command, tiny_model, option, value, "-o", tmp_path / "x.png")
    assert result.exit_code == 2 and option in result.output and says in result.output
    assert list(tmp_path.iterdir()) == []


def test_write_samples_writes_lazily_and_reports_each(tiny_model, tmp_path):
    from sinshape.runtime import generate, load, write

    model, made, done = load.load_model(tiny_model), [], []

    def outputs():
        for seed in (1, 2):
            made.append(seed)
            yield tmp_path / f"s{seed}.npz", generate.sample(model, seed)

    write.write_samples(model, outputs(), progress=lambda: done.append(len(made)))
    assert done == [1, 2]  # each sample written before the next one is made
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s1.npz", "s2.npz"]


def test_size_and_smoothing_options(tiny_model, tmp_path):
    plain, wide, smooth = tmp_path / "p.ply", tmp_path / "w.ply", tmp_path / "s.ply"
    assert sinrun("sample", tiny_model, "--seed", 1, "-o", plain, "--frame", "model").exit_code == 0
    assert sinrun("sample", tiny_model, "--seed", 1, "--size", "2,1,1", "-o", wide, "--frame", "model").exit_code == 0
    assert sinrun("sample", tiny_model, "--seed", 1, "--smooth", 3, "--largest", "-o", smooth,
                  "--frame", "model").exit_code == 0
    plain, wide, smooth = (trimesh.load(p) for p in (plain, wide, smooth))
    assert wide.extents[0] > 1.6 * plain.extents[0]
    assert abs(wide.extents[1] - plain.extents[1]) < 2
    assert len(smooth.split(only_watertight=False)) == 1
    assert not np.allclose(smooth.vertices[:10], plain.vertices[:10])


def test_interpolate_writes_every_step(tiny_model, tmp_path):
    result = sinrun("interpolate", tiny_model, "--seeds", 3, 7, "--steps", 5, "-o", tmp_path / "i.ply")
    assert result.exit_code == 0, result.output
    names = sorted(p.name for p in tmp_path.iterdir())
    assert len(names) == 5 and names[0] == "i_step00_alpha-0.50.ply" and names[-1] == "i_step04_alpha+1.50.ply"


def test_info_shows_the_manifest(tiny_model, tiny_pyramid):
    result = sinrun("info", tiny_model)
    assert result.exit_code == 0
    for text in (f"sinshape {fmt.FORMAT_VERSION}", tiny_pyramid.name, "20x18x15", "15x15x15", "iterations per level",
                 "tiles       9 x 8 voxels along x and y; a map's pixel is a square of 9 voxels a side"):
        assert text in result.output


def test_version_is_the_packages():
    from importlib import metadata

    from sinshape import runtime

    assert runtime.__version__ == metadata.version("sinshape")
    result = sinrun("--version")
    assert result.exit_code == 0 and result.output == f"sinrun, version {runtime.__version__}\n"


def test_library_errors_name_parameters_and_the_cli_names_options():
    from sinshape.cli.main import command_line_message
    from sinshape.core.errors import InputError

    levels = InputError("t.h5 has 3 levels; `levels` 5 asks for more", "levels")
    assert command_line_message(levels) == "t.h5 has 3 levels; --levels 5 asks for more"
    assert command_line_message(InputError("`factors` must be 3 positive numbers", "factors")).startswith("--size must")
    assert command_line_message(InputError("`seed` must be an integer", "seed")) == "seed must be an integer"


def test_help_for_every_command():
    for command in ("sample", "interpolate", "info", "models"):
        result = sinrun(command, "--help")
        assert result.exit_code == 0 and "Usage" in result.output
    assert "--scale" in sinrun("sample", "--help").output


def rewrite_manifest(source, target, change):
    """`source` with its manifest changed, resealed so the change itself is what is refused."""
    model = onnx.load(source)
    for prop in model.metadata_props:
        if prop.key == fmt.METADATA_KEY:
            manifest = json.loads(prop.value)
            change(manifest)
            prop.value = json.dumps(manifest)
    target.write_bytes(sealed_bytes(model))
    return target


def foreign_model(path):
    node = onnx.helper.make_node("Relu", ["x"], ["y"])
    graph = onnx.helper.make_graph([node], "g", [onnx.helper.make_tensor_value_info("x", 1, [1])],
                                   [onnx.helper.make_tensor_value_info("y", 1, [1])])
    onnx.save(onnx.helper.make_model(graph), path)
    return path


def external_data_model(source, path):
    model = onnx.load(source)
    tensor = model.graph.initializer[0]
    tensor.data_location = onnx.TensorProto.EXTERNAL
    entry = tensor.external_data.add()
    entry.key, entry.value = "location", "weights.bin"
    path.write_bytes(sealed_bytes(model))  # onnx.save would try to write the data file
    (path.parent / "weights.bin").write_bytes(b"\0" * 1024)
    return path


def test_bad_models_are_refused_in_one_line(tiny_model, tmp_path):
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"\x00\x01 not a protobuf at all \xff" * 10)
    cases = [
        (tmp_path / "missing.onnx", "is missing"),
        (garbage, "not an ONNX file"),
        (foreign_model(tmp_path / "foreign.onnx"), "not a sinshape model"),
        (rewrite_manifest(tiny_model, tmp_path / "newer.onnx", lambda m: m.update(format_version=99)),
         "newer than this sinshape reads"),
        (rewrite_manifest(tiny_model, tmp_path / "broken.onnx", lambda m: m["levels"].pop()), "stages"),
        (rewrite_manifest(tiny_model, tmp_path / "sizes.onnx", lambda m: m["levels"][0].update(size=[0, 1, 1])),
         "size"),
        (external_data_model(tiny_model, tmp_path / "external.onnx"), "external data"),
    ]
    for path, fragment in cases:
        out = tmp_path / "out.ply"
        assert_one_line_error(sinrun("sample", path, "-o", out), fragment)
        assert not out.exists() and not list(tmp_path.glob(".out*"))


def test_bad_options_are_refused_in_one_line(tiny_model, tmp_path):
    out = tmp_path / "out.ply"
    cases = [
        (["--scale", "0"], "--scale must be a positive number"),
        (["--scale", "-2"], "positive"),
        (["--scale", "100000"], "--scale 100000.0 asks for"),
        (["--size", "1000"], "GiB"),  # petabytes: beyond any machine's memory
        (["--scale", "3000", "-o", str(tmp_path / "g.npz")], "GiB"),
        (["-o", str(tmp_path / "out.xyz")], "unsupported output format"),
        (["-o", str(tmp_path / "nowhere" / "out.ply")], "does not exist"),
        (["-o", "/proc/sinshape.ply"], "cannot write"),
        (["--threads", "0"], "--threads must be 1 to 256"),
        (["--threads", "1000000"], "--threads must be 1 to 256"),  # started a million threads
        (["--recon", "--size", "2"], "training size; drop --size"),
        (["--smooth", "-1"], "--smooth must be 0 to 100"),
        (["--smooth", "1000000"], "--smooth must be 0 to 100"),
    ]
    for options, fragment in cases:
        result = sinrun("sample", tiny_model, "-o", str(out), *options)
        assert_one_line_error(result, fragment)
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    usage = sinrun("sample", tiny_model, "--size", "0,1,1")
    assert usage.exit_code == 2 and "positive factors" in usage.output


def test_models_lists_shipped_models(monkeypatch):
    from sinshape import models

    shipped = models.available()
    assert {"towerruins", "terrain", "acropolis"} <= set(shipped) and models.DEFAULT in shipped
    lines = sinrun("models").output.splitlines()
    assert len(lines) == len(shipped)
    for line, (name, path) in zip(lines, sorted(shipped.items())):
        marker = " (default)" if name == models.DEFAULT else ""
        assert line == f"{name}{marker}  {path}" and path.is_file()
    monkeypatch.setattr(models, "available", dict)
    result = sinrun("models")
    assert result.exit_code == 0 and result.output == "no shipped models are installed\n"


def test_help_imports_nothing_heavy():
    """--help must stay instant: no onnxruntime, trimesh or torch behind it."""
    code = ("import sys\nfrom sinshape.cli.main import cli\n"
            "try:\n    cli(prog_name='sinrun')\nexcept SystemExit:\n    pass\n"
            "heavy = [m for m in ('torch', 'onnxruntime', 'trimesh', 'skimage') if m in sys.modules]\n"
            "assert not heavy, heavy\n")
    result = subprocess.run([sys.executable, "-c", code, "--help"], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


@pytest.mark.parametrize("output, needed", [("s.ply", []), ("s.npz", []), ("s.glb", ["trimesh"])])
def test_a_sample_imports_only_what_its_output_needs(tmp_path, output, needed):
    """Start-up is most of a small sample's time: a .ply needs no trimesh, and
    no command needs scipy, scikit-image or the onnx package to sample (a
    .glb does need trimesh, which shows the check sees imports)."""
    code = ("import sys\nfrom sinshape.cli.main import cli\n"
            "try:\n    cli(prog_name='sinrun')\nexcept SystemExit as done:\n    assert not done.code, done.code\n"
            "print('imported:', *(m for m in ('trimesh', 'scipy', 'skimage', 'onnx', 'google.protobuf', 'torch', 'h5py', "
            "'PIL', 'importlib.metadata') if m in sys.modules))\n")
    result = subprocess.run([sys.executable, "-c", code, "sample", str(TINY_ONNX), "--seed", "3",
                             "-o", str(tmp_path / output)], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    imported = result.stdout.splitlines()[-1].split()[1:]
    assert imported == needed if not needed else set(needed) <= set(imported)
    assert (tmp_path / output).is_file()


def test_a_finished_command_ends_at_once_with_its_output_whole(tmp_path):
    """main() ends a successful command without the interpreter's teardown:
    what it printed and wrote is all there; a failure still exits as usual."""
    code = ("import atexit\natexit.register(print, 'teardown ran')\n"
            "from sinshape.cli.main import main\nmain()\n")
    done = subprocess.run([sys.executable, "-c", code, "sample", str(TINY_ONNX), "--seed", "3", "--scale", "2",
                           "-o", str(tmp_path / "s.ply")], capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout == f"wrote {tmp_path / 's.ply'}\n"
    assert trimesh.load(tmp_path / "s.ply").is_watertight
    failed = subprocess.run([sys.executable, "-c", code, "sample", str(TINY_ONNX), "--scale", "0"],
                            capture_output=True, text=True)
    assert failed.returncode != 0 and failed.stdout == "teardown ran\n"


def test_a_sample_is_never_written_over_its_model(tiny_model, tmp_path):
    """Through a link named like a mesh, for the first of --seeds or a later one."""
    model = tmp_path / "m.onnx"
    model.write_bytes(tiny_model.read_bytes())
    (tmp_path / "s_3.ply").symlink_to(model)
    for options in (["--seed", "3"], ["--seeds", "2-3"]):
        result = sinrun("sample", model, *options, "-o", tmp_path / "s_{seed}.ply")
        assert_one_line_error(result, "s_3.ply: is the input")
    assert model.read_bytes() == tiny_model.read_bytes()
