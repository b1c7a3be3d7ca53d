"""One training run's state and the steps of one iteration.

At level i only G_i (plus P at level 0) and the shared decoder train; lower
levels are frozen (with `train_depth`, the newest levels train together).
One iteration is `d_steps` critic updates (WGAN-GP) then `g_steps`
generator updates (adversarial + 10 x reconstruction MSE). A coloured
example adds colour: the critic sees occupancy and occupancy x RGB
(`networks.critic_input`), and the reconstruction's colour error counts in
the band around the surface (`colour_error`). The
discriminator is shared by all levels and keeps training across them; the
optimisers are created anew per level.

The `Trainer` owns its position (level, iteration, plan, time) and changes
it itself: the run (train.py) asks it to start, step, count, rewind and
finish a level, and never assigns its attributes.
"""

import copy
import math
import time

import torch
import torch.nn.functional as F

from sinshape.core import noise
from sinshape.prep.pyramid import training_targets

from . import device as devices
from .checkpoint import CHECKPOINT_FORMAT, CHECKPOINT_VERSION, count_levels
from .config import TrainConfig
from .networks import Discriminator, critic_input, make_generator

# A box the critic judges holds at least this share of the example inside
# and as much outside (Trainer.critic_box), found in at most so many draws.
MIXED_SHARE = 0.01
CRITIC_BOX_DRAWS = 50


def seeded(seed: int, *ids: int) -> int:
    """A torch seed for one purpose, derived from the run's seed."""
    return noise.stream_key(seed, *ids) >> 1  # torch seeds must fit in int64


def framed(box: tuple | None, size) -> tuple:
    """What the critic reads for a box (None: the whole grid): the box and
    the voxel around it on every side, which the critic's first layer reads.

    Returns (slices of the grid to take, F.pad's zero padding). The frame is
    the grid's own voxels where the box lies inside the grid and zeros only
    beyond the grid's faces, as for the whole grid. Padded with zeros on
    every side instead, a box cut through solid looks to the critic like
    solid meeting the grid's face, which the example shows rarely.
    """
    if box is None:
        return None, (1,) * 6
    taken = tuple(slice(max(s.start - 1, 0), min(s.stop + 1, n)) for s, n in zip(box, size))
    pad = [(int(s.start == 0), int(s.stop == n)) for s, n in zip(box, size)]
    return taken, tuple(side for low_high in reversed(pad) for side in low_high)  # F.pad: last axis first


