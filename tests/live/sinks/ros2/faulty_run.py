"""``skinloc run`` with a model that raises on one frame and a sink that raises on every frame.

Run by ``test_node.py`` as ``python faulty_run.py RUN-ARGS...``: the command line of
``skinloc run``, after two faults are put in, as a user's broken plug-ins would:

* every engine the runner loads raises ``FloatingPointError`` on the 5th touched frame of
  whichever skin reaches it first (once in the whole run);
* the sink ``failing`` (``--sink failing``) raises ``ConnectionError`` on every delivery.
"""

from __future__ import annotations

import sys
from typing import Any

import skinloc.live.runner as runner_module
from skinloc.cli.main import main
from skinloc.live.sinks.base import Sink, register_sink

_calls = {"n": 0}
_real_load = runner_module.load_engine


def _load_faulty(model: Any) -> Any:
    engine = _real_load(model)
    real = engine.contacts

    def contacts(*args: Any, **kwargs: Any) -> Any:
        _calls["n"] += 1
        if _calls["n"] == 5:
            raise FloatingPointError("the model blew up on this frame")
        return real(*args, **kwargs)

    engine.contacts = contacts
    return engine


@register_sink("failing", form="failing (raises on every delivery)")
class FailingSink(Sink):
    """A sink whose every delivery fails (a robot bus that is down)."""

    name = "failing"

    @classmethod
    def from_spec(cls, spec: Any) -> FailingSink:
        spec.no_argument()
        return cls()

    def emit(self, contact: Any) -> None:
        raise ConnectionError("the robot's bus is down")

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Any) -> None:
        raise ConnectionError("the robot's bus is down")


if __name__ == "__main__":
    runner_module.load_engine = _load_faulty
    sys.argv = ["skinloc", *sys.argv[1:]]
    main()
