"""The live loop's serial reader: line masks on a port, frames of one read stamped in time."""

from __future__ import annotations

import numpy as np

from skinloc.hardware.protocol import encode_binary
from skinloc.live.core import PipelineConfig, SkinCore
from skinloc.live.runner import Runner, SkinConfig
from skinloc.live.sinks import ListSink
from skinloc.sim.skin import SimulatedSkin
from skinloc.sim.virtual_device import VirtualSkin
from tests._helpers import wait_until
from tests._live import model_path, stream

#: what the masked-out line sends: a count no real frame of the simulated skin reaches
MARK = 65000


class NinthLine(SimulatedSkin):
    """The simulated 9 x 8 skin whose ninth TX line (the one masked out) sends ``MARK``."""

    def _read(self, timeout_s: float):
        frame = super()._read(timeout_s)
        frame.values[8 * 8 :] = MARK
        return frame


class FrameSink(ListSink):
    """Keeps the raw frames the runner hands to recording sinks."""

    wants_frames = True

    def __init__(self) -> None:
        super().__init__()
        self.raw: list[np.ndarray] = []

    def emit_frame(self, skin: str, values: np.ndarray, timestamp_s: float, index: int) -> None:
        self.raw.append(np.array(values))


def test_the_runner_applies_line_masks_on_a_port():
    """A 9 x 8 board whose last TX line is masked out runs a 64-sensor model in the loop.

    Before the one reader, the loop built the masks and never applied them: the skin failed
    at start (a 9 x 8 grid has 72 sensors but the model takes 64).
    """
    skin = NinthLine(n_tx=9, n_rx=8, random_state=0)
    with VirtualSkin(skin, fmt="binary", rate_hz=200) as dev:
        spec = SkinConfig(
            model=model_path("map"),
            source=dev.path,
            wire_format="binary",
            n_tx=9,  # the grid the device sends
            tx_mask="111111110",
            config=PipelineConfig(emit_idle=True),
        )
        sink = FrameSink()
        runner = Runner([spec], sinks=[sink])
        core = runner.cores[0]
        assert (core.n_sensors, core.n_tx, core.n_rx) == (64, 8, 8)
        runner.start()
        try:
            wait_until(lambda: len(sink.contacts) >= 50, "50 idle records from the port", 60.0)
        finally:
            runner.close()
        stats = runner.stats()[0]
    assert stats["port"] == dev.path and stats["wire"]["n_frames"] >= 50
    assert stats["wire"]["n_wrong_grid"] == 0
    assert sink.raw and all(f.shape == (64,) for f in sink.raw)
    assert max(float(f.max()) for f in sink.raw) < MARK  # the ninth line never got in


def test_the_frames_of_one_read_carry_the_device_clock():
    """Bytes of 30 frames read at once after a stall: 30 stamps 10 ms apart, not one time."""
    frames, script = stream()
    frames = np.round(frames).astype(np.uint16)
    first = script[0][0]  # the first touch's first frame
    core = SkinCore(model_path("map"), PipelineConfig(emit_idle=True), name="t")
    t0 = 1000.0
    k = 0
    while k < first + 10:  # read promptly, one frame per read, 100 Hz
        core.feed(encode_binary(frames[k], 8, 8, k), t0 + k * 0.01)
        k += 1
    burst = b"".join(encode_binary(frames[j], 8, 8, j) for j in range(k, k + 30))
    t_read = t0 + (k + 29) * 0.01
    got = core.feed(burst, t_read)
    times = np.array([c.timestamp_s for c in got])
    assert [c.index for c in got] == list(range(k, k + 30))
    assert times[-1] == t_read
    np.testing.assert_allclose(np.diff(times), 0.01, rtol=0.05)
