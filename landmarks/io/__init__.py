"""Files in and out: images of any common kind (atomic output files), H.264 video with PyAV, and ``lsr landmarks``."""
