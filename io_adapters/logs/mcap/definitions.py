"""The Schema and Channel records of an MCAP file by id, and the checks every reader of it makes.

MCAP ids are unique in a file: a repeated Schema or Channel record repeats the first one's content
(else the messages after it would be read as another topic or type), and a message needs a channel
defined before it, of a schema defined before it. The track reader and the salvage copy share
these checks, so a damaged chunk is skipped by both alike: :meth:`Definitions.check_chunk` checks
a chunk's records against a copy before any of them is used.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import Any

from mcap.opcode import Opcode

from lanecast.io_adapters.logs.mcap.errors import LogDamage
from lanecast.io_adapters.logs.mcap.records import MSG_HEAD, records


class Definitions:
    """Schema and channel records by id (of any record type that compares by content)."""

    def __init__(self, schemas: dict[int, Any] | None = None, channels: dict[int, Any] | None = None) -> None:
        self.schemas: dict[int, Any] = {} if schemas is None else schemas
        self.channels: dict[int, Any] = {} if channels is None else channels

    def schema(self, offset: int, sid: int, record: Any) -> None:
        """Define schema ``sid``; LogDamage if it was defined with other content."""
        self._define(self.schemas, "schema", offset, sid, record)

    def channel(self, offset: int, cid: int, record: Any) -> None:
        """Define channel ``cid``; LogDamage if it was defined with other content."""
        self._define(self.channels, "channel", offset, cid, record)

    @staticmethod
    def _define(table: dict[int, Any], kind: str, offset: int, ident: int, record: Any) -> None:
        before = table.get(ident)
        if before is not None and before != record:
            raise LogDamage(
                offset,
                f"{kind} {ident} defined again with other content ({record}; before: {before})",
                f"one {kind} per id (a repeated {kind.capitalize()} record the same as the first)",
                False,
            )
        table[ident] = record

    def channel_of(self, offset: int, cid: int, where: str = "", *, resync: bool = False) -> Any:
        """The channel a message (``where``: its place, for the error) is on, which must be defined,
        of a schema that is defined; LogDamage if not."""
        channel = self.channels.get(cid)
        if channel is None:
            raise LogDamage(
                offset,
                f"message {where}on channel {cid}, which was never defined",
                "a Channel record first",
                resync,
            )
        if channel.schema_id and channel.schema_id not in self.schemas:
            raise LogDamage(
                offset,
                f"topic {channel.topic!r} refers to schema {channel.schema_id}, which the file does not define",
                "a Schema record for every channel",
                resync,
            )
        return channel

    def check_chunk(self, items: Iterable[tuple[int, int, int, int, Any]], offset: int) -> None:
        """Check the records of a chunk at file ``offset`` (``items``: :func:`parsed`) against these
        definitions and those made earlier in it, before any is used: with salvage a damaged chunk
        is skipped whole, so none of its messages may be read or copied before the damage is found."""
        trial = Definitions(dict(self.schemas), dict(self.channels))
        for op, pos, _body, _nxt, value in items:
            if op == Opcode.MESSAGE:
                trial.channel_of(offset, value[0], f"at byte {pos} of the chunk ", resync=True)
            elif op == Opcode.SCHEMA:
                trial.schema(offset, *value)
            elif op == Opcode.CHANNEL:
                trial.channel(offset, *value)


def parsed(
    buf: Any,
    start: int,
    end: int,
    schema: Callable[[Any, int, int], tuple[int, Any]],
    channel: Callable[[Any, int, int], tuple[int, Any]],
) -> Iterator[tuple[int, int, int, int, Any]]:
    """(opcode, offset, body, end, content) of the Schema, Channel and Message records of
    buf[start:end]: (id, record) as ``schema``/``channel`` parse a body, a Message's header fields
    (channel id, sequence, log time, publish time)."""
    for op, pos, body, nxt in records(buf, start, end):
        if op == Opcode.MESSAGE:
            if nxt - body < MSG_HEAD.size:
                raise ValueError(f"a Message record of {nxt - body} bytes, shorter than its header")
            yield op, pos, body, nxt, MSG_HEAD.unpack_from(buf, body)
        elif op == Opcode.SCHEMA:
            yield op, pos, body, nxt, schema(buf, body, nxt)
        elif op == Opcode.CHANNEL:
            yield op, pos, body, nxt, channel(buf, body, nxt)
