"""The face as points: the iBUG-68 scheme, the mesh-to-68 mapping, expression measures and edits, and the landmark image."""
