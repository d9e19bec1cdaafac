"""One document router: a typed document goes to the handler registered for its model.

Every reader of a session is a router: the CLI progress, the live page, the report, replay, the
recorders. A router is a subscriber of a live stream (``bus.subscribe(router)``: documents as the
writer publishes them) and a reader of a recorded one (``router.read(reader)``: a
:class:`~stereo_bench.campaign.session.SessionReader`'s documents, in stream order), with the same
handlers::

    class Progress(DocumentRouter):
        @handles(MoveEvent)
        def move(self, doc: MoveEvent) -> None: ...

        @handles(ResultDocument)
        def result(self, doc: ResultDocument) -> None: ...

    bus.subscribe(Progress())                 # live
    Progress().read(SessionReader(session))   # recorded

A handler is found by the document's model, most specific first (its class, then the classes it
derives from: a ``MoveEvent`` handler, else an ``EventDocument`` handler, else a ``Document`` one); a
document nothing handles goes to :meth:`DocumentRouter.default` (by default: ignored). An event of a
kind no model lists is a plain :class:`EventDocument`, so it reaches the ``EventDocument`` handler or
the default. Handlers come from methods marked :func:`handles` (inherited, overridable by name) and
from :meth:`DocumentRouter.on` for a router assembled from functions. :meth:`DocumentRouter.handler`
resolves a model class without a document: a recorder routes a draft (``draft.model``) with it.

(Shaped after bluesky event-model's ``DocumentRouter``, which dispatches on the document's name to a
method of that name; here the key is the pydantic model, so an event kind is routed like a document type.)
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any, TypeVar

from stereo_bench.campaign.documents import Document

D = TypeVar("D", bound=Document)
Handler = Callable[[Any], Any]

_MODELS_ATTRIBUTE = "__routes_models__"


def handles(*models: type[Document]) -> Callable[[Callable], Callable]:
    """Mark a :class:`DocumentRouter` method as the handler of documents of ``models`` (and their subclasses)."""
    if not models or not all(isinstance(model, type) and issubclass(model, Document) for model in models):
        raise TypeError("handles() takes one or more document models (classes of stereo_bench.campaign.documents)")

    def mark(method: Callable) -> Callable:
        setattr(method, _MODELS_ATTRIBUTE, (*getattr(method, _MODELS_ATTRIBUTE, ()), *models))
        return method

    return mark


class DocumentRouter:
    """Dispatches a typed document to the handler of its model (see the module docstring)."""

    #: model -> name of the method that handles it, collected from :func:`handles` marks (class and bases)
    _routes: dict[type[Document], str] = {}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        routes: dict[type[Document], str] = {}
        for klass in reversed(cls.__mro__):
            for name, member in vars(klass).items():
                for model in getattr(member, _MODELS_ATTRIBUTE, ()):
                    routes[model] = name
        cls._routes = routes

    def __init__(self) -> None:
        self._table: dict[type[Document], Handler] = {}
        self._resolved: dict[type, Handler] = {}

    def on(self, model: type[D], handler: Callable[[D], Any]) -> DocumentRouter:
        """Handle documents of ``model`` (and of its subclasses) with ``handler``; returns the router."""
        if not (isinstance(model, type) and issubclass(model, Document)):
            raise TypeError(f"{model!r} is not a document model")
        self._table[model] = handler
        self._resolved.clear()
        return self

    def handler(self, model: type) -> Handler:
        """The handler of documents of ``model``: the most specific registered, else :meth:`default`."""
        found = self._resolved.get(model)
        if found is None:
            found = self.default
            for klass in model.__mro__:
                if klass in self._table:
                    found = self._table[klass]
                    break
                name = self._routes.get(klass)
                if name is not None:
                    found = getattr(self, name)
                    break
            self._resolved[model] = found
        return found

    def __call__(self, document: Document) -> Any:
        """Route one document (a :class:`~stereo_bench.campaign.stream.DocumentBus` subscriber is called so)."""
        return self.handler(type(document))(document)

    def read(self, documents: Iterable[Document] | Any) -> DocumentRouter:
        """Route every document of a recorded stream in order: a ``SessionReader`` (its documents) or any
        iterable of documents. Returns the router."""
        for document in documents.documents() if hasattr(documents, "documents") else documents:
            self(document)
        return self

    def default(self, document: Document) -> Any:
        """A document no handler takes: ignored (override to collect or refuse them)."""
        return None


__all__ = ["DocumentRouter", "handles"]
