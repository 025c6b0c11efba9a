"""Duplicate marker labels made unique (suffix + note), the same way in every marker reader.

Why a suffix and not a refusal: a file with two points of one name (a Vicon label reused after a
gap split, two subjects' prefixes cut off, names truncated to a 4-character limit) still holds
good data, and refusing it would make the whole capture unusable over a naming slip. Why not
"the first wins": that throws a trajectory away without a word. So the first point keeps its
name (a layout matches it as before), every later one becomes ``<label>_2``, ``<label>_3``...
(a layout does not know that name, so it is reported as unplaced, never silently merged), and
a note names both point indices. Labels compare case-insensitively, as layout matching does.
"""
from __future__ import annotations


def unique_labels(labels: list[str], what: str = "point") -> tuple[list[str], list[str]]:
    """(labels with later duplicates suffixed ``_2``, ``_3``..., one note per renamed label).

    Indices in the notes are 0-based positions in ``labels`` (file order).
    """
    taken = {lab.lower() for lab in labels}
    first_at: dict[str, int] = {}
    count: dict[str, int] = {}
    out: list[str] = []
    notes: list[str] = []
    for k, lab in enumerate(labels):
        key = lab.lower()
        if key not in first_at:
            first_at[key] = k
            out.append(lab)
            continue
        n = count.get(key, 1)
        while True:
            n += 1
            new = f"{lab}_{n}"
            if new.lower() not in taken:
                break
        count[key] = n
        taken.add(new.lower())
        out.append(new)
        notes.append(f"duplicate label {lab!r}: {what}s {first_at[key]} and {k} share it; "
                     f"{what} {k} renamed {new!r}")
    return out, notes
