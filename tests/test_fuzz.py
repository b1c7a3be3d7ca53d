"""Property-based fuzzing of every command and the runtime's API, of
corrupted model and mesh files (bits flipped in the graph's attributes
among them), of a resumed job whose outputs were damaged, and of HTTP
clients that leave: no traceback, no hang, no partial or foreign file
touched (docs/RELIABILITY.md, "The fuzz test").

CI runs a bounded, derandomised pass (the same cases every run, no example
database). A longer run draws new cases each time:

    SINSHAPE_FUZZ_EXAMPLES=2000 pytest tests/test_fuzz.py --hypothesis-show-statistics

Values are drawn from two kinds: small ones that give quick work, and
absurd ones (huge, negative, NaN, of the wrong type) that must be refused
up front. Valid work that is merely long (--scale 50) is left out, so that a
case that runs past CASE_SECONDS is a hang, a bug. The memory available is
fixed at 2 GiB, so that what is refused does not depend on the machine.
"""

import contextlib
import hashlib
import io
import os
import select
import signal
import struct
import sys
import tempfile
import time
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import TINY_ONNX, sealed_bytes
from sinshape import runtime
from sinshape.cli.main import cli
from sinshape.cli.params import SEEDS
from sinshape.core import budget
from sinshape.core.errors import InputError

EXAMPLES = int(os.environ.get("SINSHAPE_FUZZ_EXAMPLES", "0"))
LONG = EXAMPLES > 0
CASE_SECONDS = 30  # a case running longer is a hang
FUZZ = settings(
    max_examples=EXAMPLES or 60,
    deadline=timedelta(seconds=CASE_SECONDS),  # hypothesis's own bound, per example: a hang guard only
    derandomize=not LONG,  # CI: the same cases every run
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                           HealthCheck.function_scoped_fixture, HealthCheck.data_too_large],
)
MEMORY = 2 << 30


class Hang(Exception):
    """A case ran past CASE_SECONDS."""


@contextlib.contextmanager
def bounded(seconds=CASE_SECONDS):
    """Fail a case that runs too long, even inside native code that never
    returns to hypothesis's deadline check (SIGALRM; pytest runs tests in
    the main thread)."""
    def ring(signum, frame):
        raise Hang(f"a case ran past {seconds} s")

    previous = signal.signal(signal.SIGALRM, ring)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@pytest.fixture(autouse=True)
