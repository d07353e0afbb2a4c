"""loopid.experiments."""
