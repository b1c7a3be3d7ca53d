"""How a model is trained: one frozen dataclass, the paper's values as defaults.

A config is built once (from a preset plus command-line overrides), saved
into the checkpoint and the exported model, and never mutated. Networks take
plain ints; only the run (`train` and the parts it calls) reads a config.
"""

import dataclasses
from dataclasses import dataclass

from sinshape.core.errors import ConflictError, InputError, named
from sinshape.prep.pyramid import LEVEL_FACTOR, MIN_SIZE


@dataclass(frozen=True)
class TrainConfig:
    # Data: the finest level's longest side in voxels, and the level count
    # (None: as many as bring the coarsest longest side to 33 or below).
    res: int = 128
    levels: int | None = None
    level_factor: float = LEVEL_FACTOR  # size[i-1] = ceil(size[i] * factor), per axis
    min_size: int = MIN_SIZE  # shorter axes are stretched to this (the D needs room)
    blur_sigma: float = 0.5  # Gaussian blur of the training targets

    # Networks (Wu & Zheng 2022): 32 channels everywhere, 8 pooling bins.
    # generator "voxel" is the paper's SinGAN-3D baseline (3-D convs on voxels).
    generator: str = "triplane"
    channels: int = 32
    pool_bins: int = 8
    mlp_hidden: int = 32

    # Optimisation, per level.
    iters: int = 2000
    d_steps: int = 3
    g_steps: int = 3
    d_rate: float = 1.0  # the critic's learning rate over the generator's
    lr: float = 1e-4
    # None keeps lr at every level, as the paper does. A number sets each
    # level's rate from the iterations it is given: lr_total / iterations,
    # between lr and lr_max. A short level learns fast; a long one slows down
    # before its generator learns to ignore the noise: a fixed 1e-3 over 700
    # iterations gave copies of the example, and so did 2e-4 over 1000 at res 64.
    lr_total: float | None = None
    lr_max: float = 1e-3
    beta1: float = 0.5
    beta2: float = 0.999
    # Levels trained at once (as ConSinGAN, and the authors' `train_depth`):
    # the newest at the level's rate, each older one at lr_scale times the
    # next. 1, one level at a time with the older ones frozen, is the paper's.
    train_depth: int = 1
    lr_scale: float = 0.1
    gp_weight: float = 0.1
    rec_weight: float = 10.0
    noise_ratio: float = 0.1  # sigma_i = noise_ratio * RMSE(upsampled rec_(i-1), real_i)

    # Speed. A time budget in minutes plans the iterations of every level to
    # fit it (`iters` is then unused) and records the plan in level_iters.
    minutes: float | None = None
    level_iters: tuple | None = None
    min_iters: int = 50  # a budget that gives fewer per level is refused before training
    # "auto": bf16 autocast on CPUs with native bf16, TF32 on CUDA, else fp32.
    precision: str = "auto"
    # Off (0) in the paper's method: at levels larger than this many voxels
    # per side, each step sees random boxes of at most this side instead of
    # the whole grid (the critic's field is 11): the critic compares the same
    # box of real and fake, the reconstruction is measured in another, and
    # only boxes are decoded, so an iteration costs what its boxes cost.
    box: int = 0

    # A coloured example's colour tiles (prep/appearance.py) stay within this
    # many MB: finer than the texture's own detail they never are, coarser
    # (halved sides) where they would pass it. The model's file grows by them.
    colour_mb: float = 48.0

    # Which axis of the input points up, recorded in the model for viewers
    # and pictures; None: the input's own (prep.pyramid.up_axis for .h5, y for a mesh).
    up: str | None = None

    # Randomness: the training run, and the fixed reconstruction noise z0*.
    seed: int = 0
    recon_seed: int = 1234

    def __post_init__(self):
        checks = [  # (fine, parameter, message): the command line writes the parameter as its option
            (self.res >= self.min_size, "res", f"`res` {self.res} is below the {self.min_size}-voxel minimum of every level"),
            (self.levels is None or self.levels >= 1, "levels", f"`levels` must be at least 1, got {self.levels}"),
            (self.generator in ("triplane", "voxel"), "generator",
             f"`generator` must be triplane or voxel, got {self.generator!r}"),
            (self.iters >= 1, "iters", f"`iters` must be at least 1, got {self.iters}"),
            (self.d_steps >= 1 and self.g_steps >= 1, "d_steps", "`d_steps` and g_steps must be at least 1"),
            (self.train_depth >= 1, "train_depth", f"`train_depth` must be at least 1, got {self.train_depth}"),
            (0 < self.lr_scale <= 1, None, f"`lr_scale` must be in (0, 1], got {self.lr_scale}"),
            (self.lr > 0, "lr", f"`lr` must be positive, got {self.lr}"),
            (self.d_rate > 0, "d_rate", f"`d_rate` must be positive, got {self.d_rate}"),
            (0 < self.colour_mb <= 1024, "colour_mb", f"`colour_mb` must be in (0, 1024] MB, got {self.colour_mb}"),
            (self.lr_total is None or self.lr_total > 0, None, f"`lr_total` must be positive, got {self.lr_total}"),
            (self.lr_total is None or self.lr_max >= self.lr, None, f"`lr_max` {self.lr_max} is below lr {self.lr}"),
            (self.min_iters >= 1, "min_iters", f"`min_iters` must be at least 1, got {self.min_iters}"),
            (self.minutes is None or 0 < self.minutes <= 60 * 24 * 365, "minutes",
             f"`minutes` must be positive (and at most a year), got {self.minutes}"),
            (self.precision in ("auto", "fp32", "bf16"), "precision",
             f"`precision` must be auto, fp32 or bf16, got {self.precision!r}"),
            (self.box == 0 or self.box >= 16, "box",
             f"`box` must be 0 (whole grids) or at least 16 voxels (the critic's field is 11), got {self.box}"),
            (0 <= self.seed < 2**63, "seed", f"`seed` must be in [0, 2**63), got {self.seed}"),
            (self.up in (None, "y", "z"), "up", f"`up` must be y or z, got {self.up!r}"),
        ]
        for ok, parameter, message in checks:
            if not ok:
                raise InputError(message, parameter)

    def level_lr(self, iterations: int) -> float:
        """Adam's learning rate for a level given this many iterations."""
        if self.lr_total is None:
            return self.lr
        return min(self.lr_max, max(self.lr, self.lr_total / max(iterations, 1)))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict) -> "TrainConfig":
        known = {f.name for f in dataclasses.fields(cls)}
        values = {k: v for k, v in values.items() if k in known}
        if values.get("level_iters") is not None:  # a list once saved as JSON
            values["level_iters"] = tuple(values["level_iters"])
        return cls(**values)


