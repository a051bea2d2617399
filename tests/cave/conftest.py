"""Fixtures of the cluster tests."""

import pytest

from cave_packets import FrameMaker


@pytest.fixture(autouse=True)
def cave_keys(tmp_path_factory, monkeypatch):
    """Every test (and the node processes it starts) makes and reads CURVE keys in a folder
    of its own, never the user's ``~/.config/softvr/cave-keys``."""
    folder = tmp_path_factory.mktemp("cave-keys")
    monkeypatch.setenv("SOFTVR_CAVE_KEYS", str(folder))
    return folder


@pytest.fixture
def frame_maker():
    """Valid frames of a small rippling sheet and the state a node must hold after each."""
    return FrameMaker()
