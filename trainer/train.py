"""A training run, level after level, coarse to fine, with checkpoints that
survive a crash.

`train` opens the run (the input, or the checkpoint a resumed run continues
from), plans a time budget (schedule.py, from costs measured here), trains
each level in turn and exports the model. A level is started, stepped and
finished by its `Trainer` (steps.py); beside it run the parts with one job
each: when the level ends (`schedule.LevelPlan`), going back when it
diverges (rewind.py) and when to save (checkpoint.py).

A checkpoint (weights-only loadable) is written after every level and every
few minutes; `resume=True` continues from it without redoing finished levels.
Ctrl-C saves one before it stops.
"""

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

from sinshape.core.errors import InputError, NamesParameters
from sinshape.core.files import check_writable, is_same_file
from sinshape.prep.pyramid import load_pyramid

from . import device as devices
from . import export, schedule
from .checkpoint import Checkpoints, default_checkpoint_path, load_checkpoint
from .config import TrainConfig
from .memory import check_training_memory
from .rewind import Rewinds
from .steps import Trainer


class Interrupted(NamesParameters, RuntimeError):
    """Ctrl-C during training; a checkpoint was saved first. `parameter`, as
    in InputError, names what the message says continues it."""

    parameter = "resume"


@dataclass
class Progress:
    """What a progress display needs after each iteration."""

    level: int
    levels: int
    iteration: int  # iterations done in this level
    iters: int
    size: tuple
    losses: dict

    @classmethod
    def of(cls, trainer: Trainer, losses: dict) -> "Progress":
        """Where `trainer` stands after an iteration with these losses; under
        a budget the last level may run past its plan, and `iters` with it."""
        level, done = trainer.level, trainer.iteration
        return cls(level, len(trainer.sizes), done, max(trainer.plan[level], done), trainer.sizes[level], losses)


def train(input_path, output_path, config: TrainConfig | None, *, resume: bool = False, device: str = "auto",
          checkpoint_path=None, checkpoint_every: float = 300.0, progress=None, log=None, colour: bool = True,
          asset_folder=None):
    """Train on a mesh or SSG pyramid and export the model to `output_path`.

    A mesh with colour trains a coloured model (format 5, its colour and
    relief as tiles) unless `colour` is False, which reads no colour at all
    (a resumed run keeps its checkpoint's, and refuses False for a coloured
    one); a mesh without it, a geometry-only model with its relief (format
    5), an .h5 pyramid one without (format 3). The files a mesh names are
    read from its folder, or `asset_folder`.

    With resume, `config` must be None: the checkpoint's config is used (the
    device may differ from the one the run started on). `progress(Progress)`
    is called after every iteration; `log(str)` for the plan, level starts and
    checkpoints. Returns the manifest written into the model.
    Raises InputError for bad input, TrainingDiverged, or Interrupted.
    """
    clock_started = time.monotonic()  # a time budget counts from here
    log = log or (lambda message: None)
    output_path = Path(output_path)
    checkpoint_path = Path(checkpoint_path) if checkpoint_path else default_checkpoint_path(output_path)
    trainer = open_run(input_path, output_path, config, resume, device, checkpoint_path, log, colour, asset_folder)
    budget = plan_budget(trainer, clock_started, log)
    checkpoints = Checkpoints(checkpoint_path, checkpoint_every)
    try:
        while trainer.level < len(trainer.sizes):
            train_level(trainer, budget, checkpoints, progress, log)
    except KeyboardInterrupt:
        checkpoints.save(trainer)
        raise Interrupted(f"interrupted; progress saved to {checkpoint_path}; `resume` continues from it") from None
    return export_run(trainer, budget, output_path)


