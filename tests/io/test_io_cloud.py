"""Cloud views and the classes written (SPEC section 1), ASPRS names and ignored points."""
from __future__ import annotations

import laspy
import numpy as np
import pytest

from gfjax.io import asprs
from gfjax.io.cloud import Cloud


def _cloud(classes, *, withheld=None, returns=None) -> Cloud:
    n = len(classes)
    cloud = Cloud.from_xyz(np.column_stack([np.arange(n), np.zeros(n), np.arange(n) * 0.5]),
                           classification=np.asarray(classes, np.uint8))
    if withheld is not None:
        cloud.las.withheld = np.asarray(withheld, bool)
    if returns is not None:
        cloud.las.return_number, cloud.las.number_of_returns = returns
    return cloud


def test_with_ground_classes_per_spec():
    #                  ground?  old class -> new class
    cloud = _cloud([2, 2, 1, 6, 0, 7, 18, 3])
    ground = np.array([True, False, True, False, False, True, False, True])
    expected = [2, 1, 2, 6, 0, 7, 18, 2]  # noise (7, 18) keeps its class even if "ground"
    np.testing.assert_array_equal(cloud.with_ground(ground).classification, expected)
    reset = cloud.with_ground(ground, reset_nonground=True).classification
    np.testing.assert_array_equal(reset, [2, 1, 2, 1, 1, 7, 18, 2])
    np.testing.assert_array_equal(cloud.classification, [2, 2, 1, 6, 0, 7, 18, 3])  # unchanged


def test_withheld_and_non_last_returns_keep_their_class():
    cloud = _cloud([2, 1, 2, 1], withheld=[True, False, False, False],
                   returns=(np.array([1, 1, 1, 2], np.uint8), np.array([1, 1, 2, 2], np.uint8)))
    assert cloud.ignored.tolist() == [True, False, False, False]
    used = cloud.filter_mask("last")
    assert used.tolist() == [False, True, False, True]
    out = cloud.with_ground(np.array([False, True, False, True]), used=used)
    np.testing.assert_array_equal(out.classification, [2, 2, 2, 2])
    with pytest.raises(ValueError, match="returns must be 'all' or 'last'"):
        cloud.filter_mask("first")
    with pytest.raises(ValueError, match=r"ground must have shape \(4,\)"):
        cloud.with_ground(np.ones(3, bool))


def test_with_extra_dim_adds_or_overwrites_without_touching_the_original():
    cloud = _cloud([1, 2, 1])
    tagged = cloud.with_extra_dim("instance_id", np.array([0, 5, 7], np.uint32), description="object")
    assert "instance_id" not in set(cloud.las.point_format.dimension_names)
    assert tagged.las["instance_id"].dtype == np.uint32
    np.testing.assert_array_equal(tagged.las["instance_id"], [0, 5, 7])
    again = tagged.with_extra_dim("instance_id", np.array([1, 1, 1], np.uint32))
    assert list(again.las.point_format.extra_dimension_names) == ["instance_id"]
    np.testing.assert_array_equal(again.las["instance_id"], [1, 1, 1])
    np.testing.assert_array_equal(tagged.las["instance_id"], [0, 5, 7])
    np.testing.assert_array_equal(tagged.xyz, cloud.xyz)


def test_xyz_m_applies_horizontal_and_vertical_factors():
    cloud = _cloud([1, 2])
    feet = Cloud(las=cloud.las, horizontal_unit_m=0.3048, vertical_unit_m=1200 / 3937)
    np.testing.assert_allclose(feet.xyz_m[:, :2], cloud.xyz[:, :2] * 0.3048, rtol=1e-15)
    np.testing.assert_allclose(feet.xyz_m[:, 2], cloud.xyz[:, 2] * 1200 / 3937, rtol=1e-15)
    local, origin = feet.local_xyz_m()
    assert local.dtype == np.float32 and local.min() == 0.0
    np.testing.assert_allclose(origin, feet.xyz_m.min(axis=0))


def test_class_names_and_counts():
    assert asprs.class_name(2) == "ground" and asprs.class_name(18) == "high noise"
    assert asprs.class_name(40) == "reserved" and asprs.class_name(200) == "user defined"
    with pytest.raises(ValueError, match="0-255"):
        asprs.class_name(256)
    las = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
    las.x = las.y = las.z = np.zeros(5)
    las.classification = np.array([2, 2, 7, 1, 2], np.uint8)
    assert asprs.class_counts(las) == {1: 1, 2: 3, 7: 1}


def test_points_from_records_views_one_array_and_joins_a_sequence_contiguously():
    from gfjax.io.cloud import Points
    from gfjax.survey.catalog import STORE

    records = np.zeros(5, STORE)
    records["xyz_m"] = np.arange(15.0).reshape(5, 3)
    records["classification"] = [1, 2, 2, 6, 7]
    records["ignored"] = [False, False, False, False, True]
    one = Points.from_records(records, "one")
    assert np.shares_memory(one.xyz_m, records)                 # a view: no copy of a whole survey
    joined = Points.from_records([records[:2], records[2:]], "two")
    assert joined.xyz_m.flags.c_contiguous and not np.shares_memory(joined.xyz_m, records)
    for name in ("xyz_m", "classification", "return_number", "number_of_returns", "ignored"):
        np.testing.assert_array_equal(getattr(joined, name), getattr(one, name))
    assert joined.filter_mask().tolist() == [True, True, True, True, False]
