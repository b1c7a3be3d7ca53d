"""The SSG networks in PyTorch: projection, per-level tri-plane generators,
the shared MLP decoder, and the 3-D discriminator.

Conventions shared with the runtime (docs/FORMAT.md):
- A level's grid is (X, Y, Z). Its planes, in this order, are xy (X, Y),
  xz (X, Z) and yz (Y, Z); plane k drops axis 2 - k.
- Plane tensors are (B, C, H, W); occupancy grids are (B, X, Y, Z), volumes
  (B, 1, X, Y, Z). A coloured decoder's grids are (B, 4, X, Y, Z):
  occupancy, then sRGB. Training batches independent samples (the critic steps'
  fakes, a fake with the reconstruction); export and sampling use B = 1.
- The decoder's feature of a point concatenates its xy, xz, yz features.

Networks take plain ints; nothing here reads a config.
"""

import torch
import torch.nn.functional as F
from torch import nn

from sinshape.core.errors import InputError
from sinshape.core.manifest import PLANE_AXES, PLANES, plane_sizes


def plane_stack(channels: int) -> nn.Sequential:
    """Four 3x3 convs; the first three without bias, each followed by
    InstanceNorm (no affine) and LeakyReLU(0.2); the last with bias, bare."""
    layers = []
    for _ in range(3):
        layers += [
            nn.Conv2d(channels, channels, 3, padding=1, bias=False),
            nn.InstanceNorm2d(channels),
            nn.LeakyReLU(0.2),
        ]
    layers.append(nn.Conv2d(channels, channels, 3, padding=1))
    return nn.Sequential(*layers)


class LevelGenerator(nn.Module):
    """G_i: one independent conv stack per plane."""

    def __init__(self, channels: int):
        super().__init__()
        self.stacks = nn.ModuleList(plane_stack(channels) for _ in PLANES)

    def forward(self, planes: list) -> list:
        return [stack(plane) for stack, plane in zip(self.stacks, planes)]


class Projection(nn.Module):
    """P: average-pool a 3-D noise into `bins` slabs per plane, then a 1x1 conv."""

    def __init__(self, bins: int, channels: int):
        super().__init__()
        self.bins = bins
        self.convs = nn.ModuleList(nn.Conv2d(bins, channels, 1) for _ in PLANES)

    def pool(self, volume: torch.Tensor) -> list:
        """volume : (B, 1, X, Y, Z) -> [(B, bins, X, Y), (B, bins, X, Z), (B, bins, Y, Z)].

        Bin k of n covers floor(k n / bins) .. ceil((k + 1) n / bins), exactly
        torch's adaptive average pooling.
        """
        x, y, z = volume.shape[-3:]
        b = self.bins
        xy = F.adaptive_avg_pool3d(volume, (x, y, b))[:, 0].permute(0, 3, 1, 2)  # (B, b, X, Y)
        xz = F.adaptive_avg_pool3d(volume, (x, b, z))[:, 0].permute(0, 2, 1, 3)  # (B, b, X, Z)
        yz = F.adaptive_avg_pool3d(volume, (b, y, z))[:, 0]  # (B, b, Y, Z)
        return [xy, xz, yz]

    def forward(self, volume: torch.Tensor) -> list:
        return [conv(p) for conv, p in zip(self.convs, self.pool(volume))]


