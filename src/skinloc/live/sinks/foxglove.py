"""Foxglove: a live 3D scene of the skin and its contacts (WebSocket), and MCAP recording.

Through ``foxglove-sdk``. Topics: ``/skinloc/scene`` (``foxglove.SceneUpdate``: each skin's mesh
as a translucent triangle list and every contact of a frame as a sphere, one entity per slot
(``<skin>/slot<k>``) in its finger's colour (``live.contact.track_colour``), removed when the
finger lifts),
``/skinloc/<skin>/contact`` (``foxglove.Point3InFrame``, m: the frame's first contact, lowest
slot), ``/skinloc/contacts`` (JSON, the same object as the JSON-lines sink, one per contact),
``/skinloc/gestures`` (``foxglove.Log``: one line per gesture, for the Log panel) and
``/skinloc/gesture_events`` (JSON, the same object as the JSON-lines sink's gesture lines).
Every skin is drawn in the frame ``skin/<name>`` (its mesh frame). Open the live view in
Foxglove with "Open connection", ``ws://HOST:PORT``, or open the ``.mcap`` file.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from skinloc._lazy import require_extra
from skinloc.live.contact import track_colour
from skinloc.live.sinks.base import Sink, SinkSpec, SkinInfo, gesture_json

if TYPE_CHECKING:
    from skinloc.live.contact import Contact

log = logging.getLogger(__name__)

__all__ = ["FoxgloveSink"]

_MESH_REPUBLISH_S = 2.0  # clients that connect later get the mesh within this time


def _require_foxglove() -> Any:
    return require_extra("foxglove", "the Foxglove sink")


class FoxgloveSink(Sink):
    """Publish contacts to a Foxglove WebSocket server and/or an MCAP file.

    Parameters
    ----------
    host, port : str, int
        Where the live server listens (``port=0`` picks a free one: see ``port``).
    mcap_path : str or Path, optional
        Record everything to this MCAP file as well.
    live : bool, default=True
        Run the live server (``False`` with ``mcap_path`` only records).
    """

    name = "foxglove"

    @classmethod
    def from_spec(cls, spec: SinkSpec) -> FoxgloveSink:
        """``foxglove[://HOST][:PORT][?mcap=FILE&live=0]``: a live server, an MCAP file or both."""
        host, port = spec.address(8766)
        options = spec.query("mcap", "live")
        mcap = options.get("mcap")
        if mcap == "":
            raise spec.error("mcap= names no file")
        live = options.get("live", "1").lower()
        if live not in ("0", "1", "false", "true", "no", "yes"):
            raise spec.error(f"live= takes 1 or 0, got {live!r}")
        return cls(host=host, port=port, mcap_path=mcap, live=live not in ("0", "false", "no"))

    @classmethod
    def from_mcap_spec(cls, spec: SinkSpec) -> FoxgloveSink:
        """``mcap:FILE``: the Foxglove scene recorded to FILE, no live server."""
        return cls(mcap_path=spec.file(), live=False)

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8766,
        mcap_path: str | Path | None = None,
        live: bool = True,
    ) -> None:
        if not live and mcap_path is None:
            raise ValueError("a Foxglove sink needs a live server or an MCAP file (or both)")
        if not 0 <= int(port) < 65536:
            raise ValueError(f"Foxglove port must be 0 (any free port) or 1-65535, got {port}")
        self.host, self.port = host, int(port)
        self.mcap_path = None if mcap_path is None else Path(mcap_path)
        self.live = live
        self._ctx = None
        self._server = None
        self._writer = None
        self._skins: list[SkinInfo] = []
        self._scene = None
        self._json = None
        self._log = None
        self._gestures = None
        self._points: dict[str, Any] = {}
        self._last_mesh = 0.0
        self.n_sent = 0

    @property
    def url(self) -> str | None:
        """``ws://host:port`` of the live server (after ``open``: the port bound), else None."""
        if not self.live:
            return None
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def open(self, skins: list[SkinInfo]) -> None:
        """Start the server and/or open the MCAP file; publish the meshes."""
        fg = _require_foxglove()
        from foxglove import channels

        if self._ctx is not None:
            return
        self._skins = list(skins)
        self._ctx = fg.Context()
        if self.mcap_path is not None:
            self.mcap_path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = fg.open_mcap(self.mcap_path, allow_overwrite=True, context=self._ctx)
        if self.live:
            try:
                self._server = fg.start_server(
                    name="skinloc", host=self.host, port=self.port, context=self._ctx
                )
            except Exception as exc:
                self.close()
                raise OSError(
                    f"Foxglove server cannot listen on {self.host}:{self.port}: {exc}"
                ) from None
            self.port = self._server.port
            log.info("Foxglove live view on %s", self.url)
        self._scene = channels.SceneUpdateChannel("/skinloc/scene", context=self._ctx)
        self._json = fg.Channel("/skinloc/contacts", message_encoding="json", context=self._ctx)
        self._log = channels.LogChannel("/skinloc/gestures", context=self._ctx)
        self._gestures = fg.Channel(
            "/skinloc/gesture_events", message_encoding="json", context=self._ctx
        )
        for s in self._skins:
            self._points[s.name] = channels.Point3InFrameChannel(
                f"/skinloc/{s.name}/contact", context=self._ctx
            )
        self._publish_meshes()

    @staticmethod
    def _stamp(t_s: float) -> Any:
        from foxglove.messages import Timestamp

        sec = int(t_s)
        return Timestamp(sec=sec, nsec=int((t_s - sec) * 1e9))

    def _publish_meshes(self) -> None:
        from foxglove.messages import Color, Point3, SceneEntity, SceneUpdate, TriangleListPrimitive

        entities = []
        for s in self._skins:
            if s.vertices is None or s.faces is None:
                continue
            pts = [Point3(x=float(a), y=float(b), z=float(c)) for a, b, c in s.vertices]
            entities.append(
                SceneEntity(
                    timestamp=self._stamp(time.time()),
                    frame_id=f"skin/{s.name}",
                    id=f"{s.name}/mesh",
                    triangles=[
                        TriangleListPrimitive(
                            points=pts,
                            indices=[int(i) for i in np.asarray(s.faces).ravel()],
                            color=Color(r=0.8, g=0.75, b=0.7, a=0.6),
                        )
                    ],
                )
            )
        if entities:
            self._scene.log(SceneUpdate(entities=entities))
        self._last_mesh = time.monotonic()

    def emit(self, contact: Contact) -> None:
        """Log one contact (a frame of one contact)."""
        self.emit_contacts(contact.skin, contact.timestamp_s, [contact])

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Sequence[Contact]) -> None:
        """Log a frame's contacts: one sphere per slot, the first as a point, each as JSON."""
        if self._ctx is None:
            self.open([SkinInfo(skin)])
        from foxglove.messages import (
            Color,
            Point3,
            Point3InFrame,
            Pose,
            Quaternion,
            SceneEntity,
            SceneEntityDeletion,
            SceneEntityDeletionType,
            SceneUpdate,
            SpherePrimitive,
            Vector3,
        )

        if self.live and time.monotonic() - self._last_mesh > _MESH_REPUBLISH_S:
            self._publish_meshes()
        now = time.time()
        log_ns = int(now * 1e9)
        stamp = self._stamp(now)
        frame = f"skin/{skin}"
        entities, deletions = [], []
        first = None
        for c in contacts:
            x, y, z = c.position_m
            ent_id = f"{skin}/slot{max(c.slot, 0)}"
            if c.state == "end":  # the finger lifted: its sphere goes
                deletions.append(
                    SceneEntityDeletion(
                        timestamp=stamp, type=SceneEntityDeletionType.MatchingId, id=ent_id
                    )
                )
            elif x == x:  # not nan
                r, g, b = track_colour(c)
                sphere = SpherePrimitive(
                    pose=Pose(
                        position=Vector3(x=x, y=y, z=z), orientation=Quaternion(x=0, y=0, z=0, w=1)
                    ),
                    size=Vector3(x=0.01, y=0.01, z=0.01),
                    color=Color(r=r, g=g, b=b, a=1.0),
                )
                entities.append(
                    SceneEntity(timestamp=stamp, frame_id=frame, id=ent_id, spheres=[sphere])
                )
                if first is None:
                    first = (x, y, z)
            self._json.log(c.to_dict(), log_time=log_ns)
            self.n_sent += 1
        if entities or deletions:
            self._scene.log(SceneUpdate(entities=entities, deletions=deletions), log_time=log_ns)
        if first is not None:
            ch = self._points.get(skin)
            if ch is None:
                from foxglove import channels

                ch = self._points[skin] = channels.Point3InFrameChannel(
                    f"/skinloc/{skin}/contact", context=self._ctx
                )
            x, y, z = first
            ch.log(
                Point3InFrame(timestamp=stamp, frame_id=frame, point=Point3(x=x, y=y, z=z)),
                log_time=log_ns,
            )

    def emit_gesture(self, skin: str, timestamp_s: float, event: dict[str, Any]) -> None:
        """Log the gesture: a line on ``/skinloc/gestures``, the event on ``gesture_events``."""
        if self._ctx is None:
            self.open([SkinInfo(skin)])
        from foxglove.messages import Log, LogLevel

        now = time.time()
        log_ns = int(now * 1e9)
        kind = event.get("kind", "?")
        direction = event.get("direction")
        ids = ", ".join(str(i) for i in event.get("track_ids", []))
        conf = event.get("confidence")
        conf_text = f", confidence {conf:.2f}" if isinstance(conf, int | float) else ""
        text = f"{kind}{' ' + direction if direction else ''} (tracks {ids}{conf_text})"
        self._log.log(
            Log(timestamp=self._stamp(now), level=LogLevel.Info, message=text, name=skin),
            log_time=log_ns,
        )
        self._gestures.log(json.loads(gesture_json(skin, event)), log_time=log_ns)

    def close(self) -> None:
        """Stop the server and finish the MCAP file."""
        if self._server is not None:
            self._server.stop()
            self._server = None
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        self._ctx = None
