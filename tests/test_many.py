"""Many seeds as one resumable job: worker processes, Ray, an index that a rerun verifies."""

import json
import signal
import sys

import pytest
from click.testing import CliRunner

from sinshape.cli.main import cli
from sinshape.runtime import many, many_workers
from test_cli_train import assert_one_line_error

SCALE = 1.5  # a little meshing work per seed, still fast


def sinrun(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def index_records(folder) -> list:
    """The seed records of a job's index (its first line records the job)."""
    lines = (folder / "index.jsonl").read_text().splitlines()
    assert set(json.loads(lines[0])) == {"job"}
    return [json.loads(line) for line in lines[1:]]


def index_seeds(folder) -> list:
    return [record["seed"] for record in index_records(folder)]


@pytest.fixture(scope="module")
def sequential(tiny_model, tmp_path_factory):
    """Seeds 0-7 written one after another in this process: the reference bytes."""
    folder = tmp_path_factory.mktemp("sequential")
    many.sample_many(tiny_model, range(8), folder / "{seed}.ply", workers=1, scale=SCALE)
    return folder


def interrupt_after(count: int):
    """A progress callback that presses Ctrl-C after `count` seeds are written."""
    written = []

    def progress(seed, record):
        if record is not None:
            written.append(seed)
            if len(written) == count:
                raise KeyboardInterrupt
    return progress


def assert_same_files(folder, reference, seeds):
    for seed in seeds:
        assert (folder / f"{seed}.ply").read_bytes() == (reference / f"{seed}.ply").read_bytes(), seed


def test_the_index_records_each_seed(sequential):
    records = index_records(sequential)
    assert [r["seed"] for r in records] == list(range(8))
    first = records[0]
    assert first["file"] == "0.ply" and first["faces"] > 0 and first["watertight"] is True
    assert first["volume"] > 0 and first["seconds"] >= 0
    assert sorted(p.name for p in sequential.iterdir()) == sorted([f"{s}.ply" for s in range(8)] + ["index.jsonl"])


def test_worker_processes_write_the_sequential_bytes(tiny_model, sequential, tmp_path):
    many.sample_many(tiny_model, range(4), tmp_path / "{seed}.ply", workers=2, scale=SCALE)
    assert_same_files(tmp_path, sequential, range(4))
    assert sorted(index_seeds(tmp_path)) == list(range(4))


def test_an_interrupted_job_resumes_without_redoing_seeds(tiny_model, sequential, tmp_path, monkeypatch):
    with pytest.raises(KeyboardInterrupt):
        many.sample_many(tiny_model, range(8), tmp_path / "{seed}.ply", workers=1, scale=SCALE,
                         progress=interrupt_after(3))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["0.ply", "1.ply", "2.ply", "index.jsonl"]
    # A crash in the middle of an index line: the line is dropped, its seed redone.
    with open(tmp_path / "index.jsonl", "a") as f:
        f.write('{"seed": 7, "fi')
    runs, run = [], many_workers.Worker.run
    monkeypatch.setattr(many_workers.Worker, "run", lambda self, seed: runs.append(seed) or run(self, seed))
    result = many.sample_many(tiny_model, range(8), tmp_path / "{seed}.ply", workers=1, scale=SCALE)
    assert runs == [3, 4, 5, 6, 7] and result["written"] == 5 and result["skipped"] == 3
    assert index_seeds(tmp_path) == list(range(8))
    assert_same_files(tmp_path, sequential, range(8))


def test_a_rerun_redoes_damaged_and_missing_files_and_keeps_one_line_per_seed(tiny_model, sequential, tmp_path,
                                                                             monkeypatch):
    many.sample_many(tiny_model, range(6), tmp_path / "{seed}.ply", workers=1, scale=SCALE)
    records = {record["seed"]: record for record in index_records(tmp_path)}
    assert records[0]["bytes"] == (tmp_path / "0.ply").stat().st_size and len(records[0]["sha256"]) == 64
    with open(tmp_path / "5.ply", "r+b") as f:  # truncate -s 100
        f.truncate(100)
    (tmp_path / "3.ply").unlink()
    data = bytearray((tmp_path / "1.ply").read_bytes())  # same size, one byte changed
    data[-1] ^= 1
    (tmp_path / "1.ply").write_bytes(bytes(data))
    runs, run = [], many_workers.Worker.run
    monkeypatch.setattr(many_workers.Worker, "run", lambda self, seed: runs.append(seed) or run(self, seed))
    result = many.sample_many(tiny_model, range(6), tmp_path / "{seed}.ply", workers=1, scale=SCALE)
    assert sorted(runs) == [1, 3, 5] and result["skipped"] == 3
    assert sorted(index_seeds(tmp_path)) == list(range(6))  # one line per seed
    assert_same_files(tmp_path, sequential, range(6))


def test_many_seeds_need_seed_in_the_file_name(tiny_model, tmp_path):
    with pytest.raises(many.InputError, match=r"need \{seed\} in the output file name"):
        many.sample_many(tiny_model, range(2), tmp_path / "out.ply")
    assert list(tmp_path.iterdir()) == []


def test_a_jobs_folder_is_made_for_it_but_not_for_a_refused_one(tiny_model, tmp_path):
    # As a world's tiles' folder is (sinrun world): `-o job/{seed}.ply` needs no mkdir first.
    many.sample_many(tiny_model, range(2), tmp_path / "job" / "deeper" / "{seed}.ply", workers=1)
    assert sorted(p.name for p in (tmp_path / "job" / "deeper").iterdir()) == ["0.ply", "1.ply", "index.jsonl"]
    with pytest.raises(many.InputError, match="fills in the file's name"):
        many.sample_many(tiny_model, range(2), tmp_path / "{seed}" / "s{seed}.ply")
    (tmp_path / "file").write_text("")
    with pytest.raises(many.InputError, match="is a file, not a folder"):
        many.sample_many(tiny_model, range(2), tmp_path / "file" / "{seed}.ply")
    with pytest.raises(many.InputError, match="cannot make the folder"):
        many.sample_many(tiny_model, range(2), tmp_path / "file" / "sub" / "{seed}.ply")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "job"]


