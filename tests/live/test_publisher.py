"""The publisher thread behind the ROS 2 sink: bounded, drop-oldest, never blocking, drained."""

import threading

import pytest

from skinloc.live.sinks.publisher import PublisherThread


def test_a_full_queue_drops_its_oldest_items_and_put_never_waits():
    started, release = threading.Event(), threading.Event()
    got: list[list[int]] = []

    def handle(batch):
        got.append(batch)
        if batch == [0]:
            started.set()
            assert release.wait(10.0)

    pub = PublisherThread(handle, maxsize=3, gather_s=0.0)
    try:
        pub.put(0)
        assert started.wait(10.0)  # the thread is now stuck in handle
        for k in range(1, 10):
            pub.put(k)  # returns although nothing is being sent
        assert (pub.n_put, pub.n_dropped, pub.pending) == (10, 6, 3)
        release.set()
        assert pub.flush(10.0)
    finally:
        assert pub.close()
    assert got == [[0], [7, 8, 9]]  # the newest three survived, in order
    assert pub.stats()["sent"] == 4 and pub.stats()["errors"] == 0


def test_close_sends_what_is_queued_then_joins():
    got: list[int] = []
    gate = threading.Event()
    pub = PublisherThread(lambda b: (gate.wait(10.0), got.extend(b)), maxsize=100, max_batch=7)
    for k in range(50):
        pub.put(k)
    gate.set()
    assert pub.close(10.0)
    assert got == list(range(50)) and not pub._thread.is_alive()
    assert pub.n_batches >= 50 // 7  # at most max_batch items per batch
    pub.put(99)  # after close: not sent, counted as dropped
    assert got[-1] == 49 and pub.n_dropped == 1
    assert pub.close()  # idempotent


def test_a_failing_batch_is_counted_and_the_thread_goes_on(caplog):
    got: list[int] = []

    def handle(batch):
        if 3 in batch:
            raise OSError("DDS write failed")
        got.extend(batch)

    pub = PublisherThread(handle, gather_s=0.0)
    pub.put(3)
    assert pub.flush(10.0)
    pub.put(4)
    assert pub.flush(10.0)
    pub.close()
    assert got == [4] and pub.n_errors == 1
    assert "publishing failed" in caplog.text


def test_bad_queue_size_is_refused():
    with pytest.raises(ValueError, match="at least 1"):
        PublisherThread(lambda b: None, maxsize=0)
