"""The sink interface and the sink registry: ``make_sink`` builds one from a short text spec.

A sink is registered once, by one ``SinkType`` entry in ``_BUILTIN`` (built-ins, named as
``"package.module:Class.from_spec"`` so that no backend is imported before a spec asks for it),
by ``register_sink`` (a decorator, for code outside the package), or by an installed package's
entry point in the ``skinloc.sinks`` group. The sink's ``from_spec`` reads its settings from the
parsed spec (``SinkSpec``), which refuses a spec the sink cannot mean with one line.
"""

from __future__ import annotations

import abc
import json
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qs, urlsplit

import numpy as np

from skinloc._lazy import require_extra, resolve

if TYPE_CHECKING:
    from skinloc.live.contact import Contact

log = logging.getLogger(__name__)

__all__ = [
    "SINK_SPECS",
    "CallbackSink",
    "ListSink",
    "Sink",
    "SinkSpec",
    "SinkType",
    "SkinInfo",
    "check_sink",
    "gesture_json",
    "make_sink",
    "register_sink",
    "sink_files",
    "sink_forms",
    "sink_type",
    "sink_types",
    "unregister_sink",
]


@dataclass(frozen=True)
class SkinInfo:
    """What a sink may want to know of a skin: its name, mesh, grid and pose on the robot.

    Attributes
    ----------
    name : str
        Skin name (``Contact.skin``).
    vertices : (V, 3) float or None
        Mesh vertices, m.
    faces : (F, 3) int or None
        Mesh triangles.
    n_tx, n_rx : int or None
        Grid of the raw frames.
    parent_frame : str or None
        A robot frame (link) the skin is mounted on; None: not configured.
    translation_m : (float, float, float)
        Origin of the skin's mesh frame in ``parent_frame``, m.
    rotation_xyzw : (float, float, float, float)
        Orientation of the mesh frame in ``parent_frame``, unit quaternion.
    max_contacts : int
        K: contacts (tracks, slots) per frame at most.
    """

    name: str
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None
    n_tx: int | None = None
    n_rx: int | None = None
    parent_frame: str | None = None
    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    max_contacts: int = 1


def _json_ready(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_ready(v) for v in value]
    return value


def gesture_json(skin: str, event: dict[str, Any], **extra: Any) -> str:
    """A gesture event as one line of JSON.

    ``"event": "gesture"`` and ``"skin"`` are always set, nan and infinities become null, and
    ``extra`` keys come first (the WebSocket sink's ``"type"``).
    """
    d = {**extra, **event, "event": "gesture", "skin": event.get("skin", skin)}
    return json.dumps(_json_ready(d), separators=(",", ":"))


class Sink(abc.ABC):
    """A consumer of contacts.

    ``open`` is called once with the skins it will see, ``emit`` for every contact from the
    pipeline's thread (it must not block for long: network sinks queue and send on their own
    thread), ``close`` once at the end. Usable as a context manager.
    """

    name: str = "sink"

    @classmethod
    def from_spec(cls, spec: SinkSpec) -> Sink:
        """The sink ``spec`` describes (``make_sink``); this default takes no argument."""
        spec.no_argument()
        return cls()

    def open(self, skins: list[SkinInfo]) -> None:  # noqa: B027 - optional hook
        """Prepare for the given skins (start servers, advertise channels)."""

    @abc.abstractmethod
    def emit(self, contact: Contact) -> None:
        """Deliver one contact."""

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Sequence[Contact]) -> None:
        """Deliver every contact of one frame of ``skin`` (one per track, ``end`` included).

        Sinks that send a frame's contacts together (Foxglove, ROS 2) override this; the
        default delivers them one by one through ``emit``.
        """
        for contact in contacts:
            self.emit(contact)

    def emit_gesture(  # noqa: B027 - optional hook
        self, skin: str, timestamp_s: float, event: dict[str, Any]
    ) -> None:
        """Deliver a gesture event of ``skin`` (a JSON-ready dict); ignored unless overridden.

        The ROS 2 sinks publish it on ``/skinloc/<skin>/gestures``.
        """

    def end_turn(self) -> None:  # noqa: B027 - optional hook
        """The end of one turn of the runner's loop: send what the turn's calls gathered.

        ``skinloc.live.runner.Runner`` calls it after each turn (the frames that came in
        together, a few each on a busy loop) when the sink's class overrides it. A sink that
        sends one write per turn instead of one per frame (the ROS 2 sink) overrides it; a
        sink must still deliver without it (programs that call ``emit`` themselves).
        """

    def close(self) -> None:  # noqa: B027 - optional hook
        """Flush and release everything; no thread may be left behind."""

    def __enter__(self) -> Sink:
        self.open([])
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class CallbackSink(Sink):
    """Call ``fn(contact)`` for every contact."""

    name = "callback"

    def __init__(self, fn: Callable[[Contact], Any]) -> None:
        self.fn = fn

    def emit(self, contact: Contact) -> None:
        """Call the function."""
        self.fn(contact)


