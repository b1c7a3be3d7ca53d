"""An exponential moving average of the weights a level trains.

A GAN's generator weights jump around the point they circle; their running
average is a steadier generator than the last step's (Yazici et al. 2019,
"The Unusual Effectiveness of Averaging in GAN Training"). The average
spans a share of the level's planned iterations, so a short level averages
over few iterations and a long one over many. When the level ends, the
average replaces the trained weights: later levels build on it and export
writes it.
"""

import torch


class WeightAverage:
    """The running average of `params` (updated once per iteration)."""

    def __init__(self, params: list, iterations: int, share: float):
        self.params = list(params)
        self.average = [p.detach().clone() for p in self.params]
        self.horizon = max(share * iterations, 1.0)  # iterations an update's weight decays over
        self.count = 0

    @torch.no_grad()
    def update(self) -> None:
        """Fold in the current weights. Until `horizon` updates, each weighs
        1/count (the plain mean of all so far), so the average never leans on
        the untrained start; after, each weighs 1/horizon."""
        self.count += 1
        weight = max(1.0 / self.count, 1.0 / self.horizon)
        torch._foreach_lerp_(self.average, [p.detach() for p in self.params], weight)

    @torch.no_grad()
    def apply(self) -> None:
        """Put the average into the trained weights."""
        for param, average in zip(self.params, self.average):
            param.copy_(average)

    def state(self) -> dict:
        return {"average": [a.clone() for a in self.average], "count": self.count}

    def restore(self, state: dict) -> None:
        for average, saved in zip(self.average, state["average"]):
            average.copy_(saved)
        self.count = state["count"]
