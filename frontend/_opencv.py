"""OpenCV's own bound on the images it decodes, set before OpenCV is first imported.

OpenCV reads ``OPENCV_IO_MAX_IMAGE_PIXELS`` once, when ``cv2`` loads (a static in
``imgcodecs/src/loadsave.cpp``), and refuses to allocate an image with more pixels; its default,
2^30, is a gigabyte of grey. The package's ``__init__`` imports this module before any module
that imports ``cv2``; a user's own earlier ``import cv2`` or setting is left alone, and the
header checks in :mod:`markergraph.frontend.decode` hold either way.
"""

from __future__ import annotations

import os

__all__ = ["MAX_IMAGE_PIXELS"]

# No camera a marker map is made with gives more: 8192 x 8192 is 64 MiB of grey, 128 MiB of
# 16-bit depth.
MAX_IMAGE_PIXELS = 8192 * 8192

os.environ.setdefault("OPENCV_IO_MAX_IMAGE_PIXELS", str(MAX_IMAGE_PIXELS))