class ListSink(Sink):
    """Keep every contact in ``contacts``, every frame's in ``frames``, gestures in ``gestures``."""

    name = "list"

    def __init__(self) -> None:
        self.contacts: list[Contact] = []
        self.frames: list[list[Contact]] = []
        self.gestures: list[dict[str, Any]] = []

    def emit(self, contact: Contact) -> None:
        """Append."""
        self.contacts.append(contact)

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Sequence[Contact]) -> None:
        """Append the frame's contacts (to ``frames`` and one by one to ``contacts``)."""
        self.frames.append(list(contacts))
        self.contacts.extend(contacts)

    def emit_gesture(self, skin: str, timestamp_s: float, event: dict[str, Any]) -> None:
        """Append."""
        self.gestures.append(event)


def _port_error(spec: str, port: str) -> ValueError:
    return ValueError(f"bad port {port!r} in sink {spec!r} (ports are whole numbers 0-65535)")


@dataclass(frozen=True)
class SinkSpec:
    """A sink spec, parsed: ``scheme[:argument]``, as ``--sink`` and skins files give it.

    Each sink's ``from_spec`` reads the argument through one of the methods here, which
    refuse what the sink cannot mean with a one-line ``ValueError`` naming the spec.

    Attributes
    ----------
    text : str
        The spec as given (stripped), for messages.
    scheme : str
        The part before the first ``:``, lower case (``udp``).
    argument : str or None
        The part after the first ``:`` (``//host:9870``), ``None`` when there is no ``:``.

    Examples
    --------
    >>> SinkSpec.parse("udp://10.0.0.2:9000").address(9870)
    ('10.0.0.2', 9000)
    >>> SinkSpec.parse("udp:10.0.0.2").address(9870)
    ('10.0.0.2', 9870)
    """

    text: str
    scheme: str
    argument: str | None = None

    @classmethod
    def parse(cls, text: str) -> SinkSpec:
        """Split ``text`` into scheme and argument (no checks of the argument yet)."""
        text = str(text).strip()
        scheme, colon, rest = text.partition(":")
        if not scheme:
            raise ValueError(f"sink {text!r} names no kind; use one of: {'; '.join(sink_forms())}")
        return cls(text, scheme.lower(), rest if colon else None)

    def error(self, why: str) -> ValueError:
        """A ``ValueError`` ``sink '<text>': <why>``, to raise."""
        return ValueError(f"sink {self.text!r}: {why}")

    def _split(self) -> tuple[str, str]:
        """``(netloc-and-path, query)`` of an address argument (``//`` optional)."""
        rest = (self.argument or "").removeprefix("//")
        where, _, query = rest.partition("?")
        return where, query

    def address(self, default_port: int) -> tuple[str, int]:
        """``(host, port)`` of ``scheme[://][HOST][:PORT][?QUERY]``.

        A missing host is 127.0.0.1 and a missing port ``default_port``; ``:0`` stays 0 (a
        server then binds any free port; a sender refuses it). A port that is not a whole
        number 0-65535, or a path after the address, is refused.
        """
        where, _ = self._split()
        netloc, slash, path = where.partition("/")
        if slash and path:
            raise self.error(f"unexpected path {'/' + path!r} after the address")
        try:
            parts = urlsplit("//" + netloc)
            port = parts.port
        except ValueError:
            raise _port_error(self.text, netloc.rpartition(":")[2]) from None
        if netloc.endswith(":"):  # 'udp://host:' names no port: a slip, not the default
            raise _port_error(self.text, "")
        return parts.hostname or "127.0.0.1", default_port if port is None else port

    def query(self, *allowed: str) -> dict[str, str]:
        """The ``?key=value&...`` options of an address spec; keys not in ``allowed`` refused."""
        _, query = self._split()
        try:
            pairs = parse_qs(query, keep_blank_values=True, strict_parsing=bool(query))
        except ValueError:
            raise self.error(f"cannot read the options {query!r} (key=value&...)") from None
        unknown = sorted(set(pairs) - set(allowed))
        if unknown:
            known = ", ".join(allowed) or "none"
            raise self.error(f"unknown option(s) {', '.join(unknown)} (known: {known})")
        return {k: v[-1] for k, v in pairs.items()}

    def file(self) -> str:
        """The file of ``scheme:FILE``; refused when there is none."""
        if not self.argument:
            raise ValueError(f"sink '{self.scheme}:FILE' needs a file name, got {self.text!r}")
        return self.argument

    def optional_file(self) -> str | None:
        """The file of ``scheme:FILE``, ``None`` for ``scheme`` alone or ``scheme:-`` (stdout).

        ``scheme:`` with nothing after the colon is refused: it is a slip, not a request for
        stdout.
        """
        if self.argument is None or self.argument == "-":
            return None
        if not self.argument.strip():
            raise self.error(
                f"names no file: give {self.scheme}:FILE, or {self.scheme} alone for stdout"
            )
        return self.argument

    def label(self, default: str) -> str:
        """The name of ``scheme[:NAME]`` (``default`` without one); an empty name is refused."""
        if self.argument is None:
            return default
        if not self.argument.strip():
            raise self.error("the name after ':' is empty (leave out the ':' for the default)")
        return self.argument

    def option_values(self, key: str) -> list[str]:
        """Every value of ``?key=`` in an address spec, unchecked (``query`` checks them all)."""
        _, query = self._split()
        return parse_qs(query).get(key, [])

    def no_argument(self) -> None:
        """Refuse an argument, for sinks that take none."""
        if self.argument is not None:
            raise self.error(f"the {self.scheme!r} sink takes no argument")