def fixed_memory(monkeypatch):
    monkeypatch.setattr(budget, "available_memory", lambda: MEMORY)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A folder with the tiny model, a small mesh and a foreign file that no
    command may touch."""
    root = tmp_path_factory.mktemp("fuzz")
    (root / "tiny.onnx").write_bytes(TINY_ONNX.read_bytes())
    trimesh.creation.box((2, 1, 1)).export(root / "box.obj")
    (root / "untouched.ply").write_bytes(b"not sinshape's")
    return root


def snapshot(root: Path) -> dict:
    return {p.relative_to(root): p.read_bytes() for p in root.rglob("*") if p.is_file()}


def run_cli(root: Path, args: list):
    """Run sinrun in-process in `root`; check there is no traceback and no
    temporary, partial or foreign file left. Returns the result."""
    before = snapshot(root)
    cwd = os.getcwd()
    os.chdir(root)
    try:
        with bounded():
            result = CliRunner().invoke(cli, [str(a) for a in args])
    finally:
        os.chdir(cwd)
    after = snapshot(root)
    assert not isinstance(result.exception, Hang), args
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        import traceback

        raise AssertionError(f"sinrun {args}: {''.join(traceback.format_exception(result.exception))}")
    assert "Traceback" not in result.output, (args, result.output)
    if result.exit_code != 0:
        assert result.exit_code in (1, 2), (args, result.exit_code)
        assert any(line.startswith("Error:") for line in result.output.splitlines()), (args, result.output)
    assert after[Path("untouched.ply")] == before[Path("untouched.ply")]  # named by no case
    new = set(after) - set(before)
    assert not [p for p in new if p.name.startswith(".")], (args, new)  # temporaries, probes
    for path in set(after) & set(before):
        if after[path] != before[path] and path.name not in ("tiny.onnx", "box.obj"):
            before.pop(path)  # an output written again
    for path in new:  # leave the folder as it was for the next case
        (root / path).unlink()
    assert after[Path("tiny.onnx")] == before[Path("tiny.onnx")] and after[Path("box.obj")] == before[Path("box.obj")]
    return result


# -- values ---------------------------------------------------------------
ABSURD_INTS = st.one_of(st.integers(-2**70, -1), st.integers(10**6, 2**70))
ABSURD_FLOATS = st.one_of(st.sampled_from([float("nan"), float("inf"), -float("inf"), 0.0, -0.0, 1e308, -1e-300]),
                          st.floats(-1e30, 0), st.floats(1e4, 1e300))
TEXT = st.text(st.sampled_from("0123456789-,.eE+ x{}:!nainf/"), max_size=12)


def small_or_absurd_float(low, high):
    return st.one_of(st.floats(low, high), ABSURD_FLOATS, TEXT)


def seed_list_text():
    """Seed lists that parse to at most 3 seeds, and text that may not parse."""
    def few(text):
        try:
            return len(SEEDS.convert(text, None, None)) <= 3
        except Exception:  # click's BadParameter: refused, which is what we test
            return True
    return st.one_of(st.from_regex(r"\A[0-9]{1,2}(-[0-9]{1,2})?(,[0-9]{1,2})?\Z"), TEXT).filter(few)


def size_text():
    factor = st.one_of(st.floats(0.01, 2.5), ABSURD_FLOATS).map(lambda f: f"{f:g}")
    return st.one_of(factor, st.lists(factor, min_size=2, max_size=4).map(",".join), TEXT)


OUTPUTS = st.sampled_from(["s.ply", "s.obj", "s.stl", "s.off", "s.glb", "s.npz", "s.xyz", "s", "{seed}.ply",
                           "s_{seed:5}.ply", "{step}_{alpha}.ply", "{nope}.ply", "missing/s.ply", ".", "foreign.ply",
                           "s.png", "{seed!r}.ply", "tiny.onnx"])
MESH_OPTIONS = {
    "--smooth": st.one_of(st.integers(0, 120), ABSURD_INTS, TEXT),
    "--smoother": st.one_of(st.sampled_from(["laplacian", "taubin"]), TEXT),
    "--frame": st.one_of(st.sampled_from(["input", "model"]), TEXT),
    "--largest": st.just(None),
    "--threads": st.one_of(st.integers(-2, 4), ABSURD_INTS),
    "--scale": small_or_absurd_float(0.05, 2.5),
    "--size": size_text(),
}


def options(table: dict):
    """Some of the options of `table`, each with a drawn value (None: a flag)."""
    def arguments(chosen):
        args = []
        for name, value in chosen:
            args += [name] if value is None else [name, value]
        return args
    pairs = [st.tuples(st.just(name), values) for name, values in table.items()]
    return st.lists(st.one_of(pairs), max_size=4).map(arguments)


@FUZZ
@given(args=options({**MESH_OPTIONS, "--seed": st.one_of(st.integers(0, 99), ABSURD_INTS, TEXT),
                     "--seeds": seed_list_text(), "--recon": st.just(None), "-o": OUTPUTS}),
       model=st.sampled_from(["tiny.onnx", "missing.onnx", "box.obj", ".", "foreign.ply"]))
def test_sample(folder, args, model):
    run_cli(folder, ["sample", model, *args])


@FUZZ
@given(args=options({**MESH_OPTIONS, "--steps": st.one_of(st.integers(-1, 3), ABSURD_INTS, TEXT),
                     "-o": OUTPUTS}),
       seeds=st.tuples(st.one_of(st.integers(0, 9), ABSURD_INTS), st.one_of(st.integers(0, 9), TEXT)),
       alpha=st.tuples(small_or_absurd_float(-2, 2), small_or_absurd_float(-2, 2)))
def test_interpolate(folder, args, seeds, alpha):
    run_cli(folder, ["interpolate", "tiny.onnx", "--seeds", *seeds, "--range", *alpha, *args])


@FUZZ
@given(args=options({
    "--seeds": seed_list_text(), "--recon": st.just(None), "--scale": small_or_absurd_float(0.05, 1.5),
    "--size": size_text(), "--smooth": st.one_of(st.integers(0, 5), ABSURD_INTS),
    "--views": st.one_of(st.integers(-1, 3), ABSURD_INTS), "--columns": st.one_of(st.integers(-1, 5), ABSURD_INTS),
    "--image-size": st.one_of(st.integers(-1, 80), ABSURD_INTS), "--zoom": small_or_absurd_float(0.5, 4),
    "--focus": st.one_of(size_text(), st.just("0.5,0.5,0.5")), "--azimuth": small_or_absurd_float(-720, 720),
    "--elevation": small_or_absurd_float(-90, 90), "--up": st.one_of(st.sampled_from(["y", "z"]), TEXT),
    "-o": st.sampled_from(["r.png", "r.jpg", "missing/r.png", "foreign.ply", "."])}),
       inputs=st.lists(st.sampled_from(["tiny.onnx", "box.obj", "missing.obj", "."]), min_size=1, max_size=2))
def test_render(folder, args, inputs):
    if "-o" not in args:
        args += ["-o", "r.png"]
    if "--image-size" not in args:
        args += ["--image-size", "32"]  # small pictures keep each case short
    run_cli(folder, ["render", *inputs, *args])


@FUZZ
@given(name=st.one_of(st.sampled_from(["terrain", "acropolis", "stairs", "wall", "cheese"]), TEXT),
       detail=st.one_of(st.integers(-1, 12), ABSURD_INTS, st.integers(10**4, 10**5), TEXT),
       seed=st.one_of(st.integers(0, 5), ABSURD_INTS), output=OUTPUTS)
def test_shape(folder, name, detail, seed, output):
    run_cli(folder, ["shape", name, "--detail", detail, "--seed", seed, "-o", output])


@FUZZ
@given(command=st.sampled_from([["info", "tiny.onnx"], ["info", "box.obj"], ["info", "."], ["models"],
                                ["eval", "tiny.onnx", "--reference", "box.obj"], ["eval", "tiny.onnx"]]),
       args=options({"-n": st.one_of(st.integers(-1, 3), ABSURD_INTS), "--first-seed": st.one_of(st.integers(0, 9),
                     ABSURD_INTS), "--scale": small_or_absurd_float(0.5, 1.5), "--json": OUTPUTS.filter(lambda name: name not in ("tiny.onnx", "box.obj"))}))
def test_info_models_eval(folder, command, args):
    if command[0] == "eval" and not any(a == "-n" for a in args):
        args += ["-n", "2"]
    run_cli(folder, [*command, *(args if command[0] == "eval" else [])])


# -- the Python API -------------------------------------------------------
@pytest.fixture(scope="module")
def model():
    return runtime.load_model(TINY_ONNX, threads=1)


ANY = st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70), st.floats(allow_nan=True), TEXT,
                st.lists(st.floats(-3, 3), max_size=4).map(tuple))


def api_call(function, *args, **kwargs):
    """Call a runtime function: it returns, or raises InputError; nothing else."""
    with bounded():
        try:
            return function(*args, **kwargs)
        except InputError:
            return None


@FUZZ
@given(seed=st.one_of(st.integers(0, 99), ANY), factors=st.one_of(st.sampled_from([(1, 1, 1), (0.5, 1, 2)]), ANY),
       limit=st.one_of(st.none(), st.integers(-1, 2**40)), scale=st.one_of(st.floats(0.1, 2), ANY),
       smooth=st.one_of(st.integers(0, 5), ANY), smoother=st.one_of(st.just("taubin"), ANY),
       largest=ANY, frame=st.one_of(st.sampled_from(["input", "model"]), ANY))
def test_api_sample_extract_dense(model, seed, factors, limit, scale, smooth, smoother, largest, frame):
    triplane = api_call(runtime.sample, model, seed, factors, memory_limit=limit)
    if triplane is None:
        return
    api_call(runtime.extract, model, triplane, scale, smooth, smoother, largest, frame)
    api_call(runtime.dense, model, triplane, scale)


@FUZZ
@given(a=st.one_of(st.integers(0, 9), ANY), b=st.one_of(st.integers(0, 9), ANY),
       alpha=st.one_of(st.floats(-2, 2), ANY),
       coords=st.one_of(st.lists(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=3, max_size=3),
                                 max_size=5), st.lists(st.floats(-5, 30), max_size=7), ANY))
def test_api_interpolate_points(model, a, b, alpha, coords):
    triplane = api_call(runtime.interpolate, model, a, b, alpha)
    if triplane is not None:
        values = api_call(runtime.points, model, triplane, coords)
        assert values is None or (np.isfinite(values).all() and ((0 <= values) & (values <= 1)).all())


@FUZZ
@given(threads=st.one_of(st.integers(-1, 4), ANY), name=st.sampled_from(["tiny.onnx", "box.obj", "none", "."]))
def test_api_load_model(folder, threads, name):
    api_call(runtime.load_model, folder / name, threads)


# -- corrupted files ------------------------------------------------------
def corrupt(data: bytes, draw) -> bytes:
    """Truncate, flip bytes, or overwrite a run of bytes with a drawn value."""
    kind = draw(st.sampled_from(["truncate", "flip", "write"]))
    if kind == "truncate":
        return data[:draw(st.integers(0, len(data) - 1))]
    data = bytearray(data)
    for _ in range(draw(st.integers(1, 8))):
        at = draw(st.integers(0, len(data) - 1))
        if kind == "flip":
            data[at] ^= 1 << draw(st.integers(0, 7))
        else:
            value = draw(st.sampled_from([b"\xff" * 8, b"\x00" * 8, struct.pack("<d", float("nan")),
                                          struct.pack("<q", 2**62), b"9" * 8, b"-1"]))
            data[at:at + len(value)] = value
    return bytes(data)


def manifest_edits():
    """A manifest field set to an odd value, as an editor would."""
    keys = st.sampled_from(["format", "format_version", "created_by", "planes", "channels", "pool_bins", "mlp_hidden",
                            "levels", "recon_seed", "noise", "frame", "stages", "source", "config", "training"])
    values = st.one_of(st.none(), st.integers(-2**70, 2**70), st.floats(allow_nan=True), TEXT,
                       st.lists(st.integers(-3, 40), max_size=4), st.just({}), st.just([{}]))
    return st.tuples(keys, values)


@FUZZ
@given(data=st.data())
def test_corrupted_models_are_refused_or_work(folder, data):
    """A corrupted model loads and samples, or is refused in one line. An
    edited manifest is resealed half the time, as a careful editor would,
    so that its fields are read."""
    import json

    import onnx

    from sinshape.core import manifest as fmt

    source = data.draw(st.sampled_from([TINY_ONNX, TINY_ONNX.with_name("tiny_v2.onnx")]))
    raw = source.read_bytes()
    if data.draw(st.booleans()):
        proto = onnx.load_from_string(raw)
        entry = next(p for p in proto.metadata_props if p.key == fmt.METADATA_KEY)
        manifest = json.loads(entry.value)
        key, value = data.draw(manifest_edits())
        if data.draw(st.booleans()):
            manifest["levels"][data.draw(st.integers(0, 1))][data.draw(st.sampled_from(["size", "noise_amp"]))] = value
        else:
            manifest[key] = value
        reseal = data.draw(st.booleans())
        if reseal and "checksum" in manifest:  # format 2's checksum field
            weights = [(t.name, onnx.numpy_helper.to_array(t)) for t in proto.graph.initializer]
            manifest["checksum"] = fmt.checksum_v2(manifest, weights)
        entry.value = json.dumps(manifest)
        raw = sealed_bytes(proto) if reseal and source == TINY_ONNX else proto.SerializeToString()
    else:
        raw = corrupt(raw, data.draw)
    path = folder / "bad.onnx"
    path.write_bytes(raw)
    try:
        loaded = api_call(runtime.load_model, path, 1)
        if loaded is not None:
            triplane = api_call(runtime.sample, loaded, 1)
            if triplane is not None:
                api_call(runtime.extract, loaded, triplane)
        run_cli(folder, ["info", "bad.onnx"])
    finally:
        path.unlink()


MESHES = {suffix: trimesh.creation.box((2, 1, 1)).export(file_type=suffix[1:]) for suffix in
          (".obj", ".ply", ".stl", ".off", ".glb")}


@FUZZ
@given(data=st.data(), suffix=st.sampled_from(sorted(MESHES)))
def test_corrupted_meshes_are_refused_or_work(folder, data, suffix):
    """A corrupted mesh is voxelised and drawn, or refused in one line."""
    from sinshape.prep import pyramid

    raw = MESHES[suffix]
    raw = corrupt(raw.encode() if isinstance(raw, str) else raw, data.draw)
    path = folder / f"bad{suffix}"
    path.write_bytes(raw)
    try:
        api_call(pyramid.load_pyramid, path, 16, 1)
        run_cli(folder, ["render", path.name, "--image-size", "32", "-o", "r.png"])
    finally:
        path.unlink()


# -- graph attributes ------------------------------------------------------
NODE_ATTRIBUTE = 5  # NodeProto.attribute (onnx.proto)
SEAL_REFUSAL = "corrupt model: its bytes do not match the SHA-256 sealed at its end"


def attribute_spans(data: bytes) -> list:
    """(start, end) of every node attribute entry in a model's graph (the
    LeakyRelu slopes, Conv kernel shapes, pads and strides, InstanceNormalization
    epsilons, Transpose perms), read with the runtime's own protobuf reader."""
    from sinshape.runtime import onnxfile as of

    spans = []
    for number, wire, graph, _ in of.fields(data):
        if number == of.MODEL_GRAPH and wire == 2:
            for n, w, node, _ in of.fields(data, *graph):
                if n == of.GRAPH_NODE and w == 2:
                    spans += [entry for a, aw, _, entry in of.fields(data, *node) if a == NODE_ATTRIBUTE and aw == 2]
    return spans


