"""Input/output: MCAP recordings, atomic file writes."""