#: A sink factory: a parsed spec to a sink.
SinkFactory = Callable[[SinkSpec], "Sink"]


@dataclass(frozen=True)
class SinkType:
    """One registered kind of sink.

    Attributes
    ----------
    scheme : str
        What a spec starts with (``udp``), lower case.
    factory : str or callable
        ``"package.module:Class.from_spec"`` (imported when a spec names the scheme, so the
        registry never imports a backend or its optional dependencies) or a callable
        ``(SinkSpec) -> Sink``.
    form : str
        The spec's form for help texts and errors (``udp://HOST:PORT (...)``).
    aliases : tuple of str
        Other schemes that mean this sink (``websocket`` for ``ws``).
    requires : str or None
        The optional dependency the sink needs (a top-level module in ``_lazy.EXTRAS``).
    file_argument : bool
        Whether the argument of ``scheme:ARG`` is a file the sink writes (``jsonl:FILE``).
    file_options : tuple of str
        Options of an address spec that name files the sink writes (``?mcap=FILE``).
    """

    scheme: str
    factory: str | SinkFactory
    form: str
    aliases: tuple[str, ...] = ()
    requires: str | None = None
    file_argument: bool = False
    file_options: tuple[str, ...] = ()

    def files(self, spec: SinkSpec) -> list[str]:
        """The files a sink of ``spec`` writes (stdout's ``-`` is none), for checks up front."""
        out = [v for key in self.file_options for v in spec.option_values(key)]
        arg = spec.argument
        if self.file_argument and arg and arg.strip() and arg != "-":
            out.insert(0, arg)
        return out

    def build(self, spec: SinkSpec) -> Sink:
        """The sink ``spec`` describes, importing the backend now."""
        factory = resolve(self.factory) if isinstance(self.factory, str) else self.factory
        return factory(spec)


