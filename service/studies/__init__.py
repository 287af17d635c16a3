"""Study files, grids, runs and results: schema, variables, chunk store, datasets, runner."""
