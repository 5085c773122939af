//! Pure pursuit path following, velocity limits and the safety stop.