class Decoder(nn.Module):
    """Shared MLP: Linear(3C, H) -> ReLU -> Linear(H, 1) -> sigmoid. With
    `colour`, a wider last layer: Linear(H, 3) -> sigmoid beside it, the
    colour head (sRGB), on the same hidden layer.

    The first layer is linear in the concatenated features, so it is applied
    to each plane before the planes are combined (docs/METHOD.md):
    W [f_xy; f_xz; f_yz] = W_xy f_xy + W_xz f_xz + W_yz f_yz. A voxel then
    costs a sum of three H-vectors instead of a (3C x H) product, and the
    backward pass never holds a (voxels, 3C) tensor.
    """

    def __init__(self, channels: int, hidden: int, colour: bool = False):
        super().__init__()
        self.channels = channels
        self.fc1 = nn.Linear(3 * channels, hidden)
        self.fc2 = nn.Linear(hidden, 1)
        self.fc_colour = nn.Linear(hidden, 3) if colour else None

    def project_planes(self, planes: list) -> list:
        """[(B, C, H, W)] * 3 -> [(B, H, W, hidden)] * 3: each plane times its W_k."""
        weights = self.fc1.weight.split(self.channels, dim=1)  # 3 x (hidden, C)
        return [torch.einsum("bchw,oc->bhwo", plane, w) for plane, w in zip(planes, weights)]

    def grid(self, planes: list, box: tuple | None = None) -> torch.Tensor:
        """Occupancy at the planes' own resolution: voxel (x, y, z) reads plane
        cells xy[x, y], xz[x, z], yz[y, z]. Returns (B, X, Y, Z), or with a
        box (slices along x, y, z) only that part of the grid: a box costs
        what its voxels cost, whatever the size of the planes. A coloured
        decoder returns (B, 4, X, Y, Z): occupancy and RGB."""
        if box is not None:
            sx, sy, sz = box
            planes = [planes[0][..., sx, sy], planes[1][..., sx, sz], planes[2][..., sy, sz]]
        with torch.autocast(planes[0].device.type, enabled=False):  # occupancy is always float32
            pxy, pxz, pyz = self.project_planes([plane.float() for plane in planes])
        pxy = pxy + self.fc1.bias
        if self.fc_colour is not None:
            weight = torch.cat([self.fc2.weight, self.fc_colour.weight])
            bias = torch.cat([self.fc2.bias, self.fc_colour.bias])
            return torch.stack([WideGridHead.apply(pxy[b], pxz[b], pyz[b], weight, bias) for b in range(len(pxy))])
        return torch.stack([GridHead.apply(pxy[b], pxz[b], pyz[b], self.fc2.weight, self.fc2.bias)
                            for b in range(len(pxy))])

    def points(self, planes: list, coords: torch.Tensor) -> torch.Tensor:
        """Occupancy at arbitrary points, the straightforward way: sample each
        plane bilinearly (align_corners=True) and run the whole MLP.

        planes of one sample (B = 1); coords : (n, 3) in [-1, 1] (grid corner
        to corner) -> (n,) occupancy, or (n, 4) occupancy and RGB when coloured.
        """
        features = []
        for plane, (a, b) in zip(planes, PLANE_AXES):
            # grid_sample's grid is (x=width, y=height): width is the plane's last axis.
            grid = coords[:, [b, a]].view(1, 1, -1, 2)
            features.append(F.grid_sample(plane, grid, align_corners=True)[0, :, 0].T)  # (n, C)
        hidden = F.relu(self.fc1(torch.cat(features, dim=1)))
        if self.fc_colour is not None:
            return torch.sigmoid(torch.cat([self.fc2(hidden), self.fc_colour(hidden)], dim=1))
        return torch.sigmoid(self.fc2(hidden))[:, 0]


