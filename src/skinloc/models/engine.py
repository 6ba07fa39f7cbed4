"""The prediction engine: one implementation per model kind turns frames into contact points.

A model is fitted once (``ContactLocalizer.fit``) and then described by a *spec*: plain arrays
(``ModelSpec`` and one subclass per kind) that say everything prediction needs. An *engine*
(``Engine`` and one subclass per kind) is built from a spec and is the only code that predicts:
the library (``ContactLocalizer.predict``, ``evaluate``), the live pipeline, the benchmarks and
the app all call it, and the exports (``models.export``) are generated from the same spec and
tested against it.

Kinds: ``network`` (``skinloc.models.network_engine``: an ensemble of fully connected networks) and
``map`` (``skinloc.models.map_engine``: a response map matched coarse to fine), registered in
``models.kinds``. A kind's spec subclass has an ``engine`` method and its ``Engine`` subclass
``localise_into`` (one frame, allocation-free) and ``_predict_rows`` (a batch); optionally
``contacts_into`` (several contacts) and ``search_tables``; everything else here serves every kind.

Units: input images are baseline-subtracted counts, points metres, spread millimetres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from skinloc._jit import all_finite, jit
from skinloc._lazy import resolve
from skinloc._typing import Frames, Points
from skinloc.geometry.snap import CONSTRAINTS, Surface
from skinloc.models.multi_contact.contacts import N_COLS, ContactSet, CountRule, noise_weights
from skinloc.models.multi_contact.search import SearchMemory, SearchTables, single_into

__all__ = ["ContactSet", "Engine", "ModelSpec", "Prediction", "load_engine"]

#: Most contacts per frame ``Engine.contacts`` looks for.
MAX_CONTACTS = 3
#: The error of an image with a NaN or infinite value (the compiled kernels assume none).
NONFINITE = "sensor image has NaN or infinite values; pass finite baseline-subtracted counts"

_NORMS = {"none": 0, "l1": 1, "l2": 2}
_MODEL_CLASS = "skinloc.models.localizer:ContactLocalizer"


@dataclass(frozen=True)
class Prediction:
    """Localiser output for a batch.

    Attributes
    ----------
    points : (n, 3) float
        Contact points on the skin, m.
    raw : (n, 3) float
        Ensemble mean before the surface constraint, m (for a map, the points themselves).
    uncertainty_mm : (n,) float
        Spread of the ensemble members or of the map's likely candidates, mm (nan for a
        single network).
    """

    points: Points
    raw: Points
    uncertainty_mm: np.ndarray


@dataclass(kw_only=True)
class ModelSpec:
    """What every kind's spec holds: the input, the preprocessing and the skin surface.

    Attributes
    ----------
    n_features : int
        Sensors per image.
    clip_negative : bool
        Zero negative deltas before normalising.
    constraint : {"snap", "project", "none"}
        Output constraint.
    surface_points : (P, 3) float or None
        Discretised surface for ``snap`` (a map's candidates), m.
    vertices : (V, 3) float or None
        Skin mesh vertices, m.
    faces : (F, 3) int or None
        Skin mesh triangles.
    meta : dict
        Free-form facts about the model (its ``arch``).
    sensor_noise : (n_features,) float or None
        Noise per sensor of the training skin, counts (``None``: not known).
    contact_rule : dict or None
        The count rule of ``Engine.contacts`` (``CountRule.as_dict``; ``None``: defaults).
    """

    kind: ClassVar[str] = ""

    n_features: int
    clip_negative: bool
    constraint: str = "snap"
    surface_points: np.ndarray | None = None
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    sensor_noise: np.ndarray | None = None
    contact_rule: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        if self.constraint not in CONSTRAINTS:
            raise ValueError(
                f"the spec's constraint must be one of snap, project, none, got {self.constraint!r}"
            )

    def engine(self, constraint: str | None = None) -> Engine:
        """The engine of this spec (``constraint`` overrides the spec's own)."""
        raise NotImplementedError

    @classmethod
    def from_localizer(cls, model: Any) -> ModelSpec:
        """The spec of a fitted ``ContactLocalizer``."""
        return model.spec()

    @classmethod
    def load(cls, path: str | Path) -> ModelSpec:
        """The spec of a saved model file."""
        # the file format belongs to the model class, which builds on this module: named only
        return resolve(_MODEL_CLASS).load(path).spec()


class Engine:
    """Frames to contact points for one model; subclasses implement one kind each.

    Parameters
    ----------
    spec : ModelSpec
        The fitted model as arrays.
    constraint : {"snap", "project", "none"}, optional
        Override the spec's output constraint.

    Examples
    --------
    >>> engine = load_engine("model.h5")  # doctest: +SKIP
    >>> point, raw, spread_mm = engine.predict_one(delta)  # doctest: +SKIP
    """

    kind: ClassVar[str] = ""
    #: The model's spec (its ``vertices``, ``faces`` and ``contact_rule`` for the pipeline).
    spec: ModelSpec
    #: The count rule of ``contacts`` (the spec's, else the defaults).
    rule: CountRule

    def __init__(self, spec: ModelSpec, constraint: str | None = None) -> None:
        self.spec = spec
        self.n_features = int(spec.n_features)
        mode = spec.constraint if constraint is None else constraint
        points = spec.surface_points
        if mode == "snap" and points is None and spec.vertices is not None:
            # a mesh without snap points: sample them the way a fitted model does
            from skinloc.geometry.mesh import mesh_from_arrays, surface_points

            points = surface_points(mesh_from_arrays(spec.vertices, spec.faces))
        self.surface = Surface(mode, points, spec.vertices, spec.faces)
        self.constraint = self.surface.constraint
        self._x = np.zeros(self.n_features, dtype=np.float32)
        self._out = np.zeros(7, dtype=np.float64)
        self.rule = CountRule.from_dict(spec.contact_rule)
        self._w = noise_weights(spec.sensor_noise, self.n_features)
        self._rows = np.zeros((MAX_CONTACTS, N_COLS))

    def noise_weights(self) -> np.ndarray:
        """``(n_features,)`` float32: 1 / each sensor's noise (counts to noise levels)."""
        return self._w

    def search_tables(self) -> SearchTables | None:
        """The multi-contact search's arrays (what the live footprint watch reads).

        ``None``: this kind has no multi-contact search (a network); a map builds them once.
        """
        return None

    @property
    def n_members(self) -> int:
        """Networks in the ensemble (1 for a response map)."""
        return 1

    @classmethod
    def from_model(cls, model: Any, constraint: str | None = None) -> Engine:
        """The engine of a fitted ``ContactLocalizer``, a spec, or a path to a saved model."""
        if isinstance(model, str | Path):
            spec = ModelSpec.load(model)
        elif isinstance(model, ModelSpec):
            spec = model
        else:
            spec = model.spec()
        return spec.engine(constraint)

    # ------------------------------------------------------------------ per kind
    def localise_into(self, x: np.ndarray, out: np.ndarray) -> None:
        """One image ``x (n_features,)`` float32 counts into ``out (7,)`` float64.

        ``out`` = [raw x, y, z (m), point x, y, z (m, on the surface), spread (mm)]. The
        allocation-free call the pipeline makes per frame.
        """
        raise NotImplementedError

    def _predict_rows(self, X: np.ndarray) -> tuple[Points, Points, np.ndarray]:
        """``predict_batch`` on checked, contiguous float32 rows."""
        raise NotImplementedError

    def contacts_into(
        self,
        x: np.ndarray,
        max_contacts: int,
        out: np.ndarray,
        memory: SearchMemory | None = None,
    ) -> int:
        """The contacts of ``x (n_features,)`` float32 counts into ``out (>= k, 5)``; returns k.

        Rows: x, y, z (m), strength (counts), uncertainty (mm), strongest first. The
        allocation-free call behind ``contacts``. This kind: at most one contact, its own
        single-contact answer when a sensor reaches the rule's ``z_on`` noise levels
        (``memory``, a stream's ``SearchMemory`` for the multi-contact search, is unused).
        """
        self.localise_into(x, self._out)
        return single_into(x, self._w, self.rule.z_on, self._out, out)

    # ------------------------------------------------------------------ every kind
    def contacts(
        self,
        x: np.ndarray,
        max_contacts: int = MAX_CONTACTS,
        memory: SearchMemory | None = None,
    ) -> ContactSet:
        """How many contacts one image holds and where: a ``ContactSet``, strongest first.

        Parameters
        ----------
        x : (n_features,) float32
            Baseline-subtracted counts of one frame.
        max_contacts : int, default 3
            Most contacts to report, 1..3; 1 is the single-contact answer (``predict_one``)
            with a detection rule. A network model reports at most one.
        memory : SearchMemory, optional
            One stream's memory of its last full search: consecutive frames of a held touch
            then skip the search while nothing suggests a second finger (the stream's frames
            in order, ``reset`` at each touch's start). None: every frame searched in full.
        """
        if not (type(x) is np.ndarray and x.dtype == np.float32 and x.shape == self._x.shape):
            x = np.ascontiguousarray(x, dtype=np.float32)
            if x.shape != self._x.shape:
                raise ValueError(
                    f"sensor image must have shape ({self.n_features},), got {x.shape}"
                )
        if not 1 <= max_contacts <= MAX_CONTACTS:
            raise ValueError(f"max_contacts must be 1..{MAX_CONTACTS}, got {max_contacts}")
        if not all_finite(x):
            raise ValueError(NONFINITE)
        k = self.contacts_into(x, max_contacts, self._rows, memory)
        return ContactSet(self._rows[:k].copy())

    def predict_batch(self, X: Frames) -> tuple[Points, Points, np.ndarray]:
        """``(points (n, 3) m, raw (n, 3) m, spread_mm (n,))`` for ``X (n, n_features)``."""
        X = np.asarray(X)
        if X.ndim == 1:
            X = X[None, :]
        if X.ndim != 2 or X.shape[1] != self.n_features:
            raise ValueError(
                f"sensor images must have shape (n, {self.n_features}), got {np.shape(X)}"
            )
        X = np.ascontiguousarray(X, dtype=np.float32)
        if not np.isfinite(X).all():
            raise ValueError(NONFINITE)
        return self._predict_rows(X)

    def predict(self, X: Frames) -> Prediction:
        """``predict_batch`` as a ``Prediction``."""
        points, raw, spread = self.predict_batch(X)
        return Prediction(points=points, raw=raw, uncertainty_mm=spread)

    def predict_one(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """``(point (3,) m, raw (3,) m, spread_mm)`` for one image ``x (n_features,)``."""
        xx = np.ascontiguousarray(x, dtype=np.float32).reshape(-1)
        if xx.shape != (self.n_features,):
            raise ValueError(
                f"sensor image must have shape ({self.n_features},), got {np.shape(x)}"
            )
        if not all_finite(xx):
            raise ValueError(NONFINITE)
        out = np.empty(7)
        self.localise_into(xx, out)
        return out[3:6].copy(), out[:3].copy(), float(out[6])

    def constrain(self, q: Points) -> Points:
        """Constrain ``q (n, 3)`` m onto the surface; returns ``(n, 3)`` m."""
        return self.surface.constrain(q)

    def constrain_into(self, q0: float, q1: float, q2: float, out: np.ndarray) -> None:
        """Put the point ``(q0, q1, q2)`` m on the surface by this model's constraint."""
        self.surface.constrain_into(q0, q1, q2, out)

    def warm_up(self) -> Engine:
        """Compile the kernels now (numba caches them on disk) rather than on the first frame."""
        self.localise_into(self._x, self._out)
        x = np.zeros_like(self._x)
        x[0] = 1e4  # a touch, so that every stage of the contact search compiles
        self.contacts(x, MAX_CONTACTS)
        self.predict_batch(np.zeros((256, self.n_features), dtype=np.float32))
        self.constrain_into(0.0, 0.0, 0.0, np.zeros(3))
        return self


def load_engine(model: Any, constraint: str | None = None) -> Engine:
    """A warmed-up engine from a model path, a ``ContactLocalizer``, a spec or an engine."""
    if isinstance(model, Engine):
        return model
    return Engine.from_model(model, constraint).warm_up()


@jit()
def clip_and_norm(x: np.ndarray, clip: int, norm: int, z: np.ndarray) -> float:  # pragma: no cover
    """Clipped image into ``z`` (float32) and the inverse of its floored norm.

    ``norm``: 0 none (returns 1), 1 L1, 2 L2; the norm is floored at one count so that an
    empty frame stays near zero instead of being blown up into noise.
    """
    nrm = 0.0
    for i in range(x.shape[0]):
        v = x[i]
        if clip and v < 0.0:
            v = 0.0
        z[i] = v
        if norm == 1:
            nrm += abs(v)
        elif norm == 2:
            nrm += v * v
    if norm == 2:
        nrm = math.sqrt(nrm)
    if norm == 0 or nrm <= 1.0:
        return 1.0
    return 1.0 / nrm


def norm_code(name: str) -> int:
    """The kernels' code of a normalisation: none 0, l1 1, l2 2."""
    return _NORMS[name]
