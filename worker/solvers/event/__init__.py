"""``method: event``: the event-driven solver (roots, regimes, kernel, driver)."""
