"""Landmarks toolkit: detection, tracking, smoothing, head pose, crop/paste-back,
rasterisation and retargeting of iBUG-68 facial landmarks.

numpy + OpenCV + dlib only; no torch. Import the submodules you need
(``landmarks.detect``, ``landmarks.raster``, ...): nothing heavy loads here.
"""
