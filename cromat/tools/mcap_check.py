"""Strict check of an MCAP file with the reference ``mcap`` Python library, standing in for ``mcap doctor``.

The ``mcap`` command-line tool is a Go binary published only as a GitHub release; it is in none of PyPI, npm
or Debian, so it cannot be installed where this project runs (docs/tools.md). This check reads a file twice:

1. front to back (``StreamReader``, ``validate_crcs``): every record parses, every chunk's CRC and the data
   section's CRC (``DataEnd``) match, and the summary section follows;
2. through the summary (``SeekingReader``, chunk indexes): the messages reached by the index are the same, per
   channel, as those read front to back, and the ``Statistics`` record counts them right (messages, per-channel
   counts, channels, schemas, chunks, first and last log time).

Every message of a ``json`` channel must parse as JSON, and every ``jsonschema`` schema as a JSON document.
``python -m cromat.tools.mcap_check FILE...`` prints one line per file; ``cromat record --verify`` runs it on
what it wrote.
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, DataEnd, Message, Schema, Statistics
from mcap.stream_reader import StreamReader


class McapCheckError(ValueError):
    """The file is not a complete, consistent MCAP file; the message says what is wrong."""


@dataclass
class McapCheck:
    path: str
    messages: int = 0
    per_topic: dict[str, int] = field(default_factory=dict)
    chunks: int = 0
    chunk_crcs: int = 0
    """Chunks whose CRC was present and checked (a writer may leave it 0: not computed)."""
    data_crc_checked: bool = False
    first_ns: int = 0
    last_ns: int = 0

    def line(self) -> str:
        crc = (f"{self.chunk_crcs}/{self.chunks} chunk CRCs and the data section CRC ok" if self.data_crc_checked
               else f"{self.chunk_crcs}/{self.chunks} chunk CRCs ok, no data section CRC written")
        return (f"{self.path}: ok: {self.messages} messages on {len(self.per_topic)} channels; {crc}; "
                "summary statistics and indexes agree")


def check_mcap(path: str | Path) -> McapCheck:
    """Check ``path``; raise :class:`McapCheckError` naming the first problem."""
    path = Path(path)
    result = McapCheck(str(path))
    try:
        streamed, channels, schemas = _stream_pass(path, result)
        indexed, stats = _index_pass(path)
    except McapCheckError:
        raise
    except Exception as exc:  # the library's own errors: bad magic, CRC mismatch, truncated record...
        raise McapCheckError(f"{path}: {type(exc).__name__}: {exc}") from None
    topic = {cid: ch.topic for cid, ch in channels.items()}
    if indexed != streamed:
        raise McapCheckError(f"{path}: the chunk indexes reach {sum(indexed.values())} messages, the file holds "
                             f"{sum(streamed.values())} ({_diff(indexed, streamed, topic)})")
    if stats is None:
        raise McapCheckError(f"{path}: no Statistics record in the summary")
    expected = {"message_count": sum(streamed.values()), "channel_count": len(channels),
                "schema_count": len(schemas), "chunk_count": result.chunks,
                "message_start_time": result.first_ns, "message_end_time": result.last_ns}
    for name, value in expected.items():
        if getattr(stats, name) != value:
            raise McapCheckError(f"{path}: Statistics.{name} is {getattr(stats, name)}, the file has {value}")
    if dict(stats.channel_message_counts) != {c: n for c, n in streamed.items() if n}:
        raise McapCheckError(f"{path}: Statistics.channel_message_counts disagree with the messages: "
                             f"{_diff(dict(stats.channel_message_counts), streamed, topic)}")
    result.messages = sum(streamed.values())
    result.per_topic = {topic[c]: n for c, n in sorted(streamed.items())}
    return result


def _stream_pass(path: Path, result: McapCheck) -> tuple[Counter[int], dict[int, Channel], dict[int, Schema]]:
    counts: Counter[int] = Counter()
    channels: dict[int, Channel] = {}
    schemas: dict[int, Schema] = {}
    with open(path, "rb") as f:  # chunks first, unbroken, to count them and see whether their CRCs were written
        for record in StreamReader(f, emit_chunks=True, validate_crcs=False).records:
            if isinstance(record, Chunk):
                result.chunks += 1
                result.chunk_crcs += record.uncompressed_crc != 0
    with open(path, "rb") as f:
        in_data = True
        for record in StreamReader(f, validate_crcs=True).records:
            if isinstance(record, DataEnd):
                in_data = False
                result.data_crc_checked = record.data_section_crc != 0
            elif isinstance(record, Schema) and in_data:
                schemas[record.id] = record
                if record.encoding == "jsonschema":
                    _json(record.data, f"{path}: schema {record.name!r}")
            elif isinstance(record, Channel) and in_data:
                if record.schema_id and record.schema_id not in schemas:
                    raise McapCheckError(f"{path}: channel {record.topic!r} names schema {record.schema_id}, "
                                         "which comes nowhere before it")
                channels[record.id] = record
            elif isinstance(record, Message):
                ch = channels.get(record.channel_id)
                if ch is None:
                    raise McapCheckError(f"{path}: a message on channel {record.channel_id}, never declared")
                if ch.message_encoding == "json":
                    _json(record.data, f"{path}: message {record.sequence} on {ch.topic!r}")
                counts[record.channel_id] += 1
                result.first_ns = min(result.first_ns, record.log_time) if result.first_ns else record.log_time
                result.last_ns = max(result.last_ns, record.log_time)
    for cid in channels:
        counts.setdefault(cid, 0)
    return counts, channels, schemas


def _index_pass(path: Path) -> tuple[Counter[int], Statistics | None]:
    counts: Counter[int] = Counter()
    with open(path, "rb") as f:
        reader = SeekingReader(f, validate_crcs=True)
        summary = reader.get_summary()
        if summary is None:
            raise McapCheckError(f"{path}: no summary section (a recording that was not finished?)")
        for cid in summary.channels:
            counts[cid] = 0
        for _schema, channel, _message in reader.iter_messages(log_time_order=False):
            counts[channel.id] += 1
    return counts, summary.statistics


def _json(data: bytes, what: str) -> None:
    try:
        json.loads(data)
    except ValueError as exc:
        raise McapCheckError(f"{what} is not JSON: {exc}") from None


def _diff(a: dict[int, int], b: dict[int, int], topic: dict[int, str]) -> str:
    keys = sorted(set(a) | set(b))
    return ", ".join(f"{topic.get(k, k)}: {a.get(k, 0)} vs {b.get(k, 0)}" for k in keys if a.get(k, 0) != b.get(k, 0))


def main(argv: list[str] | None = None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m cromat.tools.mcap_check",
                                description="Check MCAP files strictly (CRCs, chunk indexes, summary statistics, "
                                            "JSON messages and schemas), as `mcap doctor` would.")
    p.add_argument("files", nargs="+", metavar="FILE.mcap")
    args = p.parse_args(argv)
    code = 0
    for path in args.files:
        try:
            print(check_mcap(path).line())
        except (McapCheckError, OSError) as exc:
            print(f"{exc}", file=sys.stderr)
            code = 1
    return code


if __name__ == "__main__":
    raise SystemExit(main())
