"""What a job writes for people and viewers: PLY/GLB/NPY exports and the run report."""
