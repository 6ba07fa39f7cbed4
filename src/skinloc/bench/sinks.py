"""Publishing cost per contact of the sinks, JSON lines against ROS 2 (``skinloc bench --online``).

Every sink gets the same contacts in interleaved rounds of one process run, so all see the same
machine load. Two figures per sink: what ``emit`` costs the pipeline's thread, and for the ROS 2
sink, which only packs and queues there, the CPU its publisher process spends per contact
encoding and writing (``publisher_cpu_us_per_contact``, Cyclone's threads included); their sum
is the whole publishing cost.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["LOOPBACK_DDS", "bench_dds", "sink_cost"]

#: Cyclone DDS on the loopback interface only, unicast: benchmarks must not talk to the network
LOOPBACK_DDS = (
    "<CycloneDDS><Domain Id='any'><General><Interfaces><NetworkInterface name='lo'/>"
    "</Interfaces><AllowMulticast>false</AllowMulticast></General><Discovery>"
    "<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>30</MaxAutoParticipantIndex>"
    "<Peers><Peer address='127.0.0.1'/></Peers></Discovery></Domain></CycloneDDS>"
)


def bench_dds() -> tuple[int, str]:
    """A DDS domain for a benchmark run and its configuration: loopback, or CYCLONEDDS_URI.

    The configuration goes to the publishers (``Ros2Sink(dds_config=...)``) and to the
    benchmark's own participants (``cyclonedds.domain.Domain``); ``os.environ`` is not changed.
    """
    return 100 + os.getpid() % 100, os.environ.get("CYCLONEDDS_URI") or LOOPBACK_DDS


def _contacts(n: int, n_skins: int, random_state: int) -> list[Any]:
    """``n`` ``move`` contacts of ``n_skins`` skins at random points (m), 10 ms apart."""
    from skinloc.live.contact import Contact

    rng = np.random.default_rng(random_state)
    pos = rng.uniform(-0.05, 0.05, (n, 3))
    return [
        Contact(
            f"skin{k % n_skins:03d}",
            1.0 + 0.01 * k,
            k,
            "move",
            tuple(p),
            tuple(p),
            0.8,
            20.0,
            float("nan"),
            40.0,
            1,
            track_id=1,
            slot=0,
        )  # fmt: skip
        for k, p in enumerate(pos.tolist())
    ]


def _wait_matched(sink: Any, infos: list[Any], timeout_s: float = 10.0) -> None:
    """Until every skin's ``contacts`` writer has matched the subscriber (bounded)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and not all(
        sink.matched(f"/skinloc/{i.name}/contacts") for i in infos
    ):
        time.sleep(0.01)


