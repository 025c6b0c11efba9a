"""The sequence-number rule: what a receiver concludes from one stream's numbers (loss, resend, restart).

A stream is one sending process on one topic: its header carries the process's random stream id
(`codec.STREAM_ID`) and numbers from 1. A frame with another stream id than the last is a new
stream (the sender restarted: a respawn), delivered at once whatever its number. Within a stream:
the next number is the usual case; a jump forward by k+1 means k messages were lost; the same
number with the same publish stamp is a resend (a latched value re-sent to a late joiner), dropped.
A number a little below the last (within DUPLICATE_WINDOW) is a *suspected* duplicate: the first
is dropped, but a second in a row is taken as the real stream and the edge resynchronises to it
(the number it fell back from was forged, or the sender restarted under the same id), so a
suspected duplicate never silences an edge for more than one frame. Anything else (a jump forward
beyond MAX_GAP, a fall back beyond the window, a fall back to 1) resynchronises at once and is
counted as an anomaly or a restart, neither as loss (a forged 2**63 is not 2**63 lost messages)
nor as a duplicate (which would silence the real stream until it passed the forged number).
"""
from __future__ import annotations

DUPLICATE = -1
RESTART = -2
ANOMALY = -3

#: more lost messages than this in one jump is not believed (over 4 h at 1 kHz)
MAX_GAP = 1 << 24
#: a number this much below the last one at most is a suspected duplicate; further back is an anomaly
DUPLICATE_WINDOW = 4096


def sequence_gap(last: int, seq: int, same_stamp: bool = True) -> int:
    """Messages lost between ``last`` (0: none seen yet) and ``seq``; or DUPLICATE, RESTART, ANOMALY.

    The stateless part of the rule (one stream, no memory of the frame before): `StreamTracker`
    adds the stream id and the one-frame limit on suspected duplicates. Joining a running stream
    (first number > 1) is no loss: those messages were never ours. ``same_stamp``: whether the
    message carries the publish stamp of the last one. A resend is the same bytes; a restarted
    sender's latched value repeats the number (1) with a new stamp, and is a RESTART to deliver,
    not a duplicate to drop. RESTART and ANOMALY both mean: take ``seq`` as the new last number.
    """
    if seq == last:
        return DUPLICATE if same_stamp else RESTART
    if seq < last:
        if seq == 1:
            return RESTART
        return DUPLICATE if last - seq <= DUPLICATE_WINDOW else ANOMALY
    if last and seq > last + 1:
        return seq - last - 1 if seq - last - 1 <= MAX_GAP else ANOMALY
    return 0


class StreamTracker:
    """The rule applied to one (topic, sender) edge, with its counts.

    ``take`` classifies one arrival; its counters say what the edge has seen: ``gaps`` (messages
    lost), ``duplicates`` (dropped: resends and suspected duplicates), ``restarts`` (new streams),
    ``anomalies`` (resynchronisations on numbers beyond belief).
    """

    __slots__ = ("stream", "last", "last_stamp", "suspect", "jump", "gaps", "duplicates", "restarts", "anomalies")

    def __init__(self) -> None:
        self.stream: int | None = None   # stream id of the last frame taken (None: none yet)
        self.last = 0
        self.last_stamp = 0
        self.suspect = False   # the frame before was dropped as a suspected duplicate
        self.jump = 0          # messages counted lost by the jump that took us to ``last``
        self.gaps = self.duplicates = self.restarts = self.anomalies = 0

    def take(self, stream: int, seq: int, publish_ns: int) -> int:
        """Classify one arrival: 0 or k (k lost before it), RESTART or ANOMALY: deliver it;
        DUPLICATE: drop it."""
        if stream != self.stream:
            first = self.stream is None   # joining a stream is no loss
            if not first:
                self.restarts += 1
            self._set(stream, seq, publish_ns, 0)
            return 0 if first else RESTART
        code = sequence_gap(self.last, seq, publish_ns == self.last_stamp)
        if code == DUPLICATE:
            if seq == self.last:   # a resend: silences nothing (the stream goes on above it)
                self.duplicates += 1
                return DUPLICATE
            if not self.suspect:   # the first below the last: dropped, once
                self.suspect = True
                self.duplicates += 1
                return DUPLICATE
            # a second in a row: the real stream is down here; the number it fell from was forged
            # (so the jump to it lost nothing) or the sender restarted under its old id
            code = ANOMALY
            self.gaps -= self.jump
        jump = 0
        if code == RESTART:
            self.restarts += 1
        elif code == ANOMALY:
            self.anomalies += 1
        else:
            jump = code
            self.gaps += code
        self._set(stream, seq, publish_ns, jump)
        return code

    def _set(self, stream: int, seq: int, publish_ns: int, jump: int) -> None:
        self.stream, self.last, self.last_stamp, self.suspect, self.jump = stream, seq, publish_ns, False, jump
