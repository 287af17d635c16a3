"""The HTTP API: app, settings, dependencies, schemas, routes, job queue, catalogue, schedule."""
