//! Scan-to-map ICP SLAM with dynamic-point map maintenance.
