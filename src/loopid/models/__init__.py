"""loopid.models."""
