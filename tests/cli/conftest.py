"""Fixtures of the command-line tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.conftest import make_recording

GOLDEN_MODEL = Path(__file__).resolve().parents[1] / "golden" / "model_main_default.h5"


@pytest.fixture(scope="session")
def wrong_inputs(tmp_path_factory) -> dict[str, Path]:
    """Files of every kind a command may be given by mistake."""
    from skinloc.data.recording import write_recording
    from skinloc.geometry.mesh import cone_skin
    from skinloc.sources.replay import write_stream_recording

    d = tmp_path_factory.mktemp("plain-inputs")
    files = {"model": GOLDEN_MODEL, "rec": d / "cal.h5", "stream": d / "stream.h5"}
    write_recording(make_recording(12, 4), files["rec"])
    rng = np.random.default_rng(0)
    write_stream_recording(
        files["stream"],
        n_tx=8,
        n_rx=8,
        mesh=cone_skin(),
        baseline_frames=rng.normal(1000, 2, (20, 64)),
        frames=rng.normal(1000, 2, (30, 64)),
        times_s=np.arange(30) / 100,
        index=np.arange(30),
    )
    files["text"] = d / "notes.h5"
    files["text"].write_text("not a recording\n")
    files["empty"] = d / "empty.h5"
    files["empty"].touch()
    files["bag"] = d / "bag.mcap"
    files["bag"].write_bytes(b"\x89MCAP0\r\n" + bytes(64))
    files["out"] = d / "out"
    files["out"].mkdir()
    return files
