"""The sequence-number rule: what a receiver concludes from one stream's numbers (loss, resend, restart).

Sequence numbers are per (topic, sender) and start at 1, so a sender that starts again (seq back
to 1, or lower than before) is a new stream, not loss; a number seen again is a latched resend
or a repeat, to be dropped; a jump forward by k+1 means k messages were lost.
"""
from __future__ import annotations

DUPLICATE = -1
RESTART = -2


def sequence_gap(last: int, seq: int, same_stamp: bool = True) -> int:
    """Messages lost between ``last`` (0: none seen yet) and ``seq``; or DUPLICATE, or RESTART.

    Joining a running stream (first number > 1) is no loss: those messages were never ours.
    ``same_stamp``: whether the message carries the publish stamp of the last one. A resend is the
    same bytes; a restarted sender's latched value repeats the number (1) with a new stamp, and is
    a RESTART to deliver, not a duplicate to drop.
    """
    if (seq == last and same_stamp) or (0 < seq < last and seq != 1):
        return DUPLICATE
    if seq <= last:
        return RESTART
    if last and seq > last + 1:
        return seq - last - 1
    return 0
