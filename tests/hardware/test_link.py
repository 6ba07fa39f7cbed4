"""The one serial reader's pieces: frames stamped by the device counter, masks, the unwrap."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.hardware.link import FrameStamper, PortLink, WireDecoder
from skinloc.hardware.protocol import encode_binary, encode_text


def _binary(counters, n_tx=1, n_rx=3):
    return b"".join(encode_binary([c % 100, 1, 2][: n_tx * n_rx], n_tx, n_rx, c & 0xFFFF)
                    for c in counters)  # fmt: skip


def test_a_stalled_read_is_stamped_by_the_device_counter_not_all_at_the_read_time():
    """A 100 Hz device read every frame, then once after a 0.3 s stall of the host: the 30
    frames of that read are 10 ms apart, the last one at the read, after the previous stamps."""
    dec = WireDecoder("binary", 1, 3)
    t = 100.0
    stamps = []
    for c in range(100):  # 1 s of prompt reads, with 2 ms of jitter, to measure the period
        t = 100.0 + c * 0.01 + (0.002 if c % 3 == 0 else 0.0)
        (frame,) = dec.feed(_binary([c]), t)
        stamps.append(frame.timestamp_s)
    assert dec.stamper.period_s == pytest.approx(0.01, rel=0.02)
    stall = dec.feed(_binary(range(100, 130)), 100.0 + 129 * 0.01 + 0.0005)
    times = np.array([f.timestamp_s for f in stall])
    assert [f.index for f in stall] == list(range(100, 130))
    assert times[-1] == 100.0 + 129 * 0.01 + 0.0005  # the last frame: the read's time
    assert np.diff(times) == pytest.approx(np.full(29, 0.01), rel=0.03)
    assert times[0] > stamps[-1]  # monotonic across reads
    # before the fix every frame of a read carried the read's time
    assert len(set(times.tolist())) == 30


def test_stamps_never_go_back_nor_ahead_of_the_read():
    st = FrameStamper(period_s=0.01)
    a = st.stamp([0, 1, 2], 1.0)
    b = st.stamp([3, 4, 5, 6], 1.005)  # came sooner than the period says: squeezed, in order
    assert a == pytest.approx([0.98, 0.99, 1.0])
    assert b[-1] == 1.005 and all(x >= 1.0 for x in b) and b == sorted(b)
    c = st.stamp([70000, 70001], 2.0)  # a counter jump (frames lost): the read time anchors it
    assert c == pytest.approx([1.99, 2.0])
    assert st.stamp([], 3.0) == []


def test_the_period_follows_the_device_and_ignores_a_pause():
    st = FrameStamper(window=10)
    t, i = 0.0, 0
    for _ in range(40):
        st.stamp([i], t)
        i, t = i + 1, t + 0.005
    assert st.period_s == pytest.approx(0.005)
    st.stamp([i], t + 1.0)  # the device paused 1 s: one window far off, ignored
    for _ in range(12):
        i, t = i + 1, t + 0.005
        st.stamp([i], t + 1.0)
    assert st.period_s == pytest.approx(0.005, rel=0.05)
    for _ in range(60):  # the device now runs at 50 Hz: after three windows, the new rate
        i, t = i + 1, t + 0.02
        st.stamp([i], t + 1.0)
    assert st.period_s == pytest.approx(0.02, rel=0.05)
    with pytest.raises(ValueError, match="period_s"):
        FrameStamper(period_s=0.0)


def test_text_frames_are_counted_and_stamped_in_order():
    dec = WireDecoder("text", 1, 2, period_s=0.01)
    frames = dec.feed(b"\n" + encode_text([1, 2]) + encode_text([3, 4]), 5.0)
    assert [f.index for f in frames] == [0, 1]
    assert [f.timestamp_s for f in frames] == pytest.approx([4.99, 5.0])
    assert frames[0].values.dtype == np.float32


def test_the_counter_unwraps_and_a_lost_link_starts_a_fresh_epoch():
    dec = WireDecoder("binary", 1, 3, period_s=0.01)
    got = [f.index for f in dec.feed(_binary([65534, 65535, 0, 1]), 1.0)]
    assert got == [65534, 65535, 65536, 65537]
    dec.reset()  # the device may restart its counter
    got = [f.index for f in dec.feed(_binary([5, 6]), 2.0)]
    assert got == [2 * 65536 + 5, 2 * 65536 + 6]


def test_masks_keep_the_lines_asked_for():
    dec = WireDecoder("binary", 2, 3, tx_mask="01", rx_mask="110")
    (frame,) = dec.feed(encode_binary([1, 2, 3, 4, 5, 6], 2, 3, 0), 1.0)
    assert (dec.n_tx, dec.n_rx, dec.n_sensors) == (1, 2, 2)
    assert frame.values.tolist() == [4.0, 5.0]
    with pytest.raises(ValueError, match="tx_mask must have 2 entries"):
        WireDecoder("binary", 2, 3, tx_mask="1")


def test_a_port_link_counts_losses_and_reconnects():
    link = PortLink("loop://", 115200)
    link.open()
    assert link.up
    link.lost(OSError("gone"))
    assert not link.up and link.n_disconnects == 1 and link.last_error == "gone"
    assert link.reopen() and link.up and link.n_reconnects == 1
    link.close()
    missing = PortLink("/nonexistent/ttyNONE", 115200, nonblocking=True)
    assert not missing.reopen() and isinstance(missing.open_error, OSError)
    assert missing.n_reconnects == 0
