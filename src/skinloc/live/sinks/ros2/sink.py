"""ROS 2: contacts as standard ROS 2 messages, over DDS without a ROS install, or through rclpy.

The topics, types and stamps are ``skinloc.live.sinks.ros2.topics``'s (``/skinloc/S/contact``,
``contacts``, ``markers``, ``mesh``, ``gestures`` and ``/tf_static``).

Without ``rclpy`` the messages go out through a plain DDS participant (Cyclone DDS, the
``cyclonedds`` wheel) writing on ``rt/<topic>`` with the DDS type names and CDR encoding a ROS 2
node uses, on domain ``ROS_DOMAIN_ID`` (default 0): ``ros2 topic echo /skinloc/S/contact`` on the
same machine or network sees them with no bridge. With ``rclpy`` importable (a sourced ROS 2
install) a real node named ``NODE`` publishes the same bytes.

The encoding and the writes run in a **process of their own** (``ros2.publisher``): the DDS
writes hold the interpreter lock, and on a thread beside the pipeline they multiplied the loop's
p99 latency by 5-10 at 100 skins (docs/benchmarks.md). The pipeline's thread packs each frame's
contacts into a record of about 100 bytes a contact and writes it to a pipe without blocking;
when the pipe is full (the publisher is behind by ``queue_frames`` frames) the frame is dropped
and counted (``stats()["dropped"]``). ``close`` lets the publisher publish what is in the pipe
and waits for it to end; the publisher also ends by itself when this process is gone.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import math
import os
import re
import select
import subprocess
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from skinloc.errors import MissingExtraError
from skinloc.live.sinks.base import Sink, SinkSpec, SkinInfo
from skinloc.live.sinks.ros2.records import (
    pack_control,
    pack_frame,
    pack_gesture,
    pack_matched,
    pack_skins,
    pack_sync,
)

# the runner, the bag source and users' code import these from here
from skinloc.live.sinks.ros2.topics import quaternion_from_rpy as quaternion_from_rpy
from skinloc.live.sinks.ros2.topics import ros_name as ros_name
from skinloc.live.sinks.ros2.topics import topic_base as topic_base
from skinloc.ros2.names import node_name_error

if TYPE_CHECKING:
    from skinloc.live.contact import Contact

log = logging.getLogger(__name__)

__all__ = ["Ros2Sink", "p99"]

_PIPE_BUF = 4096  # POSIX: a write of at most this many bytes to a pipe is atomic
_BYTES_PER_FRAME = 256  # a frame record of up to 3 contacts, rounded up: sizes the pipe
#: How long a frame that ends a track waits for room in a full pipe, s: a subscriber must not
#: be left with a finger that lifted (any other frame is dropped at once)
_END_WAIT_S = 2.0
#: The longest a record waits in its turn's batch, s, before it goes with the next: the turns
#: of a busy 100-skin loop took 9-27 ms of CPU at their p99, and a record held for the whole
#: turn reached DDS 1-1.6 ms later at the median
_BATCH_WAIT_S = 0.0002
_START_TIMEOUT_S = 120.0  # a loaded machine may take long to import cyclonedds and join
_DIAG_PERIOD_S = 1.0  # /diagnostics, as diagnostic_updater publishes
#: the most of a sweep spent on diagnostics, s (at least one skin a sweep): the statuses of 50
#: skins at once stopped the loop for 15-30 ms a second, the p99 of every skin's frames
_DIAG_BUDGET_S = 0.0002
_LATENCIES = 256  # the latest frames' latencies kept per skin, for the diagnostics' p99
_ERRORS = {
    "ValueError": ValueError,
    "ImportError": ImportError,
    "MissingExtraError": MissingExtraError,
    "OSError": OSError,
}


def p99(values: np.ndarray) -> float:
    """The 99th percentile of ``values``' finite entries (nan: none), as ``np.percentile``'s.

    Linear between the two nearest ranks, the same arithmetic as NumPy's default method, in a
    tenth of its time (a skin's diagnostics took it once a second: 20-30 us of the loop's).
    """
    v = np.sort(values[np.isfinite(values)])
    n = len(v)
    if n == 0:
        return math.nan
    at = (n - 1) * 0.99
    lo = math.floor(at)
    a = float(v[lo])
    b = float(v[min(lo + 1, n - 1)])
    t = at - lo
    d = b - a
    return b - d * (1.0 - t) if t >= 0.5 else a + d * t


def _pipe_max() -> int:
    try:
        return int(Path("/proc/sys/fs/pipe-max-size").read_text())
    except (OSError, ValueError):
        return 1 << 20


class Ros2Sink(Sink):
    """Publish contacts on ROS 2 topics (see ``skinloc.live.sinks.ros2.topics``).

    Parameters
    ----------
    node_name : str
        The node's name (rclpy only; over plain DDS there is no node graph entry).
    domain_id : int, optional
        DDS domain (default: ``ROS_DOMAIN_ID``, else 0).
    backend : {"auto", "dds", "rclpy"}
        ``auto``: the environment variable ``SKINLOC_ROS2_BACKEND`` when set, else rclpy when
        importable, else plain DDS.
    queue_frames : int, default=4096
        About how many frames the pipe to the publisher holds (``_BYTES_PER_FRAME`` each, within
        the system's pipe size limit); a frame that finds it full is dropped and counted. 4096
        is 0.4 s of 100 skins at 100 Hz.
    gather_s : float, default=0.001
        The publisher's pause after each batch it reads, s: a bound on its wake-ups per second.
    dds_config : str, optional
        Cyclone DDS configuration (XML or a file URI) for the publisher process, in place of
        the ``CYCLONEDDS_URI`` it would inherit; this process's environment is left as it is.
    """

    name = "ros2"

    @classmethod
    def from_spec(cls, spec: SinkSpec) -> Ros2Sink:
        """``ros2[:NODE]``: the node NODE (default ``skinloc``), by ROS 2's node-name rules."""
        node = spec.label("skinloc")
        why = node_name_error(node)
        if why:
            raise spec.error(why)
        return cls(node)

    def __init__(
        self,
        node_name: str = "skinloc",
        *,
        domain_id: int | None = None,
        backend: str = "auto",
        queue_frames: int = 4096,
        gather_s: float = 0.001,
        dds_config: str | None = None,
    ) -> None:
        if backend == "auto":
            backend = os.environ.get("SKINLOC_ROS2_BACKEND", "").strip() or "auto"
        if backend not in ("auto", "dds", "rclpy"):
            raise ValueError(f"unknown ROS 2 backend {backend!r}; use auto, dds or rclpy")
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", node_name or ""):
            raise ValueError(
                f"ROS 2 node name {node_name!r} is not valid: letters, digits and underscores, "
                "not starting with a digit"
            )
        if domain_id is None:
            env = os.environ.get("ROS_DOMAIN_ID", "").strip()
            try:
                domain_id = int(env) if env else 0
            except ValueError:
                raise ValueError(f"ROS_DOMAIN_ID must be an integer, not {env!r}") from None
        if not 0 <= domain_id <= 232:
            raise ValueError(f"a ROS 2 domain id is in 0..232, not {domain_id}")
        if queue_frames < 1:
            raise ValueError(f"the ROS 2 sink's queue holds at least 1 frame, not {queue_frames}")
        self.node_name = node_name
        self.domain_id = domain_id
        self.backend = backend
        self.backend_used = ""
        self.queue_frames = int(queue_frames)
        self.gather_s = float(gather_s)
        self.dds_config = dds_config
        self._proc: subprocess.Popen | None = None
        self._w = self._r = -1  # our ends of the record pipe and of the reply pipe
        self._replies = b""
        self._index: dict[str, int] = {}
        self._token = 0
        self.n_put = self.n_dropped = 0
        # the records of the loop's turn, written together at its end (``end_turn``): once the
        # owner has called ``end_turn``, the records emitted on its thread gather until then (at
        # most one atomic write); those of another thread are written at once, as before
        self._turn_thread: int | None = None
        self._batch: list[bytes] = []
        self._batch_bytes = 0
        self._batch_keep = False
        self._batch_t0 = 0.0  # when the batch's first record was made (time.monotonic(), s)
        self._child: dict[str, Any] = {}  # the publisher's latest statistics
        self._gone_logged = False
        self._requests: list[dict[str, Any]] = []  # the node's requests, for ``serve``
        self._served_skins: set[str] = set()  # skins whose settings the node has
        self._next_diag = 0.0
        self._diag: list[dict[str, Any]] | None = None  # the statuses of the round in progress
        self._diag_slot = 0  # the next skin of that round
        self._latency: dict[int, np.ndarray] = {}  # per skin: a ring of latencies, us
        self._n_latency: dict[int, int] = {}

    # ------------------------------------------------------------------ the publisher process
    @property
    def publisher_pid(self) -> int | None:
        """The publisher process's id while it runs."""
        return self._proc.pid if self._proc is not None else None

    def open(self, skins: list[SkinInfo]) -> None:
        """Start the publisher (join the domain, advertise, publish meshes and transforms).

        Returns once the publisher is ready; its errors (no ``cyclonedds``, two skins on one
        topic, ...) are raised here as one-line exceptions. Later calls add skins.
        """
        if self._proc is None:
            self._start()
            try:
                self._add(list(skins))
            except BaseException:
                self._stop(5.0)
                raise
            return
        new = [s for s in skins if s.name not in self._index]
        if new:
            self._add(new)

    def _start(self) -> None:
        r_rec, w_rec = os.pipe()
        r_rep, w_rep = os.pipe()
        want = min(max(self.queue_frames * _BYTES_PER_FRAME, 4096), _pipe_max())
        with contextlib.suppress(OSError, AttributeError):  # Linux only; the default is 64 KB
            fcntl.fcntl(w_rec, fcntl.F_SETPIPE_SZ, want)
        config = {
            "node_name": self.node_name,
            "domain_id": self.domain_id,
            "backend": self.backend,
            "gather_s": self.gather_s,
        }
        # the publisher runs this very package, wherever it was imported from
        root = str(Path(__file__).resolve().parents[3])
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
        if self.dds_config is not None:
            env["CYCLONEDDS_URI"] = self.dds_config
        cmd = [sys.executable, "-m", "skinloc.live.sinks.ros2.publisher"]
        try:
            self._proc = subprocess.Popen(
                [*cmd, str(r_rec), str(w_rep), json.dumps(config)],
                pass_fds=(r_rec, w_rep),
                env=env,
                stdin=subprocess.DEVNULL,
            )
        finally:
            os.close(r_rec)
            os.close(w_rep)
        self._w, self._r = w_rec, r_rep
        os.set_blocking(self._r, False)

    def _add(self, skins: list[SkinInfo]) -> None:
        """Send ``skins`` to the publisher and wait until it has advertised them."""
        first = not self._index
        self._write_all(pack_skins(skins))
        for s in skins:
            self._index[s.name] = len(self._index)
        if first:
            msg = self._reply(lambda m: "ready" in m, _START_TIMEOUT_S, "start")
            self.backend_used = msg.get("backend", "")
            if self.backend_used == "dds":
                log.warning(
                    "ROS 2 without rclpy: plain DDS topics and /tf_static only; no node in the "
                    "ROS graph, no parameters, no tare or reset_tracks services, no /diagnostics "
                    "(pip install 'skinloc[ros2]' or source a ROS 2 install for those)"
                )
            os.set_blocking(self._w, False)  # from now on a full pipe drops, never waits
        else:
            self._sync(30.0)

    def _write_all(self, data: bytes) -> None:
        """Write a record whole, waiting for room (start-up and new skins only)."""
        if threading.get_ident() == self._turn_thread:  # the turn's records first, in order
            self._send_batch()
        view = memoryview(data)
        while view:
            try:
                n = os.write(self._w, view)
            except BlockingIOError:
                select.select([], [self._w], [], 0.1)
                continue
            except BrokenPipeError:
                self._raise_gone("while starting")
            view = view[n:]

    def _reply(self, want: Any, timeout_s: float, what: str) -> dict[str, Any]:
        """The publisher's next answer satisfying ``want``; its error is raised here."""
        end = time.monotonic() + timeout_s
        while True:
            while b"\n" in self._replies:
                line, _, self._replies = self._replies.partition(b"\n")
                msg = json.loads(line)
                if "error" in msg:
                    raise _ERRORS.get(msg.get("type"), RuntimeError)(msg["error"])
                if "stats" in msg or "final" in msg:
                    self._child = msg.get("stats") or msg.get("final")
                if "request" in msg:
                    self._requests.append(msg)
                    continue
                if want(msg):
                    return msg
            left = end - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"the ROS 2 publisher did not answer ({what}) in {timeout_s} s")
            ready, _, _ = select.select([self._r], [], [], min(left, 0.5))
            if ready:
                chunk = os.read(self._r, 65536)
                if not chunk:
                    self._raise_gone(what)
                self._replies += chunk
            elif self._proc is not None and self._proc.poll() is not None:
                self._raise_gone(what)

    def _raise_gone(self, what: str) -> None:
        code = None
        if self._proc is not None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                code = self._proc.wait(10)
        raise RuntimeError(
            f"the ROS 2 publisher process ended ({what}, exit code {code}); see its messages above"
        )

    def _sync(self, timeout_s: float) -> bool:
        """Wait until everything written so far is published; False on timeout."""
        if self._proc is None:
            return True
        self._token += 1
        token = self._token
        try:
            self._write_all(pack_sync(token))
            self._reply(lambda m: m.get("sync") == token, timeout_s, "sync")
        except TimeoutError:
            return False
        return True

    def matched(self, topic: str, timeout_s: float = 10.0) -> int:
        """How many subscriptions the writer of ``topic`` (``/skinloc/S/contacts``...) matched.

        Whether anyone listens yet: a volatile topic's messages before that are lost.
        """
        if self._proc is None:
            return 0
        self._token += 1
        token = self._token
        self._write_all(pack_matched(token, topic))
        return int(self._reply(lambda m: m.get("matched") == token, timeout_s, "matched")["n"])

    # ------------------------------------------------------------------ the pipeline's side
    def _put(self, record: bytes, keep: bool, now: float) -> None:
        """Queue one record (made at ``now``, ``time.monotonic()``) for the publisher.

        Once the owner ends its turns (``end_turn``), a record emitted on the owner's thread
        joins the turn's batch, written at the turn's end, or with this record once the batch's
        first is ``_BATCH_WAIT_S`` old, or before it when it would not fit one atomic write;
        else (another thread, or no turns) it is written now. Never blocks, except a record to
        ``keep`` (a frame that ends a track): it waits up to ``_END_WAIT_S`` for room in a full
        pipe; any other that finds the pipe full (or no publisher) is dropped.
        """
        self.n_put += 1
        if threading.get_ident() == self._turn_thread:
            n = len(record)
            if self._batch_bytes + n > _PIPE_BUF:
                self._send_batch()
            if n <= _PIPE_BUF:
                if not self._batch:
                    self._batch_t0 = now
                self._batch.append(record)
                self._batch_bytes += n
                if keep:
                    self._batch_keep = True
                if now - self._batch_t0 >= _BATCH_WAIT_S:  # a long turn: do not hold it all
                    self._send_batch()
                return
        self._write_records(record, 1, keep)

    def end_turn(self) -> None:
        """The loop's turn ended (``Sink.end_turn``): write its records in one write.

        From the first call on, the records this thread emits gather and go out together at the
        end of each turn: one system call a turn instead of one a frame (a few frames a turn on
        a busy loop). Records of other threads are still written at once.
        """
        self._turn_thread = threading.get_ident()
        if self._batch:
            self._send_batch()

    def _send_batch(self) -> None:
        """Write the gathered records (at most ``_PIPE_BUF`` bytes: one atomic write)."""
        batch = self._batch
        if not batch:
            return
        data = batch[0] if len(batch) == 1 else b"".join(batch)
        count, keep = len(batch), self._batch_keep
        self._batch = []
        self._batch_bytes = 0
        self._batch_keep = False
        self._write_records(data, count, keep)

    def _write_records(self, data: bytes, count: int, keep: bool) -> None:
        """Write ``count`` whole records without blocking; dropped (and counted) if no room."""
        if self._w < 0:
            self.n_dropped += count
            return
        if keep:
            self._wait_for_room(len(data), _END_WAIT_S)
        try:
            if len(data) > _PIPE_BUF and not self._room_for(len(data)):
                self.n_dropped += count
                return
            n = os.write(self._w, data)
        except BlockingIOError:
            self.n_dropped += count
            return
        except BrokenPipeError:
            self.n_dropped += count
            if not self._gone_logged:
                self._gone_logged = True
                code = self._proc.poll() if self._proc is not None else None
                log.error("the ROS 2 publisher process ended (exit code %s); not publishing", code)
            return
        if n < len(data):  # only a write over PIPE_BUF can be cut: finish it
            os.set_blocking(self._w, True)
            try:
                os.write(self._w, data[n:])
            finally:
                os.set_blocking(self._w, False)

    def _wait_for_room(self, n: int, timeout_s: float) -> None:
        """Wait (bounded) until ``n`` bytes fit in the pipe or the publisher has gone."""
        end = time.monotonic() + timeout_s
        while not self._room_for(n) and time.monotonic() < end:
            if self._proc is None or self._proc.poll() is not None:
                return
            time.sleep(0.001)

    def _room_for(self, n: int) -> bool:
        """Whether ``n`` bytes fit in the pipe now (Linux; elsewhere assume they do)."""
        import termios

        try:
            size = fcntl.fcntl(self._w, fcntl.F_GETPIPE_SZ)
            used = int.from_bytes(
                fcntl.ioctl(self._w, termios.FIONREAD, b"\0\0\0\0"), sys.byteorder
            )
        except (OSError, AttributeError):
            return True
        return size - used >= n

    def _skin(self, skin: str) -> int:
        i = self._index.get(skin)
        if i is None:
            if self._proc is None:
                self.open([SkinInfo(skin)])
            else:
                self._add([SkinInfo(skin)])
            i = self._index[skin]
        return i

    def emit(self, contact: Contact) -> None:
        """Queue the one contact of a single-contact pipeline's frame (see ``Ros2Topics.emit``)."""
        now = time.monotonic()
        record = pack_frame(self._skin(contact.skin), contact.timestamp_s, now, (contact,))
        self._put(record, contact.state == "end", now)

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Sequence[Contact]) -> None:
        """Queue one frame of ``skin`` for the publisher (see ``Ros2Topics.emit_contacts``)."""
        keep = False
        for c in contacts:  # a loop, not any() over a generator: this runs every frame
            if c.state == "end":
                keep = True
                break
        i = self._skin(skin)
        if contacts:
            ring = self._latency.get(i)
            if ring is None:
                ring = self._latency[i] = np.full(_LATENCIES, np.nan)
            n = self._n_latency.get(i, 0)
            ring[n % _LATENCIES] = contacts[0].latency_us
            self._n_latency[i] = n + 1
        now = time.monotonic()
        self._put(pack_frame(i, timestamp_s, now, contacts), keep, now)

    def emit_gesture(self, skin: str, timestamp_s: float, event: Mapping[str, Any]) -> None:
        """Queue a gesture event of ``skin`` (published as JSON on ``/skinloc/S/gestures``)."""
        now = time.monotonic()
        self._put(pack_gesture(self._skin(skin), timestamp_s, now, dict(event)), False, now)

    # ------------------------------------------------------------------ the node's requests
    def serve(self, control: Any, now: float | None = None) -> None:
        """Serve the node from the pipeline's thread (the runner calls it every sweep).

        ``control`` is the runner's ``skinloc.live.control.SkinControl``: the node's requests
        (a parameter set, a tare) are applied to the skins through it, between frames, and
        answered; each skin's settings go to the node once, the diagnostics about once a
        second, a few skins a sweep (within ``_DIAG_BUDGET_S``) and published once all are
        in. Without a node (plain DDS) there is nothing to serve.
        """
        if self._proc is None or self._r < 0 or self.backend_used != "rclpy":
            return
        now = time.monotonic() if now is None else now
        self._read_requests()
        new = [n for n in self._index if n not in self._served_skins]
        if new:
            self._served_skins.update(new)
            self._control({"settings": {n: control.settings(n) for n in new}})
        for req in self._requests:
            answer = control.handle(req)
            if answer is not None:
                self._control({"answer": req["request"], **answer})
        self._requests.clear()
        for rid, answer in control.finished():
            self._control({"answer": rid, **answer})
        if self._diag is None and now >= self._next_diag:
            self._next_diag = now + _DIAG_PERIOD_S
            self._diag, self._diag_slot = [], 0
        if self._diag is not None:
            self._diagnostics_step(control, now)

    def _diagnostics_step(self, control: Any, now: float) -> None:
        """The next skins' statuses of the round (one at least, then within the budget)."""
        assert self._diag is not None
        names = control.skin_names
        t0 = time.perf_counter()
        queued = self._queued()  # once a sweep: a system call
        while self._diag_slot < len(names):
            slot = self._diag_slot
            self._diag_slot += 1
            extra = self._queue_values([names[slot]], queued)
            self._diag += control.diagnostics(now, extra, slots=[slot])
            if time.perf_counter() - t0 >= _DIAG_BUDGET_S:
                break
        if self._diag_slot >= len(names):
            status, self._diag = self._diag, None
            self._control({"diagnostics": status}, wait_s=0.0)  # the next one comes in 1 s

    def _read_requests(self) -> None:
        """Read what the publisher said since (never blocks); requests go to ``_requests``."""
        while True:
            try:
                chunk = os.read(self._r, 65536)
            except BlockingIOError:
                break
            except OSError:
                return
            if not chunk:
                break
            self._replies += chunk
        while b"\n" in self._replies:
            line, _, self._replies = self._replies.partition(b"\n")
            with contextlib.suppress(ValueError):
                msg = json.loads(line)
                if "request" in msg:
                    self._requests.append(msg)
                elif "stats" in msg or "final" in msg:
                    self._child = msg.get("stats") or msg.get("final")
                elif "error" in msg:
                    log.warning("ROS 2 publisher: %s", msg["error"])

    def _control(self, message: dict[str, Any], wait_s: float = 0.1) -> None:
        """A message to the node (a ``CONTROL`` record; dropped if the pipe stays full)."""
        if threading.get_ident() == self._turn_thread:
            self._send_batch()
        record = pack_control(message)
        self._wait_for_room(len(record), wait_s)
        if not self._room_for(len(record)):
            return
        with contextlib.suppress(BlockingIOError, BrokenPipeError):
            os.set_blocking(self._w, True)
            try:
                os.write(self._w, record)
            finally:
                os.set_blocking(self._w, False)

    def _queued(self) -> int:
        """Bytes waiting in the pipe to the publisher (-1: unknown)."""
        import termios

        try:
            return int.from_bytes(
                fcntl.ioctl(self._w, termios.FIONREAD, b"\0\0\0\0"), sys.byteorder
            )
        except (OSError, AttributeError):
            return -1

    def _queue_values(
        self, names: Sequence[str] | None = None, queued: int | None = None
    ) -> dict[str, dict[str, float]]:
        """Per skin (``names``, default all): latency p99 (us), publisher queue and drops.

        ``queued``: the pipe's bytes if the caller has just read them (``_queued``).
        """
        if queued is None:
            queued = self._queued()
        out = {}
        for name in self._index if names is None else names:
            i = self._index.get(name)
            ring = self._latency.get(i) if i is not None else None
            out[name] = {
                "latency_p99_us": math.nan if ring is None else p99(ring),
                "publisher_queue_bytes": queued,
                "publisher_dropped": self.n_dropped,
            }
        return out

    # ------------------------------------------------------------------ the owner's side
    def flush(self, timeout_s: float = 10.0) -> bool:
        """Wait until every frame queued so far is published; False on timeout."""
        try:
            return self._sync(timeout_s)
        except RuntimeError:
            return False

    def stats(self) -> dict[str, Any]:
        """Frames queued, dropped, sent (published); pending; the publisher's CPU and delays.

        ``cpu_s`` is the publisher process's CPU time (Cyclone's threads included);
        ``publish_delay_*_us`` the time from ``emit`` to the DDS write.
        """
        if self._proc is not None and self._proc.poll() is None:
            with contextlib.suppress(RuntimeError, OSError):
                self._sync(5.0)
        c = self._child
        sent = int(c.get("sent", 0))
        return {
            "queued": self.n_put,
            "dropped": self.n_dropped,
            "sent": sent,
            "pending": max(self.n_put - self.n_dropped - sent, 0),
            "errors": int(c.get("errors", 0)),
            "batches": int(c.get("batches", 0)),
            "cpu_s": float(c.get("cpu_s", 0.0)),
            "publish_delay_median_us": c.get("publish_delay_median_us"),
            "publish_delay_p99_us": c.get("publish_delay_p99_us"),
        }

    def close(self, timeout_s: float = 30.0) -> None:
        """Let the publisher publish what is queued, wait for it to end. Idempotent."""
        self._stop(timeout_s)

    def _stop(self, timeout_s: float) -> None:
        self._send_batch()  # the loop has ended (the runner closes its sinks after it)
        proc, self._proc = self._proc, None
        if self._w >= 0:
            os.close(self._w)  # the end of the records: the publisher drains and ends
            self._w = -1
        if proc is not None:
            # one bound for both waits: the owner's Ctrl-C waits on this
            end = time.monotonic() + timeout_s
            self._read_final(timeout_s)
            try:
                proc.wait(max(end - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                log.warning("the ROS 2 publisher did not end within %.0f s; killed", timeout_s)
                proc.kill()
                proc.wait()
        if self._r >= 0:
            os.close(self._r)
            self._r = -1
        self._index.clear()

    def _read_final(self, timeout_s: float) -> None:
        """The publisher's last statistics, read until it closes its end (bounded)."""
        end = time.monotonic() + timeout_s
        while self._r >= 0 and time.monotonic() < end:
            ready, _, _ = select.select([self._r], [], [], min(end - time.monotonic(), 0.5))
            if not ready:
                continue
            try:
                chunk = os.read(self._r, 65536)
            except OSError:
                break
            if not chunk:
                break
            self._replies += chunk
        for line in self._replies.split(b"\n"):
            with contextlib.suppress(ValueError):
                msg = json.loads(line)
                if isinstance(msg, dict) and ("final" in msg or "stats" in msg):
                    self._child = msg.get("final") or msg.get("stats")
        self._replies = b""