def test_the_ray_engine_without_ray_is_one_line(tiny_model, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray fails, as where it is not installed
    result = sinrun("sample", tiny_model, "--seeds", "0-3", "--engine", "ray", "-o", tmp_path / "{seed}.ply")
    assert_one_line_error(result, "pip install 'sinshape[ray]'")
    assert not list(tmp_path.glob("*.ply"))


def test_a_world_size_sample_that_does_not_fit_is_refused(tmp_path):
    result = sinrun("sample", "terrain", "--size", "500,500,1", "-o", tmp_path / "big.ply")
    assert_one_line_error(result, "GiB")
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray", reason="the ray extra is not installed: pip install 'sinshape[ray]'")
    with many_workers.handler_kept(signal.SIGTERM):  # Ray's own would outlive the fixture
        ray.init(num_cpus=2, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    yield ray
    ray.shutdown()


def test_an_unreachable_ray_address_is_one_line(tiny_model, tmp_path):
    pytest.importorskip("ray", reason="the ray extra is not installed: pip install 'sinshape[ray]'")
    result = sinrun("sample", tiny_model, "--seeds", "0-3", "--engine", "ray", "--address", "127.0.0.1:1",
                    "-o", tmp_path / "{seed}.ply")
    assert_one_line_error(result, "cannot reach the Ray cluster at 127.0.0.1:1")
    assert not list(tmp_path.glob("*.ply"))


def test_ray_writes_the_sequential_bytes_and_resumes(local_ray, tiny_model, sequential, tmp_path):
    with pytest.raises(KeyboardInterrupt):
        many.sample_many(tiny_model, range(8), tmp_path / "{seed}.ply", engine="ray", scale=SCALE,
                         progress=interrupt_after(3))
    first = index_seeds(tmp_path)
    assert len(first) == 3 and not list(tmp_path.glob(".*"))  # no temporary file left
    result = many.sample_many(tiny_model, range(8), tmp_path / "{seed}.ply", engine="ray", scale=SCALE)
    assert result["skipped"] == 3 and result["written"] == 5
    assert sorted(index_seeds(tmp_path)) == list(range(8))  # every seed once: none redone
    assert_same_files(tmp_path, sequential, range(8))


def test_ray_refuses_more_workers_than_the_cluster_has_cpus(local_ray, tiny_model, tmp_path):
    result = sinrun("sample", tiny_model, "--seeds", "0-3", "--engine", "ray", "--workers", "3",
                    "-o", tmp_path / "{seed}.ply")
    assert_one_line_error(result, "--workers 3 of 1 thread each need 3 CPUs; the Ray cluster has 2")
    assert not list(tmp_path.glob("*.ply"))


def test_more_workers_than_cores_is_refused(tiny_model, tmp_path):
    result = sinrun("sample", tiny_model, "--seeds", "0-3", "--workers", "100000", "-o", tmp_path / "{seed}.ply")
    assert_one_line_error(result, "workers must be 1 to")
    assert not list(tmp_path.glob("*.ply"))


def test_outputs_already_there_are_checked_before_the_first_seed(tiny_model, tmp_path):
    (tmp_path / "s_3.ply").symlink_to(tiny_model)
    result = sinrun("sample", tiny_model, "--seeds", "2-3", "-o", tmp_path / "s_{seed}.ply")
    assert_one_line_error(result, "s_3.ply")
    assert not (tmp_path / "s_2.ply").exists() and tiny_model.read_bytes()[:4] != b"ply\n"


@pytest.mark.parametrize("seeds", ["0-99999999999999999999999", "9223372036854775806-9223372036854775809"])
def test_seed_ranges_past_2_63_are_refused_before_any_file(tiny_model, tmp_path, seeds):
    result = sinrun("sample", tiny_model, "--seeds", seeds, "-o", tmp_path / "{seed}.ply")
    assert result.exit_code == 2 and "Traceback" not in result.output  # click's usage error
    assert result.output.strip().splitlines()[-1].endswith("seeds are integers in [0, 2**63)")
    assert not list(tmp_path.glob("*.ply"))
