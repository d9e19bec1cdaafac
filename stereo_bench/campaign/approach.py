"""How the plan's rig arrives at each configuration, so that a resumed run arrives there the same way.

Pure functions over the plan's sequence of moves (the configurations and design visits its Move steps
go to, in order, from where homing leaves the rig):

- :func:`move_sequence` (:mod:`stereo_bench.campaign.plan.steps`'s): that sequence, from the steps.
- :func:`approach_moves`: where a run that has not just come from the previous configuration of the
  sequence (a resume, after homing; a run after a recovery homing) must go first, so that the move to
  the configuration is the very move the uninterrupted run made: from the previous configuration, with
  every axis that move leaves alone standing where it arrived from the same side. Backlash follows the
  direction of approach, on a real rig as on the simulated one (and the kinematic model corrects for it
  by the approach the runner records); so does the ringing of what that move excites.
- :func:`arrivals` and :func:`placements`: per configuration, where the plan's rig arrived at each axis
  value and which manual target placement it stands in front of (the first configuration of each run
  of consecutive ones sharing it): the simulated bench keys its random draws by them, so they are the
  same whatever order the runs happen to take.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from stereo_bench.campaign.plan import Configuration, Visit
from stereo_bench.campaign.plan.steps import move_sequence

__all__ = ["APPROACH_ACTION", "approach_moves", "arrivals", "move_sequence", "placements"]

APPROACH_ACTION = "approach"  # what an approach document's data.action says (documents.ApproachEvent)
_SAME = 1e-9  # commanded values closer than this are one position


def _runs(values: Sequence[float | None]) -> list[int]:
    """Per index, the index where its run of equal consecutive values begins."""
    first: list[int] = []
    for i, value in enumerate(values):
        same = i > 0 and value is not None and values[i - 1] is not None and abs(value - values[i - 1]) <= _SAME
        first.append(first[-1] if same else i)
    return first


def arrivals(sequence: Sequence[Configuration | Visit]) -> dict[str, dict[str, str]]:
    """config_id -> {quantity: the config_id at which the plan's rig arrived at this configuration's value}.

    The first of the run of consecutive moves in ``sequence`` that command that value: the move that went
    there (the later ones of the run leave that axis where it is).
    """
    requests = [entry.move_request() for entry in sequence]
    quantities = sorted({q for request in requests for q in request})
    out: dict[str, dict[str, str]] = {entry.config_id: {} for entry in sequence}
    for quantity in quantities:
        first = _runs([request.get(quantity) for request in requests])
        for i, entry in enumerate(sequence):
            if requests[i].get(quantity) is not None:
                out[entry.config_id][quantity] = sequence[first[i]].config_id
    return out


def placements(sequence: Sequence[Configuration | Visit]) -> dict[str, str]:
    """config_id -> the name of the manual target placement its measurement frames see.

    The configurations (design visits show no target) in the order they are moved to; consecutive ones at
    one target distance share a placement (the operator leaves the target standing), named after the first.
    """
    shown = [entry for entry in sequence if isinstance(entry, Configuration)]
    first = _runs([entry.distance_mm for entry in shown])
    return {entry.config_id: shown[first[i]].config_id for i, entry in enumerate(shown)}


def approach_moves(commanded: Sequence[Mapping[str, float]], index: int, here: Mapping[str, float], *,
                   start: Mapping[str, float], limits: Mapping[str, tuple[float, float]] | None = None,
                   ) -> list[dict[str, float]]:
    """The moves (0, 1 or 2 targets) that make the move to ``commanded[index]`` from ``here`` the uninterrupted run's.

    ``commanded``: per Move of the plan, in order, the commanded value of every motor-driven quantity;
    ``start``: where that run began (where homing leaves the axes); ``here``: where the rig stands now;
    ``limits``: per quantity its soft limits (a pre-move outside them is left out). The uninterrupted run
    came to ``commanded[index]`` from ``commanded[index - 1]`` (``start`` for the first), so:

    1. every axis that this last move leaves alone (its value already the target) must arrive at that value
       from the side the plan's rig last arrived from, the previous distinct value of the axis in the sequence
       (``start`` if it has none): where the direct way from ``here`` comes from the other side, or does not
       move the axis at all (its side is then unknown), it first goes to that previous value;
    2. then everything goes to ``commanded[index - 1]`` (left out when the rig stands there);

    after which the move to ``commanded[index]`` moves the same axes over the same distances in the same
    directions as the uninterrupted run's. Values are physical (mm, deg). Example, one axis ``B``:

    >>> approach_moves([{"B": 100.0}, {"B": 150.0}], 1, {"B": 349.0}, start={"B": 349.0})
    [{'B': 100.0}]
    """
    if not 0 <= index < len(commanded):
        raise IndexError(f"index {index} outside the {len(commanded)} moves of the plan")
    positions = [dict(start), *[dict(c) for c in commanded[: index + 1]]]  # positions[k + 1] is commanded[k]
    target, before = positions[-1], positions[-2]
    limits = limits or {}
    side: dict[str, float] = {}
    for quantity, value in target.items():
        if quantity not in before or abs(before[quantity] - value) > _SAME:
            continue  # the last move moves it: it arrives from before[quantity], as in the plan
        previous = next((p[quantity] for p in reversed(positions[:-1])
                         if quantity in p and abs(p[quantity] - value) > _SAME), None)
        if previous is None:
            continue  # never moved from where the run started: no side to recreate
        low, high = limits.get(quantity, (-math.inf, math.inf))
        from_here = here.get(quantity, value) - value
        wanted = previous - value
        if (from_here * wanted > 0 and abs(from_here) > _SAME) or not low <= previous <= high:
            continue  # the direct way already comes from that side (or the side cannot be reached)
        side[quantity] = previous
    moves = [side] if side else []
    last = {**here, **side}
    if any(abs(last.get(q, math.inf) - v) > _SAME for q, v in before.items()):
        moves.append(dict(before))
    return moves