ATTRIBUTE_SOURCES = {"sealed": TINY_ONNX, "resealed": TINY_ONNX, "format 2": TINY_ONNX.with_name("tiny_v2.onnx"),
                     "format 1": TINY_ONNX.with_name("tiny_v1.onnx")}


def test_the_attribute_spans_are_the_graphs_attributes():
    """The property below flips bits where onnx itself finds the attributes."""
    import onnx

    from sinshape.runtime import onnxfile

    for source in set(ATTRIBUTE_SOURCES.values()):
        data = source.read_bytes()
        nodes = onnx.load_from_string(data).graph.node
        found = []
        for start, end in attribute_spans(data):
            ((number, _, (first, last), _),) = onnxfile.fields(data, start, end)
            assert number == NODE_ATTRIBUTE
            found.append(onnx.AttributeProto.FromString(data[first:last]))
        assert found == [attribute for node in nodes for attribute in node.attribute] and len(found) == 90
        assert {a.name for a in found} == {"alpha", "epsilon", "kernel_shape", "pads", "perm"}


@contextlib.contextmanager
def file_descriptors():
    """What is written to file descriptors 1 and 2 meanwhile, past CliRunner
    (onnxruntime's C++ logger writes there): a list that holds the text after."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    written = []
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)
        try:
            yield written
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            sink.seek(0)
            written.append(sink.read().decode(errors="replace"))


@pytest.fixture(scope="module")
def intact_grid(folder):
    """Seed 1's occupancy grid from the intact model, as `sample -o s.npz` writes it."""
    model = runtime.load_model(TINY_ONNX, threads=1)
    return runtime.dense(model, runtime.sample(model, 1), 1.0)


