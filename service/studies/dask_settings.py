"""Whether the user made a dask setting: what the embedded cluster changes (the runner's quiet
intervals, the forkserver's start method) it changes only where the user did not."""

from __future__ import annotations

import os

__all__ = ["env_name", "user_set"]


def env_name(key: str) -> str:
    """The environment variable that sets dask config ``key`` (dask's own convention)."""
    return "DASK_" + key.upper().replace(".", "__").replace("-", "_")


def user_set(key: str) -> bool:
    """Whether the user set dask config ``key``: its environment variable is set, or its value
    is not dask's shipped default (a dask config file's, or one set in this process)."""
    import dask
    import distributed  # noqa: F401  # registers its config defaults

    if env_name(key) in os.environ:
        return True
    shipped = dask.config.merge(*dask.config.defaults)
    return dask.config.get(key, None) != dask.config.get(key, None, config=shipped)