PRESETS = {
    # The paper's method and setting, exactly (res 128 comparisons; the
    # gallery used 256): for reproducing it and comparing against it.
    "paper": TrainConfig(),
    # The paper's method at res 64 and 1000 iterations per level (well under
    # an hour on a 2-core CPU), with the learning rate set from each level's
    # iterations: 1000 at 1e-4, the paper's rate, spread over what the level
    # gets, so a short time budget learns up to ten times faster
    # (docs/EVALUATION.md, "Quality per minute").
    "default": TrainConfig(res=64, iters=1000, lr_total=0.1),
    # Seconds, for tests and smoke runs: two levels, a few iterations.
    "tiny": TrainConfig(res=32, levels=2, iters=10, min_iters=1),
}


def make_config(preset: str | None = None, resume: bool = False, **overrides) -> TrainConfig | None:
    """A preset (None: default) with the given fields replaced; None values
    are ignored. With resume, None: a resumed run takes its checkpoint's
    config, so neither a preset nor a field may be given. iters and minutes
    both say how long to train: give one. Either rule broken is a
    ConflictError naming what was given, in TrainConfig's order."""
    names = [field.name for field in dataclasses.fields(TrainConfig)]
    if set(overrides) - set(names):
        raise TypeError(f"TrainConfig has no field {', '.join(sorted(set(overrides) - set(names)))}")
    changes = {name: overrides[name] for name in names if overrides.get(name) is not None}
    if "iters" in changes and "minutes" in changes:
        raise ConflictError("give `iters` or `minutes`, not both: a time budget plans the iterations", ("iters", "minutes"))
    if resume:
        given = ([] if preset is None else ["preset"]) + list(changes)
        if given:
            raise ConflictError(f"`resume` continues with the checkpoint's settings; leave out {named(given)}",
                                ("resume", *given))
        return None
    preset = "default" if preset is None else preset
    if preset not in PRESETS:
        raise InputError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
    if "lr" in changes:  # a rate given is the rate used, at every level
        changes.setdefault("lr_total", None)
    return dataclasses.replace(PRESETS[preset], **changes)
