"""loopid.algorithms."""
