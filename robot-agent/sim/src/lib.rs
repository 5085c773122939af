//! The built-in simulated world: terrain, obstacles, walkers, VLP-16 and depth-camera ray casting, differential-drive plant, odometry and GNSS.
