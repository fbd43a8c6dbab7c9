"""The majority vote: the count against a loop, the filter against its voters run alone, its
settings' checks, and what `-v` says."""
from __future__ import annotations

import numpy as np
import pytest

from gfjax import methods, vote
from gfjax.errors import InputError
from gfjax.io.cloud import Cloud


def majority_loop(votes: np.ndarray) -> np.ndarray:
    """Point by point: ground when more than half the voters say so, a tie as the first says."""
    k, n = votes.shape
    out = np.zeros(n, dtype=bool)
    for i in range(n):
        yes = sum(bool(votes[j, i]) for j in range(k))
        out[i] = votes[0, i] if 2 * yes == k else 2 * yes > k
    return out


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("seed", [0, 1])
def test_majority_is_the_loop(k, seed):
    votes = np.random.default_rng(seed).random((k, 500)) < 0.5
    np.testing.assert_array_equal(vote.majority(votes), majority_loop(votes))


def test_majority_edge_cases():
    assert vote.majority(np.zeros((4, 0), dtype=bool)).shape == (0,)
    tie = np.array([[True, False], [False, True]])
    np.testing.assert_array_equal(vote.majority(tie), [True, False])              # the first breaks it
    np.testing.assert_array_equal(vote.majority(np.ones((3, 2), dtype=bool)), [True, True])
    np.testing.assert_array_equal(vote.majority(np.array([[True], [False], [False]])), [False])


