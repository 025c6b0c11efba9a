"""Video frames from a file or a camera device, with one-line errors for unusable inputs.

OpenCV (its FFmpeg backend) decodes; it comes with the ``video`` extra (mediapipe pulls
opencv-contrib-python). A file that does not open, opens with no decodable frame (an unknown
codec) or ends before its announced frame count is named in one line: :class:`VideoError` for
the first two, a ``truncated`` note for the last (the decoded frames are kept).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from ..formats.errors import FormatError

# FFmpeg and OpenCV print their own complaints on stderr: the one line of VideoError says it instead
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
os.environ.setdefault("OPENCV_LOG_LEVEL", "OFF")


class VideoError(FormatError):
    """A video file or camera that cannot be read (one line: name and fault)."""


class VideoUnavailable(RuntimeError):
    """The ``video`` extra (mediapipe, OpenCV) is not installed."""


def cv2_module():
    """OpenCV, or VideoUnavailable naming the extra to install."""
    try:
        import cv2
    except ImportError:
        raise VideoUnavailable("OpenCV is not installed: pip install 'mocapgraph[video]'") from None
    try:   # OpenCV's own warnings on stderr (a file it cannot open): VideoError says it in one line
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    except AttributeError:
        pass
    return cv2


@dataclass
class VideoInfo:
    """What a video source says about itself."""

    name: str
    width: int
    height: int
    fps: float
    frame_count: int            # announced by the container; -1 for a live camera
    notes: list[str] = field(default_factory=list)


def camera_index(source: str | int) -> int | None:
    """The device index of a camera source (``0``, ``"0"``, ``"camera:0"``), None for a file."""
    if isinstance(source, int):
        return source
    s = str(source)
    if s.startswith("camera:"):
        s = s[len("camera:"):]
    return int(s) if s.isdigit() else None


class VideoFrames:
    """Iterates (index, time_s, BGR uint8 [H, W, 3]) of a video file or a live camera.

    File time is index / fps (the container's rate); a camera's is the monotonic clock since open.
    After iteration, ``decoded`` is the number of frames read and ``info.notes`` says whether the
    file ended early.
    """

    def __init__(self, source: str | int | Path, *, width: int = 0, height: int = 0) -> None:
        cv2 = cv2_module()
        self.camera = camera_index(source) if not isinstance(source, Path) else None
        self.decoded = 0
        if self.camera is None:
            path = Path(source)
            if not path.is_file():
                raise VideoError(path, "no such video file")
            self.cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
            name = path.name
            if not self.cap.isOpened():
                raise VideoError(path, "cannot be opened as a video (not a video file, a corrupt one, or a "
                                       "container OpenCV's FFmpeg cannot read)")
        else:
            self.cap = cv2.VideoCapture(self.camera)
            name = f"camera:{self.camera}"
            if not self.cap.isOpened():
                raise VideoError(name, "cannot be opened (no such camera device, or busy)")
            self.cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)    # the newest frame, not one queued (where the backend can)
            if width and height:
                self.cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
                self.cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
        self.path = None if self.camera is not None else Path(source)
        fps = float(self.cap.get(cv2.CAP_PROP_FPS) or 0.0)
        count = -1 if self.camera is not None else int(self.cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        self.info = VideoInfo(name, int(self.cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
                              int(self.cap.get(cv2.CAP_PROP_FRAME_HEIGHT)), fps if fps > 0 else 30.0, count)
        if fps <= 0:
            self.info.notes.append("no frame rate in the file: 30 fps assumed")

    def __iter__(self) -> Iterator[tuple[int, float, np.ndarray]]:
        import time
        t0 = time.monotonic()
        while True:
            ok, frame = self.cap.read()
            if not ok or frame is None:
                break
            t = (time.monotonic() - t0) if self.camera is not None else self.decoded / self.info.fps
            yield self.decoded, t, frame
            self.decoded += 1
        self._finish()

    def _finish(self) -> None:
        if self.camera is not None:
            return
        if self.decoded == 0:
            raise VideoError(self.path, "no frame could be decoded (an unknown codec, or no video stream)")
        if self.info.frame_count > 0 and self.decoded < self.info.frame_count:
            self.info.notes.append(f"truncated: {self.decoded} of {self.info.frame_count} announced frames decoded")

    def close(self) -> None:
        self.cap.release()

    def __enter__(self) -> "VideoFrames":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