# The built-in sinks: one entry each. Backends are named, imported only when a spec asks for
# one, so this module imports no backend (they import it) and no optional dependency.
_BUILTIN: tuple[SinkType, ...] = (
    SinkType(
        "jsonl",
        "skinloc.live.sinks.jsonl:JsonLinesSink.from_spec",
        "jsonl[:FILE] (JSON lines on stdout, or to FILE)",
        file_argument=True,
    ),
    SinkType(
        "ws",
        "skinloc.live.sinks.websocket:WebSocketSink.from_spec",
        "ws://HOST:PORT (WebSocket server; port 0: any free port)",
        aliases=("websocket",),
    ),
    SinkType(
        "udp",
        "skinloc.live.sinks.udp:UdpSink.from_spec",
        "udp://HOST:PORT (one JSON datagram per contact)",
    ),
    SinkType(
        "foxglove",
        "skinloc.live.sinks.foxglove:FoxgloveSink.from_spec",
        "foxglove://HOST:PORT[?mcap=FILE] (Foxglove live 3D scene, port 0: any free port; MCAP)",
        requires="foxglove",
        file_options=("mcap",),
    ),
    SinkType(
        "mcap",
        "skinloc.live.sinks.foxglove:FoxgloveSink.from_mcap_spec",
        "mcap:FILE (Foxglove MCAP recording only)",
        requires="foxglove",
        file_argument=True,
    ),
    SinkType(
        "lsl",
        "skinloc.live.sinks.lsl:LslSink.from_spec",
        "lsl[:NAME] (Lab Streaming Layer outlet)",
        requires="pylsl",
    ),
    SinkType(
        "ros2",
        "skinloc.live.sinks.ros2.sink:Ros2Sink.from_spec",
        "ros2[:NODE] (ROS 2 topics over DDS, or through rclpy when present)",
        requires="cyclonedds",
    ),
    SinkType(
        "mcap-ros2",
        "skinloc.live.sinks.ros2.bag:Ros2BagSink.from_spec",
        "mcap-ros2:FILE (the ROS 2 topics and raw frames as a ROS 2 bag, MCAP)",
        requires="mcap",
        file_argument=True,
    ),
)

#: Every registered sink by scheme and alias: the built-ins, ``register_sink`` calls and (on
#: first use) the ``skinloc.sinks`` entry points of installed packages.
_REGISTRY: dict[str, SinkType] = {}
_ENTRY_POINT_GROUP = "skinloc.sinks"
_entry_points_loaded = False


def _add(entry: SinkType, *, replace: bool) -> None:
    for key in (entry.scheme, *entry.aliases):
        if not replace and key in _REGISTRY:
            raise ValueError(f"a sink is already registered as {key!r}")
        _REGISTRY[key] = entry


for _entry in _BUILTIN:
    _add(_entry, replace=False)

#: The spec forms of the built-in sinks, for help texts (``sink_forms()``: every registered).
SINK_SPECS: tuple[str, ...] = tuple(e.form for e in _BUILTIN)


def _load_entry_points() -> None:
    """Register the sinks installed packages declare under ``skinloc.sinks`` (once).

    An entry point ``toy = "package.module:ToySink.from_spec"`` registers the scheme ``toy``;
    its target is imported only when a spec names it. Built-in schemes are never replaced.
    """
    global _entry_points_loaded
    if _entry_points_loaded:
        return
    _entry_points_loaded = True
    from importlib.metadata import entry_points

    for ep in entry_points(group=_ENTRY_POINT_GROUP):
        scheme = ep.name.lower()
        if scheme in _REGISTRY:
            log.warning("sink %r of entry point %s is taken: ignored", scheme, ep.value)
            continue
        form = f"{scheme}[:...] (from {ep.dist.name if ep.dist else ep.value})"
        _add(SinkType(scheme, ep.value, form), replace=False)