class GridHead(torch.autograd.Function):
    """sigmoid(w2 . relu(xy[x, y] + xz[x, z] + yz[y, z]) + b2) on the whole grid,
    slab by slab along x, never holding the (X, Y, Z, hidden) sum.

    Done by autograd, the sum, the ReLU and their gradients each fill a
    (X, Y, Z, hidden) tensor in memory; slabs that stay in cache, with the
    backward pass recomputing them, make forward plus backward about 3x faster
    at 96^3 (benchmarks/train_speed.py).
    """

    SLAB_FLOATS = 1 << 20  # 4 MB of hidden sums per slab: measured best of 2^16..2^22

    @staticmethod
    def slabs(pxy: torch.Tensor, pyz: torch.Tensor):
        y, z, hidden = pyz.shape
        step = max(1, GridHead.SLAB_FLOATS // (y * z * hidden))
        return [(s, min(s + step, pxy.shape[0])) for s in range(0, pxy.shape[0], step)]

    @staticmethod
    def hidden(pxy, pxz, pyz, start, end) -> torch.Tensor:
        """relu of the summed pre-activations of x-slab [start, end): (n, Y, Z, hidden)."""
        h = pxy[start:end, :, None] + pxz[start:end, None]
        h += pyz
        return h.relu_()

    @staticmethod
    def forward(ctx, pxy, pxz, pyz, w2, b2):
        """pxy (X, Y, H) with b1 added, pxz (X, Z, H), pyz (Y, Z, H), w2 (1, H), b2 (1,)."""
        ctx.save_for_backward(pxy, pxz, pyz, w2, b2)
        logits = pxy.new_empty(pxy.shape[0], *pyz.shape[:2])
        for start, end in GridHead.slabs(pxy, pyz):
            torch.matmul(GridHead.hidden(pxy, pxz, pyz, start, end), w2[0], out=logits[start:end])
        return (logits + b2).sigmoid_()

    @staticmethod
    def backward(ctx, grad_out):
        pxy, pxz, pyz, w2, b2 = ctx.saved_tensors
        w = w2[0]
        grad_xy, grad_xz = torch.empty_like(pxy), torch.empty_like(pxz)
        grad_yz, grad_w, grad_b = torch.zeros_like(pyz), torch.zeros_like(w), torch.zeros_like(b2)
        for start, end in GridHead.slabs(pxy, pyz):
            h = GridHead.hidden(pxy, pxz, pyz, start, end)  # (n, Y, Z, H), >= 0
            occupancy = (torch.matmul(h, w) + b2).sigmoid_()
            grad_logit = grad_out[start:end] * occupancy * (1 - occupancy)  # (n, Y, Z)
            grad_w += torch.matmul(h.reshape(-1, h.shape[-1]).T, grad_logit.reshape(-1))
            grad_b += grad_logit.sum()
            # d/dh of w . relu(h) is w where h > 0: built in h's own buffer.
            grad_h = h.sign_().mul_(w).mul_(grad_logit[..., None])
            grad_xy[start:end] = grad_h.sum(2)
            grad_xz[start:end] = grad_h.sum(1)
            grad_yz += grad_h.sum(0)
        return grad_xy, grad_xz, grad_yz, grad_w[None], grad_b


class WideGridHead(GridHead):
    """GridHead with K outputs instead of one (occupancy and colour): the
    same hidden layer read by the rows of w (K, hidden), each through a
    sigmoid. Returns (K, X, Y, Z). The hidden sum is made once per slab for
    all K, which is why colour costs little more than occupancy alone."""

    @staticmethod
    def forward(ctx, pxy, pxz, pyz, w, b):
        ctx.save_for_backward(pxy, pxz, pyz, w, b)
        out = pxy.new_empty(pxy.shape[0], *pyz.shape[:2], len(w))
        for start, end in GridHead.slabs(pxy, pyz):
            torch.matmul(GridHead.hidden(pxy, pxz, pyz, start, end), w.T, out=out[start:end])
        return (out + b).sigmoid_().permute(3, 0, 1, 2)

    @staticmethod
    def backward(ctx, grad_out):
        pxy, pxz, pyz, w, b = ctx.saved_tensors
        grad_out = grad_out.permute(1, 2, 3, 0)  # (X, Y, Z, K)
        grad_xy, grad_xz = torch.empty_like(pxy), torch.empty_like(pxz)
        grad_yz, grad_w, grad_b = torch.zeros_like(pyz), torch.zeros_like(w), torch.zeros_like(b)
        for start, end in GridHead.slabs(pxy, pyz):
            h = GridHead.hidden(pxy, pxz, pyz, start, end)  # (n, Y, Z, H), >= 0
            out = (torch.matmul(h, w.T) + b).sigmoid_()
            grad_logit = grad_out[start:end] * out * (1 - out)  # (n, Y, Z, K)
            flat = grad_logit.reshape(-1, len(w))
            grad_w += flat.T @ h.reshape(-1, h.shape[-1])
            grad_b += flat.sum(0)
            grad_h = torch.matmul(grad_logit, w).mul_(h.sign_())  # d/dh of relu(h) w^T: w where h > 0
            grad_xy[start:end] = grad_h.sum(2)
            grad_xz[start:end] = grad_h.sum(1)
            grad_yz += grad_h.sum(0)
        return grad_xy, grad_xz, grad_yz, grad_w, grad_b


def resize_planes(planes: list, size: tuple) -> list:
    """Bilinear resize (align_corners=True) of tri-planes to a grid size."""
    return [
        F.interpolate(p, size=s, mode="bilinear", align_corners=True)
        for p, s in zip(planes, plane_sizes(size))
    ]


class TriplaneGenerator(nn.Module):
    """P, the level generators G_0..G_n and the decoder, chained.

    Level 0: T_0 = G_0(P(z0)). Level i > 0: U = resize(T_(i-1));
    T_i = U + G_i(U + sigma_i * n_i). Levels are appended as training grows.
    """

    def __init__(self, channels: int = 32, bins: int = 8, hidden: int = 32, colour: bool = False):
        super().__init__()
        self.channels = channels
        self.projection = Projection(bins, channels)
        self.levels = nn.ModuleList()
        self.decoder = Decoder(channels, hidden, colour)

    def add_level(self) -> LevelGenerator:
        level = LevelGenerator(self.channels)
        self.levels.append(level)
        return level

    def start(self, z0: torch.Tensor) -> list:
        """z0 : (B, 1, X, Y, Z) -> T_0, the coarsest tri-plane."""
        return self.levels[0](self.projection(z0))

    def step(self, planes: list, level: int, size: tuple, noise: list | None) -> list:
        """T_(level-1) -> T_level at grid `size`; noise: 3 planes already
        scaled by sigma_level, or None for none (reconstruction)."""
        upsampled = resize_planes(planes, size)
        inputs = upsampled if noise is None else [u + n for u, n in zip(upsampled, noise)]
        return [u + g for u, g in zip(upsampled, self.levels[level](inputs))]

    def planes(self, z0: torch.Tensor, noises: list, sizes: list, upto: int | None = None) -> list:
        """The tri-plane after level `upto` (default: the last).

        noises[i] is level i's scaled noise (3 planes) or None; noises[0] is unused.
        """
        upto = len(self.levels) - 1 if upto is None else upto
        planes = self.start(z0)
        for level in range(1, upto + 1):
            planes = self.step(planes, level, sizes[level], noises[level])
        return planes

    def forward(self, z0: torch.Tensor, noises: list, sizes: list, upto: int | None = None) -> torch.Tensor:
        """Occupancy (B, X, Y, Z) of level `upto`'s grid (default: the last
        level); with colour (B, 4, X, Y, Z)."""
        return self.decoder.grid(self.planes(z0, noises, sizes, upto))

    def level_planes(self, inputs: list, level: int, size: tuple, noise: list | None) -> list:
        """Level `level`'s tri-plane from its inputs and scaled noise."""
        return self.levels[0](inputs) if level == 0 else self.step(inputs, level, size, noise)

    # The interface the trainer uses, shared with VoxelGenerator.
    def noise_shapes(self, size: tuple) -> list:
        """Shapes of one sample's noise at a level: a C-channel map per plane."""
        return [(1, self.channels, *s) for s in plane_sizes(size)]

    def inputs(self, z0: torch.Tensor, noises: list, sizes: list, first: int) -> list:
        """What the trained levels, `first` on, build on: P(z0) when level 0
        trains (P trains with it), else the frozen levels' tri-plane,
        computed without gradients."""
        if first == 0:
            return self.projection(z0)
        with torch.no_grad():
            return self.planes(z0, noises, sizes, upto=first - 1)

    def output(self, inputs: list, first: int, level: int, sizes: list, noises: list, boxes: list) -> list:
        """The occupancy of `level` from the trained levels' inputs and their
        scaled noises (noises[k] for level first + k): for sample b of the
        batch, the box boxes[b] of its grid (None: all of it), decoded alone."""
        planes = inputs
        for at, noise in zip(range(first, level + 1), noises):
            planes = self.level_planes(planes, at, sizes[at], noise)
        return [self.decoder.grid([p[b:b + 1] for p in planes], box)[0] for b, box in enumerate(boxes)]

    def level_modules(self, level: int) -> list:
        """G_level's own modules (and P's at level 0)."""
        return [self.levels[level]] + ([self.projection] if level == 0 else [])

    def trained_modules(self, level: int) -> list:
        """What trains at a level: G_level and the shared decoder (and P at level 0)."""
        return self.level_modules(level) + [self.decoder]


class VoxelLevel(nn.Module):
    """A SinGAN-3D level: 3-D convs on the voxel grid, adding to its input.

    head Conv3d(1 -> C) and two Conv3d(C -> C), each with InstanceNorm and
    LeakyReLU(0.2); tail Conv3d(C -> 1) and tanh. out = input + tail, softly
    clamped to [0, 1] (slope 0.002 outside), as the authors' baseline does.
    """

    def __init__(self, channels: int):
        super().__init__()
        layers = []
        for c_in in (1, channels, channels):
            layers += [nn.Conv3d(c_in, channels, 3, padding=1, bias=False), nn.InstanceNorm3d(channels),
                       nn.LeakyReLU(0.2)]
        self.net = nn.Sequential(*layers, nn.Conv3d(channels, 1, 3, padding=1), nn.Tanh())

    def forward(self, noise: torch.Tensor, volume: torch.Tensor) -> torch.Tensor:
        out = volume + self.net(noise + volume)
        return torch.maximum(torch.minimum(out, 0.002 * out + 0.998), 0.002 * out)


class VoxelGenerator(nn.Module):
    """The paper's 3-D baseline (SinGAN-3D): the same pipeline with 3-D conv
    generators on voxels instead of tri-planes.

    Level 0: V_0 = L_0(z0, 0). Level i > 0: U = trilinear resize of V_(i-1)
    (align_corners=True); V_i = L_i(sigma_i n_i, U) with n_i a 1-channel
    volume. Training only: it has no .onnx export.
    """

    def __init__(self, channels: int = 32):
        super().__init__()
        self.channels = channels
        self.levels = nn.ModuleList()

    def add_level(self) -> VoxelLevel:
        level = VoxelLevel(self.channels)
        self.levels.append(level)
        return level

    def noise_shapes(self, size: tuple) -> list:
        return [(1, 1, *size)]

    def volume(self, z0, noises, sizes, upto: int) -> torch.Tensor:
        """(B, 1, X, Y, Z) output of level `upto`."""
        volume = self.levels[0](z0, torch.zeros_like(z0))
        for level in range(1, upto + 1):
            volume = self.output_volume(volume, level, sizes[level], noises[level])
        return volume

    def output_volume(self, previous, level, size, noise) -> torch.Tensor:
        upsampled = F.interpolate(previous, size=size, mode="trilinear", align_corners=True)
        return self.levels[level](torch.zeros_like(upsampled) if noise is None else noise[0], upsampled)

    def forward(self, z0, noises, sizes, upto: int | None = None) -> torch.Tensor:
        return self.volume(z0, noises, sizes, len(self.levels) - 1 if upto is None else upto)[:, 0]

    def inputs(self, z0, noises, sizes, first: int):
        """z0 when level 0 trains, else the frozen levels' volume (no gradients)."""
        if first == 0:
            return z0
        with torch.no_grad():
            return self.volume(z0, noises, sizes, first - 1)

    def output(self, inputs, first: int, level: int, sizes: list, noises: list, boxes: list) -> list:
        volume = inputs
        for at, noise in zip(range(first, level + 1), noises):
            volume = (self.levels[0](volume, torch.zeros_like(volume)) if at == 0
                      else self.output_volume(volume, at, sizes[at], noise))
        return [volume[b, 0] if box is None else volume[b, 0][box] for b, box in enumerate(boxes)]

    def level_modules(self, level: int) -> list:
        return [self.levels[level]]

    def trained_modules(self, level: int) -> list:
        return self.level_modules(level)


def make_generator(kind: str, channels: int, bins: int, hidden: int, colour: bool = False) -> nn.Module:
    """The generator a config names: the paper's tri-planes (with a colour
    head for a coloured example) or the voxel baseline (geometry only)."""
    if kind == "triplane":
        return TriplaneGenerator(channels, bins, hidden, colour)
    if kind == "voxel" and colour:
        raise InputError("the voxel baseline learns geometry only; train it with `no_colour`", "no_colour")
    if kind == "voxel":
        return VoxelGenerator(channels)
    raise ValueError(f"unknown generator {kind!r}; choose triplane or voxel")


class Discriminator(nn.Module):
    """Patch critic with an 11^3 receptive field. It returns its score map;
    the WGAN losses use the map's mean, the gradient penalty its sum.
    `inputs` channels: 1 (occupancy), or 4 for colour (`critic_input`)."""

    def __init__(self, channels: int = 32, inputs: int = 1):
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv3d(inputs, channels, 3, stride=2, padding=1, bias=False),
            nn.InstanceNorm3d(channels),
            nn.LeakyReLU(0.2),
            nn.Conv3d(channels, channels, 3, bias=False),
            nn.InstanceNorm3d(channels),
            nn.LeakyReLU(0.2),
            nn.Conv3d(channels, 1, 3),
        )

    def forward(self, volume: torch.Tensor, framed: bool = False) -> torch.Tensor:
        """volume : (B, 1, X, Y, Z) -> (B, 1, x, y, z) scores. framed: the
        volume carries the one voxel around it that the first layer reads
        (zeros where that is outside the grid), so it is not padded again."""
        first, norm1, act1, middle, norm2, act2, last = self.net
        volume = act1(norm1(F.conv3d(volume, first.weight, stride=2) if framed else first(volume)))
        volume = act2(norm2(valid_conv(middle, volume)))
        return valid_conv(last, volume).float()  # the WGAN losses are small differences of large scores


