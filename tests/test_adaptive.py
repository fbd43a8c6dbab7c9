"""Defaults that follow the cloud: the terrain statistics on clouds whose answer is known, and
the rules applied, reported and overridden."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gfjax import adaptive, smrf
from gfjax.io.cloud import Cloud


def grid_plane(spacing_m: float, size_m: float, *, slope: float = 0.0, noise_m: float = 0.0, seed: int = 0) -> np.ndarray:
    """Points `(n, 3)` on a square lattice of `spacing_m` over `size_m` squared, z = slope * x."""
    axis = np.arange(0.0, size_m, spacing_m)
    x, y = np.meshgrid(axis, axis)
    z = slope * x + np.random.default_rng(seed).normal(0.0, noise_m, x.shape)
    return np.column_stack([x.ravel() + 500_000.0, y.ravel() + 5_000_000.0, z.ravel() + 200.0])


@pytest.mark.parametrize("spacing_m", [0.25, 1.0, 3.0, 7.0])
def test_spacing_of_a_lattice_is_its_pitch(spacing_m):
    terrain = adaptive.measure(grid_plane(spacing_m, 60 * spacing_m))
    assert terrain.spacing_m == pytest.approx(spacing_m, rel=0.08)
    assert terrain.last_spacing_m == terrain.spacing_m


def test_spacing_counts_the_covered_area_not_the_box():
    """Two patches far apart: the empty land between them is no part of the density."""
    patch = grid_plane(1.0, 50.0)
    far = patch + np.array([2000.0, 0.0, 0.0])
    terrain = adaptive.measure(np.concatenate([patch, far]))
    assert terrain.spacing_m == pytest.approx(1.0, rel=0.2)       # the box's density would give 4.5 m


@pytest.mark.parametrize("slope", [0.0, 0.1, 0.5, 1.0])
def test_slope_of_a_tilted_plane(slope):
    terrain = adaptive.measure(grid_plane(1.0, 200.0, slope=slope))
    assert terrain.slope_p50 == pytest.approx(slope, abs=0.01)
    assert terrain.slope_p90 == pytest.approx(slope, abs=0.01)
    assert terrain.relief_m == pytest.approx(0.96 * 200.0 * slope, abs=0.1 * 200 * slope + 0.05)


def test_a_step_is_seen_in_the_upper_slopes_only():
    xyz = grid_plane(1.0, 200.0)
    xyz[xyz[:, 0] - xyz[:, 0].min() >= 100.0, 2] += 5.0
    terrain = adaptive.measure(xyz)
    assert terrain.slope_p50 == pytest.approx(0.0, abs=1e-9)
    assert terrain.relief_m == pytest.approx(5.0)


def test_last_returns_give_their_own_spacing():
    xyz = grid_plane(1.0, 100.0)
    last = xyz[::16]                                  # one point in 16: four times the spacing
    terrain = adaptive.measure(xyz, last)
    assert terrain.last_spacing_m == pytest.approx(4.0, rel=0.1)


def test_measure_of_one_point_and_of_none():
    terrain = adaptive.measure(np.array([[1.0, 2.0, 3.0]]))
    assert math.isfinite(terrain.spacing_m) and terrain.slope_p90 == 0.0
    with pytest.raises(ValueError, match="at least one point"):
        adaptive.measure(np.empty((0, 3)))


def test_points_far_apart_are_refused_by_name_before_a_grid_beyond_the_budget(monkeypatch):
    """Two groups 400 km apart: the measuring grids over their box would not fit a 1 GiB
    budget, so `InputError` names the points and the extent before any such grid is made;
    the same groups 2 km apart measure as usual."""
    from gfjax.errors import InputError
    from gfjax.limits import BUDGET_ENV

    monkeypatch.setenv(BUDGET_ENV, "1")
    rng = np.random.default_rng(0)
    group = np.column_stack([rng.uniform(0, 100, (5000, 2)), rng.normal(50, 1, 5000)])
    made = []
    for maker in ("full", "zeros"):
        original = getattr(np, maker)
        monkeypatch.setattr(np, maker, lambda shape, *a, made_by=original, **k: made.append(shape) or made_by(shape, *a, **k))
    far = np.concatenate([group, group + [400_000.0, 300_000.0, 0.0]])
    with pytest.raises(InputError, match=r"far.laz: spread over 400\.1 x 300\.1 km.*memory budget of 1\.00 GiB"):
        adaptive.measure_chunks(adaptive.cloud_parts(tuple(far.T), tuple(far[:, :2].T)), name="far.laz")
    assert all(np.prod(shape) < 2**27 for shape in made)
    near = np.concatenate([group, group + [2_000.0, 0.0, 0.0]])
    assert adaptive.measure(near).n_points == len(near)


def chunked(xyz: np.ndarray, last: np.ndarray, bounds: list[int], last_bounds: list[int]):
    """`measure_chunks`' chunks of `xyz` and `last` cut at `bounds` and `last_bounds` (as many
    of each: a chunk may hold no point, or no last return), a list."""
    return [(tuple(xyz[a:b, j] for j in range(3)), (last[c:d, 0], last[c:d, 1]))
            for (a, b), (c, d) in zip(zip(bounds[:-1], bounds[1:]), zip(last_bounds[:-1], last_bounds[1:]))]


def as_parts(chunks: list, per_part: int) -> list:
    """`chunks` dealt into parts of `per_part` chunks each (a part yields its chunks anew at each call)."""
    return [lambda k=k: iter(chunks[k:k + per_part]) for k in range(0, len(chunks), per_part)]


@pytest.mark.parametrize("seed", range(4))
def test_a_cloud_measured_in_chunks_is_the_cloud_measured_whole(seed):
    """Every statistic equal, exactly, whatever the chunks, however they are dealt into parts
    and read side by side: single, empty, without a last return."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2_000, 40_000))
    xyz = rng.uniform(0.0, rng.uniform(50.0, 2_000.0), (n, 3)) + [500_000.0, 5_000_000.0, 0.0]
    xyz[:, 2] = 0.1 * xyz[:, 0] % 7.0 + rng.normal(0.0, 0.5, n)
    xyz[: n // 50, :2] += 5_000.0                           # a patch far away: the cover passes matter
    last = xyz[rng.random(n) < 0.4]
    whole = adaptive.measure(xyz, last)
    k = len(last)
    cuts = [
        ([0, n], [0, k]),                                   # one chunk
        ([0, n, n], [0, k, k]),                             # and an empty one
        ([0, n // 2, n], [0, 0, k]),                        # a chunk with no last return
        ([0, n // 3, 2 * n // 3, n], [0, k // 3, 2 * k // 3, k]),
        (list(range(0, n, 997)) + [n], np.linspace(0, k, len(range(0, n, 997)) + 1).astype(int).tolist()),
    ]
    for bounds, last_bounds in cuts:
        chunks = chunked(xyz, last, bounds, last_bounds)
        for per_part, workers in ((len(chunks), 1), (1, 1), (1, 2), (2, 3)):
            assert adaptive.measure_chunks(as_parts(chunks, per_part), workers=workers) == whole
    chunks = chunked(xyz, xyz[:0], [0, n // 3, n], [0, 0, 0])
    assert adaptive.measure_chunks(as_parts(chunks, 1), workers=2) == adaptive.measure(xyz)


def test_a_cloud_in_slices_measures_as_one(monkeypatch):
    """`cloud_parts` cuts a cloud into slices read side by side; the statistics stay exactly
    those of one slice."""
    rng = np.random.default_rng(7)
    xyz = rng.uniform(0.0, 300.0, (5_000, 3))
    last = xyz[rng.random(5_000) < 0.5]
    whole = adaptive.measure(xyz, last)
    monkeypatch.setattr(adaptive, "_PART_POINTS", 700)
    parts = adaptive.cloud_parts(tuple(xyz[:, j] for j in range(3)), (last[:, 0], last[:, 1]), workers=3)
    assert len(parts) == 3
    assert sum(len(chunk[0][0]) for part in parts for chunk in part()) == 5_000
    assert adaptive.measure_chunks(parts, workers=3) == whole
    assert adaptive.measure(xyz, last) == whole


def test_chunks_without_a_point_measure_nothing():
    empty = np.empty((0, 3))
    assert adaptive.measure_chunks(as_parts(chunked(empty, empty, [0, 0, 0], [0, 0, 0]), 1), workers=2) is None
    assert adaptive.measure_chunks([lambda: iter([])]) is None
    assert adaptive.measure_chunks([]) is None


def test_combine_of_two_halves_matches_the_whole():
    xyz = grid_plane(2.0, 400.0, slope=0.2)
    left = xyz[:, 0] < np.median(xyz[:, 0])
    whole = adaptive.measure(xyz)
    both = adaptive.combine([adaptive.measure(xyz[left]), adaptive.measure(xyz[~left])])
    assert both.n_points == whole.n_points
    assert both.spacing_m == pytest.approx(whole.spacing_m, rel=0.05)
    assert both.slope_p50 == pytest.approx(whole.slope_p50, abs=0.01)


def test_smrf_cell_follows_sparse_last_returns_only():
    dense, sparse = adaptive.measure(grid_plane(1.0, 100.0)), adaptive.measure(grid_plane(5.0, 500.0))
    assert smrf.adapt(dense) == {"cell_m": 1.0}
    assert smrf.adapt(sparse) == {"cell_m": 5.0}
    # the ISPRS samples' 2.4 m spacing keeps the 1 m cell the defaults were chosen with
    assert smrf.adapt(adaptive.measure(grid_plane(2.4, 480.0))) == {"cell_m": 1.0}


def test_smrf_filter_settles_what_the_caller_left_open():
    cloud = Cloud.from_xyz(grid_plane(5.0, 500.0, noise_m=0.02))
    open_ = smrf.filter(cloud)
    assert open_.settled.chosen == {"cell_m": 5.0}
    assert open_.diagnostics.cell_m == 5.0
    given = smrf.filter(cloud, config=smrf.Config())          # a given Config is used as it is
    assert given.settled is None and given.diagnostics.cell_m == 1.0
    tuned = smrf.filter(cloud, params=smrf.Params(slope=0.2))  # given thresholds, the cell still follows
    assert tuned.settled.chosen == {"cell_m": 5.0}


def test_thinned_copy_of_a_flat_plane_stays_ground():
    """A flat plane thinned to 0.04 points/m² is all ground with the settled cell."""
    cloud = Cloud.from_xyz(grid_plane(5.0, 500.0, noise_m=0.02))
    assert np.mean(smrf.filter(cloud).ground) >= 0.995


def test_settle_keeps_fixed_fields():
    terrain = adaptive.measure(grid_plane(5.0, 500.0))
    kept = adaptive.settle_terrain(smrf.adapt, terrain, smrf.Config(cell_m=2.0), smrf.Params(), fixed={"cell_m"})
    assert kept.config.cell_m == 2.0 and kept.chosen == {}
    moved = adaptive.settle_terrain(smrf.adapt, terrain, smrf.Config(), smrf.Params())
    assert moved.config.cell_m == 5.0 and "cell_m=5" in moved.describe()


def _write_plane(path, spacing_m: float, size_m: float):
    import laspy

    xyz = grid_plane(spacing_m, size_m, noise_m=0.02)
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([500_000.0, 5_000_000.0, 0.0])
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.write(path)
    return path


@pytest.mark.parametrize("options,said", [((), "chosen from it: cell_m=5"),
                                          (("--set", "cell_m=2"), "chosen from it: none (every value fixed)"),
                                          (("--preset", "fixed"), None)])
def test_cli_says_what_it_chose_and_the_user_overrides_it(tmp_path, capsys, options, said):
    from cli_helpers import run_cli

    src = _write_plane(tmp_path / "sparse.las", 5.3, 320.0)
    code, out, err = run_cli(capsys, "filter", src, "-o", tmp_path / "out.las", "--method", "smrf", "-v", *options)
    assert code == 0, err
    if said is None:
        assert "terrain:" not in err
    else:
        assert said in err and "spacing 5." in err


def test_a_stray_point_far_away_does_not_change_the_spacing():
    patch = grid_plane(1.0, 100.0)
    stray = np.concatenate([patch, patch[:1] + np.array([10_000.0, 3_000.0, 0.0])])
    assert adaptive.measure(stray).spacing_m == pytest.approx(adaptive.measure(patch).spacing_m, rel=0.05)


def test_smrf_cell_of_scattered_points_stays_within_the_window():
    """Two points kilometres apart: a spacing of kilometres, a cell of at most a third of the window."""
    terrain = adaptive.measure(np.array([[0.0, 0.0, 0.0], [3000.0, 4000.0, 1.0]]))
    assert smrf.adapt(terrain)["cell_m"] == adaptive.MAX_CELL_M
    smrf.Config(**smrf.adapt(terrain))                     # a valid Config


@pytest.mark.parametrize("points_per_m2", [1.0, 20.0])
@pytest.mark.parametrize("name", ["smrf", "pmf", "csf", "dmf", "masf", "sparsegf", "vote"])
def test_a_flat_plane_is_ground_with_every_method(name, points_per_m2):
    """100 x 100 m of evenly spaced points with 2 cm of noise: at least 99.5 % ground."""
    from gfjax import methods

    spacing = 1.0 / math.sqrt(points_per_m2)
    cloud = Cloud.from_xyz(grid_plane(spacing, 100.0, noise_m=0.02, seed=3))
    ground = np.asarray(methods.get(name).filter(cloud).ground)
    assert np.mean(ground) >= 0.995


def test_pmf_rule_follows_spacing_and_slope():
    from gfjax import pmf

    flat = pmf.adapt(adaptive.measure(grid_plane(1.0, 200.0)))
    assert flat == {"cell_m": 1.0, "initial_distance_m": 0.5, "max_distance_m": 2.5}
    steep = pmf.adapt(adaptive.measure(grid_plane(1.0, 200.0, slope=0.6)))
    assert steep["max_distance_m"] == pytest.approx(0.6 * pmf.Config().max_window_m / 2, rel=0.02)
    sparse = pmf.adapt(adaptive.measure(grid_plane(4.0, 800.0)))
    assert sparse["cell_m"] == 4.0


def test_dmf_rule_sets_nothing_masf_leaves_its_neighbour_test_to_the_hidden_low_outliers_csf_takes_the_trend_off():
    from gfjax import csf, dmf, masf

    for xyz in (grid_plane(1.0, 100.0), grid_plane(0.2, 60.0)):
        terrain = adaptive.measure(xyz)
        assert dmf.adapt(terrain) == {}
        assert masf.adapt(terrain) == {"neighbour_test": False} and masf.HIDES_LOW_OUTLIERS
        assert csf.adapt(terrain) == {"trend_m": csf.TREND_M, "rigidness": 1, "class_threshold_m": 0.5}


@pytest.mark.parametrize("spacing_m, trend_m", [(1.0, 30.0), (2.5, 30.0), (3.0, 36.0), (5.0, 60.0)])
def test_csf_trend_widens_where_its_cells_would_hold_fewer_than_four_last_returns(spacing_m, trend_m):
    from gfjax import csf

    terrain = adaptive.measure(grid_plane(spacing_m, 600.0))
    assert csf.adapt(terrain)["trend_m"] == pytest.approx(trend_m, rel=0.1)


@pytest.mark.parametrize("slope, threshold_m, time_step", [
    (0.0, 0.5, None),            # flat: the package's threshold and time step
    (0.1, 0.7, None),            # a gentle slope: its rise over two 1 m cells on top, the same time step
    (0.3, 1.1, 1.0),             # relief: the cloth falls harder
    (0.6, 1.25, 1.0),            # the threshold at its cap
])
def test_csf_threshold_and_time_step_follow_the_slope(slope, threshold_m, time_step):
    from gfjax import csf

    terrain = adaptive.measure(grid_plane(1.0, 200.0, slope=slope))
    assert terrain.slope_p90 == pytest.approx(slope, abs=0.01)
    chosen = csf.adapt(terrain)
    assert chosen["class_threshold_m"] == pytest.approx(threshold_m, abs=0.02)
    assert chosen.get("time_step") == time_step
    assert (chosen["trend_m"], chosen["rigidness"]) == (csf.TREND_M, 1)


def test_finish_drops_a_spike_only_where_the_values_followed_the_cloud():
    from gfjax.result import Result

    xyz = grid_plane(1.0, 50.0)
    xyz[100, 2] += 7.0                                   # a chimney top a filter kept as ground
    cloud = Cloud.from_xyz(xyz)
    kept = Result(ground=np.ones(len(xyz), bool))
    settled = adaptive.settle_cloud(smrf.adapt, cloud, smrf.Config(), smrf.Params())
    finished = adaptive.finish(kept, cloud, settled)
    assert not finished.ground[100] and finished.ground.sum() == len(xyz) - 1
    assert finished.settled is settled
    assert adaptive.finish(kept, cloud, None) is kept    # fixed values: labels as the filter gave them


def thin_cloud(n: int = 1000, seed: int = 0) -> np.ndarray:
    """`n` points spread evenly at random over 3.4 x 4.5 km (a point per 15,000 m²), a fifth
    of them 2-20 m above a gentle slope."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, [3400.0, 4500.0], (n, 2))
    z = 200.0 + 0.01 * xy[:, 0] + rng.normal(0.0, 0.1, n)
    objects = rng.random(n) < 0.2
    z[objects] += rng.uniform(2.0, 20.0, objects.sum())
    return np.column_stack([xy + [600_000.0, 4_900_000.0], z])


def test_the_cost_cell_keeps_rasters_within_their_cells_per_point():
    terrain = adaptive.measure(thin_cloud())
    cell = adaptive.cost_cell_m(terrain)
    assert terrain.area_m2 / cell ** 2 <= adaptive.CELLS_PER_POINT * terrain.n_points
    assert terrain.area_m2 / (cell - 0.5) ** 2 > adaptive.CELLS_PER_POINT * terrain.n_points   # the finest such
    assert adaptive.raster_cell_m(terrain) == cell > adaptive.MAX_CELL_M
    # a cloud of ordinary density keeps its cells: the sparsest labelled file has 16 m² a point
    assert adaptive.cost_cell_m(adaptive.measure(grid_plane(4.0, 800.0))) <= 1.0
    assert adaptive.cost_cell_m(adaptive.measure(thin_cloud(10))) == 0.0                   # too few to measure


@pytest.mark.parametrize("name", ["smrf", "pmf", "csf", "dmf", "masf", "sparsegf", "vote"])
def test_a_cloud_spread_thin_over_square_kilometres_filters_with_every_method(name):
    """Each method's rasters follow the points: no run over millions of cells for 1,000 points."""
    from gfjax import methods

    xyz = thin_cloud()
    result = methods.get(name).filter(Cloud.from_xyz(xyz))
    ground = np.asarray(result.ground)
    assert ground.shape == (len(xyz),) and ground.mean() > 0.5


def test_a_users_value_against_one_chosen_from_the_cloud_is_one_line(tmp_path, capsys):
    """A window narrower than the cell the sparse cloud gets: exit 2, both values named."""
    from cli_helpers import run_cli

    src = _write_plane(tmp_path / "sparse.las", 5.3, 320.0)
    code, _, err = run_cli(capsys, "filter", src, "-o", tmp_path / "out.las", "--method", "smrf", "--set", "window_m=4")
    assert code == 2 and "Traceback" not in err
    assert "window_m given, cell_m=5.5 chosen from the cloud" in err
    assert not (tmp_path / "out.las").exists()


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (9, 1), (2, 3), (12, 17), (60, 39)], ids=str)
@pytest.mark.parametrize("size", [3, 5, 7, 13])
@pytest.mark.parametrize("empty", [0.0, 0.4, 1.0])
def test_the_minimum_surface_erosion_is_scipys_percentile_filter(shape, size, empty, monkeypatch):
    """`measure` erodes with scipy.ndimage's 10th percentile filter, without importing it: the
    same values, ties and empty (+inf) cells included, whole and in blocks of rows."""
    from scipy import ndimage

    rng = np.random.default_rng(size)
    z = np.round(rng.normal(0.0, 5.0, shape), 1)           # rounded: ties
    z[rng.random(shape) < empty] = np.inf
    expected = ndimage.percentile_filter(z, 10, size=size, mode="nearest")
    np.testing.assert_array_equal(adaptive._percentile_filter(z, 10, size), expected)
    monkeypatch.setattr(adaptive, "_FILTER_BLOCK", 1)
    np.testing.assert_array_equal(adaptive._percentile_filter(z, 10, size), expected)
