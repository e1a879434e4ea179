"""Part banks (issue 63): the person's own eyes and mouth, from every frame they give, one real exemplar per part
and frame moved into place over the synthesis.

* ``eye_bank``: both eyes of each frame, chosen by lid opening, gaze and head turn, the iris moved to the target's
  gaze;
* ``mouth_bank``: the lips, teeth and cavity of each frame, chosen by the lips' shape and head turn;
* ``hysteresis``: which entry a sequence shows, kept and cross-faded so parts do not pop;
* ``realism``: how far an output eye lies from the person's real ones.

numpy + OpenCV only (the inference core's rule): both runtimes share it.
"""
