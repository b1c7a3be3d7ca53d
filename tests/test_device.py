"""Where training runs: device and precision choice, and CUDA end to end.

The CUDA tests are marked `cuda` and skipped, visibly, where torch sees no GPU.
"""

import subprocess
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from click.testing import CliRunner  # noqa: E402

from sinshape.cli.main import cli, command_line_message  # noqa: E402
from sinshape.runtime import generate, load, query  # noqa: E402
from sinshape.core.errors import InputError  # noqa: E402
from sinshape.trainer import checkpoint, device, train  # noqa: E402
from sinshape.trainer.config import make_config  # noqa: E402

HAS_CUDA = torch.cuda.is_available()
cuda = pytest.mark.skipif(not HAS_CUDA, reason="torch sees no CUDA GPU")


def test_auto_picks_what_this_machine_has_and_says_why():
    placement = device.choose()
    assert placement.device.type == ("cuda" if HAS_CUDA else "cpu")
    assert placement.reason.startswith("auto: ")
    if not HAS_CUDA:
        assert placement.precision == ("bf16" if device.native_bf16() else "fp32")
    assert device.choose("cpu", "fp32").precision == "fp32"


def test_cpu_precision_follows_native_bf16(monkeypatch):
    monkeypatch.setattr(device, "native_bf16", lambda: True)
    assert device.choose("cpu").precision == "bf16"
    monkeypatch.setattr(device, "native_bf16", lambda: False)
    assert device.choose("cpu").precision == "fp32"
    with pytest.raises(InputError, match="no native bf16") as refused:
        device.choose("cpu", "bf16")
    assert command_line_message(refused.value).endswith("; use --precision fp32 or auto")


@pytest.mark.parametrize("name", ["tpu", "cuda:x", "", "cpu:0:1"])
def test_unknown_devices_are_refused(name):
    with pytest.raises(InputError, match="device must be one of"):
        device.choose(name)


@pytest.mark.skipif(HAS_CUDA, reason="this checks the refusal where there is no GPU")
def test_cuda_without_a_gpu_is_one_line_and_leaves_nothing(tmp_path, tiny_pyramid):
    out = tmp_path / "m.onnx"
    result = CliRunner().invoke(cli, ["train", str(tiny_pyramid), "-o", str(out), "--preset", "tiny",
                                      "--device", "cuda"])
    assert result.exit_code == 1
    assert result.output.strip().count("\n") == 0 and "sees no CUDA GPU" in result.output
    assert list(tmp_path.iterdir()) == []


def test_train_help_says_what_auto_picks():
    result = CliRunner().invoke(cli, ["train", "--help"])
    assert result.exit_code == 0
    picked = device.choose()
    assert f"picks {picked.device} ({picked.precision})" in " ".join(result.output.split())


def test_bf16_autocast_runs_the_convolutions_in_bf16_and_keeps_the_decoder_in_float32():
    placement = device.Placement(torch.device("cpu"), "bf16", "test")
    from sinshape.trainer import networks

    gen = networks.TriplaneGenerator(8, 4, 8)
    gen.add_level()
    planes = gen.projection(torch.randn(1, 1, 15, 15, 16))
    with placement.autocast():
        features = gen.levels[0](planes)
        occupancy = gen.decoder.grid(features)
        scores = networks.Discriminator(8)(occupancy[:, None])
    assert features[0].dtype == torch.bfloat16
    assert occupancy.dtype == scores.dtype == torch.float32
    reference = gen.decoder.grid([f.float() for f in features])  # the decoder outside autocast
    torch.testing.assert_close(occupancy, reference)


def test_bf16_steps_see_the_weights_the_optimiser_just_changed():
    """Autocast's weight cache would keep the first bf16 copy of each weight
    for the whole context; training updates weights inside it."""
    from sinshape.trainer import networks

    placement = device.Placement(torch.device("cpu"), "bf16", "test")
    critic = networks.Discriminator(8)
    volume = torch.rand(2, 1, 20, 16, 16)
    optimiser = torch.optim.SGD(critic.parameters(), lr=0.1)
    with placement.autocast():
        before = critic(volume)
        before.mean().backward()
        optimiser.step()
        after = critic(volume)
    fresh = critic(volume)  # outside autocast: float32 with the new weights
    assert (after - before).abs().max() > 1e-3
    torch.testing.assert_close(after, fresh, rtol=0.05, atol=0.05)


