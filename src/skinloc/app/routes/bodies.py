"""The JSON bodies of the app's actions, checked by pydantic (422 naming the field otherwise)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, Field


class ConnectBody(BaseModel):
    """``POST /api/connect``."""

    source: str = "sim"
    tx: int = Field(8, ge=1, le=21)
    rx: int = Field(8, ge=1, le=12)
    baud: int = Field(115200, ge=50, le=12_000_000)
    format: Literal["auto", "text", "binary"] = "auto"
    seed: int = Field(0, ge=0, le=2**32 - 1)
    rate_hz: float = Field(100.0, gt=0, le=2000)


class SessionBody(BaseModel):
    """``POST /api/sessions``."""

    name: str = Field("session", max_length=80)
    n_points: int = Field(80, ge=1, le=2000)
    mode: str = "even"
    samples: int = Field(50, ge=1, le=1000)
    baseline_frames: int = Field(50, ge=2, le=5000)
    seed: int = Field(0, ge=0, le=2**32 - 1)
    mesh_file: str | None = None
    targets_csv: str | None = Field(None, max_length=1_000_000)
    n_validation: int = Field(20, ge=1, le=500)


#: A coordinate of a touch, m: any skin fits in +-10 m, and larger numbers are a mistake.
Coordinate = Annotated[float, Field(ge=-10.0, le=10.0)]
#: A page's event time, s (its clock starts when the page loads).
PageTime = Annotated[float, Field(ge=0.0, le=1e9)]


class TouchBody(BaseModel):
    """``POST /api/sim/touch``: a point in m, or none to lift, now; or a mouse ``path``.

    ``path``: ``[t, point]`` pairs in time order, ``t`` the page's event time (s), ``point`` in m
    or null where the mouse was released (``LinkActions.sim_path``).
    """

    point: list[Coordinate] | None = Field(None, min_length=3, max_length=3)
    path: list[tuple[PageTime, list[Coordinate] | None]] | None = Field(
        None, min_length=1, max_length=1000
    )


class IndexBody(BaseModel):
    """An index of a touch (0-based) and which recording it is in."""

    index: int = Field(ge=0)
    recording: Literal["calibration", "validation"] = "calibration"


class FlagBody(BaseModel):
    """A switch."""

    on: bool


class ValidateBody(BaseModel):
    """``POST /api/validate/start``."""

    n_points: int | None = Field(None, ge=1, le=500)


class TrainBody(BaseModel):
    """``POST /api/train``: touches (0-based) to leave out, with those left out already."""

    exclude: list[Annotated[int, Field(ge=0)]] = Field(default_factory=list, max_length=10_000)


class LeaveOutBody(BaseModel):
    """``POST /api/train/leave_out``: a calibration touch (0-based) left out or put back."""

    index: int = Field(ge=0)
    out: bool = True


class RecordBody(BaseModel):
    """``POST /api/record/start``: the file's format."""

    format: Literal["h5", "mcap"] = "h5"


class SettingsBody(BaseModel):
    """``POST /api/live/settings``: the live pipeline's settings to change, by name."""

    values: dict[str, bool | int | float | str] = Field(max_length=50)


class RecalibrateBody(BaseModel):
    """``POST /api/recalibrate/start``: the model (a session's or an uploaded file's), k."""

    session: str | None = Field(None, max_length=200)
    file: str | None = Field(None, max_length=200)
    k: int = Field(10, ge=0, le=50)
    strategy: Literal["active", "random"] = "active"
