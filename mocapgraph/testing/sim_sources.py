"""What the NatNet and QTM simulators share: marker and skeleton sources, and injected delay and drift.

Sources (world frame, metres, Z up, NaN where a marker is not seen; frames loop):

- :class:`ActorSource`: the synthetic actor (its captures computed a chunk at a time) and its limbs
  as segments: a segment's origin is the joint it hangs from (a root limb's centroid), its
  orientation the limb's. Both simulators stream these as rigid bodies and skeleton bones.
- :class:`RecordedMarkers`: the labelled markers of a C3D or TRC file, or of a bag's MarkerFrame
  topic (a bag mocapgraph recorded; its latched MarkerLayout names them), with their residuals.

Faults on the link (:class:`LinkFaults`): each packet held back a random ``delay_ms`` (lo, hi)
and the device's clock running ``drift_ppm`` fast; :class:`DelayLine` holds the held-back packets
until due, in order (TCP) or free to overtake each other (UDP).
"""
from __future__ import annotations

import heapq
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


class ActorSource:
    """The synthetic actor as a capture system sees it (see module doc)."""

    def __init__(self, layout: str = "plug_in_gait", rate_hz: float = 120.0, seed: int = 0, noise_mm: float = 0.0,
                 dropout_rate_hz: float = 0.0, chunk: int = 120) -> None:
        from ..kinematics.synthetic.actor import CaptureOptions, SyntheticActor

        self.actor = SyntheticActor(layout, rate=rate_hz, seed=seed,
                                    options=CaptureOptions(noise_mm=noise_mm, dropout_rate_hz=dropout_rate_hz))
        sk = self.actor.skeleton
        self.rate_hz = float(rate_hz)
        self.labels = list(sk.marker_labels)
        self.limb_names = list(sk.limb_names)
        self.limb_parent = np.asarray(sk.limb_parent, dtype=np.int64)
        self.origin_joint = np.full(len(self.limb_names), -1, np.int64)
        for j, (_p, c) in enumerate(np.asarray(sk.joint_limbs)):
            self.origin_joint[c] = j
        self.chunk = int(chunk)
        self._chunk: tuple[int, object] | None = None

    @property
    def n_frames(self) -> int:
        return self.actor.n_frames

    def capture_at(self, k: int):
        """(the capture holding session frame ``k``, k's row in it), a chunk cached."""
        k %= self.actor.n_frames
        a = (k // self.chunk) * self.chunk
        if self._chunk is None or self._chunk[0] != a:
            self._chunk = (a, self.actor.capture(a, min(a + self.chunk, self.actor.n_frames)))
        return self._chunk[1], k - a

    def window(self, a: int, b: int):
        """The capture of session frames a..b-1 (looping; fewer when the session ends first)."""
        n = self.actor.n_frames
        return self.actor.capture(a % n, min(a % n + (b - a), n))

    def segment_origins(self, joint_centres: np.ndarray, limb_centroids: np.ndarray) -> np.ndarray:
        """Segment origins [..., L, 3] from a capture's joint centres [..., J, 3] and limb centroids."""
        j = np.maximum(self.origin_joint, 0)
        return np.where((self.origin_joint >= 0)[:, None], joint_centres[..., j, :], limb_centroids)


class RecordedMarkers:
    """A C3D, TRC or bag (.mcap, its MarkerFrame ``topic``: None = its only one) as a marker source.
    FormatError / BagError (one line) when it cannot be read."""

    def __init__(self, path: str | Path, topic: str | None = None) -> None:
        p = Path(path)
        if p.suffix.lower() not in (".c3d", ".trc", ".mcap"):
            from ..formats import FormatError

            raise FormatError(p, "not a marker recording (expected .c3d, .trc or a bag, .mcap)")
        if p.suffix.lower() == ".mcap":
            from ..bag.convert import bag_to_marker_trial
            from ..bag.reader import BagReader

            with BagReader(p) as reader:
                trial = bag_to_marker_trial(reader, topic)
        else:
            from ..formats.sources import read_marker_file

            trial = read_marker_file(p)
        self.path = p
        self.trial = trial
        self.rate_hz = float(trial.rate_hz)
        self.labels = list(trial.labels)
        self.positions = trial.positions                           # [T, M, 3] m world, NaN unseen
        self.residuals = np.where(np.isnan(trial.positions[..., 0]), np.nan, trial.residuals)
        self.first_frame = int(trial.first_frame)

    @property
    def n_frames(self) -> int:
        return self.positions.shape[0]

    def markers(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        """(positions [b-a, M, 3] m world, residuals [b-a, M] m) of frames a..b-1, looping."""
        rows = np.arange(a, b) % self.n_frames
        return self.positions[rows], self.residuals[rows]


def is_recording(spec: str) -> bool:
    """A source spec naming a file (C3D, TRC, bag) rather than the synthetic actor ('' or 'actor')."""
    return bool(spec) and spec != "actor"


@dataclass
class LinkFaults:
    """Delay and clock drift a simulator injects (see module doc); seeded."""

    delay_ms: tuple[float, float] = (0.0, 0.0)
    drift_ppm: float = 0.0
    seed: int = 0
    rng: np.random.Generator = field(init=False, repr=False)

    def __post_init__(self) -> None:
        lo, hi = (float(x) for x in self.delay_ms)
        if not 0 <= lo <= hi:
            raise ValueError(f"delay {lo:g}..{hi:g} ms: want 0 <= LO <= HI")
        self.delay_ms = (lo, hi)
        self.rng = np.random.default_rng(self.seed)

    @property
    def delays(self) -> bool:
        return self.delay_ms[1] > 0

    def device_s(self, true_s: float) -> float:
        """The device clock's reading ``true_s`` seconds (true time) after its epoch."""
        return true_s * (1.0 + self.drift_ppm * 1e-6)

    def hold_s(self) -> float:
        """How long the next packet is held back, s."""
        lo, hi = self.delay_ms
        return float(self.rng.uniform(lo, hi)) / 1000.0 if hi > 0 else 0.0


class DelayLine:
    """Packets held back until due: ``keep_order`` (a TCP stream: never before an earlier packet) or
    free to overtake each other (UDP datagrams)."""

    def __init__(self, keep_order: bool = False) -> None:
        self.keep_order = keep_order
        self._heap: list[tuple[float, int, object]] = []
        self._seq = 0
        self._last = float("-inf")

    def __len__(self) -> int:
        return len(self._heap)

    def push(self, due: float, item: object) -> None:
        if self.keep_order:
            due = self._last = max(due, self._last)
        self._seq += 1
        heapq.heappush(self._heap, (due, self._seq, item))

    def pop_due(self, now: float) -> list:
        """The items due by ``now``, in due order."""
        out = []
        while self._heap and self._heap[0][0] <= now:
            out.append(heapq.heappop(self._heap)[2])
        return out

    @property
    def next_due(self) -> float:
        return self._heap[0][0] if self._heap else float("inf")

    def clear(self) -> None:
        self._heap.clear()
        self._last = float("-inf")
