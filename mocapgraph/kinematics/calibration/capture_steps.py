"""Streaming steps of a calibration capture: find the base pose, sample the gym, calibrate (capture time, s)."""
from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from ..model import ActorModel

SEARCHING, FOUND, TIMED_OUT = "searching", "found", "timed_out"


class BasePoseFinder:
    """The first frame in which every marker is visible, within ``timeout_s`` of capture time.

    Feed ``step(ok, t)`` frame by frame (ok: bool[M] marker visible; t: s since the first frame).
    After TIMED_OUT, ``never_seen`` (bool[M]) and ``best_missing`` (bool[M], missing from the most
    complete frame) say why.
    """

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = float(timeout_s)
        self.seen: np.ndarray | None = None
        self.best_missing: np.ndarray | None = None
        self._best_n = -1
        self.progress = 0.0

    def step(self, ok: np.ndarray, t: float) -> str:
        self.seen = ok.copy() if self.seen is None else (self.seen | ok)
        n = int(ok.sum())
        if n > self._best_n:
            self._best_n, self.best_missing = n, ~ok
        if ok.all():
            return FOUND
        if t >= self.timeout_s:
            return TIMED_OUT
        self.progress = t / self.timeout_s
        return SEARCHING

    @property
    def never_seen(self) -> np.ndarray:
        return ~self.seen if self.seen is not None else np.zeros(0, bool)


class GymSampler:
    """The frames of ``seconds`` of capture time, kept at ``rate_hz`` (0: every frame)."""

    @staticmethod
    def checked(seconds: object, rate_hz: object) -> tuple[float, float]:
        """(seconds, rate_hz) as floats; ValueError unless seconds > 0 and rate_hz >= 0."""
        try:
            s, r = float(seconds), float(rate_hz)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            s = r = float("nan")
        if not (0 < s <= 3600 and 0 <= r <= 10_000):  # inf / 1e308 from a command would capture forever
            raise ValueError(f"seconds must be > 0 (at most 3600) and rate_hz >= 0 (at most 10000), "
                             f"got {seconds!r}, {rate_hz!r}")
        return s, r

    def __init__(self, seconds: float, rate_hz: float) -> None:
        self.seconds = float(seconds)
        self.rate_hz = float(rate_hz)
        self.frames: list[np.ndarray] = []
        self._next_k = 0
        self.progress = 0.0

    def step(self, x: np.ndarray, t: float) -> bool:
        """Offer frame ``x`` (float[M,3]) at ``t`` s after the first; True once the capture is
        complete (that frame is not kept)."""
        if t >= self.seconds:
            return True
        k = int(np.floor(t * self.rate_hz + 1e-6)) if self.rate_hz > 0 else self._next_k
        if k >= self._next_k:
            self.frames.append(x)
            self._next_k = k + 1
        self.progress = t / self.seconds
        return False


class CaptureSession:
    """One calibration capture: the base-pose search, then the gym sample, on capture stamps (ns).

    Each step's clock starts at the first frame it is offered (the search at the first frame
    after a reset, the gym at the first frame after :meth:`start_gym`).
    """

    def __init__(self, timeout_s: float, gym_seconds: float, gym_rate_hz: float) -> None:
        self.finder = BasePoseFinder(timeout_s)
        self.sampler = GymSampler(gym_seconds, gym_rate_hz)
        self.base: np.ndarray | None = None   # float[M,3] m, the base pose once found
        self.base_frame = -1
        self.frames_used = 0
        self._ns0: int | None = None

    def _elapsed_s(self, ns: int) -> float:
        if self._ns0 is None:
            self._ns0 = ns
        self.frames_used += 1
        return (ns - self._ns0) * 1e-9

    def search(self, x: np.ndarray, ok: np.ndarray, ns: int, frame_number: int) -> str:
        """Offer a frame to the base-pose search: SEARCHING, FOUND (kept as ``base``) or TIMED_OUT."""
        found = self.finder.step(ok, self._elapsed_s(ns))
        if found == FOUND:
            self.base, self.base_frame = x, frame_number
        return found

    def start_gym(self, seconds: float, rate_hz: float) -> None:
        """Begin (or restart) the gym sample: ``seconds`` of capture time at ``rate_hz`` (0: all)."""
        self.sampler = GymSampler(seconds, rate_hz)
        self._ns0 = None

    def sample(self, x: np.ndarray, ns: int) -> bool:
        """Offer a gym frame; True once the gym is complete."""
        return self.sampler.step(x, self._elapsed_s(ns))

    @property
    def gym(self) -> list[np.ndarray]:
        """The gym frames kept so far (float[M,3] each, m, NaN unseen)."""
        return self.sampler.frames

    def gym_data(self, stream_rate_hz: float = 0.0) -> dict[str, Any]:
        """Status figures of the gym sample: frames kept, seconds, rate (the stream's when 0)."""
        return {"frames": len(self.gym), "seconds": self.sampler.seconds,
                "rate_hz": self.sampler.rate_hz or stream_rate_hz}

    def frames(self) -> np.ndarray:
        """float[1 + G, M, 3]: the base pose, then the gym frames (what calibration takes)."""
        return np.concatenate([self.base[None], np.asarray(self.gym)]) if self.gym else self.base[None]

    def process(self, definition: Any, **options: Any) -> tuple[ActorModel, list[str]]:
        """Calibrate ``definition`` from the base pose + gym (``options`` go to
        :func:`~mocapgraph.kinematics.calibration.calibrate.calibrate`): (model, its warnings as text).
        CalibrationError when no model can be made."""
        # the calibration (scipy, the solver's numba kernels: ~0.5 s to import) when calibrating: the
        # capture steps before it need none of it, nor does the launcher checking a calibration node
        from .calibrate import CalibrationWarning, calibrate

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", CalibrationWarning)
            model = calibrate(definition, self.frames(), base_frame=0, rate_hz=self.sampler.rate_hz or None,
                              source="gym capture", **options)
        return model, [str(w.message) for w in caught if issubclass(w.category, CalibrationWarning)]
