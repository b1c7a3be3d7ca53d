"""LP-IoU, LP-F-score and diversity: answers known by construction, and the
vectorised matching against a plain loop over patch pairs."""

import numpy as np
import pytest
from scipy import ndimage

from sinshape.runtime import evaluate
from sinshape.core.errors import InputError
from sinshape.runtime.evaluate import diversity, lp_metrics, lp_scores, valid_patches


def scores(generated, reference, seed=0, max_patches=1000):
    return lp_scores(generated, valid_patches(reference), np.random.default_rng(seed), max_patches)


def assert_perfect(result):
    assert result["lp_iou"] == result["lp_f"] == result["mean_iou"] == 1.0
    assert result["mean_f"] == pytest.approx(1.0, abs=1e-8)  # the paper's F has 1e-8 in its denominator


def blobs(shape, seed):
    """A smooth random solid: thresholded smoothed noise, surfaces everywhere."""
    noise = np.random.default_rng(seed).random(shape)
    return ndimage.gaussian_filter(noise, 1.5) > 0.5


def lattice(period, seed, size=30):
    """A random period^3 block tiled over a size^3 grid."""
    block = np.random.default_rng(seed).random((period,) * 3) < 0.5
    return np.tile(block, (size // period,) * 3)


# ---- valid_patches ----------------------------------------------------------

# Patch starts are 0, 5, 10, ... in the padded volume, so a patch's central
# 3^3 region covers volume coordinates start - 1 .. start + 1 on each axis.

@pytest.mark.parametrize("voxel, index", [
    ((5, 6, 9), (5, 6, 4)),     # starts (5, 5, 10); index in patch = voxel + 5 - start
    ((0, 0, 0), (5, 5, 5)),     # corner: the patch at start 0 is mostly padding
    ((11, 11, 11), (6, 6, 6)),  # far corner: start 10 still exists (10 + 11 <= 22)
])
def test_a_single_voxel_is_in_exactly_one_patch(voxel, index):
    volume = np.zeros((12, 12, 12), bool)
    volume[voxel] = True
    patches = valid_patches(volume)
    assert patches.shape == (1, 11, 11, 11)
    assert np.argwhere(patches[0]).tolist() == [list(index)]


def test_a_voxel_between_patch_centres_is_in_no_valid_patch():
    volume = np.zeros((12, 12, 12), bool)
    volume[2, 5, 5] = True  # x = 2 is 2 away from the centres at 0 and 5
    assert valid_patches(volume).shape == (0, 11, 11, 11)
    assert len(valid_patches(np.zeros((12, 12, 12), bool))) == 0


@pytest.mark.parametrize("side, expected", [
    (12, 27 - 8),  # starts 0, 5, 10; the padding is in the centre of start 0 only
    (11, 27 - 1),  # starts 0, 5, 10; start 10's centre 9..11 reaches the padding at 11
])
def test_a_full_volume_has_valid_patches_where_its_centre_meets_the_padding(side, expected):
    assert len(valid_patches(np.ones((side,) * 3, bool))) == expected


# ---- lp_scores / lp_metrics: answers known by construction ------------------

def test_a_volume_against_itself_scores_one():
    volume = blobs((24, 20, 28), seed=1)
    assert_perfect(scores(volume, volume))


def test_the_complement_of_a_tiny_volume_scores_zero():
    # A volume of at most 5^3 voxels has one patch position (start 0 on every
    # axis) holding the whole volume, so both the volume and its complement
    # have one patch, placed identically inside the (empty) padding. No voxel
    # is occupied in both: overlap 0, so IoU = F = 0 exactly.
    # Larger volumes need not score 0: the padding is empty in both, so the
    # complement gains surfaces along the volume's faces, and those patches
    # can match reference patches (a half-space's complement has LP-F 0.3).
    volume = np.random.default_rng(2).random((5, 5, 5)) < 0.5
    result = scores(~volume, volume)
    assert result == {"lp_iou": 0.0, "lp_f": 0.0, "mean_iou": 0.0, "mean_f": 0.0, "patches": 1}


def test_a_lattice_shifted_by_whole_periods_scores_one():
    # Period 5 = the stride: a window moved by whole periods and cut to the
    # same size modulo 5 has the reference's patches, padding included.
    reference = lattice(5, seed=3)
    assert_perfect(scores(reference[5:, 10:, :-5], reference))
    assert_perfect(scores(np.roll(reference, 5, axis=1), reference))


def test_a_shift_by_a_non_multiple_of_the_stride_needs_translation_invariant_statistics():
    # Patches are cut at x = 0, 5, 10, ... only, so a copy shifted by 2 shows
    # its content at phases the reference may never have been sampled at.
    # A period-3 lattice looks the same from every position up to its phase,
    # and the starts 0, 5, 10, ... hit every phase mod 3 (3 and 5 are
    # coprime): every shifted patch away from the x padding (4 of the 6
    # x starts: 5, 10, 15, 20) is exactly some reference patch. Only the
    # patches reaching into the padding (starts 0 and 25) show a phase next to
    # the border that the reference lacks.
    reference = lattice(3, seed=4)
    result = scores(np.roll(reference, 2, axis=0), reference)
    assert result["patches"] == 6**3  # every centre 3^3 holds a whole block: all valid
    assert result["lp_iou"] >= 4 / 6 and result["lp_f"] >= 4 / 6
    # A period-5 lattice is sampled at one phase only; shifted by 2, nothing matches.
    period_5 = lattice(5, seed=3)
    assert scores(np.roll(period_5, 2, axis=0), period_5)["lp_iou"] == 0.0


@pytest.mark.parametrize("axes", [(0,), (1,), (2,), (0, 1, 2)])
def test_flipped_copies_of_a_mirror_symmetric_volume_score_one(axes):
    x, y, z = np.meshgrid(*[np.linspace(-1, 1, n) for n in (31, 24, 19)], indexing="ij")
    ellipsoid_shell = np.abs(x**2 + 2 * y**2 + 3 * z**2 - 0.6) < 0.15
    flipped = np.flip(ellipsoid_shell, axes)
    assert np.array_equal(flipped, ellipsoid_shell)  # the premise
    assert_perfect(scores(flipped, ellipsoid_shell))


def test_a_shape_without_valid_patches_scores_zero():
    result = scores(np.zeros((20, 20, 20), bool), blobs((20, 20, 20), seed=5))
    assert result == {"lp_iou": 0.0, "lp_f": 0.0, "mean_iou": 0.0, "mean_f": 0.0, "patches": 0}


def test_max_patches_picks_a_seeded_subset():
    reference = blobs((40, 40, 40), seed=6)
    generated = reference ^ (np.random.default_rng(7).random(reference.shape) < 0.02)
    assert len(valid_patches(generated)) > 100
    results = [scores(generated, reference, seed, max_patches=20) for seed in range(5)]
    assert all(r["patches"] == 20 for r in results)
    assert scores(generated, reference, 3, max_patches=20) == results[3]
    assert len({r["mean_iou"] for r in results}) > 1  # different seeds, different subsets
    assert scores(generated, reference, max_patches=10**6)["patches"] == len(valid_patches(generated))


def test_lp_metrics_averages_samples_that_do_not_affect_each_other():
    reference = blobs((24, 24, 24), seed=8)
    copy = reference ^ (np.random.default_rng(9).random(reference.shape) < 0.02)
    empty = np.zeros((10, 12, 14), bool)
    with_empty = lp_metrics([empty, copy], reference, seed=1, max_patches=30)
    with_self = lp_metrics([reference, copy], reference, seed=1, max_patches=30)
    # Sample i's subset comes from its own generator: the first sample (with
    # 0 or 30 patches) does not change the second's.
    assert with_empty["per_sample"]["lp_iou"][1] == with_self["per_sample"]["lp_iou"][1]
    assert with_empty["per_sample"]["patches"] == [0, 30]
    second = with_empty["per_sample"]
    for key in ("lp_iou", "lp_f", "mean_iou", "mean_f"):
        assert with_empty[key] == pytest.approx(second[key][1] / 2)  # the empty shape counts 0
    assert with_self["lp_iou"] == pytest.approx((1 + second["lp_iou"][1]) / 2)
    assert with_self["reference_patches"] == len(valid_patches(reference))


def test_a_voxelised_example_against_itself_scores_one(tmp_path):
    from sinshape.prep import pyramid, shapes

    path = tmp_path / "acropolis.obj"
    shapes.write_shape("acropolis", path, detail=4)
    volume = pyramid.load_pyramid(path, res=64, levels=1).levels[-1]
    assert len(valid_patches(volume)) > 100
    assert_perfect(lp_metrics([volume], volume))


# ---- the vectorised matching against a plain loop ---------------------------

def loop_valid_patches(volume, size=11, stride=5):
    padded = np.pad(volume, size // 2)
    starts = [range(0, n - size + 1, stride) for n in padded.shape]
    patches = []
    for i in starts[0]:
        for j in starts[1]:
            for k in starts[2]:
                patch = padded[i:i + size, j:j + size, k:k + size]
                centre = patch[4:7, 4:7, 4:7]
                if centre.any() and not centre.all():
                    patches.append(patch)
    return np.array(patches).reshape(-1, size, size, size)


def loop_lp(generated, reference, threshold=0.95):
    """The paper's definitions, one pair at a time."""
    best_iou, best_f = [], []
    for a in generated:
        ious, fs = [], []
        for b in reference:
            overlap = np.sum(a & b)
            ious.append(overlap / np.sum(a | b))
            precision, recall = overlap / a.sum(), overlap / b.sum()
            fs.append(2 * precision * recall / (precision + recall + 1e-8))
        best_iou.append(max(ious))
        best_f.append(max(fs))
    best_iou, best_f = np.array(best_iou), np.array(best_f)
    return {"lp_iou": np.mean(best_iou > threshold), "lp_f": np.mean(best_f > threshold),
            "mean_iou": best_iou.mean(), "mean_f": best_f.mean()}


def test_vectorised_matching_equals_the_loop(monkeypatch):
    monkeypatch.setattr(evaluate, "REFERENCE_CHUNK", 7)  # many chunks: the running best across them
    rng = np.random.default_rng(10)
    reference = blobs((22, 17, 26), seed=11)
    generated = [
        reference ^ (rng.random(reference.shape) < 0.01),   # near matches, both sides of 0.95
        np.roll(reference, (2, 1), axis=(0, 1))[:19, :, 3:],  # shifted and cropped
        blobs((16, 21, 18), seed=12),                         # unrelated
        rng.random((14, 12, 13)) < 0.5,                       # noise
    ]
    reference_patches = valid_patches(reference)
    assert np.array_equal(reference_patches, loop_valid_patches(reference))
    thresholds_crossed = False
    for volume in generated:
        patches = valid_patches(volume)
        assert np.array_equal(patches, loop_valid_patches(volume))
        result = lp_scores(volume, reference_patches, rng, max_patches=10**6)
        expected = loop_lp(patches, reference_patches)
        for key, value in expected.items():
            assert result[key] == pytest.approx(value, abs=1e-6), key
        thresholds_crossed |= 0 < expected["lp_iou"] < 1
    assert thresholds_crossed


# ---- diversity --------------------------------------------------------------

def halves(shape=(10, 6, 8)):
    left = np.zeros(shape, bool)
    left[: shape[0] // 2] = True
    return left, ~left


def test_identical_shapes_have_no_diversity():
    shape = blobs((12, 12, 12), seed=13)
    assert diversity([shape, shape.copy(), shape.copy()]) == 0.0
    assert diversity([shape]) == 0.0  # documented: one shape differs from nothing


def test_disjoint_halves_have_diversity_one():
    assert diversity(list(halves())) == 1.0


def test_diversity_of_three_hand_computed_shapes():
    left, right = halves()
    full = np.ones_like(left)
    # 1 - IoU: left/right 1, left/full 1 - 1/2, right/full 1 - 1/2.
    # Per shape: left (1 + 0.5) / 2, right the same, full (0.5 + 0.5) / 2.
    expected = (0.75 + 0.75 + 0.5) / 3
    assert diversity([left, right, full]) == pytest.approx(expected)
    assert diversity([left.astype(np.float32), right, full]) == pytest.approx(expected)  # occupancy > 0.5


# ---- bad input --------------------------------------------------------------

def test_a_reference_without_valid_patches_is_an_input_error():
    shape = blobs((16, 16, 16), seed=14)
    for reference in (np.zeros((16, 16, 16), bool), np.pad(np.ones((1, 1, 1), bool), ((2, 0), (2, 0), (2, 0)))):
        with pytest.raises(InputError, match="no valid patches"):
            lp_metrics([shape], reference)


def test_bad_inputs_are_input_errors():
    left, _ = halves()
    with pytest.raises(InputError, match="one shape"):
        diversity([left, left[:-1]])
    with pytest.raises(InputError):
        diversity([])
    with pytest.raises(InputError):
        lp_metrics([], left)
    with pytest.raises(InputError, match="3-D"):
        valid_patches(np.zeros((8, 8), bool))


# ---- height_autocorrelation -------------------------------------------------

def ridges(up: int) -> np.ndarray:
    """A height field with a ridge every 18 voxels along one horizontal axis and
    a random phase per line across it: (60, 72, 12) with z up, (60, 12, 72) with y up."""
    rng = np.random.default_rng(0)
    along = np.arange(72)
    heights = 6 + 4 * np.sin(2 * np.pi * along / 18 + rng.uniform(0, 2 * np.pi, (60, 1)))  # (60 across, 72 along)
    volume = np.arange(12) < heights[..., None]  # (60, 72, 12): z up
    return volume if up == 2 else np.moveaxis(volume, 2, 1)


@pytest.mark.parametrize("up", [2, 1])
def test_height_autocorrelation_follows_the_axis_asked_for(up):
    """Ridges every 18 voxels along the second horizontal axis: about 1 at 18 and 36
    along it, and none across it, whichever axis is up (an index into the height
    field taken as the volume's axis once measured x when asked for y)."""
    volume = ridges(up)
    along, across = (1, 0) if up == 2 else (2, 0)
    period = evaluate.height_autocorrelation(volume, up, along, [9, 18, 36])
    assert period[0] < -0.7 and period[1] > 0.7 and period[2] > 0.6
    assert max(abs(v) for v in evaluate.height_autocorrelation(volume, up, across, [9, 18, 36])) < 0.3
    with pytest.raises(InputError):
        evaluate.height_autocorrelation(volume, up, up, [18])
