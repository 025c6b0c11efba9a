"""The sequence-number rule: what a receiver concludes from one stream's numbers (loss, resend, restart).

Sequence numbers are per (topic, sender) and start at 1, so a sender that starts again (seq back
to 1) is a new stream, not loss; a number seen again, or a little lower than the last (within
DUPLICATE_WINDOW), is a latched resend or a repeat, to be dropped; a jump forward by k+1 means k
messages were lost. Anything else (a jump forward beyond MAX_GAP, a fall back beyond the window,
a restart that is not at 1) is an anomaly: a forged frame or a sender that restarted while we
missed its first messages. The receiver resynchronises to the new number and counts the anomaly,
neither as loss (a forged 2**63 is not 2**63 lost messages) nor as a duplicate (which would
silence the real stream until it passed the forged number).
"""
from __future__ import annotations

DUPLICATE = -1
RESTART = -2
ANOMALY = -3

#: more lost messages than this in one jump is not believed (over 4 h at 1 kHz)
MAX_GAP = 1 << 24
#: a number this much below the last one at most is a resend; further back is an anomaly
DUPLICATE_WINDOW = 4096


def sequence_gap(last: int, seq: int, same_stamp: bool = True) -> int:
    """Messages lost between ``last`` (0: none seen yet) and ``seq``; or DUPLICATE, RESTART, ANOMALY.

    Joining a running stream (first number > 1) is no loss: those messages were never ours.
    ``same_stamp``: whether the message carries the publish stamp of the last one. A resend is the
    same bytes; a restarted sender's latched value repeats the number (1) with a new stamp, and is
    a RESTART to deliver, not a duplicate to drop. RESTART and ANOMALY both mean: take ``seq`` as
    the new last number.
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
