"""Going back when a level diverges.

A WGAN critic can blow up. A level that diverges goes back to a copy of its
networks and optimisers kept in memory, 20 to 40 iterations earlier (the
latest copy may already be on the way out), and goes on at half its rate;
the third time, the run stops with its last good checkpoint.
"""

import math

from sinshape.core.errors import NamesParameters

LOSS_LIMIT = 1e6  # a loss beyond this (or NaN) means training has diverged
KEEP_EVERY = 20
REWINDS = 2


class TrainingDiverged(NamesParameters, RuntimeError):
    """A level's losses exploded even at a quarter of its rate; the last
    good checkpoint is kept.
    `parameter`, as in InputError, names what the message suggests changing."""

    parameter = "seed"


class Rewinds:
    """One level's copies to go back to, and the going back."""

    def __init__(self, trainer, checkpoint_path, log):
        self.trainer, self.checkpoint_path, self.log = trainer, checkpoint_path, log
        self.kept = [trainer.keep()] * 2  # the older copy is the one to go back to

    def went_back(self, losses: dict) -> bool:
        """After an iteration: whether its losses diverged, and the level went
        back to the older copy at half its rate. Raises TrainingDiverged
        when the level has gone back REWINDS times already."""
        trainer, level = self.trainer, self.trainer.level
        bad = ", ".join(f"{k} loss {v:.3g}" for k, v in losses.items() if not math.isfinite(v) or abs(v) > LOSS_LIMIT)
        if not bad:
            return False
        if sum(r[0] == level for r in trainer.rewinds) == REWINDS:
            raise TrainingDiverged(
                f"training diverged at level {level + 1}, iteration {trainer.iteration + 1} ({bad}) "
                f"after {REWINDS} halvings of its learning rate; "
                f"the last good checkpoint is {self.checkpoint_path}; try another `seed`"
            )
        trainer.rewind(self.kept[0])
        self.kept = [self.kept[0]] * 2
        self.log(f"level {level + 1} diverged at iteration {trainer.rewinds[-1][1]} ({bad}); going on "
                 f"from iteration {trainer.iteration} at half the rate, {trainer.lrs[level]:.3g}")
        return True

    def counted(self) -> None:
        """After an iteration that counted: every KEEP_EVERY, a new copy."""
        if self.trainer.iteration % KEEP_EVERY == 0:
            self.kept = [self.kept[1], self.trainer.keep()]