@FUZZ
@given(data=st.data(), kind=st.sampled_from(sorted(ATTRIBUTE_SOURCES)))
def test_flipped_graph_attributes_are_refused(folder, tmp_path, intact_grid, data, kind):
    """Bits flipped inside the graph's node attributes, nowhere else. A sealed
    file is refused as corrupt, in one line, before anything reads it. Where
    nothing vouches for the graph (the file resealed afterwards, as a careful
    editor would; formats 2 and 1, whose checks cover only weights and
    manifest), the checks behind the seal read the damage: one line, or a
    sample of finite values of the manifest's shape (then maybe a different
    one: nothing can tell), and never a word from onnxruntime itself."""
    from hypothesis import event

    from sinshape.core import manifest as fmt

    raw = bytearray(ATTRIBUTE_SOURCES[kind].read_bytes())
    where = st.sampled_from(attribute_spans(bytes(raw))).flatmap(lambda span: st.integers(span[0], span[1] - 1))
    for at, bit in data.draw(st.lists(st.tuples(where, st.integers(0, 7)), min_size=1, max_size=8, unique=True),
                             label="flips (byte, bit)"):
        raw[at] ^= 1 << bit
    raw = bytes(raw)
    if kind == "resealed":
        raw = fmt.seal(fmt.unseal(raw)[0])
    (folder / "bad.onnx").write_bytes(raw)
    out = tmp_path / "s.npz"
    try:
        with file_descriptors() as written:
            result = run_cli(folder, ["sample", "bad.onnx", "--seed", 1, "--threads", 1, "-o", out])
        assert written == [""], written  # nothing past click: onnxruntime said nothing of its own
        lines = result.output.splitlines()
        if kind == "sealed":
            assert result.exit_code == 1 and lines == [f"Error: bad.onnx: {SEAL_REFUSAL}"], result.output
            with pytest.raises(InputError, match=SEAL_REFUSAL):
                runtime.load_model(folder / "bad.onnx", 1)
        if result.exit_code == 1:
            assert len(lines) == 1 and lines[0].startswith("Error: bad.onnx: "), result.output
            assert not out.exists()
            event(f"{kind}: refused: {lines[0].split(': ')[2][:40]}")
            return
        assert result.exit_code == 0, result.output
        with np.load(out) as saved:
            grid = saved["occupancy"]
        assert grid.shape == intact_grid.shape and np.isfinite(grid).all() and (0 <= grid).all() and (grid <= 1).all()
        event(f"{kind}: sampled, {'the same' if np.array_equal(grid, intact_grid) else 'a different'} grid")
    finally:
        (folder / "bad.onnx").unlink()
        out.unlink(missing_ok=True)


