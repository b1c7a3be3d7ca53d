"""Bounded work: every command estimates its memory before it starts and
refuses, with the figure, what would not fit; lists stream; long work shows
progress (docs/RELIABILITY.md, "Bounded work")."""

import pytest
import trimesh

from sinshape.prep import pyramid, shapes
from sinshape.core import budget
from sinshape.runtime import mesh, render
from sinshape.core.errors import InputError, MemoryLimitError
from test_cli_sample import sinrun
from test_cli_train import assert_one_line_error


@pytest.fixture
def little_memory(monkeypatch):
    """The machine has 1 GiB available."""
    monkeypatch.setattr(budget, "available_memory", lambda: 1 << 30)


def test_the_refusal_gives_the_figure_and_the_limit():
    with pytest.raises(MemoryLimitError, match=r"^a thing needs about 2\.0 GiB of memory \(limit 1\.0 GiB\)$"):
        budget.check_memory(2 << 30, "a thing", 1 << 30)
    budget.check_memory(1 << 30, "a thing", 1 << 30)  # exactly the limit fits


def test_training_memory_grows_with_the_level_and_shrinks_with_a_box():
    pytest.importorskip("torch")
    from sinshape.trainer.config import make_config
    from sinshape.trainer.memory import level_memory

    config = make_config("default")
    small, large = level_memory((32, 32, 32), config), level_memory((64, 64, 64), config)
    assert 4 < (large - small) / (level_memory((48, 32, 32), config) - small) < 16  # voxels and plane cells
    # measured 454 and 1888 MiB whole, 706 MiB in boxes of 48 (benchmarks/train_speed.py)
    assert 400 << 20 < level_memory((72, 72, 72), config) < 520 << 20
    assert 1700 << 20 < level_memory((128, 128, 128), config) < 2200 << 20
    assert 600 << 20 < level_memory((128, 128, 128), make_config("default", box=48)) < 800 << 20
    assert level_memory((64, 64, 64), make_config("default", box=16)) < large
    assert level_memory((64, 64, 64), make_config("default", channels=64)) > 1.9 * large - (40 << 20)


@pytest.mark.parametrize("where", ["cpu", pytest.param("cuda", marks=pytest.mark.cuda)])
def test_train_refuses_a_pyramid_too_large_before_any_level_trains(tiny_pyramid, tmp_path, monkeypatch, where):
    """The limit is the memory available on the CPU, the GPU's free memory on CUDA."""
    torch = pytest.importorskip("torch")
    if where == "cuda":
        if not torch.cuda.is_available():
            pytest.skip("torch sees no CUDA GPU")
        monkeypatch.setattr(torch.cuda, "mem_get_info", lambda device=None: (10 << 20, 80 << 30))
    else:
        monkeypatch.setattr(budget, "available_memory", lambda: 10 << 20)
    out = tmp_path / "m.onnx"
    result = sinrun("train", tiny_pyramid, "-o", out, "--preset", "tiny", "--device", where)
    assert_one_line_error(result, "training a level of 20x18x15 voxels needs about", "(limit 0.0 GiB)")
    assert list(tmp_path.iterdir()) == []  # no model, no checkpoint


def test_voxelising_is_refused_before_it_starts_and_the_sizes_are_checked_first(tmp_path):
    path = tmp_path / "box.obj"
    trimesh.creation.box((2, 1, 1)).export(path)
    with pytest.raises(MemoryLimitError, match="voxelising a 100000x50000x50000 grid"):
        pyramid.load_pyramid(path, res=100000)
    seen = []
    with pytest.raises(MemoryLimitError, match="too large"):
        def refuse(sizes):
            seen.append(sizes)
            raise MemoryLimitError("too large")
        pyramid.load_pyramid(path, res=40, check=refuse)
    assert seen == [[(30, 15, 15), (40, 20, 20)]]  # every level's size, before any was voxelised


def test_shape_detail_is_bounded_by_memory_and_a_cap(tmp_path, little_memory):
    out = tmp_path / "t.ply"
    assert_one_line_error(sinrun("shape", "terrain", "--detail", 1000, "-o", out),
                          "a shape on a 1005x630x237 grid (its detail) needs about 8.", "(limit 1.0 GiB)")
    assert_one_line_error(sinrun("shape", "wall", "--detail", 10**9, "-o", out), "--detail must be in [2, 100000]")
    assert not out.exists()
    with pytest.raises(InputError) as refused:
        shapes.make_shape("stairs", detail=1)
    assert refused.value.parameter == "detail"


