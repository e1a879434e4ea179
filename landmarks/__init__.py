"""Landmarks toolkit: face detection and tracking (MediaPipe's detector and 468-point mesh on onnxruntime by
default, dlib's as an option), iBUG-68 points, smoothing, head pose, crop/paste-back, rasterisation and
retargeting.

numpy + OpenCV + onnxruntime (dlib only when asked for); no torch. Import the submodules you need
(``landmarks.detect.registry``, ``landmarks.shape.raster``, ...): nothing heavy loads here.
"""
