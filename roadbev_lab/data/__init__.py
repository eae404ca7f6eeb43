"""Real data and labels: KITTI and RSRD readers, LiDAR-made labels, labelling a recorded bag."""
