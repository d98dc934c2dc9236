"""Session-wide test ordering.

llama.cpp's CPU backend keeps a thread pool (OpenMP) that does not survive
``fork``: an ActorSystem created in a process that has already run a model
in-process forks a fork server whose llama.cpp children hang. Tests that run
llama.cpp in the pytest process are marked ``llama_in_process`` and run last,
after every test that starts actor processes.
"""

from __future__ import annotations

import pytest


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: item.get_closest_marker("llama_in_process") is not None)  # stable
