//! Goal assignment, reachability floods, A* on the traversability grid, path smoothing.