def critic_input(volume: torch.Tensor) -> torch.Tensor:
    """What the critic sees of one grid: (1, 1, X, Y, Z) occupancy, or for a
    coloured grid (4, X, Y, Z) (1, 4, X, Y, Z) occupancy and occupancy x RGB,
    so that colour counts where there is solid, and the critic judges shape
    and colour together (snow on tops, not anywhere)."""
    if volume.dim() == 3:
        return volume[None, None]
    return torch.cat([volume[:1], volume[:1] * volume[1:]])[None]


# PyTorch (aten's use_mkldnn rule) runs a batch-1 float32 convolution with
# stride 1 and a kernel of at most 3 on its generic slow_conv kernel, not
# oneDNN, when batch * channels * the first two spatial sides is at most this.
SLOW_KERNEL_LIMIT = 20480
# From this many input voxels per sample in the batch (a batch of B: B times
# this many), a one-output-channel convolution and its gradients are faster
# as a matrix product than in oneDNN (measured from 8x6x6 to 62x16x28).
ONE_CHANNEL_PRODUCT_VOXELS = 8192


def valid_conv(conv: nn.Conv3d, x: torch.Tensor) -> torch.Tensor:
    """conv(x) for a stride-1, unpadded 3-D convolution, computed the fastest
    of three equal ways (`valid_conv_method`)."""
    method = valid_conv_method(conv, x)
    if method == "product":
        return one_channel_conv(x, conv.weight, conv.bias)
    return halves_conv(conv, x) if method == "halves" else conv(x)


