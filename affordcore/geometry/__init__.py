"""A room's geometry: clouds, gravity, voxel fields, the pose grid, skeletons and the features relating
them."""