def open_run(input_path, output_path: Path, config: TrainConfig | None, resume: bool, device: str,
             checkpoint_path: Path, log, colour: bool = True, asset_folder=None) -> Trainer:
    """The trainer of a new run, or of a resumed one at its checkpoint (whose
    config it takes), once every check that needs no training has passed."""
    if (config is None) != resume:
        raise ValueError("pass a config to start training, or resume=True without one")
    state = None
    if resume:
        # The checkpoint says how the pyramid was made; the hash, of what file.
        state = load_checkpoint(checkpoint_path)
        config = TrainConfig.from_dict(state["config"])
        if not colour and state.get("colour", False):
            raise InputError(f"{checkpoint_path}: this checkpoint trains colour, which a resumed run keeps; "
                             "drop `no_colour`, or train afresh", ("no_colour", "resume"))
        colour = state.get("colour", False)  # checkpoints from before colour had none
    check_outputs(input_path, output_path, checkpoint_path, config.generator)
    placement = devices.choose(device, config.precision)
    placement.activate(shapes_vary=bool(config.box))
    first = state["level"] if state else 0  # the levels still to train
    pyramid = load_pyramid(input_path, config.res, config.levels, config.level_factor, config.min_size,
                           check=lambda sizes: check_training_memory(sizes[first:], config, placement),
                           colour=colour, asset_folder=asset_folder, tile_bytes=int(config.colour_mb * 2**20))
    if resume:
        check_same_input(pyramid, state["source"], checkpoint_path)
    # Record what was actually used: an .h5 pyramid fixes res and levels.
    config = dataclasses.replace(config, res=max(pyramid.sizes[-1]), levels=len(pyramid.levels))
    if pyramid.colour_read:
        log(f"colour: {pyramid.colour_read}")
    for warning in pyramid.colour_warnings:
        log(f"warning: {warning}")

    log(f"training on {placement.describe()}")
    trainer = Trainer(config, pyramid, placement)
    if state is not None:
        try:
            trainer.restore(state)
        except (RuntimeError, KeyError, ValueError, IndexError) as error:  # tensors whose shapes do not fit
            why = " ".join(str(error).split())[:200] or type(error).__name__
            raise InputError(f"{checkpoint_path}: a checkpoint whose state does not fit its networks ({why})") from None
        if trainer.level < len(trainer.sizes):
            log(f"resuming at level {trainer.level + 1}/{len(trainer.sizes)}, iteration {trainer.iteration}")
        else:
            log("every level is trained already; exporting")
    return trainer


def check_same_input(pyramid, source: dict, checkpoint_path: Path) -> None:
    """A resumed run reads what its checkpoint was trained on: the same file,
    and the same files it names (textures, material libraries, buffers:
    checkpoints from before these were recorded are not compared)."""
    if pyramid.source_sha256 != source["sha256"]:
        raise InputError(f"{checkpoint_path}: this checkpoint was trained on another file ({source['name']})")
    if source.get("files", pyramid.files_sha256) != pyramid.files_sha256:
        raise InputError(f"{checkpoint_path}: the files {source['name']} names (its textures, material library or "
                         "buffers) have changed since this checkpoint; put them back, or train afresh")


def check_outputs(input_path, output_path: Path, checkpoint_path: Path, generator: str) -> None:
    """Refuse, before any work, outputs that would be lost or destroy a file:
    the wrong kind of model file, a model and checkpoint that are one file
    (but for the voxel baseline, whose checkpoint is its model), and an
    output or checkpoint that is the training input."""
    for path in (output_path, checkpoint_path):
        check_writable(path, [input_path])
    suffix = ".pt" if generator == "voxel" else ".onnx"
    if output_path.suffix.lower() != suffix:
        raise InputError(f"{output_path}: the triplane generator writes a .onnx model, the voxel baseline "
                         "a .pt checkpoint")
    same = checkpoint_path.absolute() == output_path.absolute() or is_same_file(checkpoint_path, output_path)
    if suffix == ".onnx" and same:
        raise InputError(f"{checkpoint_path}: the checkpoint would overwrite the model; name another file")
    if suffix == ".pt" and not same:
        raise InputError(f"{checkpoint_path}: the voxel baseline's checkpoint is its model {output_path}; "
                         "give one of them")


def plan_budget(trainer: Trainer, clock_started: float, log) -> schedule.Budget | None:
    """Under a time budget (`minutes`), its plan for the levels still to
    train, from their costs measured here; None without one. Before the
    first level, a budget too small is refused; once a level has begun, never."""
    config = trainer.config
    if config.minutes is None or trainer.level == len(trainer.sizes):
        return None
    seconds = config.minutes * 60 - trainer.trained_seconds()
    fresh = trainer.level == 0 and trainer.iteration == 0
    costs, startups = time_levels(config, trainer.pyramid, trainer.placement, seconds, refuse=fresh)
    budget = schedule.Budget(seconds, clock_started, costs, startups, config.min_iters,
                             works=[schedule.level_work(size, config.box) for size in trainer.sizes])
    if fresh:
        budget.refuse_if_too_small(trainer.sizes, trainer.pyramid.source_kind == "mesh")
    log(budget.describe(trainer.level))
    if fresh and budget.shortfall():
        log("warning: " + budget.shortfall())
    return budget