def valid_conv_method(conv: nn.Conv3d, x: torch.Tensor) -> str:
    """How `valid_conv` computes conv(x): on a CPU in float32,

    - "product": one output channel (the critic's last layer) on a large
      grid, as a matrix product and shifted sums. oneDNN's kernels vectorise
      over output channels and run such a layer at a tenth of their speed;
    - "halves": batch 1 where PyTorch would pick its generic slow_conv kernel
      (generator steps and gradient penalty below about 90x25x40), as two
      overlapping halves along x in a batch of two, which oneDNN takes;
    - "conv": PyTorch's own choice, as everywhere else (GPU, bf16).
    """
    if x.device.type != "cpu" or x.dtype != torch.float32 or torch.is_autocast_enabled("cpu"):
        return "conv"
    if conv.out_channels == 1 and x.shape[2:].numel() >= ONE_CHANNEL_PRODUCT_VOXELS * x.shape[0]:
        return "product"
    if x.shape[0] == 1 and x.shape[:4].numel() <= SLOW_KERNEL_LIMIT and x.shape[2] > conv.kernel_size[0]:
        return "halves"
    return "conv"


def one_channel_conv(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    """conv3d(x, weight, bias) for one output channel and no padding: every
    kernel tap's channel sum in one matrix product, then the taps' grids
    shifted and added. x (B, C, X, Y, Z), weight (1, C, k, k, k)."""
    b, c, *size = x.shape
    k = weight.shape[-1]
    taps = torch.matmul(weight.reshape(c, -1).T, x.reshape(b, c, -1)).view(b, -1, *size)  # (B, k^3, X, Y, Z)
    out_size = [n - k + 1 for n in size]
    out = None
    for tap, tap_grid in enumerate(taps.unbind(1)):  # unbind: each tap's gradient is its own small tensor
        i, j, h = tap // (k * k), tap // k % k, tap % k
        part = tap_grid[:, i:i + out_size[0], j:j + out_size[1], h:h + out_size[2]]
        if out is None:  # one output tensor, summed into in place
            out = part.clone() if bias is None else part + bias
        else:
            out += part
    return out[:, None]


def halves_conv(conv: nn.Conv3d, x: torch.Tensor) -> torch.Tensor:
    """conv(x) for batch 1, stride 1 and no padding, as one call on the two
    halves of x along its first axis (overlapping by the kernel's reach, and by
    one output slice more when the count is odd): the same outputs."""
    reach = conv.kernel_size[0] - 1
    length = x.shape[2] - reach  # output slices
    half = (length + 1) // 2
    out = conv(torch.cat([x[:, :, :half + reach], x[:, :, length - half:]]))
    return torch.cat([out[:1], out[1:, :, 2 * half - length:]], dim=2)
