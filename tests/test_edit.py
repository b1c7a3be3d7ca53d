"""Composing a sample from parts of others: the kept box is the source's, the
rest is the base's away from the boxes, the join has no step, bad parts are
refused in one line."""

import numpy as np
import pytest
from click.testing import CliRunner

from sinshape import models
from sinshape.cli.main import cli
from sinshape.runtime import dense, load_model, sample
from sinshape.runtime.edit import MARGIN, Part, compose, grow, parse_part
from sinshape.core.errors import InputError
from test_cli_train import assert_one_line_error

LOW, HIGH = (12, 0, 0), (40, 20, 31)  # on the acropolis (64x37x32): faces at x 12, 40 and y 20


@pytest.fixture(scope="module")
def acropolis():
    return load_model(models.find("acropolis"), threads=1)


@pytest.fixture(scope="module")
def composed(acropolis):
    return compose(acropolis, 7, [Part(3, LOW, HIGH)])


def test_the_kept_box_is_the_source_and_far_away_is_the_base(acropolis, composed):
    result, part, base = (dense(acropolis, t) for t in (composed, sample(acropolis, 3), sample(acropolis, 7)))
    kept = (slice(LOW[0] + MARGIN, HIGH[0] - MARGIN + 1), slice(0, HIGH[1] - MARGIN + 1), slice(None))
    assert np.abs(result[kept] - part[kept]).max() <= 1e-6
    # Away from the box's shadow: x and y both more than MARGIN outside its range (it spans all of z).
    x, y = np.meshgrid(np.arange(64), np.arange(37), indexing="ij")
    far = ((x <= LOW[0] - MARGIN) | (x >= HIGH[0] + MARGIN)) & (y >= HIGH[1] + MARGIN)
    assert far.sum() > 200 and np.abs(result[far] - base[far]).max() <= 1e-6
    # A new shape, not a copy of either.
    assert np.abs(result - part).max() > 0.5 and np.abs(result - base).max() > 0.5


def face_steps(planes, low, high) -> list:
    """Per face at x = low, x = high: the step between the plane cells either
    side of it, over the mean step at the 2 places either side of it (the xy
    and xz planes, rows inside the box)."""
    ratios = []
    for plane, rows in ((planes[0], slice(0, HIGH[1] + 1)), (planes[1], slice(None))):
        steps = np.abs(np.diff(plane[:, :, rows], axis=1)).mean(axis=(0, 2))
        for face in (low, high - 1):  # the step from cell `face` to `face + 1`, at the box's edge
            around = np.r_[steps[face - 2:face], steps[face + 1:face + 3]]
            ratios.append(steps[face] / around.mean())
    return ratios


def test_the_join_has_no_step_where_a_pasted_box_has_one(acropolis, composed):
    base, part = sample(acropolis, 7), sample(acropolis, 3)
    assert max(face_steps(composed.planes, LOW[0], HIGH[0] + 1)) < 1.5
    pasted = [p.copy() for p in base.planes]  # the box copied in, without a join
    pasted[0][:, LOW[0]:HIGH[0] + 1, :HIGH[1] + 1] = part.planes[0][:, LOW[0]:HIGH[0] + 1, :HIGH[1] + 1]
    pasted[1][:, LOW[0]:HIGH[0] + 1, :] = part.planes[1][:, LOW[0]:HIGH[0] + 1, :]
    assert max(face_steps(pasted, LOW[0], HIGH[0] + 1)) > 1.5  # the check sees a seam where there is one


def test_the_same_parts_give_the_same_shape_and_a_later_part_wins(acropolis, composed):
    assert all(np.array_equal(a, b) for a, b in zip(composed.planes, compose(acropolis, 7, [Part(3, LOW, HIGH)]).planes))
    both = dense(acropolis, compose(acropolis, 7, [Part(3, LOW, HIGH), Part(5, LOW, HIGH)]))
    kept = (slice(LOW[0] + MARGIN, HIGH[0] - MARGIN + 1), slice(0, HIGH[1] - MARGIN + 1), slice(None))
    assert np.abs(both[kept] - dense(acropolis, sample(acropolis, 5))[kept]).max() <= 1e-6


def test_parts_in_the_frame_and_in_percent(acropolis):
    m = acropolis.manifest
    size = m.sizes[-1]
    corner = [m.origin[a] + 10 * m.spacing[a] for a in range(3)]
    part = parse_part(f"3:{','.join(map(str, corner))}:50%,100%,100%", m, size)
    assert part.seed == 3 and np.allclose(part.low, (10, 10, 10))
    assert np.allclose(part.high, (31.5, 36, 31))


