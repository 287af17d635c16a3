"""Looking at results: selection by coordinate value, bands, figures."""