def scene(seed: int = 0) -> np.ndarray:
    """A gently tilted 80 x 80 m ground at 2 points/m² with two 12 m boxes 6 m high on it and
    scattered low vegetation: `(n, 3)` [m]."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 80.0, (12_800, 2))
    z = 0.05 * xy[:, 0] + rng.normal(0.0, 0.03, len(xy))
    for x0, y0 in ((15.0, 20.0), (50.0, 45.0)):
        inside = (xy[:, 0] > x0) & (xy[:, 0] < x0 + 12) & (xy[:, 1] > y0) & (xy[:, 1] < y0 + 12)
        z[inside] += 6.0
    bush = rng.random(len(xy)) < 0.05
    z[bush] += rng.uniform(0.5, 3.0, bush.sum())
    return np.column_stack([xy + [500_000.0, 5_000_000.0], z])


def test_the_vote_is_the_majority_of_its_voters_run_alone():
    cloud = Cloud.from_xyz(scene())
    result = vote.filter(cloud)
    names = vote.Config().names
    alone = np.stack([np.asarray(methods.get(n).filter(cloud).ground) for n in names])
    np.testing.assert_array_equal(result.diagnostics.votes, alone)
    np.testing.assert_array_equal(result.ground, majority_loop(alone))
    assert result.diagnostics.voters == names == ("smrf", "masf", "pmf")
    agreement = result.diagnostics.agreement
    assert agreement.shape == (cloud.n_points,) and agreement.min() >= 0.5
    # the boxes' roofs are not ground, the open ground is
    xyz = scene()
    roof = xyz[:, 2] - 0.05 * (xyz[:, 0] - 500_000.0) > 5.0
    assert not result.ground[roof].any() and result.ground[~roof].mean() > 0.85


def test_the_voters_share_one_terrain_and_label_alike_side_by_side_or_one_by_one(monkeypatch):
    from gfjax import adaptive, limits

    cloud = Cloud.from_xyz(scene(2))
    measured = []
    real = adaptive.measure_chunks
    monkeypatch.setattr(adaptive, "measure_chunks", lambda chunks, **kw: measured.append(1) or real(chunks, **kw))
    side_by_side = vote.filter(cloud)
    assert len(measured) == 1
    assert vote.Config().workers() > 1 or limits.processors() == 1
    monkeypatch.setattr(limits, "processors", lambda: 1)
    assert vote.Config().workers() == 1
    one_by_one = vote.filter(cloud)
    np.testing.assert_array_equal(side_by_side.diagnostics.votes, one_by_one.diagnostics.votes)
    assert side_by_side.settled == one_by_one.settled


def test_voters_run_side_by_side_only_while_their_memory_fits_together(monkeypatch):
    from gfjax import limits

    extent = (3000.0, 3000.0)
    largest = sorted((max(e.n_bytes for e in methods.get(n).Config().memory_estimates(extent))
                      for n in ("smrf", "masf", "pmf")), reverse=True)
    monkeypatch.setattr(limits, "processors", lambda: 8)
    for budget, workers in ((sum(largest) * 1.01, 3), ((largest[0] + largest[1]) * 1.01, 2),
                            ((largest[0] + largest[1]) * 0.99, 1)):
        monkeypatch.setenv(limits.BUDGET_ENV, str(budget / 2 ** 30))
        assert vote.Config().workers(extent) == workers
    monkeypatch.setattr(limits, "processors", lambda: 2)
    monkeypatch.delenv(limits.BUDGET_ENV)
    assert vote.Config().workers((10.0, 10.0)) == 2


def test_four_voters_and_the_preset():
    config, _ = methods.make_config_and_params("vote", preset="with-csf")
    assert config.names == ("smrf", "masf", "pmf", "csf")
    cloud = Cloud.from_xyz(scene(1))
    result = vote.filter(cloud, config=config)
    assert result.diagnostics.votes.shape == (4, cloud.n_points)
    np.testing.assert_array_equal(result.ground, majority_loop(result.diagnostics.votes))


def test_the_votes_memory_is_its_voters():
    extent = (2000.0, 2000.0)
    assert vote.Config().memory_estimates(extent) == [e for n in ("smrf", "masf", "pmf")
                                                      for e in methods.get(n).Config().memory_estimates(extent)]
    cloth = vote.Config(voters="smrf,csf").memory_estimates(extent)[-1]
    assert cloth.what.startswith("a cloth of") and cloth.n_bytes > 8 * 2 ** 30


@pytest.mark.parametrize("voters,said", [("smrf,nope", "'nope' cannot vote"), ("smrf,vote", "'vote' cannot vote"),
                                         ("smrf,pmf,smrf", "each method votes once"), (" , ", "at least one")])
def test_bad_voters_are_named(voters, said):
    with pytest.raises(InputError, match=said) as err:
        methods.make_config_and_params("vote", {"voters": voters})
    assert str(err.value).startswith("--set")


def test_a_voters_setting_is_not_the_votes():
    with pytest.raises(InputError, match="unknown key 'cell_m' for method vote; known keys: voters"):
        methods.make_config_and_params("vote", {"cell_m": "2"})


def test_verbose_names_what_each_voter_chose(tmp_path, capsys):
    import laspy
    from cli_helpers import run_cli

    xyz = scene(2)
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = np.array([0.01] * 3), np.array([500_000.0, 5_000_000.0, 0.0])
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.write(tmp_path / "scene.las")
    code, out, err = run_cli(capsys, "filter", tmp_path / "scene.las", "-o", tmp_path / "out.las", "--method", "vote",
                             "--set", "voters=smrf,pmf,masf", "-v", "-q")
    assert code == 0, err
    assert err.count("terrain: ") == 1
    for name in ("smrf", "pmf", "masf"):
        assert f"  {name}: chosen from it: " in err
    assert "csf:" not in err
    written = laspy.read(tmp_path / "out.las")
    alone = vote.filter(Cloud.from_xyz(np.column_stack([written.x, written.y, written.z])),
                        config=vote.Config(voters="smrf,pmf,masf"))
    assert len(written.points) == len(xyz)
    np.testing.assert_array_equal(written.classification == 2, alone.ground)


def test_a_survey_gives_the_voters_its_terrain(tmp_path, capsys):
    """Each file's window is voted on with the values the voters settle on the whole survey, in
    Python (a config or not) and on the command line, which says that terrain once."""
    from cli_helpers import run_cli
    from test_survey import town, write_grid

    import gfjax
    from gfjax import adaptive, survey

    paths, _, union = write_grid(tmp_path, *town())
    whole = adaptive.measure_cloud(gfjax.read(union))
    (tmp_path / "work").mkdir()
    for config in (None, vote.Config(voters="pmf,smrf")):
        for _, result in survey.filtered(paths, "vote", tmp_path / "work", config=config):
            voters = (config or vote.Config()).names
            assert [s.terrain for s in result.settled.settled] == [whole] * len(voters)
    (tmp_path / "out").mkdir()
    code, _, err = run_cli(capsys, "filter", *paths, "-o", tmp_path / "out", "-v", "-q")
    assert code == 0, err
    assert err.count(f"the survey: terrain: {whole.describe()}") == 1


def test_a_survey_of_files_labels_nearly_as_their_union(tmp_path):
    """The default method over four files cut from one town: each file filtered with its
    neighbours' halo, each voter settling on the survey's terrain. Measured on this town 99.89 %
    of the union's labels (bcts_1 + bcts_2 cut 3 x 3: 99.9985 %, `experiments/results/survey_seams.md`)."""
    import laspy
    from test_survey import town, write_grid

    from gfjax.cli.main import main

    paths, members, union = write_grid(tmp_path, *town())
    assert main(["filter", str(union), "-o", str(tmp_path / "whole.laz"), "-q"]) == 0
    (tmp_path / "out").mkdir()
    assert main(["filter", *map(str, paths), "-o", str(tmp_path / "out"), "-q"]) == 0
    want = np.asarray(laspy.read(tmp_path / "whole.laz").classification) == 2
    got = np.zeros_like(want)
    for path, keep in zip(paths, members):
        got[keep] = np.asarray(laspy.read(tmp_path / "out" / path.name).classification) == 2
    assert np.mean(got == want) >= 0.998
