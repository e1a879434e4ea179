"""Image warps by landmarks (numpy + OpenCV): the thin-plate spline and the piecewise-affine warp over the face mesh."""
