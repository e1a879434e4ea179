"""The face's moving parts after the synthesis: their windows, what shots cover of them, and the person's own parts.

* ``eyes/``: lids, irises, the driver's shut eyes, and the eye bank;
* ``mouth/``: the inside of an open mouth, the nearest shot's mouth, its opening, and the mouth bank;
* ``hysteresis`` and ``bank_rows``: what both banks share (which entry a sequence shows; rows bounded in memory).

numpy + OpenCV only (the inference core's rule): both runtimes share it.
"""
