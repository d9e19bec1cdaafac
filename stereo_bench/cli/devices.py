"""`stereo-bench devices` (being written; see issue 3)."""


def register(subparsers) -> None:
    return None
