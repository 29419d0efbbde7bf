"""What a recorded message is: its schema (as stored in the MCAP schema record) and one
recorder call's arguments."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

__all__ = ["MessageSchema", "Record"]


@dataclass(frozen=True)
class MessageSchema:
    """One schema as stored in an MCAP schema record, plus its channels' message encoding.

    Attributes
    ----------
    name
        Schema name (``foxglove.RawImage``, ``ogiflow.WindSample``).
    encoding
        MCAP schema encoding: ``protobuf`` (a serialized FileDescriptorSet) or ``jsonschema``.
    data
        Schema bytes as written to the file.
    message_encoding
        Encoding of the messages on channels of this schema: ``protobuf`` or ``json``.
    """

    name: str
    encoding: str
    data: bytes
    message_encoding: str

    @property
    def json_schema(self) -> dict[str, Any]:
        """The JSON Schema as a dict (JSON schemas only)."""
        if self.encoding != "jsonschema":
            raise TypeError(f"{self.name} is not a JSON schema")
        return json.loads(self.data)


@dataclass(frozen=True)
class Record:
    """The arguments of one :meth:`appliance.recording.recorder.Recorder.record` call."""

    topic: str
    schema: MessageSchema
    payload: bytes
    log_time_ns: int
    publish_time_ns: int
