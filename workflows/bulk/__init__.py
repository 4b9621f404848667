"""Runs over many inputs: bulk annotation (manifest, resume) and the backends its tasks run on."""