def train_tiny(path, tiny_pyramid, **options):
    return train.train(tiny_pyramid, path, make_config("tiny", iters=2), **options)


def assert_runtime_matches_torch(model_path):
    """The exported model samples what the checkpoint's torch generator does."""
    generator, sizes, amps = checkpoint.load_generator(train.default_checkpoint_path(model_path))
    model = load.load_model(model_path)
    sample = generate.reconstruction_noise(model, sizes)
    ours = query.dense(model, generate.triplane(model, sample, sizes), 1.0)
    with torch.no_grad():
        reference = generator(torch.from_numpy(sample.z0)[None, None], [None] * len(sizes), sizes)[0]
    assert np.abs(ours - reference.numpy()).max() < 1e-4


@pytest.mark.cuda
@cuda
def test_cuda_trains_exports_and_matches_the_runtime(tmp_path, tiny_pyramid):
    manifest = train_tiny(tmp_path / "gpu.onnx", tiny_pyramid, device="cuda")
    assert manifest["training"]["device"] == "cuda" and manifest["training"]["precision"] == "tf32"
    assert_runtime_matches_torch(tmp_path / "gpu.onnx")


@pytest.mark.cuda
@cuda
@pytest.mark.parametrize("first, then", [("cuda", "cpu"), ("cpu", "cuda")])
def test_a_checkpoint_resumes_on_the_other_device(tmp_path, tiny_pyramid, first, then):
    out = tmp_path / "m.onnx"

    def stop_at_level_1(p):
        if p.level == 1:
            raise KeyboardInterrupt

    with pytest.raises(train.Interrupted):
        train_tiny(out, tiny_pyramid, device=first, progress=stop_at_level_1)
    manifest = train.train(tiny_pyramid, out, None, resume=True, device=then)
    assert manifest["training"]["device"] == then
    assert_runtime_matches_torch(out)


FAULTS_SCRIPT = """
import ctypes, ctypes.util, resource, torch
from sinshape.trainer import device

def faults_per_step():
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(4):  # a step's worth of 4 MB tensors, allocated, used and freed together
        tensors = [torch.ones(1 << 20) for _ in range(30)]
        del tensors
    return (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 4

# glibc's own threshold moves with what was freed before; start from its
# initial 128 kB, where 4 MB blocks are always mapped and unmapped.
ctypes.CDLL(ctypes.util.find_library("c")).mallopt(device.M_MMAP_THRESHOLD, 128 << 10)
default = faults_per_step()
kept = device.keep_freed_memory()
faults_per_step()
print(kept, default, faults_per_step())
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_training_keeps_freed_memory_instead_of_faulting_it_in_again():
    """120 MB freed and allocated again: glibc returning it to the OS, every
    round page-faults it back (30,000 faults); kept, it is reused."""
    result = subprocess.run([sys.executable, "-c", FAULTS_SCRIPT], capture_output=True, text=True, check=True)
    kept, default, tuned = result.stdout.split()
    assert kept == "True"
    assert float(default) > 10_000 and float(tuned) < 1_000


def test_cudnn_autotunes_only_where_shapes_stay_fixed(monkeypatch):
    """Boxes clipped at the grid's edge change shape: the autotuner would
    time every kernel again for each new one (5.5 s an iteration on an H100)."""
    for name in ("benchmark", "allow_tf32"):  # restored after the test (the matmul switch acts only on a GPU)
        monkeypatch.setattr(torch.backends.cudnn, name, getattr(torch.backends.cudnn, name))
    placement = device.Placement(torch.device("cuda"), "tf32", "a flag test: sets switches, runs nothing")
    placement.activate()
    assert torch.backends.cudnn.benchmark
    placement.activate(shapes_vary=True)
    assert not torch.backends.cudnn.benchmark


@pytest.mark.parametrize("box, varies", [(0, False), (16, True)])
def test_training_tells_the_placement_whether_shapes_vary(tmp_path, tiny_pyramid, monkeypatch, box, varies):
    seen = []
    monkeypatch.setattr(device.Placement, "activate", lambda self, shapes_vary=False: seen.append(shapes_vary))
    train.train(tiny_pyramid, tmp_path / "m.onnx", make_config("tiny", iters=1, box=box), device="cpu")
    assert seen == [varies]
