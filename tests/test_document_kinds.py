"""Each event kind is listed once, by its class: EVENT_MODELS and AnyDocument are derived from the classes."""

from __future__ import annotations

import json
import typing
from pathlib import Path
from typing import Literal

import pytest

from stereo_bench.campaign import documents
from stereo_bench.campaign.documents import EVENT_MODELS, EventDocument, MoveEvent, parse_document

SAMPLE = Path(__file__).resolve().parents[1] / "calib_data" / "sample_session"


def test_every_typed_event_class_is_registered_under_its_kind_and_parsed_as_itself():
    classes = [cls for cls in vars(documents).values()
               if isinstance(cls, type) and issubclass(cls, EventDocument) and cls is not EventDocument]
    assert {cls.model_fields["kind"].default: cls for cls in classes} == EVENT_MODELS
    assert len(EVENT_MODELS) == 24  # + calibration_selection, presentation_time, calibration_exclusions (issue 24)
    for kind, model in EVENT_MODELS.items():
        assert typing.get_args(model.model_fields["kind"].annotation) == (kind,)
    # A kind no class names is read as the plain event (other tools may write one).
    lines = (SAMPLE / "documents.jsonl").read_text().splitlines()
    move = next(json.loads(line) for line in lines if '"kind": "move"' in line or '"kind":"move"' in line)
    assert type(parse_document(move)) is MoveEvent
    assert type(parse_document({**move, "kind": "no_such_kind", "data": {}})) is EventDocument


def test_a_second_class_for_one_kind_is_refused_at_definition():
    with pytest.raises(TypeError, match="event kind 'move' is already MoveEvent"):
        class AnotherMove(EventDocument):  # noqa: F841 - defining it is the test
            kind: Literal["move"] = "move"
    assert EVENT_MODELS["move"] is MoveEvent
