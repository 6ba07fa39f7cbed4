"""Tests of SerialSource over pyserial's loop:// URL (no hardware) and its config checks."""

from __future__ import annotations

import errno

import numpy as np
import pytest

from skinloc.errors import FrameTimeoutError, SourceAlreadyConnectedError, SourceNotConnectedError
from skinloc.hardware.protocol import encode_binary, encode_text
from skinloc.hardware.serial import (
    SerialSource,
    SerialSourceConfig,
    list_ports,
    parse_line_mask,
)
from tests._helpers import wait_until


def loop_source(**kw) -> SerialSource:
    return SerialSource(SerialSourceConfig("loop://", **kw))


def test_binary_frames_in_order_with_counts():
    with loop_source(n_tx=2, n_rx=3) as src:
        vals = np.arange(6 * 5).reshape(5, 6) + 9000
        data = b"".join(encode_binary(v, 2, 3, k) for k, v in enumerate(vals) if k != 2)
        src.write(b"garbage" + data)
        got = [src.read(timeout_s=5.0) for _ in range(4)]
        assert [f.index for f in got] == [0, 1, 3, 4]
        np.testing.assert_array_equal(got[2].values, vals[3].astype(np.float32))
        assert got[0].values.dtype == np.float32
        s = src.stats()
        assert (s.n_received, s.n_lost, s.format) == (4, 1, "binary")


def test_text_frames_with_chatter():
    with loop_source(n_tx=1, n_rx=4, format="text") as src:
        src.write(b"\r\nRX active lines: 1111\r\n1,2,3,4\r\n5,6,7\r\n8,9,10,11\r\n")
        assert src.read(5.0).values.tolist() == [1, 2, 3, 4]
        assert src.read(5.0).values.tolist() == [8, 9, 10, 11]
        s = src.stats()
        assert (s.n_received, s.n_dropped, s.n_chatter) == (2, 1, 1)


def test_line_masks_keep_the_used_lines():
    # The device sends 3 TX x 4 RX; only TX 0, 2 and RX 1, 3 are wired.
    with loop_source(n_tx=3, n_rx=4, tx_mask="101", rx_mask="0101") as src:
        assert (src.n_tx, src.n_rx, src.n_sensors) == (2, 2, 4)
        src.write(encode_binary(list(range(12)), 3, 4, 0))
        assert src.read(5.0).values.tolist() == [1, 3, 9, 11]


def test_latest_and_max_age():
    with loop_source(n_tx=1, n_rx=1) as src:
        with pytest.raises(FrameTimeoutError, match="no frame from loop:// yet"):
            src.latest()
        src.write(encode_binary([5], 1, 1, 0) + encode_binary([6], 1, 1, 1))
        src.read(5.0)
        src.read(5.0)
        assert src.latest(max_age_ms=60_000).values.tolist() == [6.0]
        with pytest.raises(FrameTimeoutError, match="ms old"):
            src.latest(max_age_ms=1e-6)


def test_bounded_buffer_counts_overflow():
    with loop_source(n_tx=1, n_rx=1, buffer_frames=2) as src:
        src.write(b"".join(encode_binary([k], 1, 1, k) for k in range(5)))

        def seen_all() -> bool:
            try:
                return src.latest(max_age_ms=60_000).index >= 4
            except FrameTimeoutError:
                return False

        wait_until(seen_all, "the reader to see 5 frames", 30.0, interval_s=0.005)
        assert [src.read(5.0).index for _ in range(2)] == [3, 4]
        assert src.stats().n_overflow == 3


def test_timeout_names_the_port_and_says_why():
    with loop_source() as src:
        with pytest.raises(
            FrameTimeoutError, match=r"no frame from loop:// within 0.05 s.*no bytes"
        ):
            src.read(timeout_s=0.05)
        src.write(b"\x00" * 50)

        # The reader thread takes the bytes when it is scheduled: until then the timeout
        # rightly says "no bytes", so poll for the message rather than expect it at once.
        def why() -> str:
            with pytest.raises(FrameTimeoutError) as exc:
                src.read(timeout_s=0.05)
            return str(exc.value)

        wait_until(lambda: "bytes but no valid frame" in why(), "the timeout to name the bytes", 0)


def test_contract_connect_twice_read_after_disconnect():
    src = loop_source()
    with pytest.raises(SourceNotConnectedError):
        src.read()
    with pytest.raises(SourceNotConnectedError):
        src.latest()
    src.connect()
    with pytest.raises(SourceAlreadyConnectedError):
        src.connect()
    src.disconnect()
    with pytest.raises(SourceNotConnectedError):
        src.read(0.01)
    with pytest.raises(SourceNotConnectedError):
        src.write(b"v\n")
    with pytest.raises(SourceNotConnectedError):
        src.disconnect()


def test_missing_port_error_names_it():
    src = SerialSource(SerialSourceConfig("/dev/skinloc-no-such-port"))
    with pytest.raises(SourceNotConnectedError, match="/dev/skinloc-no-such-port.*skinloc ports"):
        src.connect()
    assert not src.is_connected


@pytest.mark.parametrize(
    "kw, msg",
    [
        ({"port": ""}, "port"),
        ({"baud": 0}, "baud"),
        ({"n_tx": 22}, "n_tx"),
        ({"n_rx": 0}, "n_rx"),
        ({"format": "csv"}, "auto, text, binary"),
        ({"timeout_s": 0}, "timeout_s"),
        ({"buffer_frames": 0}, "buffer_frames"),
        ({"tx_mask": "1111"}, "8 entries"),
        ({"rx_mask": "1111000x"}, "0 and 1"),
        ({"rx_mask": "00000000"}, "selects no line"),
    ],
)
def test_config_rejects_bad_values(kw, msg):
    args = {"port": "loop://", **kw}
    with pytest.raises(ValueError, match=msg):
        SerialSourceConfig(**args)


def test_parse_line_mask_sequences():
    assert parse_line_mask([1, 0, 1], 3, "tx_mask").tolist() == [True, False, True]
    assert parse_line_mask(None, 2, "tx_mask").all()
    with pytest.raises(ValueError):
        parse_line_mask([2, 0], 2, "tx_mask")


def test_frames_stream_and_text_index():
    with loop_source(n_tx=1, n_rx=2, format="text") as src:
        src.write(b"\n" + b"".join(encode_text([k, k]) for k in range(3)))
        stream = src.frames(timeout_s=5.0)
        assert [next(stream).index for _ in range(3)] == [0, 1, 2]


def test_list_ports_runs():
    for p in list_ports():
        assert p.device
    assert isinstance(SerialSource.find_ports(), list)


@pytest.mark.parametrize(
    "code, hint",
    [
        (errno.ENOENT, "no such device"),
        (errno.EACCES, "dialout"),
        (errno.EBUSY, "busy"),
        (errno.ENOTTY, "not a serial port"),
        (errno.EIO, "skinloc ports"),
    ],
)
def test_open_failures_say_what_to_do(code, hint):
    import serial

    from skinloc.hardware.serial import why_not_open

    assert hint in why_not_open(serial.SerialException(code, "could not open port"))


def test_not_a_serial_port(tmp_path):
    with pytest.raises(SourceNotConnectedError, match="not a serial port"):
        SerialSource(SerialSourceConfig(str(tmp_path))).connect()
