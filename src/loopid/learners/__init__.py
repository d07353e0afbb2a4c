"""loopid.learners."""
