"""loopid.control."""
