"""loopid.systems."""
