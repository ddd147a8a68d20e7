"""The data every stage passes along: the survey (pings + geometry), voxel grids and volumes, the pulse, operator edits."""