def register_sink(
    scheme: str,
    factory: str | SinkFactory | None = None,
    *,
    form: str | None = None,
    aliases: Sequence[str] = (),
    requires: str | None = None,
    file_argument: bool = False,
    file_options: Sequence[str] = (),
    replace: bool = False,
) -> Any:
    """Register a sink under ``scheme``: the one step that adds a sink.

    Parameters
    ----------
    scheme : str
        What a spec starts with; letters, digits, ``-`` and ``_``.
    factory : str or callable, optional
        ``"package.module:Class.from_spec"`` (imported only when used) or a callable
        ``(SinkSpec) -> Sink``. Omitted: use as a class decorator, the class's ``from_spec``.
    form : str, optional
        The spec's form for help texts (default ``scheme[:...]``).
    aliases : sequence of str
        Other schemes meaning the same sink.
    requires : str, optional
        The optional dependency it needs (a module name), for tests that skip without it.
    file_argument : bool, default False
        The argument of ``scheme:ARG`` is a file the sink writes (checked before a run).
    file_options : sequence of str
        Options of an address spec (``?mcap=FILE``) that name files the sink writes.
    replace : bool, default False
        Replace a sink already registered under the scheme (otherwise ``ValueError``).

    Examples
    --------
    >>> @register_sink("null", form="null (drops every contact)")  # doctest: +SKIP
    ... class NullSink(Sink):
    ...     def emit(self, contact): pass
    """
    scheme = scheme.lower()
    if not scheme or not all(c.isalnum() or c in "-_" for c in scheme):
        raise ValueError(f"a sink scheme is letters, digits, '-' and '_', got {scheme!r}")

    def add(target: str | SinkFactory) -> None:
        entry = SinkType(
            scheme,
            target,
            form or f"{scheme}[:...]",
            tuple(aliases),
            requires,
            file_argument,
            tuple(file_options),
        )
        _add(entry, replace=replace)

    if factory is not None:
        add(factory)
        return factory

    def decorate(cls: type[Sink]) -> type[Sink]:
        add(cls.from_spec)
        return cls

    return decorate


def unregister_sink(scheme: str) -> None:
    """Remove the sink registered as ``scheme`` (and its aliases); a no-op when there is none."""
    entry = _REGISTRY.get(scheme.lower())
    if entry is not None:
        for key in (entry.scheme, *entry.aliases):
            _REGISTRY.pop(key, None)


def sink_types() -> list[SinkType]:
    """Every registered sink, once each, built-ins first."""
    _load_entry_points()
    return list({id(e): e for e in _REGISTRY.values()}.values())


def sink_forms() -> list[str]:
    """The spec forms of every registered sink, for help texts and errors."""
    return [e.form for e in sink_types()]


def sink_type(scheme: str) -> SinkType | None:
    """The sink registered as ``scheme`` (an alias too), None when there is none."""
    entry = _REGISTRY.get(scheme.lower())
    if entry is None:
        _load_entry_points()
        entry = _REGISTRY.get(scheme.lower())
    return entry


def sink_files(spec: str) -> list[str]:
    """The files the sink of ``spec`` writes (``SinkType.files``); none for an unknown scheme.

    Examples
    --------
    >>> sink_files("jsonl:out.jsonl"), sink_files("udp://127.0.0.1:9870")
    (['out.jsonl'], [])
    """
    parsed = SinkSpec.parse(spec)
    entry = sink_type(parsed.scheme)
    return [] if entry is None else entry.files(parsed)


def check_sink(spec: str) -> None:
    """Refuse ``spec`` up front, before a command loads its model.

    An unknown scheme is a ``ValueError``; a sink whose optional dependency is missing a
    ``MissingExtraError`` naming the extra. What only the backend can judge (a bad port, a
    missing file name) is left to ``make_sink``.
    """
    parsed = SinkSpec.parse(spec)
    entry = sink_type(parsed.scheme)
    if entry is None:
        raise ValueError(f"unknown sink {parsed.text!r}; use one of: {'; '.join(sink_forms())}")
    if entry.requires is not None:
        require_extra(entry.requires, f"the {entry.scheme} sink")


def make_sink(spec: str | Sink) -> Sink:
    """Build a sink from a spec string (a ``Sink`` is returned as is).

    Parameters
    ----------
    spec : str
        ``scheme[:argument]`` of a registered sink (``sink_forms()``): ``jsonl``,
        ``jsonl:out.jsonl``, ``ws://127.0.0.1:8767``, ``udp://127.0.0.1:9870``,
        ``foxglove://127.0.0.1:8766?mcap=run.mcap``, ``mcap:run.mcap``, ``lsl``, ``lsl:skin``,
        ``ros2``, ``ros2:NODE``, ``mcap-ros2:run.mcap``.

    Raises
    ------
    ValueError
        One line, naming the spec: an unknown scheme or an argument the sink cannot mean.

    Examples
    --------
    >>> make_sink("udp://127.0.0.1:9870").address
    ('127.0.0.1', 9870)
    """
    if isinstance(spec, Sink):
        return spec
    parsed = SinkSpec.parse(spec)
    entry = sink_type(parsed.scheme)
    if entry is None:
        raise ValueError(f"unknown sink {parsed.text!r}; use one of: {'; '.join(sink_forms())}")
    return entry.build(parsed)