# -- a resumed job ---------------------------------------------------------
JOB = 6  # the first run makes seeds 0-5; a rerun may ask for up to 2 more
DAMAGES = ("truncate", "flip", "append", "another seed's file", "delete", "unindexed")


def sinrun_job(root: Path, last: int):
    """`sinrun sample tiny.onnx --seeds 0-LAST --scale 0.5 -o job/{seed}.ply` in this process, one worker."""
    with bounded():
        return CliRunner().invoke(cli, ["sample", str(TINY_ONNX), "--seeds", f"0-{last}", "--workers", "1",
                                        "--threads", "1", "--scale", "0.5", "-o", str(root / "job" / "{seed}.ply")])


@pytest.fixture(scope="module")
def finished_job(tmp_path_factory):
    """A job of seeds 0-5 run to the end (its folder, index included), and
    every seed's file as a run of 0-7 makes it."""
    root = tmp_path_factory.mktemp("jobs")
    (root / "job").mkdir()
    assert sinrun_job(root, JOB + 1).exit_code == 0
    reference = {seed: (root / "job" / f"{seed}.ply").read_bytes() for seed in range(JOB + 2)}
    for path in (root / "job").iterdir():
        path.unlink()
    assert sinrun_job(root, JOB - 1).exit_code == 0
    return root / "job", reference


@settings(FUZZ, max_examples=EXAMPLES or 20)  # a case runs sinrun once or twice: 0.3 s
@given(damages=st.dictionaries(st.integers(0, JOB - 1), st.sampled_from(DAMAGES), max_size=JOB),
       data=st.data(), crash=st.sampled_from([None, "a line cut short", "a line twice"]), more=st.integers(0, 2),
       stop=st.one_of(st.none(), st.integers(1, JOB + 2)))
def test_a_resumed_job_redoes_exactly_its_damaged_seeds(finished_job, tmp_path_factory, damages, data, crash,
                                                       more, stop):
    """Outputs of a finished job truncated, changed (a bit, bytes added,
    another seed's file in their place), deleted, or dropped from the index;
    the index perhaps cut short or holding a line twice. A rerun, over the
    same seeds or more, perhaps interrupted (Ctrl-C) and run again, makes
    exactly the damaged and the new seeds, each once, and ends with every
    file whole and one index line per seed that vouches for it."""
    import json
    import shutil

    from sinshape.runtime import many_workers

    job, reference = finished_job
    root = tmp_path_factory.mktemp("resumed")
    folder = root / "job"
    shutil.copytree(job, folder)
    job, *lines = (folder / "index.jsonl").read_text().splitlines(keepends=True)  # the job's line stays first
    for seed, damage in damages.items():
        path = folder / f"{seed}.ply"
        raw = bytearray(reference[seed])
        if damage == "truncate":
            path.write_bytes(raw[:data.draw(st.integers(0, len(raw) - 1), label=f"{seed}: keep")])
        elif damage == "flip":
            raw[data.draw(st.integers(0, len(raw) - 1), label=f"{seed}: at")] ^= 1 << data.draw(st.integers(0, 7))
            path.write_bytes(raw)
        elif damage == "append":
            path.write_bytes(raw + data.draw(st.binary(min_size=1, max_size=16), label=f"{seed}: added"))
        elif damage == "another seed's file":
            path.write_bytes(reference[data.draw(st.sampled_from([s for s in range(JOB) if s != seed]))])
        elif damage == "delete":
            path.unlink()
        else:
            lines = [line for line in lines if json.loads(line)["seed"] != seed]
    if crash == "a line twice" and lines:
        lines.append(lines[data.draw(st.integers(0, len(lines) - 1))])
    elif crash == "a line cut short" and lines:
        line = lines[data.draw(st.integers(0, len(lines) - 1))]
        lines.append(line[:data.draw(st.integers(1, len(line) - 2))])  # no newline: a crash mid-write
    (folder / "index.jsonl").write_text("".join([job, *lines]))

    made, run = [], many_workers.Worker.run

    def counted(self, seed):
        if stop is not None and len(made) + 1 == stop:
            raise KeyboardInterrupt  # Ctrl-C before this seed's sample is made
        result = run(self, seed)
        made.append(seed)
        return result

    try:
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(many_workers.Worker, "run", counted)
            result = sinrun_job(root, JOB - 1 + more)
            expected = sorted(damages) + list(range(JOB, JOB + more))
            if stop is not None and stop <= len(expected):
                assert result.exit_code == 130 and result.output.splitlines()[-1] == "interrupted", result.output
                assert not [p for p in folder.iterdir() if p.name.startswith(".")]  # no temporary left
                stop = None
                result = sinrun_job(root, JOB - 1 + more)
        assert result.exit_code == 0, result.output
        assert sorted(made) == expected  # each damaged or new seed made once, none other
        seeds = range(JOB + more)
        assert sorted(p.name for p in folder.iterdir()) == sorted([f"{s}.ply" for s in seeds] + ["index.jsonl"])
        head, *records = [json.loads(line) for line in (folder / "index.jsonl").read_text().splitlines()]
        assert head == json.loads(job)  # the job, first
        assert sorted(r["seed"] for r in records) == list(seeds)  # one line per seed
        for record in records:
            whole = reference[record["seed"]]
            assert (folder / record["file"]).read_bytes() == whole, record
            assert (record["bytes"], record["sha256"]) == (len(whole), hashlib.sha256(whole).hexdigest())
    finally:
        shutil.rmtree(root)