@pytest.mark.parametrize("text, fragment", [
    ("3:0%,0%,0%", "give SEED:X0,Y0,Z0:X1,Y1,Z1"),
    ("x:0%,0%,0%:50%,50%,50%", "is not an integer"),
    ("3:0%,0%:50%,50%,50%", "needs 3 values"),
    ("3:0%,0%,a:50%,50%,50%", "not a number or a percentage"),
    ("3:0%,0%,0%:150%,50%,50%", "leaves the sample"),
    ("3:50%,0%,0%:20%,50%,50%", "empty or inverted along x"),
    ("3:40%,0%,0%:45%,50%,50%", "a kept box needs more than 8"),
    ("-1:0%,0%,0%:50%,50%,50%", "seed"),
])
def test_bad_parts_are_refused_in_one_line_and_nothing_is_written(acropolis, tmp_path, text, fragment):
    with pytest.raises(InputError, match=fragment):
        parse_part(text, acropolis.manifest, acropolis.manifest.sizes[-1])
    out = tmp_path / "k.ply"
    result = CliRunner().invoke(cli, ["sample", "acropolis", "--seed", "7", "--keep", text, "-o", str(out)])
    assert_one_line_error(result, fragment)
    assert not out.exists()


def test_sample_keep_writes_the_composed_shape(acropolis, tmp_path):
    out = tmp_path / "k.npz"
    m = acropolis.manifest
    low = ",".join(str(m.origin[a] + LOW[a] * m.spacing[a]) for a in range(3))
    parts = [f"3:{low}:60%,50%,100%", "5:50%,60%,0%:100%,100%,100%"]
    result = CliRunner().invoke(cli, ["sample", "acropolis", "--seed", "7", "--keep", parts[0], "--keep", parts[1],
                                      "-o", str(out), "--threads", "1"])
    assert result.exit_code == 0, result.output
    expected = compose(acropolis, 7, [parse_part(text, m, m.sizes[-1]) for text in parts])
    assert np.array_equal(np.load(out)["occupancy"], dense(acropolis, expected))


@pytest.fixture(scope="module")
def terrain():
    return load_model(models.find("terrain"), threads=1)


@pytest.mark.parametrize("by, anchor", [((2, 1, 1), (0, 0, 0)), ((1.5, 1.5, 1), (1, 0.5, 0))])
def test_a_grown_sample_keeps_what_it_had(terrain, by, anchor):
    old = dense(terrain, sample(terrain, 3))
    new = dense(terrain, grow(terrain, 3, by, anchor))
    assert new.shape == tuple(round(n * f) for n, f in zip(old.shape, by))
    offset = [round(a * (n - o)) for a, n, o in zip(anchor, new.shape, old.shape)]
    kept = []  # the old sample's voxels, less the join where a face lies inside the new one
    for lo, n, big in zip(offset, old.shape, new.shape):
        start = lo + MARGIN if lo > 0 else lo
        end = lo + n - MARGIN if lo + n < big else lo + n
        kept.append(slice(start, end))
    old_kept = tuple(slice(k.start - lo, k.stop - lo) for k, lo in zip(kept, offset))
    assert np.abs(new[tuple(kept)] - old[old_kept]).max() <= 1e-6
    outside = np.ones(new.shape, bool)
    outside[tuple(slice(lo, lo + n) for lo, n in zip(offset, old.shape))] = False
    assert (new[outside] > 0.5).any()  # new ground where there was none


def test_sample_grow_on_the_command_line(terrain, tmp_path):
    out = tmp_path / "g.npz"
    result = CliRunner().invoke(cli, ["sample", "terrain", "--seed", "3", "--grow", "2,1,1", "--anchor", "1,0,0",
                                      "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert np.array_equal(np.load(out)["occupancy"], dense(terrain, grow(terrain, 3, (2, 1, 1), (1, 0, 0))))
    for args, fragment in ((["--grow", "0.5"], "at least 1"), (["--grow", "2", "--anchor", "2"], "fractions"),
                           (["--anchor", "0"], "--anchor is for --grow"),
                           (["--grow", "2", "--keep", "3:0%,0%,0%:50%,100%,100%"], "give one of")):
        result = CliRunner().invoke(cli, ["sample", "terrain", "--seed", "3", *args, "-o", str(tmp_path / "x.ply")])
        assert result.exit_code != 0 and fragment in result.output, result.output
        assert not (tmp_path / "x.ply").exists()
