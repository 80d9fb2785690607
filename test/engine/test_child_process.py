"""The framing of the child processes' messages and their channel (no ROS): a broken
stream is a FramingError that shows its bytes, never an allocation of its garbage."""

from __future__ import annotations

import os
import struct
import sys
import textwrap

import numpy as np
import pytest

from grasp_fc_ros.engine import child_process
from grasp_fc_ros.engine.child_process import (
    MAGIC,
    MAX_MESSAGE_BYTES,
    ChildProcess,
    FramingError,
    MessageTooLarge,
    open_channel,
    read_message,
    write_message,
)

# What Fast DDS printed on the marker process's stdout (issue 28).
FAST_DDS_LINE = (b"2026-01-01 12:00:00.000 [XMLPARSER Error] realpath failed for "
                 b"/tmp/grasp_fc_dds_x/reader_times.xml -> Function parseXMLFile\n")
CHILD_TIMEOUT_S = 60.0


@pytest.fixture
def pipe():
    """(reader, writer): the two ends of a pipe, as the channel opens them."""
    reads, writes = os.pipe()
    reader, writer = os.fdopen(reads, "rb", buffering=0), os.fdopen(writes, "wb")
    yield reader, writer
    for stream in (reader, writer):
        if not stream.closed:
            stream.close()


def send_raw(writer, data: bytes, close: bool = True) -> None:
    writer.write(data)
    writer.flush()
    if close:
        writer.close()


def test_messages_arrive_whole_and_in_order(pipe):
    reader, writer = pipe
    big = np.arange(300_000, dtype=np.float64)  # larger than a pipe's buffer
    sent = ["ready", (True, 3), big, None]

    import threading
    thread = threading.Thread(target=lambda: [write_message(writer, m) for m in sent])
    thread.start()
    got = [read_message(reader) for _ in sent]
    thread.join()
    assert got[:2] == sent[:2] and got[3] is None
    np.testing.assert_array_equal(got[2], big)
    writer.close()
    with pytest.raises(EOFError):
        read_message(reader)


def test_text_where_a_header_should_be_is_a_framing_error_showing_it(pipe):
    reader, writer = pipe
    send_raw(writer, FAST_DDS_LINE)
    with pytest.raises(FramingError, match="no message header where one should start") as err:
        read_message(reader)
    shown = str(err.value)
    assert repr(FAST_DDS_LINE[:child_process.SHOWN_BYTES]) in shown


@pytest.mark.parametrize("data, error", [
    (struct.pack("<4sQ", MAGIC, MAX_MESSAGE_BYTES + 1) + b"x" * 10,
     f"message length {MAX_MESSAGE_BYTES + 1:,} is above MAX_MESSAGE_BYTES"),
    (struct.pack("<4sQ", MAGIC, 2**63), f"message length {2**63:,} is above"),
    (struct.pack("<4sQ", MAGIC, 1000) + b"only this",
     "ended after 9 of a message's 1,000 bytes: b'only this'"),
    (MAGIC + b"\x01", "ended inside a message header"),
    (struct.pack("<4sQ", MAGIC, 12) + b"not a pickle",
     "message of 12 bytes does not unpickle .*b'not a pickle'"),
], ids=["above_the_cap", "absurd_length", "ends_inside_a_message", "ends_inside_a_header",
        "not_a_pickle"])
def test_a_broken_stream_is_a_framing_error_showing_what_it_holds(pipe, data, error):
    """Never an allocation of a garbage length, never a hang on a short stream."""
    reader, writer = pipe
    send_raw(writer, data)
    with pytest.raises(FramingError, match=error):
        read_message(reader)


def test_a_message_above_the_limit_is_refused_before_anything_is_sent(pipe, monkeypatch):
    reader, writer = pipe
    monkeypatch.setattr(child_process, "MAX_MESSAGE_BYTES", 100)
    with pytest.raises(MessageTooLarge, match="more than the 100"):
        write_message(writer, b"x" * 200)
    write_message(writer, "small")
    assert read_message(reader) == "small"


def test_a_process_not_started_with_a_channel_says_so(monkeypatch):
    monkeypatch.delenv(child_process.CHANNEL_VARIABLE, raising=False)
    with pytest.raises(RuntimeError, match="GRASP_FC_CHANNEL"):
        open_channel()


# A child that prints on its stdout before and after it opens its channel, as a library
# would, and echoes one message; it also reports what it inherited.
ECHO_CHILD = textwrap.dedent("""
    import os, sys
    os.write(1, {line!r})
    from grasp_fc_ros.engine.child_process import CHANNEL_VARIABLE, open_channel, \\
        read_message, write_message
    requests, answers = open_channel()
    print("a library's chatter", flush=True)
    message = read_message(requests)
    write_message(answers, (message, CHANNEL_VARIABLE in os.environ, sys.stdin.read()))
""")


def test_a_child_talks_on_its_channel_whatever_it_prints(capfd):
    child = ChildProcess.start([sys.executable, "-c", ECHO_CHILD.format(line=FAST_DDS_LINE)],
                               dict(os.environ))
    try:
        write_message(child.to_child, {"grasps": 3})
        echoed, inherits_variable, stdin = read_message(child.from_child)
    finally:
        child.close_channel()
        assert child.process.wait(CHILD_TIMEOUT_S) == 0
    assert echoed == {"grasps": 3}
    assert not inherits_variable  # taken out: nothing the child starts gets its pipes
    assert stdin == ""  # /dev/null
    out = capfd.readouterr().out
    assert "[XMLPARSER Error]" in out and "a library's chatter" in out
