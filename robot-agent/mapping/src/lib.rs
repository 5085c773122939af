//! 2.5D traversability grid from the SLAM map cloud, and map tiles.
