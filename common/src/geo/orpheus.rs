//! The Orpheus navigation-computer protocol (methods.md section 7). Being written.
