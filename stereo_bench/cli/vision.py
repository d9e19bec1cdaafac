"""`stereo-bench calibrate | measure | render` (being written; see issue 2)."""


def register(subparsers) -> None:
    return None