class Trainer:
    """The state of one training run: data, networks, optimisers, position.
    Others read the position; only these methods change it (a level's
    start, steps, count, rewinds and finish, and `restore`)."""

    def __init__(self, config: TrainConfig, pyramid, placement: devices.Placement | None = None):
        self.config = config
        self.pyramid = pyramid
        self.sizes = pyramid.sizes
        self.placement = placement or devices.choose("cpu", "fp32")
        self.device = device = self.placement.device
        self.targets = [torch.from_numpy(t)[None, None].to(device) for t in training_targets(pyramid, config.blur_sigma)]
        self.colour = pyramid.colours is not None
        # What the steps compare with, per level: occupancy (X, Y, Z), with
        # colour (4, X, Y, Z) occupancy and RGB; and the colour loss's weights.
        self.reals, self.bands = [t[0, 0] for t in self.targets], None
        if self.colour:
            self.reals = [torch.cat([t[0], torch.from_numpy(rgb).to(device)])
                          for t, rgb in zip(self.targets, pyramid.colours)]
            self.bands = [torch.from_numpy(band).to(device) for band in pyramid.bands]
        self.z0_recon = torch.from_numpy(noise.z0_noise(config.recon_seed, self.sizes[0]))[None, None].to(device)
        with torch.random.fork_rng():  # weights are initialised on the CPU: the same on every device
            torch.manual_seed(seeded(config.seed, 0))
            self.generator = make_generator(config.generator, config.channels, config.pool_bins,
                                            config.mlp_hidden, self.colour).to(device)
            self.critic = Discriminator(config.channels, 4 if self.colour else 1).to(device)
        # Every random draw comes from this CPU generator, then moves to the device.
        self.rng = torch.Generator().manual_seed(seeded(config.seed, 1))
        self.noise_amps = []  # sigma_i per level; sigma_0 = 1 is the std of z0
        self.lrs = []  # Adam's learning rate per level, set from its plan as it starts
        self.level = 0  # the level being trained
        self.iteration = 0  # iterations done at that level
        self.seconds = []  # wall time per finished level
        self.level_seconds = 0.0  # wall time so far at the current level
        self.opt_g = self.opt_d = None
        self.rewinds = []  # [level, at, to, lr]: where a level diverged, where it went back, its new rate
        # Iterations per level; under a time budget each level's is planned as it starts.
        self.plan = list(config.level_iters or [0 if config.minutes else config.iters] * len(self.sizes))

    # -- levels ------------------------------------------------------------
    def start_level(self, planned: int | None = None) -> None:
        """Make the current level ready to train: `planned` iterations (None:
        as planned already), then its generator, rate and optimisers, unless
        a resumed run has begun the level already."""
        if planned is not None:
            self.plan[self.level] = planned
        if len(self.generator.levels) == self.level:
            self.begin_level()

    def begin_level(self) -> None:
        """Add G_level, set its noise amplitude and learning rate (from its
        planned iterations), create fresh optimisers."""
        level = self.level
        with torch.random.fork_rng():
            torch.manual_seed(seeded(self.config.seed, 2, level))
            self.generator.add_level().to(self.device)
        if len(self.noise_amps) == level:
            self.noise_amps.append(1.0 if level == 0 else self.initial_noise_amp(level))
        del self.lrs[level:]
        self.lrs.append(self.config.level_lr(self.plan[level]))
        self.make_optimizers()

    def finish_level(self) -> None:
        """Record the level as trained, with the iterations it ran (a budget
        may have cut or extended its plan) and its time, and move on to the
        next, whose optimisers are made when it begins."""
        self.plan[self.level] = self.iteration
        self.seconds.append(self.level_seconds)
        self.level, self.iteration, self.level_seconds = self.level + 1, 0, 0.0
        self.opt_g = self.opt_d = None

    def initial_noise_amp(self, level: int) -> float:
        """sigma_i = ratio * RMSE(trilinear upsample of rec_(i-1), real_i)."""
        with torch.no_grad():
            rec = occupancy(self.reconstruct(level - 1))
            up = F.interpolate(rec[None, None], size=self.sizes[level], mode="trilinear", align_corners=False)
            return self.config.noise_ratio * math.sqrt(F.mse_loss(up, self.targets[level]).item())

    def first_trained(self) -> int:
        """The oldest level that trains with the current one (train_depth)."""
        return max(0, self.level - self.config.train_depth + 1)

    def make_optimizers(self) -> None:
        """Adam for the critic and for the trained levels, one parameter group
        per level; a group's `scale` is its share of the level's rate (the
        critic's: d_rate)."""
        c, level, lr = self.config, self.level, self.lrs[self.level]

        def group(modules, scale):
            return {"params": [p for m in modules for p in m.parameters()], "scale": scale, "lr": lr * scale}

        groups = [group(self.generator.trained_modules(level), 1.0)]
        groups += [group(self.generator.level_modules(older), c.lr_scale ** (level - older))
                   for older in range(self.first_trained(), level)]
        # fused: one kernel for all of a step's tensors (measured 15% of an iteration
        # at the coarsest level, where Adam's per-tensor overhead shows)
        self.opt_g = torch.optim.Adam(groups, lr=lr, betas=(c.beta1, c.beta2), fused=True)
        self.opt_d = torch.optim.Adam([group([self.critic], c.d_rate)], lr=lr, betas=(c.beta1, c.beta2), fused=True)

    def set_rates(self) -> None:
        """Every parameter group at its share of the level's rate (after a rewind)."""
        for optimizer in (self.opt_g, self.opt_d):
            for group in optimizer.param_groups:
                group["lr"] = self.lrs[self.level] * group["scale"]

    # -- sampling ------------------------------------------------------------
    def random_noises(self, upto: int) -> tuple:
        """A fresh z0 and scaled per-level plane noises for levels 1..upto."""
        z0 = self.draw(torch.randn, (1, 1, *self.sizes[0]))
        noises = [None]
        for level in range(1, upto + 1):
            amp = self.noise_amps[level]
            noises.append([amp * self.draw(torch.randn, shape)
                           for shape in self.generator.noise_shapes(self.sizes[level])])
        return z0, noises

    def draw(self, sampler, shape) -> torch.Tensor:
        """A draw from the run's CPU generator, on the training device."""
        return sampler(shape, generator=self.rng).to(self.device)

    def recon_inputs(self):
        """The frozen levels' output for the reconstruction (None at level 0,
        where P trains): constant through a level, so computed once."""
        if self.first_trained() == 0:
            return None
        with self.placement.autocast():
            return self.inputs(self.z0_recon, [None] * (self.level + 1))

    def reconstruct(self, level: int) -> torch.Tensor:
        """Occupancy (X, Y, Z) at `level` for z0* and zero later noise
        (with colour (4, X, Y, Z))."""
        return self.generator(self.z0_recon, [None] * (level + 1), self.sizes, upto=level)[0]

    def inputs(self, z0, noises):
        """What the trained levels build on (frozen levels: no gradients)."""
        return self.generator.inputs(z0, noises, self.sizes, self.first_trained())

    def fake(self, inputs, noises, boxes: list) -> list:
        """This level's occupancy, sample b in the box boxes[b] (None: whole);
        noises: the trained levels' scaled noises."""
        return self.generator.output(inputs, self.first_trained(), self.level, self.sizes, noises, boxes)

    def draw_box(self) -> tuple | None:
        """Where a step looks at this level: None for the whole grid, or
        with `box`, slices of a box of at most that side at a random
        place, drawn from the run's generator (nothing is drawn at a level
        that fits in the box, so such levels train as the paper's do).

        Boxes may hang over the grid's edge by up to half their side and are
        clipped there. Boxes kept inside would see a voxel at the edge of a
        128-voxel axis 1/81 as often as one in the middle (48-voxel boxes):
        the example's outer parts would hardly be judged. Clipped ones see it
        at least half as often, and the smallest box still holds 16 voxels
        per axis, room for the critic's 11.
        """
        side, size = self.config.box, self.sizes[self.level]
        if not side or max(size) <= side:
            return None
        inside = min(side, max(side // 2, 16))  # the least of a box that stays in the grid
        box = []
        for n in size:
            if n <= side:
                box.append(slice(0, n))
                continue
            start = int(torch.randint(inside - side, n - inside + 1, (1,), generator=self.rng))
            box.append(slice(max(start, 0), min(start + side, n)))
        return tuple(box)

    def critic_box(self) -> tuple | None:
        """A box for the critic: `draw_box`'s, drawn again (up to
        CRITIC_BOX_DRAWS times) while the example is all but empty or all but
        solid in it. The critic's instance norms divide by the spread of
        what they see: on a box of constant real, a fake's faint noise is
        blown up, and the gradient penalty with it. On a hollow 93x128x92
        tower in boxes of 64 the critic's loss reached 1e10 within 100
        iterations of the finest level, each time on a box with no solid in
        it. Boxes that touch the shape at all are kept, so only the
        example's empty (or solid) corners are judged less often."""
        real = self.targets[self.level][0, 0]
        for _ in range(CRITIC_BOX_DRAWS):
            box = self.draw_box()
            if box is None or MIXED_SHARE <= float(real[box].mean()) <= 1 - MIXED_SHARE:
                break
        return box

    # -- one iteration -------------------------------------------------------
    def step(self, recon_inputs) -> tuple:
        """One iteration, timed: (losses, seconds). Its time counts toward
        the level's whether or not the iteration counts (`count_iteration`)."""
        started = time.monotonic()
        losses = self.iterate(recon_inputs)
        seconds = time.monotonic() - started
        self.level_seconds += seconds
        return losses, seconds

    def count_iteration(self) -> None:
        """The iteration just run stands: the level is one iteration further."""
        self.iteration += 1

    def iterate(self, recon_inputs) -> dict:
        """One iteration, in the precision of the run's placement."""
        with self.placement.autocast():
            return self.update_steps(recon_inputs)

    def update_steps(self, recon_inputs) -> dict:
        """(1) update D `d_steps` times, (2) update G `g_steps` times.

        Samples that go through the same network state share one batch (the
        same values, fewer and larger kernel calls): the frozen levels' output
        for every draw of the iteration, the critic steps' fakes (G does not
        change during them), and each generator step's fake with the
        reconstruction. Random draws are made in the order they are used.

        With `box`, every step shows the critic one box of the grid, the same
        box of the real and the fake (a paired comparison: where the box falls
        moves both scores alike), and the reconstruction is measured in
        another box; only boxes are decoded. Each is an unbiased estimate of
        its whole-grid term, at the cost of its box, except that the critic
        is not shown boxes where the example is all one (`critic_box`).
        The critic sees a box
        with its frame (`framed`), so a box's faces inside the grid do not
        look like the grid's own.
        """
        c, level, real = self.config, self.level, self.reals[self.level]
        critic, size = self.critic, self.sizes[level]
        d_draws = [(*self.random_noises(level), self.draw(torch.rand, 1), framed(self.critic_box(), size))
                   for _ in range(c.d_steps)]
        g_draws = [(*self.random_noises(level), framed(self.critic_box(), size), self.draw_box())
                   for _ in range(c.g_steps)]
        z0, noises = cat_draws([draw[:2] for draw in d_draws] + [draw[:2] for draw in g_draws])
        trained = noises[self.first_trained():level + 1]  # (d_steps + g_steps) samples; None at level 0
        with torch.no_grad():
            inputs = self.inputs(z0, noises)
            d_steps = slice(0, c.d_steps)
            fakes = self.fake(take(inputs, d_steps), [take(noise, d_steps) for noise in trained],
                              [draw[3][0] for draw in d_draws])

        # (1) Update D: minimise D(fake) - D(real) + gp_weight * GP.
        critic.requires_grad_(True)
        for fake, (_, _, alpha, (box, pad)) in zip(fakes, d_draws):
            seen_real = F.pad(critic_input(crop(real, box)), pad)
            seen_fake = F.pad(critic_input(fake), pad)
            scores = critic(torch.cat([seen_real, seen_fake]), framed=True)
            d_real, d_fake = scores[0].mean(), scores[1].mean()
            loss_d = d_fake - d_real + c.gp_weight * self.gradient_penalty(seen_real, seen_fake, alpha)
            self.opt_d.zero_grad(set_to_none=True)
            loss_d.backward()
            self.opt_d.step()

        # (2) Update G: minimise -D(fake) + rec_weight * MSE(rec, real).
        critic.requires_grad_(False)
        for i, (_, _, (box, pad), rec_box) in zip(range(c.d_steps, c.d_steps + c.g_steps), g_draws):
            one = slice(i, i + 1)
            if recon_inputs is None:  # P trains with G_0: both samples start from their z0
                pair = self.inputs(torch.cat([z0[one], self.z0_recon]), None)
            else:  # the reconstruction's frozen input is cached
                pair = cat_batch([take(inputs, one), recon_inputs])
            pair_noises = [None if noise is None else [torch.cat([n[one], torch.zeros_like(n[one])]) for n in noise]
                           for noise in trained]  # the reconstruction's noise is zero
            fake, rec = self.fake(pair, pair_noises, [box, rec_box])
            loss_adv = -critic(F.pad(critic_input(fake), pad), framed=True).mean()
            loss_rec = self.reconstruction_error(rec, rec_box)
            loss_g = loss_adv + c.rec_weight * loss_rec
            self.opt_g.zero_grad(set_to_none=True)
            loss_g.backward()
            self.opt_g.step()
        critic.requires_grad_(True)
        return {"D": loss_d.item(), "G": loss_adv.item(), "rec": loss_rec.item()}

    def reconstruction_error(self, rec, box) -> torch.Tensor:
        """MSE of the reconstruction's occupancy in `box` (None: the whole
        grid); with colour, plus its colour's squared error weighted by the
        surface band, over the band's share of the whole level, so that a
        box's error estimates the level's, and the colour inside a solid
        (which no vertex shows) does not count."""
        real = crop(self.reals[self.level], box)
        if not self.colour:
            return F.mse_loss(rec, real)
        band, share = crop(self.bands[self.level], box), self.bands[self.level].mean()
        colour_error = (band * (rec[1:] - real[1:]).square().mean(0)).mean() / share
        return F.mse_loss(rec[0], real[0]) + colour_error

    def gradient_penalty(self, real, fake, alpha) -> torch.Tensor:
        """WGAN-GP on the mix alpha * real + (1 - alpha) * fake (both framed).

        As the authors' code does, the norm is taken over the channel axis,
        which has size 1: the penalty is mean((|dD/dx| - 1)^2) per voxel, of
        the gradient of the score map's sum. With colour the channel axis
        holds 4, and the norm is over them.
        """
        mixed = (alpha * real + (1 - alpha) * fake).requires_grad_(True)
        (grad,) = torch.autograd.grad(self.critic(mixed, framed=True).sum(), mixed, create_graph=True)
        grad = grad[..., 1:-1, 1:-1, 1:-1]  # the grid's voxels, not the frame
        norm = grad.abs() if grad.shape[1] == 1 else grad.norm(dim=1)
        return ((norm - 1) ** 2).mean()

    # -- going back after a divergence -----------------------------------------
    def keep(self) -> dict:
        """An in-memory copy of what this level's steps change."""
        return copy.deepcopy({"iteration": self.iteration, "generator": self.generator.state_dict(),
                              "critic": self.critic.state_dict(), "opt_g": self.opt_g.state_dict(),
                              "opt_d": self.opt_d.state_dict()})

    def rewind(self, kept: dict) -> None:
        """Go back to `kept` and halve this level's learning rate."""
        self.rewinds.append([self.level, self.iteration + 1, kept["iteration"], self.lrs[self.level] / 2])
        self.iteration = kept["iteration"]
        self.lrs[self.level] /= 2
        self.generator.load_state_dict(kept["generator"])
        self.critic.load_state_dict(kept["critic"])
        self.opt_g.load_state_dict(kept["opt_g"])
        self.opt_d.load_state_dict(kept["opt_d"])
        self.set_rates()

    # -- checkpoints ---------------------------------------------------------
    def trained_seconds(self) -> float:
        """Training time so far, over every run of this model."""
        return sum(self.seconds) + self.level_seconds

    def state(self) -> dict:
        p = self.pyramid
        return {
            "format": CHECKPOINT_FORMAT,
            "version": CHECKPOINT_VERSION,
            "config": self.config.to_dict(),
            "colour": self.colour,
            "source": {"name": p.source_name, "sha256": p.source_sha256, "kind": p.source_kind,
                       "files": p.files_sha256, "colour": p.colour_read},
            "sizes": [list(s) for s in self.sizes],
            "level": self.level,
            "iteration": self.iteration,
            "noise_amps": list(self.noise_amps),
            "lrs": list(self.lrs),
            "rewinds": list(self.rewinds),
            "plan": list(self.plan),
            "seconds": list(self.seconds),
            "level_seconds": self.level_seconds,
            "generator": self.generator.state_dict(),
            "critic": self.critic.state_dict(),
            "opt_g": self.opt_g.state_dict() if self.opt_g else None,
            "opt_d": self.opt_d.state_dict() if self.opt_d else None,
            "rng": self.rng.get_state(),
        }

    def restore(self, state: dict) -> None:
        """Load a checkpoint made by `state()` for the same source and config."""
        self.level, self.iteration = state["level"], state["iteration"]
        self.noise_amps, self.seconds = list(state["noise_amps"]), list(state["seconds"])
        self.level_seconds = state["level_seconds"]
        self.plan = list(state.get("plan") or self.plan)  # checkpoints before budgets had none
        self.lrs = list(state.get("lrs") or [self.config.lr] * len(self.noise_amps))  # older: one fixed rate
        self.rewinds = list(state.get("rewinds", []))
        started = count_levels(state["generator"])
        for _ in range(started):
            with torch.random.fork_rng():
                self.generator.add_level().to(self.device)
        self.generator.load_state_dict(state["generator"])
        self.critic.load_state_dict(state["critic"])
        self.rng.set_state(state["rng"])
        if state["opt_g"] is not None and started == self.level + 1:
            self.make_optimizers()
            self.opt_g.load_state_dict(state["opt_g"])
            self.opt_d.load_state_dict(state["opt_d"])
            for optimizer in (self.opt_g, self.opt_d):  # older checkpoints: one group each, at the full rate
                for group in optimizer.param_groups:
                    group.setdefault("scale", 1.0)


def occupancy(grid: torch.Tensor) -> torch.Tensor:
    """The occupancy (X, Y, Z) of a decoded grid, coloured (4, X, Y, Z) or not."""
    return grid if grid.dim() == 3 else grid[0]


def crop(grid: torch.Tensor, box: tuple | None) -> torch.Tensor:
    """A box (slices along x, y, z; None: all) of a grid (..., X, Y, Z)."""
    return grid if box is None else grid[(Ellipsis, *box)]


def cat_batch(items: list):
    """Samples joined along the batch axis: tensors, or tri-planes (lists of 3)."""
    if isinstance(items[0], torch.Tensor):
        return torch.cat(items)
    return [torch.cat(planes) for planes in zip(*items)]


def take(batch, index: slice):
    """Some samples of a batch: a tensor, tri-planes (a list of 3), or None."""
    if batch is None or isinstance(batch, torch.Tensor):
        return None if batch is None else batch[index]
    return [planes[index] for planes in batch]


def cat_draws(draws: list) -> tuple:
    """[(z0, noises)] of single samples -> one (z0, noises) batch."""
    z0 = torch.cat([z0 for z0, _ in draws])
    noises = [None if level[0] is None else cat_batch(list(level))
              for level in zip(*(noises for _, noises in draws))]
    return z0, noises