def sink_cost(n_contacts: int = 20000, n_skins: int = 10, rounds: int = 3) -> dict:
    """Publishing cost per contact, µs: JSON lines against the ROS 2 sinks.

    Every sink gets the same ``n_contacts`` contacts (``move``, ``n_skins`` skins, one per
    frame through ``emit``) in each of ``rounds`` interleaved rounds. ``jsonl`` appends to a
    file, flushing every line; ``ros2`` is plain DDS on loopback, without and with a subscriber
    (a DDS reader of every skin's ``contacts`` topic in this process, so delivery is included),
    drained every 2000 contacts (untimed) so that nothing is dropped; ``mcap-ros2`` writes a
    bag (on the calling thread: a recording drops nothing).

    Returns, per sink: ``emit_median_us``, ``emit_p99_us``, ``emit_mean_us`` (the pipeline
    thread's cost per contact), ``publisher_cpu_us_per_contact`` (the publisher process's CPU per
    contact, 0 for sinks without one), ``total_us_per_contact`` (their sum), ``dropped``.
    """
    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import Domain, DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from skinloc.live.sinks.base import SkinInfo
    from skinloc.live.sinks.jsonl import JsonLinesSink
    from skinloc.live.sinks.ros2.bag import Ros2BagSink
    from skinloc.live.sinks.ros2.sink import Ros2Sink
    from skinloc.ros2.msgs import PoseArray

    alone, dds = bench_dds()
    heard = alone + 1  # the subscriber's domain; nothing listens on ``alone``
    contacts = _contacts(n_contacts, n_skins, 0)
    infos = [SkinInfo(f"skin{i:03d}") for i in range(n_skins)]
    times: dict[str, list[float]] = {}
    thread_cpu: dict[str, float] = {}
    dropped: dict[str, int] = {}
    received = 0
    with tempfile.TemporaryDirectory(prefix="skinloc-sink-cost-") as tmp:
        _domain = Domain(heard, dds)  # its configuration, kept while the participant lives
        reader_dp = DomainParticipant(heard)
        qos = Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(10))
        readers = [
            DataReader(
                reader_dp,
                Topic(reader_dp, f"rt/skinloc/{i.name}/contacts", PoseArray, qos),
                qos=qos,
            )
            for i in infos
        ]
        n_queue = 4096  # the default
        for r in range(rounds):
            makers = {
                "jsonl": lambda r=r: JsonLinesSink(Path(tmp) / f"c{r}.jsonl"),
                "ros2 (DDS, no subscriber)": lambda: Ros2Sink(
                    domain_id=alone, backend="dds", queue_frames=n_queue, dds_config=dds
                ),
                "ros2 (DDS, 1 subscriber)": lambda: Ros2Sink(
                    domain_id=heard, backend="dds", queue_frames=n_queue, dds_config=dds
                ),
                "mcap-ros2 (bag)": lambda r=r: Ros2BagSink(Path(tmp) / f"b{r}.mcap", frames=False),
            }
            for label, make in makers.items():
                sink = make()
                sink.open(infos)
                if "1 subscriber" in label:
                    _wait_matched(sink, infos)
                dt = np.empty(len(contacts))
                for k, c in enumerate(contacts):
                    t = time.perf_counter_ns()
                    sink.emit(c)
                    dt[k] = time.perf_counter_ns() - t
                    if k % 500 == 0:
                        received += sum(len(rd.take(N=100)) for rd in readers)
                    if k % 2000 == 1999 and hasattr(sink, "flush"):
                        # untimed: emit back to back outruns any publisher, and a live
                        # pipeline emits 10 000 frames/s at most; the pipe holds about 2000
                        sink.flush(60.0)
                if hasattr(sink, "flush"):
                    sink.flush(60.0)  # everything written before the subscriber's last take
                if "1 subscriber" in label:  # what is still in flight, bounded
                    end = time.monotonic() + 2.0
                    while time.monotonic() < end:
                        got = sum(len(rd.take(N=100)) for rd in readers)
                        received += got
                        if not got:
                            time.sleep(0.05)
                sink.close()
                times.setdefault(label, []).extend((dt / 1000.0).tolist())
                st = sink.stats() if hasattr(sink, "stats") else {"cpu_s": 0.0, "dropped": 0}
                thread_cpu[label] = thread_cpu.get(label, 0.0) + st["cpu_s"]
                dropped[label] = dropped.get(label, 0) + st["dropped"]
    out = {}
    for label, t in times.items():
        a = np.asarray(t)
        cpu = thread_cpu[label] / len(a) * 1e6
        out[label] = {
            "contacts": len(a),
            "emit_median_us": float(np.median(a)),
            "emit_p99_us": float(np.percentile(a, 99)),
            "emit_mean_us": float(a.mean()),
            "publisher_cpu_us_per_contact": cpu,
            "total_us_per_contact": float(a.mean()) + cpu,
            "dropped": dropped[label],
        }
    # keep-last 10 per topic: a reader taking every 500 contacts sees at most 10 of each batch
    out["ros2 (DDS, 1 subscriber)"]["samples_taken_by_subscriber"] = received
    return out
