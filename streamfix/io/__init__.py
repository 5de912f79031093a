"""File formats: readers and writers for motions (Kinect v2 CSV, BVH, C3D, recordings)."""