def train_level(trainer: Trainer, budget: schedule.Budget | None, checkpoints: Checkpoints, progress, log) -> None:
    """Train the current level to its end (from where a resumed run
    stopped), then save a checkpoint."""
    level = trainer.level
    trainer.start_level(budget.start_level(level) if budget and trainer.iteration == 0 else None)
    plan = schedule.LevelPlan(budget, level, trainer.plan[level], trainer.iteration)
    log(f"level {level + 1}/{len(trainer.sizes)}: grid {trainer.sizes[level]}, noise amplitude "
        f"{trainer.noise_amps[level]:.4g}, {plan.iters} iterations at lr {trainer.lrs[level]:.3g}")
    recon_inputs = trainer.recon_inputs()
    rewinds = Rewinds(trainer, checkpoints.path, log)
    while plan.goes_on(trainer.iteration):
        losses, seconds = trainer.step(recon_inputs)
        if rewinds.went_back(losses):
            continue
        trainer.count_iteration()
        rewinds.counted()
        plan.observe(seconds)
        if progress:
            progress(Progress.of(trainer, losses))
        checkpoints.save_if_due(trainer)
    if plan.cut:
        log(f"level {level + 1} used its share of the budget after {trainer.iteration} iterations")
    trainer.finish_level()
    checkpoints.save(trainer)
    log(f"level {level + 1} done in {trainer.seconds[-1]:.0f} s; checkpoint {checkpoints.path}")


def export_run(trainer: Trainer, budget: schedule.Budget | None, output_path: Path) -> dict:
    """Write the trained model with how it was made; returns its manifest
    (the voxel baseline has no .onnx form: its checkpoint is the model)."""
    config = trainer.config
    if config.minutes is not None:  # the plan is part of how the model was made
        config = dataclasses.replace(config, level_iters=tuple(trainer.plan))
    # Recorded beside the times: where training ran and, under a budget, its plan.
    placement = trainer.placement
    ran_on = {"device": placement.device.type, "precision": placement.precision, "learning_rates": trainer.lrs}
    if trainer.rewinds:
        ran_on["rewinds"] = trainer.rewinds
    if budget:
        ran_on.update(budget.record())
    if config.generator == "voxel":
        return {"levels": [{"size": list(s)} for s in trainer.sizes],
                "training": {"seconds": sum(trainer.seconds), "level_seconds": trainer.seconds, **ran_on}}
    return export.export_model(trainer.generator, sizes=trainer.sizes, noise_amps=trainer.noise_amps,
                               config=config, pyramid=trainer.pyramid, seconds=trainer.seconds, ran_on=ran_on,
                               path=output_path)


def time_levels(config: TrainConfig, pyramid, placement, seconds: float, refuse: bool = False,
                rounds: int = 3) -> tuple:
    """Seconds per iteration at the levels worth measuring within the
    budget's `seconds` (schedule.measuring_allowance), and what a level's
    start adds, on a throwaway trainer (untrained weights cost what trained
    ones do). Returns (costs, startups), None for a level left to estimate: a
    cost is the mean of a few warm rounds (with boxes, an iteration's cost
    varies with where its boxes fall); a start-up is the level's set-up and
    first iteration (it allocates and picks kernels) beyond one warm
    iteration. The two coarsest levels are always measured; a larger one only
    if its measurement, estimated from those before it, fits the allowance.
    With `refuse`, a budget that the levels measured so far already rule out
    is refused at once (every level costs at least what the one below it
    does), not after all levels are measured."""
    trainer = Trainer(config, pyramid, placement)
    works = [schedule.level_work(size, config.box) for size in trainer.sizes]
    allowance = schedule.measuring_allowance(seconds)
    costs, startups = [], []
    began = time.monotonic()
    for level in range(len(trainer.sizes)):
        if refuse and costs:
            at_least = time.monotonic() - began + config.min_iters * (
                sum(costs) + (len(trainer.sizes) - len(costs)) * costs[-1])
            if at_least > seconds:
                raise InputError(f"the time budget of {seconds / 60:.3g} min cannot give {config.min_iters} "
                                 f"iterations to each of {len(trainer.sizes)} levels: they need at least "
                                 f"{at_least / 60:.2g} min here (the {len(costs)} measured so far cost "
                                 f"{sum(costs):.2f} s per iteration); give more `minutes` or lower `min_iters`",
                                 ("minutes", "min_iters"))
        if level >= 2:
            cost = schedule.extrapolated(works[level], list(zip(works, costs)))
            if time.monotonic() - began + (rounds + 1) * cost + startups[-1] > allowance:
                break
        started = time.monotonic()
        trainer.begin_level()
        recon_inputs = trainer.recon_inputs()
        trainer.iterate(recon_inputs)
        warm = time.monotonic()
        for _ in range(rounds):
            trainer.iterate(recon_inputs)
        costs.append((time.monotonic() - warm) / rounds)
        startups.append(max(warm - started - costs[-1], 0.0))
        trainer.finish_level()
    unmeasured = [None] * (len(trainer.sizes) - len(costs))
    return costs + unmeasured, startups + unmeasured