@pytest.mark.parametrize("options, fragment", [
    (["--image-size", "100000"], "picture has more than 178956970 pixels"),
    (["--views", "100000"], "a 32000000x320 picture"),
    (["--seeds", "0-100000000"], "picture has more than"),  # refused before any sample is drawn
    (["--recon", "--seeds", "0-100000000"], "picture has more than"),
    (["--image-size", "4500"], "picture needs about 5."),  # 1 GiB available: the figure, not 5.7 GB used
])
def test_render_refuses_pictures_that_would_not_fit(tiny_model, tmp_path, little_memory, options, fragment):
    out = tmp_path / "r.png"
    assert_one_line_error(sinrun("render", tiny_model, "--seeds", "1", "-o", out, *options)
                          if "--seeds" not in options else sinrun("render", tiny_model, "-o", out, *options),
                          fragment)
    assert not out.exists()


def test_picture_sizes_match_what_is_drawn_and_progress_counts_renders():
    box = trimesh.creation.box()
    calls = []
    grid = render.render_grid([box] * 3, ["a", "b", "c"], 2, (20, 20), progress=lambda: calls.append(1))
    assert render.picture_size(3, (20, 20), columns=2) == (grid.shape[1], grid.shape[0])
    views = render.render_views(box, (20, 20), ((0, 0), (90, 0)), progress=lambda: calls.append(1))
    assert render.picture_size(1, (20, 20), views=2) == (views.shape[1], views.shape[0])
    assert len(calls) == 5
    with pytest.raises(MemoryLimitError, match="a 40x20 picture"):
        render.check_picture(1, (20, 20), views=2, memory_limit=1000)


def test_interpolate_streams_its_steps(tiny_model, tmp_path, monkeypatch):
    """The most steps (10000): names and blend weights are made one at a
    time, so the command starts at once (here it stops after two files);
    more are refused, as they would run on for hours."""
    from sinshape.runtime import write

    written = []

    def two(model, outputs, progress=None, **options):
        for (path, _), _ in zip(outputs, range(2)):
            written.append(path.name)

    monkeypatch.setattr(write, "write_samples", two)
    result = sinrun("interpolate", tiny_model, "--seeds", 1, 2, "--steps", 10_000, "-o", tmp_path / "i.ply")
    assert result.exit_code == 0, result.output
    assert written == ["i_step00_alpha-0.50.ply", "i_step01_alpha-0.50.ply"]
    assert "i_step9999_alpha+1.50.ply" in result.output  # the last is exactly the end of the range
    result = sinrun("interpolate", tiny_model, "--seeds", 1, 2, "--steps", 1_000_000, "-o", tmp_path / "i.ply")
    assert result.exit_code == 2 and "1000000 is not in the range 1<=x<=10000" in result.output


def test_interpolate_blend_weights_span_the_range(tiny_model, tmp_path):
    result = sinrun("interpolate", tiny_model, "--seeds", 1, 2, "--steps", 3, "--range", 0, 1, "-o", tmp_path / "i.ply")
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["i_step00_alpha+0.00.ply", "i_step01_alpha+0.50.ply",
                                                          "i_step02_alpha+1.00.ply"]


def test_smoothing_is_bounded(tiny_model):
    from sinshape import runtime

    model = runtime.load_model(tiny_model)
    triplane = runtime.sample(model, 1)
    with pytest.raises(InputError, match="smooth must be 0 to 100") as refused:
        runtime.extract(model, triplane, smooth=mesh.MAX_SMOOTH + 1)
    assert refused.value.parameter == "smooth"


def test_a_long_sampling_run_says_how_long_first(tiny_model, tmp_path, monkeypatch):
    monkeypatch.setattr(mesh, "estimate_seconds", lambda model, triplane, scale: 300.0)
    result = sinrun("sample", tiny_model, "--seeds", "1-2", "--scale", 3, "-o", tmp_path / "s.ply")
    assert result.exit_code == 0, result.output
    assert "--scale 3: about 0:10:00 (h:mm:ss) for 2 samples" in result.output


def test_the_time_estimate_extrapolates_a_measured_run(tiny_model, monkeypatch):
    from sinshape import runtime

    model = runtime.load_model(tiny_model)
    triplane = runtime.sample(model, 1)
    scales = []
    monkeypatch.setattr(mesh, "pieces", lambda model, triplane, scale: scales.append(scale) or [])
    ticks = iter([10.0, 11.0])
    monkeypatch.setattr("time.perf_counter", lambda: next(ticks))
    assert mesh.estimate_seconds(model, triplane, 20) == pytest.approx(10**2.2)  # 1 s at scale 2, times 10^2.2
    assert scales == [2.0]
