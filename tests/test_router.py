"""The document router: a typed document goes to the handler of its model, live and recorded alike (issue 21)."""

from __future__ import annotations

from pathlib import Path

from stereo_bench.campaign.documents import (
    EVENT_MODELS,
    CalibrationViewEvent,
    Document,
    EventDocument,
    MoveEvent,
    ResultDocument,
    StartDocument,
    parse_document,
)
from stereo_bench.campaign.router import DocumentRouter, handles
from stereo_bench.campaign.session import SessionReader

SAMPLE_SESSION = Path(__file__).resolve().parents[1] / "calib_data" / "sample_session"


class Counter(DocumentRouter):
    def __init__(self):
        super().__init__()
        self.seen: list[str] = []

    @handles(StartDocument)
    def start(self, doc: StartDocument) -> None:
        self.seen.append("start")

    @handles(MoveEvent)
    def move(self, doc: MoveEvent) -> None:
        self.seen.append("move")

    @handles(EventDocument)
    def other_event(self, doc: EventDocument) -> None:
        self.seen.append(f"event:{doc.kind}")

    def default(self, document: Document) -> None:
        self.seen.append(f"default:{document.type}")


def test_a_recorded_stream_is_routed_by_model_most_specific_first():
    router = Counter().read(SessionReader(SAMPLE_SESSION))
    assert router.seen[0] == "start" and router.seen.count("move") == 2
    assert router.seen.count("event:calibration_view") == 14 and "default:result" in router.seen
    assert router.seen[-1] == "default:stop"


def test_an_unknown_kind_goes_to_the_event_handler_and_functions_register_by_model():
    header = {"seq": 3, "time": "2026-01-01T00:00:00.000000Z", "monotonic": 1.0, "attempt": 1}
    unknown = parse_document({"type": "event", "kind": "not_a_kind", **header})
    assert type(unknown) is EventDocument
    assert Counter()(unknown) is None
    seen = []
    router = DocumentRouter().on(CalibrationViewEvent, seen.append)
    router(unknown)  # nothing handles it: the default ignores it
    assert seen == [] and router.handler(ResultDocument) == router.default


def test_every_event_kind_is_listed_once_by_its_class():
    assert EVENT_MODELS["move"] is MoveEvent and len(set(EVENT_MODELS.values())) == len(EVENT_MODELS)
    assert all(model.model_fields["kind"].default == kind for kind, model in EVENT_MODELS.items())
