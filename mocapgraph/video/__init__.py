"""Markerless capture from video: frames, a CPU pose estimator, multi-camera triangulation.

Pure code (no bus): :mod:`.frames` decodes a video file or a camera (OpenCV), :mod:`.estimator`
runs the pose estimator (mediapipe, the ``video`` extra) and turns its 33 landmarks into the
Kinect v2 skeleton, :mod:`.multiview` reads camera calibrations and triangulates several
cameras' detections into one skeleton, :mod:`.sync` finds cameras' time offsets, :mod:`.live`
groups live cameras' frames by capture time. The nodes ``video_pose_reader``, ``multiview_pose``,
``video_camera_reader`` and ``multiview_live`` put them on the bus.
"""
