"""The torch networks agree with the paper's definitions and with the runtime's numpy."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from sinshape.runtime import generate  # noqa: E402
from sinshape.trainer import networks  # noqa: E402


def test_projection_pooling_matches_the_runtime():
    volume = np.random.default_rng(0).normal(size=(17, 15, 23)).astype(np.float32)
    pooled_torch = networks.Projection(8, 32).pool(torch.from_numpy(volume)[None, None])
    pooled_numpy = generate.adaptive_pool(volume, 8)
    for t, n in zip(pooled_torch, pooled_numpy):
        np.testing.assert_allclose(t[0].numpy(), n, atol=1e-6)
    # xy drops z: the bins average slabs of z.
    np.testing.assert_allclose(pooled_numpy[0][0], volume[:, :, 0:3].mean(axis=2), atol=1e-6)


def test_plane_resize_matches_the_runtime():
    """The trainer's resize of a tri-plane to a finer grid, plane by plane,
    equals the runtime's numpy resize (both bilinear, align_corners)."""
    planes = [torch.randn(1, 8, *s) for s in networks.plane_sizes((11, 15, 9))]
    size = (21, 29, 13)
    resized = networks.resize_planes(planes, size)
    for plane, ours, shape in zip(planes, resized, networks.plane_sizes(size)):
        theirs = generate.resize_plane(plane[0].numpy(), shape)
        assert theirs.shape == (8, *shape)
        np.testing.assert_allclose(ours[0].numpy(), theirs, atol=1e-5)
    # align_corners: the corner cells are kept exactly.
    np.testing.assert_allclose(resized[0][0, :, -1, -1].numpy(), planes[0][0, :, -1, -1].numpy(), atol=1e-6)


def test_decoder_first_layer_trick_equals_the_whole_mlp():
    decoder = networks.Decoder(32, 32)
    planes = [torch.randn(1, 32, *s) for s in networks.plane_sizes((9, 7, 5))]
    grid = decoder.grid(planes)[0]
    axes = [torch.linspace(-1, 1, n) for n in (9, 7, 5)]
    coords = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
    with torch.no_grad():
        points = decoder.points(planes, coords).reshape(9, 7, 5)
    np.testing.assert_allclose(grid.detach().numpy(), points.numpy(), atol=1e-5)


def test_discriminator_receptive_field_is_11_voxels():
    critic = networks.Discriminator()
    # InstanceNorm couples every voxel through its statistics; the field is the convs'.
    critic.net = torch.nn.Sequential(*[torch.nn.Identity() if isinstance(m, torch.nn.InstanceNorm3d) else m
                                       for m in critic.net])
    volume = torch.zeros(1, 1, 31, 31, 31, requires_grad=True)
    scores = critic(volume)
    scores[0, 0, 5, 5, 5].backward()
    touched = volume.grad[0, 0].abs() > 0
    extent = [int(np.ptp(np.nonzero(touched.numpy())[axis])) + 1 for axis in range(3)]
    assert extent == [11, 11, 11]


def test_generator_keeps_sizes_through_levels():
    gen = networks.TriplaneGenerator()
    for _ in range(3):
        gen.add_level()
    sizes = [(15, 15, 15), (20, 18, 15), (26, 24, 16)]
    noises = [None] + [[torch.randn(1, 32, *s) for s in networks.plane_sizes(size)] for size in sizes[1:]]
    with torch.no_grad():
        occupancy = gen(torch.randn(1, 1, *sizes[0]), noises, sizes)
    assert occupancy.shape == (1, *sizes[-1])
    assert occupancy.min() >= 0 and occupancy.max() <= 1


def test_grid_head_gradients_are_exact(monkeypatch):
    monkeypatch.setattr(networks.GridHead, "SLAB_FLOATS", 40)  # several slabs even on a tiny grid
    gen = torch.Generator().manual_seed(0)
    shapes = [(5, 4, 3), (5, 6, 3), (4, 6, 3), (1, 3), (1,)]
    inputs = [torch.randn(s, generator=gen, dtype=torch.float64, requires_grad=True) for s in shapes]
    assert len(networks.GridHead.slabs(inputs[0], inputs[2])) > 1
    assert torch.autograd.gradcheck(networks.GridHead.apply, inputs)


def test_an_unknown_generator_kind_is_refused():
    assert isinstance(networks.make_generator("voxel", 8, 4, 8), networks.VoxelGenerator)
    with pytest.raises(ValueError, match="unknown generator 'voxels'"):
        networks.make_generator("voxels", 8, 4, 8)


@pytest.mark.parametrize("kind", ["triplane", "voxel"])
def test_a_batch_gives_each_sample_as_alone(kind):
    """Training runs several samples as one batch; each must come out as it
    would on its own (InstanceNorm is per sample, the decoder per grid)."""
    torch.manual_seed(0)
    gen = networks.make_generator(kind, 8, 4, 8)
    sizes = [(15, 15, 16), (20, 18, 21)]
    for _ in sizes:
        gen.add_level()
    z0 = torch.randn(3, 1, *sizes[0])
    noise = [torch.randn(3, *shape[1:]) for shape in gen.noise_shapes(sizes[1])]
    with torch.no_grad():
        batch = torch.stack(gen.output(gen.inputs(z0, [None, noise], sizes, 1), 1, 1, sizes, [noise], [None] * 3))
        alone = [gen.output(gen.inputs(z0[i:i + 1], [None, [n[i:i + 1] for n in noise]], sizes, 1), 1, 1,
                            sizes, [[n[i:i + 1] for n in noise]], [None])[0][None] for i in range(3)]
    assert batch.shape == (3, *sizes[1])
    np.testing.assert_allclose(batch.numpy(), torch.cat(alone).numpy(), atol=1e-5)
    assert (batch[0] - batch[1]).abs().max() > 1e-3  # the samples differ


