"""MASF configuration: the alpha pyramid (Eq. 1), validation, presets and `--set` handling."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gfjax import masf, methods


def test_default_pyramid_runs_from_alpha_max_to_twice_the_grid():
    np.testing.assert_array_equal(masf.Config().alphas_m(), np.arange(25.0, 2.0, -2.0))    # 25, 23, ..., 3


def test_samp42_top_layer_then_nine_metre_steps():
    config, params = methods.make_config_and_params(masf, preset="paper-samp42")
    np.testing.assert_array_equal(config.alphas_m(), [90.0, 20.0, 11.0, 2.0])
    assert float(params.st) == pytest.approx(0.10) and float(params.ft_m) == pytest.approx(0.5)


@pytest.mark.parametrize("sample", sorted(masf.PAPER_TABLE3))
def test_paper_presets_follow_table3(sample):
    alpha_max, step, st = masf.PAPER_TABLE3[sample]
    config, params = methods.make_config_and_params(masf, preset=f"paper-{sample}")
    alphas = config.alphas_m()
    assert alphas[-1] >= 2.0 * config.grid_m > alphas[-1] - step
    assert alphas[0 if sample != "samp42" else 1] == alpha_max
    assert float(params.st) == pytest.approx(st)


def test_spec_presets_are_exact():
    assert masf.PRESETS["flat"] == {"alpha_max_m": 25.0, "alpha_step_m": 2.0, "st": 0.02}
    assert masf.PRESETS["urban"] == {"alpha_max_m": 25.0, "alpha_step_m": 1.0, "st": 0.05}
    assert masf.PRESETS["steep"] == {"alpha_max_m": 10.0, "alpha_step_m": 1.0, "st": 0.15}
    config, params = methods.make_config_and_params(masf, {"alpha_max_m": "30", "ft_m": "0.3"}, preset="steep")
    assert config.alpha_max_m == 30.0 and config.alpha_step_m == 1.0
    assert float(params.st) == pytest.approx(0.15) and float(params.ft_m) == pytest.approx(0.3)


@pytest.mark.parametrize("change", [dict(grid_m=0.0), dict(alpha_step_m=-1.0), dict(alpha_max_m=1.0),
                                    dict(alpha_top_m=10.0), dict(outlier_gap_m=float("nan")),
                                    dict(buffer_heights="lowest"), dict(mirror_max_m=0.0)])
def test_bad_config_raises_naming_the_key(change):
    key = next(iter(change))
    with pytest.raises(ValueError, match=key.replace("alpha_max_m", "alpha_max_m")):
        dataclasses.replace(masf.Config(), **change)


def test_bad_params_raise_input_error():
    from gfjax.errors import InputError
    from gfjax.io.cloud import Cloud
    cloud = Cloud.from_xyz(np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0]]))
    with pytest.raises(InputError, match="st"):
        masf.filter(cloud, params=masf.Params(st=-1.0))
    with pytest.raises(InputError, match="returns"):
        masf.filter(cloud, returns="first")
