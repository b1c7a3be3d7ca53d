"""A time budget (`--minutes`) is a promise: planned from what the machine
really does, kept on a busy machine, refused up front when too small, and
always ending with a model once training has begun.

Training runs for real on a tiny pyramid, but on a simulated clock that
advances only by what each iteration is said to cost, so every case is exact
and takes a second, whatever the machine is doing.
"""

import math

import pytest

torch = pytest.importorskip("torch")

from sinshape.cli.main import command_line_message  # noqa: E402
from sinshape.core.errors import InputError  # noqa: E402
from sinshape.trainer import schedule, train  # noqa: E402
from sinshape.trainer.config import make_config  # noqa: E402

from conftest import write_pyramid  # noqa: E402

COSTS = [0.5, 1.0, 4.0]  # simulated seconds per iteration of the three levels


@pytest.fixture(scope="module")
def three_levels(tmp_path_factory):
    return write_pyramid(tmp_path_factory.mktemp("data") / "three.h5", [(15, 15, 15), (17, 16, 15), (20, 18, 15)])


class SimulatedMachine:
    """The clock `train` and `schedule` read, moved on by every iteration:
    COSTS[level] times the machine's load, plus `startup` for the first
    iteration of each level of each trainer (the measurement's too)."""

    def __init__(self, monkeypatch, startup=0.0):
        self.now, self.startup = 1000.0, startup
        self.loads = self.loads_after_measuring = [1.0] * len(COSTS)  # per level
        self.started = set()
        monkeypatch.setattr(train.time, "monotonic", lambda: self.now)  # one module: schedule's clock too
        real_iterate, real_time_levels = train.Trainer.iterate, train.time_levels

        def iterate(trainer, recon_inputs):
            losses = real_iterate(trainer, recon_inputs)
            first = (id(trainer), trainer.level) not in self.started
            self.started.add((id(trainer), trainer.level))
            self.now += self.loads[trainer.level] * COSTS[trainer.level] + (self.startup if first else 0.0)
            return losses

        def time_levels(*args, **kwargs):
            measured = real_time_levels(*args, **kwargs)
            self.loads = self.loads_after_measuring  # the machine gets busy once training starts
            return measured

        monkeypatch.setattr(train.Trainer, "iterate", iterate)
        monkeypatch.setattr(train, "time_levels", time_levels)

    def train(self, pyramid, out, **config):
        """Train; returns the manifest and the simulated seconds it took."""
        started = self.now
        manifest = train.train(pyramid, out, make_config("tiny", levels=3, **config), log=self.log.append)
        return manifest, self.now - started

    log: list


@pytest.fixture
def machine(monkeypatch):
    machine = SimulatedMachine(monkeypatch)
    machine.log = []
    return machine


def test_measured_costs_leave_out_start_up(machine, three_levels, tmp_path):
    machine.startup = 7.0
    costs, startups = train.time_levels(make_config("tiny", levels=3), train.load_pyramid(three_levels, 32),
                                        train.devices.choose("cpu", "fp32"))
    assert costs == pytest.approx(COSTS)
    assert startups == pytest.approx([7.0] * 3)


def test_a_slow_first_iteration_does_not_starve_the_levels_after_it(machine, three_levels, tmp_path):
    """Every level's first iteration takes 20 s more (allocation, kernel
    choice): planned as a start-up, not read as a machine three times slower."""
    machine.startup = 20.0
    manifest, took = machine.train(three_levels, tmp_path / "m.onnx", minutes=3)
    done = manifest["training"]["iterations_per_level"]
    planned = manifest["training"]["planned_iterations"]
    # (180 s - measuring 4 x 5.5 + 3 x 20 s - reserve 2 s - start-ups 60 s) / 5.5 s per round
    assert planned[0] == 6
    assert planned[1] == planned[0] and done[:2] == planned[:2]
    assert done[2] >= planned[2]  # the last level uses what is left
    assert took == pytest.approx(180, rel=0.05)


def test_a_busy_machine_gives_fewer_iterations_not_a_failure(machine, three_levels, tmp_path):
    machine.loads_after_measuring = [3.0] * 3  # three times slower than measured, from the first level on
    out = tmp_path / "m.onnx"
    manifest, took = machine.train(three_levels, out, minutes=2)
    assert out.is_file()
    done = manifest["training"]["iterations_per_level"]
    first_plan = math.floor((120 - 4 * 5.5 - schedule.Budget.RESERVE) / sum(COSTS))  # 17, from the measurement
    assert all(1 <= n < first_plan for n in done)
    assert took == pytest.approx(120, rel=0.05)
    assert took <= 120


