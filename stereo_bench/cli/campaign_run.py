"""``stereo-bench campaign run``: the campaign runner's command line lives here.

:func:`register_run` is called by :func:`stereo_bench.cli.campaign.register` with the ``campaign``
group's subparsers. It registers nothing yet: the runner (``campaign run --preset NAME --out DIR``)
is being written separately and will replace this body.
"""

from __future__ import annotations


def register_run(subparsers) -> None:
    """Add ``run`` to the ``campaign`` subcommands (placeholder until the runner lands)."""
