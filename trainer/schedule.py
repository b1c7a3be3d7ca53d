"""A time budget turned into iterations per level, kept to as training runs.

Every level gets the same number of iterations, as in the paper, planned
from the seconds per iteration measured before training, warm, and apart
from what a level's start costs (its set-up and its first iteration, which
allocates and picks kernels). Measuring is kept to a small share of the
budget: the coarse levels are measured, and the large ones, whose
measurement alone could take minutes, are estimated from them (an
iteration's cost grows linearly with the work a level holds, `level_work`)
and re-estimated from each level that has trained. Each level re-plans what
is left when it starts, with the costs scaled by how fast the machine has
actually been since (the drift). A level that runs
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

from .memory import level_extent

# Seconds a budget may spend measuring the levels before training: this
# share of it, and at least MEASURING_SECONDS. Levels beyond it are estimated.
MEASURING_SHARE = 0.02
MEASURING_SECONDS = 20.0
# A plane cell costs about as much as this many voxels in an iteration
# (fitted to the whole-grid and boxed costs in docs/BENCHMARKS.md, "Training").
PLANE_CELL_WORK = 4
# Iterations per level below which real shapes lose most of their quality
# (docs/EVALUATION.md, "What a budget gives on real shapes").
ENOUGH_ITERATIONS = 300


def level_work(size, box: int | None) -> int:
    """What an iteration at a level of `size` processes, in voxels: the
    voxels decoded and judged (a box's, with boxes) and the planes' cells."""
    seen, cells = level_extent(size, box)
    return seen + PLANE_CELL_WORK * cells


def measuring_allowance(seconds: float) -> float:
    """Seconds a budget of `seconds` may spend measuring levels."""
    return max(MEASURING_SECONDS, MEASURING_SHARE * seconds)


def extrapolated(work: int, known: list) -> float:
    """Seconds per iteration of a level holding `work`, from (work, seconds)
    of levels measured: the line through the two largest (at least 2 known),
    never cheaper than the largest; where that line falls, proportional to it."""
    (w1, c1), (w2, c2) = sorted(known)[-2:]
    slope = (c2 - c1) / (w2 - w1) if w2 > w1 else 0.0
    if slope <= 0:
        slope = c2 / w2
    return max(c2, c2 + slope * (work - w2))


class Budget:
    RESERVE = 2.0  # seconds kept for the export and the last checkpoint

    def __init__(self, seconds: float, clock_started: float, costs: list, startups: list, min_iters: int = 1,
                 works: list | None = None):
        self.started, self.deadline = clock_started, clock_started + seconds
        self.costs = list(costs)  # seconds per (warm) iteration, per level: measured or estimated
        self.startups = list(startups)  # seconds a level's start adds, per level
        self.min_iters = min_iters
        self.steady = {}  # level -> [seconds, iterations] of its iterations after the first, this run
        self.first = {}  # level -> seconds of its first iteration in this run
        self.planned = [None] * len(costs)  # the count each level was given when it started
        # Each level's work (level_work), given where the finest costs are estimates.
        self.works = works
        self.estimated = [False] * len(costs) if works is None else [c is None for c in costs]
        if works is not None:
            self.reestimate()
        # What the plan began from, for the record.
        self.planned_costs = list(self.costs)
        self.estimated_levels = [level for level, guessed in enumerate(self.estimated) if guessed]

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
        A level whose cost was estimated counts once it has trained and
        `reestimate` has made its cost a measured one.
        """
        measured = {level: record for level, record in self.steady.items() if not self.estimated[level]}
        spent = sum(seconds for seconds, _ in measured.values())
        predicted = sum(count * self.costs[level] for level, (_, count) in measured.items())
        return spent / predicted if predicted > 0 else 1.0

    def reestimate(self) -> None:
        """Turn each estimated level that has trained into a measured one (its
        own pace, less the drift) and estimate the rest again from the
        largest measured levels; their start-ups scale with their work."""
        drift = self.drift()
        for level, (seconds, count) in self.steady.items():
            if self.estimated[level]:
                self.costs[level], self.estimated[level] = seconds / count / drift, False
        measured = [level for level, e in enumerate(self.estimated) if not e]
        known = [(self.works[level], self.costs[level]) for level in measured]
        largest = max(measured, key=lambda level: self.works[level])
        for level, work in enumerate(self.works):
            if self.estimated[level]:
                self.costs[level] = extrapolated(work, known)
                self.startups[level] = self.startups[largest] * work / self.works[largest]

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
        options = [f"`minutes` {self.minutes_for(self.min_iters):g} gives {self.min_iters} iterations per level"]
        if from_mesh:
            for levels in range(len(sizes) - 1, 0, -1):  # drop the finest levels until it fits
                if self.affordable(0, levels) >= self.min_iters:
                    options.append(f"`res` {max(sizes[levels - 1])} (about {levels} levels) fits")
                    break
        if count >= 1:
            options.append(f"`min_iters` {count} trains with the {count} that fit")
        raise InputError(f"the time budget gives {count} iterations per level (all {len(sizes)} levels take "
                         f"{self.per_round()}), fewer than the minimum of {self.min_iters}; "
                         + "; ".join(options), ("minutes", "res", "min_iters"))

    def minutes_for(self, iterations: int) -> float:
        """The budget, in minutes rounded up to a tenth, that gives every
        level `iterations` (a run that has not started a level yet)."""
        needed = (time.monotonic() - self.started + self.RESERVE + sum(self.startups)
                  + iterations * sum(self.costs))
        return math.ceil(needed / 6) / 10

    def per_round(self) -> str:
        """An iteration of every level, in seconds, saying which are estimates."""
        guessed = sum(self.estimated)
        return (f"about {sum(self.costs):.1f} s per iteration here, the largest {guessed} estimated from the "
                "smaller" if guessed else f"{sum(self.costs):.1f} s per iteration here")

    def start_level(self, level: int) -> int:
        """The iteration count of a level that is starting (at least 1)."""
        if self.works is not None:
            self.reestimate()
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
        costs = ", ".join(("~" if e else "") + f"{c:.2f}" for c, e in zip(self.costs, self.estimated))
        note = " (~ estimated, refined as training runs)" if any(self.estimated) else ""
        return (f"plan: {self.affordable(first_level)} iterations per level for levels {first_level + 1}-"
                f"{len(self.costs)} in {self.left() / 60:.1f} min; s/iteration per level: {costs}{note}")

    def shortfall(self) -> str | None:
        """Before the first level: a warning if the plan gives fewer than
        ENOUGH_ITERATIONS per level, with the budget that would give them."""
        count = self.affordable(0)
        if count >= ENOUGH_ITERATIONS:
            return None
        return (f"{count} iterations per level is short of the {ENOUGH_ITERATIONS} below which real shapes "
                f"lose most of their quality; minutes {self.minutes_for(ENOUGH_ITERATIONS):g} would give them")

    def record(self) -> dict:
        """What a model records of its plan: each level's count as it started, and the measured costs."""
        return {"planned_iterations": self.planned,
                "measured_seconds_per_iteration": [round(c, 4) for c in self.planned_costs],
                "estimated_levels": self.estimated_levels}


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
