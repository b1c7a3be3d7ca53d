"""A time budget turned into iterations per level, kept to as training runs.

Every level gets the same number of iterations, as in the paper, planned
from the seconds per iteration measured at every level before training,
warm, and apart from what a level's start costs (its set-up and its first
iteration, which allocates and picks kernels). Each level
re-plans what is left when it starts, with the measured costs scaled by how
fast the machine has actually been since (the drift). A level that runs
slower than planned stops at the end of its share of the time, and the last
level runs to the deadline at its own pace, so the run ends within an
iteration of the budget on a machine that slows down or speeds up.

Before the first level, a budget that cannot give every level `min_iters`
iterations is refused, with what would fit; once training has begun, every
level gets at least one iteration and training always ends with a model.

The clock is `time.monotonic`, read through this module, so tests can run a
budget on a simulated clock.
"""

import math
import time

from sinshape.core.errors import InputError


class Budget:
    RESERVE = 2.0  # seconds kept for the export and the last checkpoint

    def __init__(self, seconds: float, clock_started: float, costs: list, startups: list, min_iters: int = 1):
        self.started, self.deadline = clock_started, clock_started + seconds
        self.costs = list(costs)  # measured seconds per (warm) iteration, per level
        self.startups = list(startups)  # measured seconds a level's start adds, per level
        self.min_iters = min_iters
        self.steady = {}  # level -> [seconds, iterations] of its iterations after the first, this run
        self.first = {}  # level -> seconds of its first iteration in this run
        self.planned = [None] * len(costs)  # the count each level was given when it started

    def left(self) -> float:
        """Seconds left for training (the reserve already kept back)."""
        return self.deadline - time.monotonic() - self.RESERVE

    def drift(self) -> float:
        """How much slower (> 1) or faster the machine runs than measured.

        The iterations done so far over what their measured costs predicted,
        leaving out each level's first iteration (it allocates and picks
        kernels) and the work between iterations (a level's set-up, the
        checkpoints). Summed over levels, so the largest level finished weighs
        most: a small level's start-up never sets the pace of the large ones.
        """
        spent = sum(seconds for seconds, _ in self.steady.values())
        predicted = sum(count * self.costs[level] for level, (_, count) in self.steady.items())
        return spent / predicted if predicted > 0 else 1.0

    def observe(self, level: int, iteration: int, seconds: float) -> None:
        """Record that iteration number `iteration` (from 1) of `level` took `seconds`."""
        if iteration == 1:
            self.first[level] = seconds
        else:
            record = self.steady.setdefault(level, [0.0, 0])
            record[0] += seconds
            record[1] += 1

    def affordable(self, level: int, levels: int | None = None) -> int:
        """Iterations per level that the time left buys levels `level` on
        (or levels `level` to `levels` - 1), which are still to start."""
        levels = len(self.costs) if levels is None else levels
        drift = self.drift()
        left = self.left() - drift * sum(self.startups[level:levels])
        return math.floor(max(left, 0.0) / (drift * sum(self.costs[level:levels])))

    def refuse_if_too_small(self, sizes: list, from_mesh: bool) -> None:
        """Before training: refuse a budget that gives fewer than `min_iters`
        iterations per level, naming what would fit by the parameters that
        set it, each once (a front end writes them its own way)."""
        count = self.affordable(0)
        if count >= self.min_iters:
            return
        per_round = sum(self.costs)
        needed = time.monotonic() - self.started + self.RESERVE + sum(self.startups) + self.min_iters * per_round
        options = [f"minutes {math.ceil(needed / 6) / 10:g} gives {self.min_iters} iterations per level"]
        if from_mesh:
            for levels in range(len(sizes) - 1, 0, -1):  # drop the finest levels until it fits
                if self.affordable(0, levels) >= self.min_iters:
                    options.append(f"res {max(sizes[levels - 1])} (about {levels} levels) fits")
                    break
        if count >= 1:
            options.append(f"min_iters {count} trains with the {count} that fit")
        raise InputError(f"the time budget gives {count} iterations per level (all {len(sizes)} levels take "
                         f"{per_round:.1f} s per iteration here), fewer than the minimum of {self.min_iters}; "
                         + "; ".join(options), ("minutes", "res", "min_iters"))

    def start_level(self, level: int) -> int:
        """The iteration count of a level that is starting (at least 1)."""
        count = max(1, self.affordable(level))
        self.planned[level] = count
        return count

    def level_end(self, level: int, count: int) -> float:
        """When a level that is starting with `count` iterations to go should
        be done: its share of the time left, at the current drift. The last
        level has all that is left."""
        if level == len(self.costs) - 1:
            return self.deadline - self.RESERVE
        return time.monotonic() + self.drift() * (self.startups[level] + count * self.costs[level])

    def pace(self, level: int) -> float:
        """Seconds the next iteration of `level` should take: its own pace so
        far in this run; after one iteration, that one less the level's
        start-up; before any, its measured cost at the current drift."""
        drift = self.drift()
        if level in self.steady:
            seconds, count = self.steady[level]
            return seconds / count
        if level in self.first:
            return max(self.first[level] - drift * self.startups[level], drift * self.costs[level])
        return drift * self.costs[level]

    def another_fits(self, level: int, end: float) -> bool:
        """Whether one more iteration of `level` ends by `end`. A level stops
        when the next would not, and the last one goes on while it does: it
        uses what the others left instead of ending early on a pessimistic plan."""
        return time.monotonic() + self.pace(level) <= end

    def describe(self, first_level: int) -> str:
        costs = ", ".join(f"{c:.2f}" for c in self.costs)
        return (f"plan: {self.affordable(first_level)} iterations per level for levels {first_level + 1}-"
                f"{len(self.costs)} in {self.left() / 60:.1f} min; measured s/iteration per level: {costs}")

    def record(self) -> dict:
        """What a model records of its plan: each level's count as it started, and the measured costs."""
        return {"planned_iterations": self.planned,
                "measured_seconds_per_iteration": [round(c, 4) for c in self.costs]}


class LevelPlan:
    """How long one level runs: its planned iterations; under a budget, also
    until the next iteration would overrun the level's share of the time,
    and at the last level, on while iterations still fit the budget."""

    def __init__(self, budget: Budget | None, level: int, iters: int, done: int):
        self.budget, self.level, self.iters = budget, level, iters
        self.end = budget.level_end(level, iters - done) if budget else math.inf
        self.last = budget is not None and level == len(budget.costs) - 1
        self.count = 0  # iterations in this run of the level (its first one allocates)
        self.cut = False  # whether the budget ended the level before its plan did

    def goes_on(self, iteration: int) -> bool:
        """Whether the level runs another iteration after `iteration`."""
        if iteration >= self.iters and not (self.last and self.fits()):
            return False
        self.cut = self.budget is not None and iteration > 0 and not self.fits()  # slower than planned
        return not self.cut

    def fits(self) -> bool:
        """Whether one more iteration ends by the level's end."""
        return self.budget.another_fits(self.level, self.end)

    def observe(self, seconds: float) -> None:
        """An iteration that counted took `seconds`."""
        self.count += 1
        if self.budget:
            self.budget.observe(self.level, self.count, seconds)