def test_a_machine_that_slows_down_mid_run_still_ends_with_a_model(machine, three_levels, tmp_path):
    """Ten times slower once the first level is done: the later levels get
    what time there is (at least one iteration each), never an error, and
    the last one starts no iteration that would end past the budget."""
    machine.loads_after_measuring = [1.0, 10.0, 10.0]
    out = tmp_path / "m.onnx"
    manifest, took = machine.train(three_levels, out, minutes=2)
    assert out.is_file()
    done = manifest["training"]["iterations_per_level"]
    assert done[0] == 17 and 1 <= done[1] < 17 and done[2] >= 1
    assert took <= 120


def test_a_budget_too_small_is_refused_before_training(machine, three_levels, tmp_path):
    out = tmp_path / "m.onnx"
    with pytest.raises(InputError) as refused:
        machine.train(three_levels, out, minutes=0.6, min_iters=5)
    message = str(refused.value)
    # (36 s - measuring 4 x 5.5 s - reserve 2 s) / 5.5 s per round: 2 iterations
    assert "gives 2 iterations per level" in message
    assert "minutes 0.9 gives 5 iterations per level" in message  # 22 + 2 + 5 x 5.5 = 51.5 s
    assert "min_iters 2 trains with the 2 that fit" in message
    assert "--" not in message  # the library names parameters; the command line writes options
    assert not out.exists() and not train.default_checkpoint_path(out).exists()
    assert not any(line.startswith("level ") for line in machine.log)
    # The same budget with the minimum lowered trains.
    manifest, _ = machine.train(three_levels, out, minutes=0.6, min_iters=2)
    assert manifest["training"]["planned_iterations"][0] == 2


def test_a_budget_far_too_small_is_refused_after_the_first_level_is_measured(machine, three_levels, tmp_path):
    """--minutes 0.05 was refused only after every level was measured (36 s
    on a 2-core machine); the first level's cost already rules it out."""
    out = tmp_path / "m.onnx"
    with pytest.raises(InputError, match="cannot give 5 iterations to each of 3 levels"):
        machine.train(three_levels, out, minutes=0.05, min_iters=5)
    assert {level for _, level in machine.started} == {0}  # levels 1 and 2 were never run
    assert not out.exists()


def test_a_too_small_budget_for_a_mesh_names_a_resolution_that_fits():
    # 98 s for 5.5 s per round of all levels gives 17; without the finest, 65.
    budget = schedule.Budget(100.0, train.time.monotonic(), [0.5, 1.0, 4.0], [0.0] * 3, min_iters=20)
    with pytest.raises(InputError, match=r"gives 17 iterations.*; res 31 \(about 2 levels\) fits") as refused:
        budget.refuse_if_too_small([(15, 15, 15), (31, 20, 20), (64, 40, 40)], from_mesh=True)
    assert "; --res 31 (about 2 levels) fits" in command_line_message(refused.value)
    with pytest.raises(InputError) as refused:
        budget.refuse_if_too_small([(15, 15, 15), (31, 20, 20), (64, 40, 40)], from_mesh=False)
    assert " res " not in str(refused.value)  # an .h5 pyramid has its resolution


def test_the_command_line_writes_the_refusal_in_options(machine, three_levels, tmp_path):
    from click.testing import CliRunner

    from sinshape.cli.main import cli

    result = CliRunner().invoke(cli, ["train", str(three_levels), "-o", str(tmp_path / "m.onnx"), "--preset", "tiny",
                                      "--levels", "3", "--minutes", "0.6", "--min-iters", "5", "--quiet"])
    assert result.exit_code == 1
    assert "; --minutes 0.9 gives 5 iterations per level; --min-iters 2 trains with the 2 that fit" in result.output


def test_the_plan_and_what_was_done_are_in_the_model(machine, three_levels, tmp_path):
    out = tmp_path / "m.onnx"
    manifest, _ = machine.train(three_levels, out, minutes=1, lr_total=1.0, lr_max=1.0)
    training = manifest["training"]
    assert training["measured_seconds_per_iteration"] == pytest.approx(COSTS, abs=1e-3)
    assert len(training["planned_iterations"]) == 3
    # each level's rate comes from the count it was planned when it started
    assert training["learning_rates"] == pytest.approx([1 / n for n in training["planned_iterations"]])
    assert list(manifest["config"]["level_iters"]) == training["iterations_per_level"]
    from click.testing import CliRunner

    from sinshape.cli.main import cli

    shown = CliRunner().invoke(cli, ["info", str(out)]).output
    assert f"planned {training['planned_iterations']}" in shown
    assert "budget      1 min" in shown
    assert f"  {1 / training['planned_iterations'][2]:<14.3g}  " in shown  # the last level's rate
