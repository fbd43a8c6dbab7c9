"""gfjax.bench.peers: names, the not-installed path, and each adapter on a synthetic scene."""
from __future__ import annotations

import sys

import numpy as np
import pytest
from bench_helpers import scene_xyz

from gfjax.bench import peers
from gfjax.errors import InputError


def test_parse_peers():
    assert peers.parse_peers(None) == list(peers.PEERS)
    assert peers.parse_peers("none") == []
    assert peers.parse_peers(" pysmrf , pysmrf,cloth-simulation-filter") == ["pysmrf", "cloth-simulation-filter"]
    with pytest.raises(InputError, match="--peers: unknown peer 'lastools'"):
        peers.parse_peers("pysmrf,lastools")


@pytest.mark.parametrize("name", list(peers.PEERS))
def test_a_peer_whose_import_fails_is_not_installed(name, monkeypatch):
    monkeypatch.setitem(sys.modules, peers.PEERS[name].module, None)   # import -> ImportError
    assert not peers.installed(name)
    note = peers.skip_note(name)
    assert name in note and "\n" not in note and "[bench]" in note


@pytest.mark.parametrize("name", list(peers.PEERS))
def test_peer_separates_terrain_from_a_building(name):
    if not peers.installed(name):
        pytest.skip(f"peer {name} not installed (pip install -e '.[bench]')")
    xyz, classes = scene_xyz()
    ground = peers.PEERS[name].run(xyz)
    assert ground.dtype == np.bool_ and ground.shape == (len(xyz),)
    on_terrain, on_roof = classes == 2, classes == 6
    assert np.mean(ground[on_terrain]) > 0.9
    assert np.mean(ground[on_roof]) < 0.1