def critic_and_its_plain_twin(volume: torch.Tensor, critic: "networks.Discriminator") -> list:
    """Scores, input gradient and weight gradients of the gradient penalty's
    double backward, through `critic` and through its layers as PyTorch runs them."""
    results = []
    for forward in (critic, critic.net):
        critic.zero_grad()
        x = volume.clone().requires_grad_(True)
        scores = forward(x)
        (grad,) = torch.autograd.grad(scores.sum(), x, create_graph=True)
        grad.square().sum().backward()
        results.append([scores, grad] + [p.grad.clone() for p in critic.parameters() if p.grad is not None])
    return results


@pytest.mark.parametrize("size, batch, methods", [
    ((24, 15, 17), 1, ["halves", "halves"]),  # an even number of output slices
    ((25, 15, 17), 1, ["halves", "halves"]),  # odd: the halves overlap by one more
    ((60, 48, 50), 1, ["halves", "product"]),  # the last layer on 28x22x23 voxels
    ((92, 48, 50), 2, ["conv", "product"]),   # real and fake: twice the voxels
    ((24, 15, 17), 2, ["conv", "conv"]),
])
def test_the_critic_computes_each_layer_as_pytorch_does(size, batch, methods):
    """Its convolutions take other kernels (valid_conv), not other values."""
    torch.manual_seed(0)
    critic = networks.Discriminator(8 if max(size) < 60 else 4)
    volume = torch.rand(batch, 1, *size)
    middle_in = [(n + 1) // 2 for n in size]
    picked = [networks.valid_conv_method(critic.net[3], torch.empty(batch, critic.net[3].in_channels, *middle_in)),
              networks.valid_conv_method(critic.net[6], torch.empty(batch, critic.net[6].in_channels,
                                                                    *[n - 2 for n in middle_in]))]
    if "product" in methods:  # the rule counts voxels; these tests use fewer channels, not fewer voxels
        assert picked[1] == "product"
    assert picked == methods
    ours, plain = critic_and_its_plain_twin(volume, critic)
    for mine, theirs in zip(ours, plain):  # float sums in another order: within 1e-5 of the largest
        assert mine.shape == theirs.shape
        assert (mine - theirs).abs().max() <= 1e-5 * theirs.abs().max()
    assert ours[1].abs().sum() > 0 and all(g.abs().sum() > 0 for g in ours[2:])


def test_batch_one_calls_leave_the_slow_kernel():
    critic = networks.Discriminator(8)
    volume = torch.rand(1, 1, 24, 15, 17, requires_grad=True)
    with torch.profiler.profile(record_shapes=True) as profile:
        (grad,) = torch.autograd.grad(critic(volume).sum(), volume, create_graph=True)
        grad.square().sum().backward()
    # (batch, channels) of the inputs that took the slow kernel: only 1-channel
    # ones (the first layer: cheap) may remain.
    slow = [tuple(e.input_shapes[0][:2]) for e in profile.events() if e.name == "aten::slow_conv3d_forward"]
    assert all(channels == 1 for _, channels in slow)
    assert any(e.name == "aten::mkldnn_convolution" for e in profile.events())


def test_the_critic_keeps_pytorchs_kernels_under_autocast():
    with torch.autocast("cpu", dtype=torch.bfloat16):
        assert networks.valid_conv_method(networks.Discriminator(8).net[6], torch.empty(1, 8, 40, 40, 40)) == "conv"

def test_wide_grid_head_gradients_are_exact(monkeypatch):
    # Occupancy and colour from one hidden layer: (K, hidden) weights, K = 4.
    monkeypatch.setattr(networks.GridHead, "SLAB_FLOATS", 40)
    gen = torch.Generator().manual_seed(0)
    shapes = [(5, 4, 3), (5, 6, 3), (4, 6, 3), (4, 3), (4,)]
    inputs = [torch.randn(s, generator=gen, dtype=torch.float64, requires_grad=True) for s in shapes]
    assert torch.autograd.gradcheck(networks.WideGridHead.apply, inputs)


def test_a_coloured_decoder_gives_occupancy_and_colour_from_one_hidden_layer():
    torch.manual_seed(0)
    plain, coloured = networks.Decoder(32, 32), networks.Decoder(32, 32, colour=True)
    coloured.fc1.load_state_dict(plain.fc1.state_dict())
    coloured.fc2.load_state_dict(plain.fc2.state_dict())
    planes = [torch.randn(1, 32, *s) for s in networks.plane_sizes((9, 7, 5))]
    with torch.no_grad():
        grid, occupancy = coloured.grid(planes)[0], plain.grid(planes)[0]
        axes = [torch.linspace(-1, 1, n) for n in (9, 7, 5)]
        coords = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
        points = coloured.points(planes, coords).T.reshape(4, 9, 7, 5)
    assert grid.shape == (4, 9, 7, 5)
    np.testing.assert_allclose(grid[0].numpy(), occupancy.numpy(), atol=1e-6)  # the occupancy is unchanged
    np.testing.assert_allclose(grid.numpy(), points.numpy(), atol=1e-5)  # and the colour is the MLP's


def test_the_critic_sees_colour_only_where_there_is_solid():
    grid = torch.rand(4, 6, 5, 4)
    seen = networks.critic_input(grid)
    assert seen.shape == (1, 4, 6, 5, 4)
    np.testing.assert_allclose(seen[0, 1:].numpy(), (grid[:1] * grid[1:]).numpy())
    assert networks.critic_input(grid[0]).shape == (1, 1, 6, 5, 4)
