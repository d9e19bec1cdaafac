"""``stereo-bench session``: the recording format.

    stereo-bench session schema            # JSON Schema of one line of documents.jsonl
    stereo-bench session schema --row      # JSON Schema of one result row (results.csv, results.sqlite)

docs/SESSION_FORMAT.md describes a session directory for someone writing their own analysis.
"""

from __future__ import annotations

import json


def register(subparsers) -> None:
    session = subparsers.add_parser(
        "session", help="the session recording format (JSON Schema of its documents)",
        description="A session directory holds documents.jsonl (one JSON document a line), frames, calibrations "
                    "and results.sqlite/results.csv; docs/SESSION_FORMAT.md describes it.",
    )
    actions = session.add_subparsers(dest="session_action", metavar="ACTION", required=True)
    schema = actions.add_parser(
        "schema", help="print the JSON Schema of a session document (or of a result row)",
        description="Print the JSON Schema (draft 2020-12) of one line of documents.jsonl: start, resume, each "
                    "event kind, result and stop, as this version writes them and reads them.",
    )
    schema.add_argument("--row", action="store_true", help="the schema of one result row instead")
    schema.set_defaults(func=_cmd_schema)


def _cmd_schema(args) -> int:
    from stereo_bench.campaign.documents import SCHEMA_VERSION, ResultRow, document_json_schema

    if args.row:
        schema = ResultRow.model_json_schema()
        schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
        schema["title"] = f"stereo-bench result row (session schema version {SCHEMA_VERSION})"
    else:
        schema = document_json_schema()
    print(json.dumps(schema, indent=2))
    return 0
