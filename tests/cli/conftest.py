"""The command's persistent compilation cache goes to a folder of the test session, never to
the user's cache folder."""

import pytest


@pytest.fixture(autouse=True)
def cache_dir(tmp_path_factory, monkeypatch):
    path = tmp_path_factory.getbasetemp() / "jax-cache"
    monkeypatch.setenv("RIGIDJAX_CACHE_DIR", str(path))
    return path
