"""`stereo-bench rig` (being written; see issue 3)."""


def register(subparsers) -> None:
    return None
