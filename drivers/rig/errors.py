"""The root of every rig failure, in a module of its own so that the pure codec can raise it too."""


class RigError(Exception):
    """Base of every rig failure the caller can report in one line."""
