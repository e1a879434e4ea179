"""The scene around the face: compositing the re-enacted face into a frame, and the person's matte."""