# -- clients that leave -----------------------------------------------------
LOG_ALARMS = ("Traceback", "ERROR", "Exception")


def alarms(lines: list) -> list:
    """The lines of a server's output that report an error."""
    return [line for line in lines if any(word in line for word in LOG_ALARMS)]


class Printed(list):
    """The lines a child process has printed (its stdout and stderr, one
    pipe), read without a thread: read() takes every byte already in the
    pipe, without waiting. The server logs as it goes (a line is in the pipe
    once logged), so what it logged before an answer it sent is here once
    read() returns after that answer came: nothing to sleep for, no race."""

    def __init__(self, pipe):
        super().__init__()
        self.fd, self.partial = pipe.fileno(), b""

    def read(self) -> "Printed":
        while select.select([self.fd], [], [], 0)[0]:
            chunk = os.read(self.fd, 1 << 16)
            if not chunk:  # the process has ended: its last line too
                chunk, self.partial = self.partial + b"\n" if self.partial else b"", b""
                self.extend(line.decode(errors="replace") + "\n" for line in chunk.splitlines())
                break
            *lines, self.partial = (self.partial + chunk).split(b"\n")
            self.extend(line.decode(errors="replace") + "\n" for line in lines)
        return self


@pytest.fixture(scope="module")
def tiny_server():
    """`sinrun serve tiny.onnx` in a child process on a free port: (base URL,
    the lines it has printed, a Printed)."""
    import subprocess

    pytest.importorskip("fastapi", reason="needs the serve extra: pip install 'sinshape[serve]'")
    pytest.importorskip("uvicorn", reason="needs the serve extra: pip install 'sinshape[serve]'")
    from browser import GUARD_SECONDS
    from test_serve import free_port, get

    port = free_port()
    process = subprocess.Popen([sys.executable, "-c", "from sinshape.cli.main import main; main()", "serve",
                                str(TINY_ONNX), "--threads", "1", "--timeout", "20", "--port", str(port)],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    printed = Printed(process.stdout)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + GUARD_SECONDS
        while True:
            assert process.poll() is None, "".join(printed.read())
            with contextlib.suppress(OSError):
                if get(f"{base}/health")[0] == 200:
                    break
            assert time.monotonic() < deadline, f"the server did not answer within {GUARD_SECONDS} s"
            time.sleep(0.1)
        yield base, printed
    finally:
        process.terminate()
        process.wait(20)  # a hang guard only
        printed.read()
        process.stdout.close()
    assert not alarms(printed), "".join(printed)


def http_request(kind: str, seed: int, scale: int, format: str) -> tuple:
    """(the request's bytes, how many of them are its head)."""
    body = b""
    if kind == "sample":
        target = f"GET /api/models/tiny/sample?seed={seed}&scale={scale}&format={format}"
    elif kind == "layout":  # a body that is no layout: answered 400 when it all arrives
        target, body = f"POST /api/models/tiny/sample?seed={seed}", bytes(range(256)) * 8
    else:
        target = {"model file": "GET /api/models/tiny/onnx", "page": "GET /", "health": "GET /health"}[kind]
    head = (f"{target} HTTP/1.1\r\nHost: 127.0.0.1\r\nAccept-Encoding: gzip\r\n"
            + (f"Content-Length: {len(body)}\r\n" if body else "") + "\r\n").encode()
    return head + body, len(head)


@settings(FUZZ, max_examples=EXAMPLES or 15)  # a case waits for the server to settle: 0.1 to 1 s
@given(kind=st.sampled_from(["sample", "sample", "layout", "model file", "page", "health"]),
       seed=st.integers(0, 3), scale=st.sampled_from([1, 2, 24]), format=st.sampled_from(["glb", "ply", "npz"]),
       data=st.data(), wait=st.floats(0, 0.3), read=st.integers(0, 1 << 16), reset=st.booleans())
def test_a_client_that_leaves_at_any_moment(tiny_server, kind, seed, scale, format, data, wait, read, reset):
    """A client sends all of a request or part of it, waits, perhaps reads
    part of the answer, and leaves (FIN, or RST). The server frees what the
    request held (nothing in flight, no sample being made), logs no error or
    traceback, and answers the next request. That a left sample stops at its
    next slab rather than running on is measured, in CPU time, by
    test_serve.py's test_a_client_that_leaves_frees_its_slot."""
    import json
    import socket

    from test_serve import get

    base, printed = tiny_server
    port = int(base.rsplit(":", 1)[1])
    request, head = http_request(kind, seed, scale, format)
    cut = data.draw(st.integers(0, len(request)), label="bytes sent")
    before = len(printed.read())
    with socket.create_connection(("127.0.0.1", port), timeout=5) as client:
        client.sendall(request[:cut])
        ends = time.perf_counter() + wait
        with contextlib.suppress(OSError):
            while read > 0 and time.perf_counter() < ends:
                client.settimeout(max(0.001, ends - time.perf_counter()))
                got = client.recv(min(read, 65536))
                if not got:
                    break
                read -= len(got)
        time.sleep(max(0.0, ends - time.perf_counter()))
        if reset:
            client.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    with bounded():  # a hang guard only: the server's --timeout 20 ends any sample left running
        while True:
            status, _, body = get(f"{base}/health")
            health = json.loads(body)
            if status == 200 and health["in_flight"] == health["sampling"] == 0:
                break
            time.sleep(0.05)
    assert get(f"{base}/api/models/tiny/sample?seed=0&format=npz")[0] == 200
    printed.read()  # all the server logged before it answered
    assert not alarms(printed[before:]), "".join(printed[before:])


def test_a_client_that_leaves_during_a_layout_upload(tiny_server):
    """Half of the body sent (or all of it, and gone at once: the fuzzer's
    case): the server gives up on it quietly (a 499 nobody reads), not with
    a ClientDisconnect logged as a 500."""
    import socket

    from test_serve import get

    base, printed = tiny_server
    request, head = http_request("layout", 1, 1, "glb")
    before = len(printed.read())
    for sent in (head + 100, len(request)):
        with socket.create_connection(("127.0.0.1", int(base.rsplit(":", 1)[1])), timeout=5) as client:
            client.sendall(request[:sent])
            time.sleep(0.1 if sent < len(request) else 0)
    get(f"{base}/health")
    started = time.perf_counter()  # two tracebacks a request end in this line, or nothing comes
    while sum("ClientDisconnect" in line for line in printed.read()[before:]) < 4 and time.perf_counter() - started < 3:
        time.sleep(0.05)
    tracebacks = [line for line in printed[before:] if any(word in line for word in LOG_ALARMS)]
    counted = sum("ClientDisconnect" in line for line in printed[before:])
    del printed[before:]  # known: not for the module's last check
    assert not tracebacks, f"{counted} lines name ClientDisconnect"


def test_the_case_bound_stops_a_hang():
    with pytest.raises(Hang), bounded(0.2):
        while True:
            io.BytesIO(b"spin")


# -- what the fuzzer found, kept as plain cases ----------------------------
@pytest.mark.parametrize("args, fragment", [
    # a finite but enormous blend weight overflowed the noise to NaN: a traceback in marching cubes
    (["interpolate", "tiny.onnx", "--seeds", 0, 0, "--range", 0, 1e308], "--range must be a number in [-100, 100]"),
    # 1e228 made a file name too long to look up: an OSError traceback
    (["interpolate", "tiny.onnx", "--seeds", 0, 0, "--range", 1e228, 0], "--range must be a number in [-100, 100]"),
    (["sample", "tiny.onnx", "-o", "s" * 300 + ".ply"], "cannot write here (File name too long)"),
    # 2e6 times the training size: numpy's int64 product of the sizes wrapped round and
    # passed the memory check; the noise then refused positions past 2**21 (ValueError)
    (["sample", "tiny.onnx", "--size", 2.0754e6], "longer than 65536 voxels"),
    (["sample", "tiny.onnx", "--size", "3e6,0.1,0.1"], "longer than 65536 voxels"),
    # an infinite scale: the clamping warning's round() overflowed
    (["interpolate", "tiny.onnx", "--seeds", 0, 0, "--scale", "inf"], "--scale must be a positive number"),
    # '.' has no name to add _stepK_alphaA to: a ValueError traceback
    (["interpolate", "tiny.onnx", "--seeds", 0, 0, "-o", "."], "'.' is not a file name"),
    # n * 1e308 is infinite: round() overflowed, in the clamping warning and in the grid's size
    (["sample", "tiny.onnx", "--scale", 1e308], "at most 65536 points per axis"),
    (["eval", "tiny.onnx", "--reference", "box.obj", "-n", 2, "--scale", 1e308], "at most 65536 points per axis"),
    # a million threads: onnxruntime started them all, for minutes
    (["sample", "tiny.onnx", "--threads", 10**6], "--threads must be 1 to 256"),
])
def test_found_by_the_fuzzer(folder, args, fragment):
    result = run_cli(folder, args)
    assert result.exit_code in (1, 2) and fragment in result.output, result.output


def test_eval_refuses_a_million_samples_up_front(folder):
    """Found by the fuzzer: every sample's grid is kept and compared with
    every other; -n 1000000 ran on for hours."""
    result = run_cli(folder, ["eval", "tiny.onnx", "--reference", "box.obj", "-n", 10**6])
    assert result.exit_code == 1 and "scoring 1000000 samples of 5400 voxels needs about 30051.5 GiB" in result.output


def test_a_corrupt_op_name_is_refused(folder):
    """Found by the fuzzer: a flipped bit made an op's name invalid UTF-8,
    which protobuf reads as bytes; sorting it with str names was a TypeError."""
    for source, message in ((TINY_ONNX.with_name("tiny_v2.onnx"), "corrupt model: a name in it is not text"),
                            (TINY_ONNX, "corrupt model: its bytes do not match the SHA-256")):  # sealed: caught first
        raw = bytearray(source.read_bytes())
        raw[raw.find(b"\x22\x04Conv") + 2] = 0xC3  # a UTF-8 lead byte with no continuation
        (folder / "bad.onnx").write_bytes(bytes(raw))
        try:
            with pytest.raises(InputError, match=message):
                runtime.load_model(folder / "bad.onnx", 1)
        finally:
            (folder / "bad.onnx").unlink()


def attribute_set(node: str, **values):
    """tiny.onnx with attributes of `node` set to `values`, sealed afresh: a
    change that only the checks behind the seal can see."""
    def make() -> bytes:
        import onnx

        proto = onnx.load(TINY_ONNX)
        (target,) = [n for n in proto.graph.node if n.name == node]
        for attribute in target.attribute:
            if attribute.name in values:
                attribute.ints[:] = values[attribute.name]
        return sealed_bytes(proto)
    return make


def attribute_name_not_text() -> bytes:
    """The format-2 copy (its checksum does not cover the graph) with the first
    attribute named b"\\xc3lpha": a UTF-8 lead byte with no continuation."""
    raw = TINY_ONNX.with_name("tiny_v2.onnx").read_bytes()
    at = raw.index(b"alpha")
    return raw[:at] + b"\xc3" + raw[at + 1:]


@pytest.mark.parametrize("make, fragment", [
    # onnxruntime could not word its error (bytes that are not UTF-8), and its Python
    # fallback printed four "EP Error" lines to stdout and tried the same provider again
    (attribute_name_not_text, "onnxruntime cannot load a stage ('utf-8' codec can't decode byte 0xc3"),
    # a kernel of 3x7 for 3x3 weights: onnxruntime logged its own error line to stderr first
    (attribute_set("Conv_53", kernel_shape=[3, 7]), "stage level1 does not run"),
    # a pad of 33: the message gave the first output's shape, which was right, (1, 32, 4, 5)
    (attribute_set("Conv_60", pads=[33, 1, 1, 1]), "stage level1 gives shape (1, 32, 36, 5), expected (1, 32, 4, 5)"),
])
def test_damaged_graph_attributes_found_by_the_fuzzer(folder, tmp_path, make, fragment):
    (folder / "bad.onnx").write_bytes(make())
    try:
        with file_descriptors() as written:
            result = run_cli(folder, ["sample", "bad.onnx", "--threads", 1, "-o", tmp_path / "s.npz"])
        lines = result.output.splitlines()
        assert written == [""] and result.exit_code == 1, (written, result.output)
        assert len(lines) == 1 and lines[0].startswith(f"Error: bad.onnx: {fragment}"), result.output
    finally:
        (folder / "bad.onnx").unlink()


def test_a_figure_past_what_a_float_holds():
    """Found by the fuzzer (--size 1.5e104, before sizes were bounded): the
    figure's division overflowed to an OverflowError traceback."""
    with pytest.raises(InputError, match=r"needs about 9\.31e\+390 GiB of memory \(limit 0\.0 GiB\)"):
        budget.check_memory(10**400, "it", 1)


def glb_with_a_flipped_bit(at: int) -> bytes:
    raw = bytearray(MESHES[".glb"])
    raw[at] ^= 1
    return bytes(raw)


@pytest.mark.parametrize("name, data, fragment", [
    # one flipped bit in a .glb put every vertex at the origin; zero extents
    # passed the flatness test (0 < 0 is false), then a ValueError
    ("point.obj", b"v 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 3\n", "no inside to voxelize"),
    # '99999999' written over an .obj's vertex lines left 2-D vertices: an IndexError
    ("flat2d.obj", b"v 0 0\nv 1 0\nv 0 1\nv 1 1\nf 1 2 3\nf 2 3 4\n", "not a 3-D mesh"),
    # a flipped bit in a .glb's index buffer: faces past the vertices, an IndexError
    ("bad.glb", glb_with_a_flipped_bit(689), "faces refer to vertices it does not have"),
])
def test_corrupt_meshes_found_by_the_fuzzer(folder, name, data, fragment):
    from sinshape.prep import pyramid

    path = folder / name
    path.write_bytes(data)
    try:
        with pytest.raises(InputError, match=fragment):
            pyramid.load_pyramid(path, 16)
    finally:
        path.unlink()
