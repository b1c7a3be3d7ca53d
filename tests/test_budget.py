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
        self.now, self.startup, self.costs = 1000.0, startup, COSTS
        self.loads = self.loads_after_measuring = [1.0] * len(COSTS)  # per level
        self.started = set()
        monkeypatch.setattr(train.time, "monotonic", lambda: self.now)  # one module: schedule's clock too
        # Every level is measured (as when a budget is large beside them);
        # the tests of estimated levels lower it.
        monkeypatch.setattr(schedule, "MEASURING_SECONDS", 1e9)
        real_iterate, real_time_levels = train.Trainer.iterate, train.time_levels

        def iterate(trainer, recon_inputs):
            losses = real_iterate(trainer, recon_inputs)
            first = (id(trainer), trainer.level) not in self.started
            self.started.add((id(trainer), trainer.level))
            self.now += self.loads[trainer.level] * self.costs[trainer.level] + (self.startup if first else 0.0)
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
                                        train.devices.choose("cpu", "fp32"), seconds=6000)
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
    assert f"  {training['iterations_per_level'][1]:<11}  " in shown  # what a level got
    assert f"  {1 / training['planned_iterations'][2]:<14.3g}  " in shown  # the last level's rate


def test_large_levels_are_estimated_from_the_small_ones_and_refused_in_seconds(machine, tmp_path, monkeypatch):
    """A finest level whose measurement alone would take minutes is not
    measured: its cost, estimated from the coarse levels (linear in the work
    a level holds), already shows the budget too small, within the seconds
    the coarse levels took."""
    monkeypatch.setattr(schedule, "MEASURING_SECONDS", 20.0)
    sizes = [(15, 15, 15), (17, 16, 15), (84, 84, 84)]
    pyramid = write_pyramid(tmp_path / "large.h5", sizes)
    machine.costs = [1e-4 * schedule.level_work(size, None) for size in sizes]  # 0.6, 0.7, 68 s
    started = machine.now
    with pytest.raises(InputError) as refused:
        machine.train(pyramid, tmp_path / "m.onnx", minutes=5, min_iters=5)
    assert {level for _, level in machine.started} == {0, 1}  # the 84^3 level never ran
    assert machine.now - started < 20
    message = str(refused.value)
    assert f"about {sum(machine.costs):.1f} s per iteration here, the largest 1 estimated from the smaller)" in message
    # 5 x 69.7 s + the 5.3 s spent measuring + the 2 s reserve: 5.9 min
    assert "minutes 5.9 gives 5 iterations per level" in message


def test_an_estimate_is_refined_by_each_level_that_trains(monkeypatch):
    """Levels 2 and 3 are estimated from levels 0 and 1; once level 2 has
    trained at its real pace, level 3 is estimated again from levels 1 and 2."""
    now = [0.0]
    monkeypatch.setattr(schedule.time, "monotonic", lambda: now[0])
    works = [100, 200, 400, 800]
    budget = schedule.Budget(1000.0, 0.0, [1.0, 2.0, None, None], [0.5, 0.5, None, None], works=works)
    assert budget.costs == pytest.approx([1.0, 2.0, 4.0, 8.0])  # the line through (100, 1) and (200, 2)
    assert budget.startups == pytest.approx([0.5, 0.5, 1.0, 2.0])  # scaled with the work
    assert budget.estimated_levels == [2, 3]
    assert "~4.00, ~8.00 (~ estimated, refined as training runs)" in budget.describe(0)
    for level, seconds in ((0, 1.0), (1, 2.0), (2, 7.0)):  # level 2 costs 7 s, not 4
        for iteration in (1, 2, 3):
            budget.observe(level, iteration, seconds)
    budget.start_level(3)
    assert budget.costs[2] == pytest.approx(7.0)
    assert budget.costs[3] == pytest.approx(7.0 + 5.0 / 200 * 400)  # the line through (200, 2) and (400, 7)
    assert budget.record()["measured_seconds_per_iteration"] == pytest.approx([1.0, 2.0, 4.0, 8.0])
    assert budget.record()["estimated_levels"] == [2, 3]


def test_a_short_plan_says_what_budget_reaches_enough_iterations(machine, three_levels, tmp_path):
    machine.train(three_levels, tmp_path / "m.onnx", minutes=2)
    warning = [line for line in machine.log if line.startswith("warning: ")]
    # 120 s gives 17 per level; 300 need 4 x 5.5 s measuring + 2 s reserve + 300 x 5.5 s = 1674 s
    assert warning == ["warning: 17 iterations per level is short of the 300 below which real shapes lose most "
                       "of their quality; minutes 27.9 would give them"]
    enough = schedule.Budget(300 * 5.5 + schedule.Budget.RESERVE, train.time.monotonic(), COSTS, [0.0] * 3)
    assert enough.affordable(0) == 300 and enough.shortfall() is None
