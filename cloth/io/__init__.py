"""I/O at the edge: OBJ meshes, Rerun recordings, run manifests and atomic file writes."""
