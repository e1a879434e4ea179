"""How a face moves: head pose (68 points, or the mesh as a rotation), cross-identity retargeting, and temporal smoothing."""
