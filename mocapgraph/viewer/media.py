"""The source video of a graph's video reader, for the page's video panel: which file, its rate, byte ranges.

A ``video_pose_reader`` publishes frame ``k`` of its clip as ``SkeletonPose.frame_number = k``, and the
clip's media time of that frame is ``k / fps`` (the container's rate, as :mod:`mocapgraph.video.frames`
times file frames). The viewer serves only the files the running graph's readers name (their
``file`` parameter in the launcher's manifest), never a path from a request, and in byte ranges
(a browser's video element seeks with HTTP Range requests), at most ``CHUNK`` bytes a response.
"""
from __future__ import annotations

import logging
import mimetypes
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

#: node types whose ``file`` is a video whose frames are their SkeletonPose frame numbers
VIDEO_READERS = ("video_pose_reader",)
CHUNK = 2 << 20          # bytes per ranged response
_RANGE = re.compile(r"^bytes=(\d*)-(\d*)$")


@dataclass
class SourceVideo:
    """One reader's clip: the node that reads it, the file, its frame rate."""

    node: str
    path: Path
    fps: float

    def hello(self) -> dict[str, Any]:
        """What the page is told (no path: the page asks by node name)."""
        return {"node": self.node, "name": self.path.name, "fps": self.fps}


def source_videos(manifest: dict[str, Any]) -> dict[str, SourceVideo]:
    """The graph's video readers' clips (node name -> SourceVideo); a clip that does not open is left out."""
    from ..bus.input_files import resolve_input_file

    out: dict[str, SourceVideo] = {}
    for node in manifest.get("nodes", []):
        if node.get("type") not in VIDEO_READERS:
            continue
        try:
            from ..video.frames import VideoFrames   # OpenCV: only for a graph with a video reader
            path = resolve_input_file(str(node.get("params", {}).get("file", "")))
            frames = VideoFrames(path)
            fps = float(frames.info.fps)
            frames.close()
        except Exception as exc:  # noqa: BLE001 - the reader reports its own file's faults; here one line
            log.warning("viewer: no source video for %s (%s)", node.get("name"), str(exc).splitlines()[0][:200])
            continue
        out[str(node["name"])] = SourceVideo(str(node["name"]), path.resolve(), fps)
    return out


def ranged(path: Path, range_header: str | None) -> tuple[int, dict[str, str], bytes]:
    """(status, headers, body) of a GET of ``path`` with an optional ``Range: bytes=a-b`` header:
    206 with at most CHUNK bytes, 416 for a range outside the file, 200 for a small whole file."""
    size = path.stat().st_size
    ctype = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    head = {"Content-Type": ctype, "Accept-Ranges": "bytes"}
    m = _RANGE.match((range_header or "").strip())
    if range_header is None or not m or not (m.group(1) or m.group(2)):
        if range_header is None and size <= CHUNK:
            return 200, head, path.read_bytes()
        m = _RANGE.match("bytes=0-")
    a, b = m.group(1), m.group(2)
    if a:
        start, end = int(a), int(b) if b else size - 1
    else:                                     # bytes=-N: the last N bytes
        start, end = max(0, size - int(b)), size - 1
    if start >= size or end < start:
        return 416, {**head, "Content-Range": f"bytes */{size}"}, b""
    end = min(end, size - 1, start + CHUNK - 1)
    with path.open("rb") as f:
        f.seek(start)
        body = f.read(end - start + 1)
    return 206, {**head, "Content-Range": f"bytes {start}-{end}/{size}"}, body
