"""The Monte Carlo renderer: photon transport through the rough sea, gated by time of flight."""
