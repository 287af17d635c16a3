"""A study run's size limits and defaults, stated once and light to import (the CLI's help,
the settings, the schema and the runner all read them from here)."""

from __future__ import annotations

__all__ = ["DEFAULT_CHUNK_SIZE", "DEFAULT_MAX_POINTS"]

#: Points a study may have unless ``IMPACTCELL_MAX_POINTS`` / ``--max-points`` says otherwise.
DEFAULT_MAX_POINTS = 2_000_000
#: Points per dask task (fewer for small studies: ``runner.default_chunk_size``).
DEFAULT_CHUNK_SIZE = 96
