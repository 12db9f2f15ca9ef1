"""The strict MCAP check (the stand-in for the mcap CLI) accepts what the reference writer makes and names what a
damaged file gets wrong: a flipped byte (CRC), a cut-off end (no summary), statistics that lie."""

from __future__ import annotations

import io
import json

import pytest
from mcap.writer import CompressionType, Writer

from cromat.tools.mcap_check import McapCheckError, check_mcap, main


def write(path, *, compression=CompressionType.ZSTD, messages=50, statistics_fix=None) -> bytes:
    buf = io.BytesIO()
    w = Writer(buf, compression=compression, chunk_size=512)
    w.start(profile="", library="test")
    schema = w.register_schema(name="T", encoding="jsonschema", data=json.dumps({"type": "object"}).encode())
    a = w.register_channel(topic="a", message_encoding="json", schema_id=schema)
    b = w.register_channel(topic="b", message_encoding="json", schema_id=schema)
    for i in range(messages):
        w.add_message(channel_id=a if i % 3 else b, log_time=1000 + i, publish_time=1000 + i, sequence=i,
                      data=json.dumps({"i": i, "pad": "x" * 40}).encode())
    w.finish()
    data = buf.getvalue()
    path.write_bytes(data)
    return data


def test_a_good_file_passes_with_its_counts(tmp_path, capsys):
    f = tmp_path / "good.mcap"
    write(f)
    result = check_mcap(f)
    assert result.messages == 50 and result.per_topic == {"a": 33, "b": 17}
    assert result.chunks > 1 and result.chunk_crcs == result.chunks
    assert not result.data_crc_checked  # the Python writer leaves DataEnd's CRC 0 ("not computed", by the spec)
    assert main([str(f)]) == 0 and "ok: 50 messages on 2 channels" in capsys.readouterr().out


def test_a_flipped_byte_inside_a_chunk_fails_its_crc(tmp_path):
    f = tmp_path / "flipped.mcap"
    data = bytearray(write(f, compression=CompressionType.NONE))
    at = data.index(b'"pad"')  # inside an uncompressed chunk's message
    data[at + 1] ^= 0x01
    f.write_bytes(bytes(data))
    with pytest.raises(McapCheckError, match="(?i)crc"):
        check_mcap(f)


def test_a_file_cut_short_fails(tmp_path, capsys):
    f = tmp_path / "cut.mcap"
    data = write(f)
    f.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(McapCheckError):
        check_mcap(f)
    assert main([str(f)]) == 1 and "cut.mcap" in capsys.readouterr().err


def test_lying_statistics_are_named(tmp_path):
    f = tmp_path / "lie.mcap"
    data = bytearray(write(f, compression=CompressionType.NONE))
    # the Statistics record (opcode 0x0B, 42 fixed bytes + a map of 2 channel counts): message_count comes first
    at = data.rindex(bytes([0x0B]) + (42 + 4 + 2 * 10).to_bytes(8, "little"))
    count = int.from_bytes(data[at + 9:at + 17], "little")
    assert count == 50
    data[at + 9:at + 17] = (51).to_bytes(8, "little")
    f.write_bytes(bytes(data))
    with pytest.raises(McapCheckError, match="message_count is 51, the file has 50"):
        check_mcap(f)


def test_help_is_help(capsys):
    """Issue 34 item 7: ``--help`` was taken for a file name (FileNotFoundError)."""
    import pytest

    with pytest.raises(SystemExit) as done:
        main(["--help"])
    assert done.value.code == 0 and "FILE.mcap" in capsys.readouterr().out
